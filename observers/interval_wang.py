r"""Gain-scheduled (LPV) interval observer of the slip angles (Y. Wang 2014, ch. 4).

Y. Wang, *Robust Gain-Scheduled Observer Design with Application to Vehicle State Estimation*, PhD
dissertation, Auburn University, 2014, ch. 4 (Theorems 3-5, Lemmas 11-14, eqs. (4.7)-(4.47)).

Uncertain model (4.36)-(4.43), ``x = (alpha_f, alpha_r)``, measured ``eta = (1/v_x, a_x/v_x)``,
unmeasured axle stiffness ``xi = (C_f, C_r)`` in a box ``[xi_lo, xi_hi]`` containing the nominal
``xi0`` (the vehicle's axle stiffness):

.. math::

    \dot x = A(\eta, \xi) x + B(\eta) (\delta, \dot\delta, r)^T,\quad
    A(\eta, \xi) = \eta_1 B_{f0} \mathrm{diag}(\xi) - \eta_2 I,\quad
    y = \delta - (l_f + l_r) r / v_x = [1, -1] x.

Observer (Theorem 4, (4.19)-(4.26)): two copies

.. math::

    \dot{\hat x}^\pm = A(\eta, \xi_0)\hat x^\pm + B(\eta) u + L(\eta)(y - C\hat x^\pm) + w^\pm,\quad
    L(\eta) = L_0 + \eta_1 L_1 + \eta_2 L_2,

with ``w`` from Lemma 12 (4.13)-(4.17): ``[A(eta, xi) - A(eta, xi0)] x = T(x) v``,
``T(x) = eta1 Bf0 diag(x)``, ``v = xi - xi0 in [v-, v+]``, and ``w+ = T+ v+ - T- v-`` at ``x = x+``,
``w- = T+ v- - T- v+`` at ``x = x-`` (``T+ = max(0, T)``, ``T- = T+ - T``). The upper error
``e+ = x+ - x`` obeys ``e+' = A_L(eta, xi) e+ + (w+ - T(x+) v)`` with a nonnegative input, and the
gains make ``A_L = A(eta, xi) - L(eta) C`` Metzler and Hurwitz with a diagonal Lyapunov matrix at all
16 vertex pairs (Theorem 5, :mod:`roadtruth.observers.interval_wang_design`), so ``x- <= x <= x+`` is kept.

*No steering derivative* (a change of variable; the printed model needs ``delta'``): the copies run on ``z1 = alpha_f - delta``; the bounds of
``alpha_f`` are those of ``z1`` shifted by the known ``delta``; ``w`` is computed from the ``alpha``
bounds, since the uncertain term multiplies ``alpha`` (it also covers the ``C_f delta`` input term of
the ``z`` model).

*Discretisation.* Exact ZOH of the common linear part ``A_L(eta, xi0)`` (one closed-form 2x2
exponential per step, shared by both copies), inputs held over the step. ``w`` is evaluated at the
start of the step and **inflated by a rigorous bound of its change within the step**: ``w+`` is
Lipschitz in ``x`` with the nonnegative matrix ``Lambda = eta1 |Bf0| diag(max|v-|, |v+|)``, and for a
Metzler ``A_L`` the drift obeys ``|x(t) - x_k| <= G(h) |f0 + Lambda D|`` (``G = int_0^h e^{A_L s} ds
>= 0``, ``f0`` the initial derivative), so ``D = (I - G Lambda)^-1 G |f0|``; ``+Lambda D`` is added to
``w+`` and subtracted from ``w-``. With inputs and ``eta`` constant over each step the discrete
bounds are therefore exactly those of the continuous-time theorem. What remains unguaranteed is the
intersample variation of sampled inputs (``r``, ``v_x`` move within a step), measurement errors
(the theorem assumes exact ``delta, r, v_x, a_x``) and any model mismatch (nonlinear tires, load
transfer, roll): this is what the MuJoCo runs measure.

*Input-error margins* (our extension, not in the dissertation): with ``|dr| <= nu_r``
(``yaw_rate_error_bound_radps``) and ``|d(y - delta)| <= nu_y`` (``y_error_bound_rad``) the error
dynamics receive the extra input ``dr (1, 1)^T + L(eta) d(y - delta)``; adding
``nu_r + |L_i(eta)| nu_y`` to ``w+_i`` and subtracting it from ``w-_i`` restores the inclusion for
bounded sensor errors or intersample variation, at the price of width. Both default to 0 (the
theorem as printed).

*Guard rails.* Without fresh ``delta, r, v_x`` for ``hold_s`` or with ``v_x`` outside the design
range, there is no certified prediction (``A(eta, xi)`` itself is not Metzler, so ``L = 0`` breaks
the ordering): the bounds fall back to the a-priori bracket ``|alpha| <= alpha_bound_rad`` and the
observer restarts from it. ``a_x`` is clamped into its design range.

Derived bounds (interval arithmetic, sound given exact ``delta, r, v_x``): from the CONTRACT slip
definitions, ``v_y = v_x tan(delta - alpha_f) - l_f r`` (decreasing in ``alpha_f``) and
``v_y = l_r r - v_x tan(alpha_r)`` (decreasing in ``alpha_r``); each slip interval gives a ``v_y``
interval, the two are intersected (their hull if they are disjoint, which only a broken slip
inclusion can cause), and ``beta = atan(v_y / v_x)`` is monotone. Point estimates are midpoints.

*Compiled.* ``step()`` and ``run()`` call the same numba kernel (:mod:`roadtruth.observers.interval_wang_loop`),
with one sample or the whole log, so they agree bit for bit.

Variants: ``interval_wang`` (fresh Theorem 5 design, certified) and ``interval_wang_printed`` (the
gain printed in (4.47), which is not Metzler at any vertex pair: it runs with the same equations,
``certified = False`` and the reason in the run's status; its bounds carry no guarantee).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver, StepOutput
from roadtruth.observers.bicycle import axle_stiffness, slip_model_terms
from roadtruth.observers.interval_wang_loop import N_PAR, derive_bounds, interval_run
from roadtruth.observers.lmi import DesignResult, usable_gains
from roadtruth.observers.registry import register

KMH = 1.0 / 3.6
_COMMON: dict[str, Any] = {
    "vx_range_mps": (15.0 * KMH, 150.0 * KMH),  # design domain (4.46)
    "ax_range_mps2": (-8.0, 8.0),
    "stiffness_uncertainty": 0.2,   # C in [(1 - u) C0, (1 + u) C0] unless a range is given
    "cf_range_Npr": None,           # explicit (lo, hi) front axle stiffness box [N/rad]
    "cr_range_Npr": None,           # explicit (lo, hi) rear axle stiffness box [N/rad]
    "alpha_bound_rad": 0.2,         # a-priori |alpha| bound: initial bracket and fallback
    "hold_s": 0.1,                  # inputs older than this: no correction, fall back to the bracket
    "vx_min_output_mps": 1.0,       # floor of v_x in the pseudo-output and derived v_y
    "y_error_bound_rad": 0.0,       # bound on the error of y - delta = -(l_f + l_r) r / v_x (noise, sampling)
    "yaw_rate_error_bound_radps": 0.0,  # bound on the error of r in the input term
    "use_cache": True,
}



def _pair(value: Any, field: str) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in value)
    except (TypeError, ValueError):
        raise InputError(f"expected a pair (lo, hi), got {value!r}", field=field) from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise InputError(f"expected finite lo <= hi, got {value!r}", field=field)
    return lo, hi


@register
class IntervalWang(ScalarLoopObserver):
    """LPV interval observer of (alpha_f, alpha_r) under uncertain axle stiffness, fresh Theorem 5 design."""

    name = "interval_wang"
    citation = "Y. Wang, PhD dissertation, Auburn University 2014, ch. 4, Theorems 4-5, eqs. (4.19)-(4.35)"
    inputs = ("delta_rad", "yaw_rate_radps", "vx_mps", "ax_mps2")
    states = ("alpha_f_rad", "alpha_r_rad", "beta_rad", "vy_mps")
    has_bounds = True
    variant = "fresh"
    default_options = {**_COMMON, "gamma_slack": 1.01}

    def _setup(self) -> None:
        v, o, f = self.vehicle, self.options, f"observer {self.name}"
        cf0, cr0 = axle_stiffness(v)
        self._vlo, self._vhi = _pair(o["vx_range_mps"], f + " vx_range_mps")
        self._alo, self._ahi = _pair(o["ax_range_mps2"], f + " ax_range_mps2")
        if self._vlo <= 0.0:
            raise InputError(f"vx_range_mps must be positive, got {o['vx_range_mps']!r}", field=f)
        u = float(o["stiffness_uncertainty"])
        if not 0.0 <= u < 1.0:
            raise InputError(f"stiffness_uncertainty must be in [0, 1), got {u!r}", field=f)
        ranges = []
        for key, c0 in (("cf_range_Npr", cf0), ("cr_range_Npr", cr0)):
            lo, hi = ((1.0 - u) * c0, (1.0 + u) * c0) if o[key] is None else _pair(o[key], f"{f} {key}")
            if not 0.0 < lo <= c0 <= hi:
                raise InputError(f"{key} {o[key]!r} must be positive and contain the vehicle's {c0:.6g} N/rad",
                                 field=f)
            ranges.append((lo, hi))
        self.cf_range, self.cr_range = ranges
        self._ab = float(o["alpha_bound_rad"])
        if not self._ab > 0.0:
            raise InputError(f"alpha_bound_rad must be > 0, got {o['alpha_bound_rad']!r}", field=f)
        A1, bf0 = slip_model_terms(v)
        self._A1 = tuple(float(a) for a in A1.reshape(-1))   # Bf0 diag(xi0), (4.36) at the nominal
        self._bf0 = tuple(float(a) for a in bf0.reshape(-1))
        self._vm = (self.cf_range[0] - cf0, self.cr_range[0] - cr0)   # v- = xi_lo - xi0  (<= 0)
        self._vp = (self.cf_range[1] - cf0, self.cr_range[1] - cr0)   # v+ = xi_hi - xi0  (>= 0)
        vmax = (max(-self._vm[0], self._vp[0]), max(-self._vm[1], self._vp[1]))
        # Lipschitz matrix of w+- in alpha, divided by eta1.
        self._lip = tuple(abs(self._bf0[2 * i + j]) * vmax[j] for i in range(2) for j in range(2))
        self._lf, self._lr = v.lf_m, v.lr_m
        self._hold = float(o["hold_s"])
        self._vmin = float(o["vx_min_output_mps"])
        self._ny = float(o["y_error_bound_rad"])
        self._nr = float(o["yaw_rate_error_bound_radps"])
        if not (self._ny >= 0.0 and self._nr >= 0.0):
            raise InputError("y_error_bound_rad and yaw_rate_error_bound_radps must be >= 0", field=f)
        self._L: tuple[float, ...] | None = None
        # the kernel's constants (roadtruth.observers.interval_wang_loop); gains filled in when first needed
        self._par = np.array([0.0] * 6 + [*self._A1, *self._bf0, *self._lip, *self._vm, *self._vp, self._vlo,
                              self._vhi, self._alo, self._ahi, self._ab, self._hold, self._vmin, self._ny,
                              self._nr, self._lf, self._lr])
        assert self._par.shape == (N_PAR,)
        self._par_has_gains = False

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.interval_wang_design import design_for
        return design_for(self.design_request({"cf_range": tuple(self.cf_range), "cr_range": tuple(self.cr_range)}))

    def gains(self) -> tuple[float, ...]:
        """``(L0, L1, L2)`` flattened to 6 floats; raises :class:`DesignFailed` without usable gains."""
        if self._L is None:
            self._L = usable_gains(self.name, self.design(), ("L0", "L1", "L2"))
        return self._L

    # internal state: [upper_1, upper_2, lower_1, lower_2] with component 1 = alpha_f until the first
    # delta, then z1 = alpha_f - delta; component 2 = alpha_r.
    def _initial_state(self) -> list[float]:
        b = self._ab
        return [b, b, -b, -b]

    def _internal_from_x0(self, z: list[float], x0: Mapping[str, float]) -> list[float]:
        """``x0`` may set ``alpha_f_rad`` / ``alpha_r_rad``: the bracket becomes ``x0 +- alpha_bound_rad``."""
        for key, value in x0.items():
            if key not in ("alpha_f_rad", "alpha_r_rad"):
                raise InputError(f"cannot initialise state {key!r} (settable: alpha_f_rad, alpha_r_rad)",
                                 field=f"observer {self.name} x0")
            i = 0 if key == "alpha_f_rad" else 1
            z[i], z[i + 2] = float(value) + self._ab, float(value) - self._ab
        return z

    def _reset_extra(self) -> None:
        self._ku = np.full(4, math.nan)       # held (delta, r, v_x, a_x)
        self._ktl = np.full(4, -math.inf)     # their arrival times [s]
        self._kz = np.array(self._z, dtype=float)
        self._ks = np.array([self._t, 0.0])   # (t_cur, have_delta)
        x, lo, hi = np.empty(4), np.empty(4), np.empty(4)
        derive_bounds(self._ku, self._kz, False, self._par, x, lo, hi)   # the initial bracket
        self._last = (x, lo, hi)

    def _compiled(self, t: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance through ``t`` (n,) [s], ``Y`` (n, 4) in the shared kernel; (x, lo, hi), each (n, 4)."""
        if not self._par_has_gains:
            self._par[:6] = self.gains()   # a failed design raises here, on the first sample
            self._par_has_gains = True
        n = t.shape[0]
        x, lo, hi = np.empty((n, 4)), np.empty((n, 4)), np.empty((n, 4))
        interval_run(t, Y, self._ku, self._ktl, self._kz, self._ks, self._par, x, lo, hi)
        if n:
            self._last = (x[-1].copy(), lo[-1].copy(), hi[-1].copy())
        return x, lo, hi

    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        """One sample through the compiled kernel (the same code ``run()`` loops in, so the same bits)."""
        x, lo, hi = self._compiled(np.array([float(t_s)]),
                                   np.ascontiguousarray(np.asarray(y, dtype=float).reshape(1, 4)))
        return StepOutput(x[0], lo[0], hi[0])

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        """Reset at ``t[0]`` and advance through the whole log in one compiled call (equal to stepping)."""
        t = np.ascontiguousarray(t, dtype=float)
        Y = np.ascontiguousarray(np.asarray(Y, dtype=float).reshape(len(t), len(self.inputs)))
        if len(t):
            self.reset(float(t[0]), x0)
        x, lo, hi = self._compiled(t, Y)
        return EstimateTrack(self.name, tuple(self.states), t, x, lo, hi)

    def _advance(self, t_s: float, y: list[float]) -> None:
        self.step(t_s, np.array(y, dtype=float))

    def _values(self) -> list[float]:
        return self._last[0].tolist()

    def _bounds(self) -> tuple[list[float], list[float]]:
        return self._last[1].tolist(), self._last[2].tolist()


@register
class IntervalWangPrinted(IntervalWang):
    """Interval observer with the gain printed in (4.47): not Metzler, runs uncertified."""

    name = "interval_wang_printed"
    citation = "Y. Wang, PhD dissertation, Auburn University 2014, eq. (4.47) (printed interval observer gain)"
    variant = "printed"
    default_options = dict(_COMMON)
