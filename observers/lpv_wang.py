r"""Polytopic LPV Luenberger slip-angle observer (Y. Wang 2014, ch. 3).

Model (3.18)-(3.21), states ``x = (alpha_f, alpha_r)``, scheduled on ``theta1 = 1/v_x``,
``theta2 = a_x/v_x``:

.. math::

    \dot x = (\theta_1 A_1 - \theta_2 I) x + (B_0 + \theta_2 B_2)(\delta, \dot\delta, r)^T,\quad
    y = \delta - (l_f + l_r) r / v_x = [1, -1] x,

``A1 = Bf0 diag(C_f, C_r)`` (:func:`roadtruth.observers.bicycle.slip_model_terms`). Observer (3.22)-(3.23):
``x' = A(theta) x + B(theta) u + L(theta)(y - C x)``, ``L(theta) = L0 + theta1 L1 + theta2 L2``.

*No steering derivative* (a change of variable; the printed model needs ``delta'``): with ``z1 = alpha_f - delta`` the model becomes
``z' = A(theta) z + theta1 A1[:, 0] delta + (1, 1)^T r`` and ``y - delta = z1 - alpha_r``; the
error dynamics, hence the LMIs and the gains, are unchanged. ``alpha_f = z1 + delta``.

Derived outputs. From the CONTRACT definitions ``tan(delta - alpha_f) = (v_y + l_f r)/v_x`` and
``tan(-alpha_r) = (v_y - l_r r)/v_x``; each gives ``v_y``; the estimate is their mean,
``v_y = [v_x tan(delta - alpha_f) - l_f r - v_x tan(alpha_r) + l_r r] / 2``, ``beta = atan2(v_y, v_x)``.

Variants: ``lpv_wang`` (nominal 4-vertex design (3.27) **with a decay rate sigma**, since L = 0
already satisfies the bare feasibility LMI), ``lpv_wang_hinf`` (robust H-infinity (3.43) on the
16 vertices of Lemma 10), and the dissertation's printed gains ``lpv_wang_printed`` /
``lpv_wang_hinf_printed``, which go through the same certification. Design code: ``lpv_wang_design``. The robust H2 and
unstructured observers of sec. 3.2.3 are in :mod:`roadtruth.observers.lpv_wang_robust`.

*Compiled.* ``step()`` and ``run()`` of every variant (these and the robust ones) call the same numba
kernel (:mod:`roadtruth.observers.lpv_wang_loop`), with one sample or the whole log, so they agree bit
for bit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver, StepOutput
from roadtruth.observers.bicycle import slip_model_terms
from roadtruth.observers.lmi import DesignResult, usable_gains
from roadtruth.observers.lpv_wang_loop import LUENBERGER, lpv_run, parameters, set_gains
from roadtruth.observers.registry import register

KMH = 1.0 / 3.6
_COMMON: dict[str, Any] = {
    "vx_range_mps": (15.0 * KMH, 150.0 * KMH),   # design domain (3.67); v_x is clamped into it
    "ax_range_mps2": (-8.0, 8.0),
    "hold_s": 0.1,             # correct only while delta, r, v_x are younger than this [s]
    "vx_min_output_mps": 1.0,  # floor of v_x in the pseudo-output and derived v_y
    # (eps1, eps2): schedule on v_m = (1 + eps1) v_x and a_m = (1 + eps2) a_x, the multiplicative
    # scheduling errors of (3.68)-(3.70); y keeps the measured v_x, as in the error model (3.34).
    "scheduling_error": (0.0, 0.0),
    "use_cache": True,
}



def scheduling_error(value: Any, field: str) -> tuple[float, float]:
    """Validate the ``scheduling_error`` option: two finite factors in (-1, 1)."""
    from roadtruth.harness.errors import InputError
    try:
        e1, e2 = (float(x) for x in value)
    except (TypeError, ValueError):
        raise InputError(f"scheduling_error must be a pair (eps1, eps2), got {value!r}", field=field) from None
    if not (-1.0 < e1 < 1.0 and -1.0 < e2 < 1.0):
        raise InputError(f"scheduling_error factors must lie in (-1, 1), got {value!r}", field=field)
    return e1, e2


@register
class LPVWang(ScalarLoopObserver):
    """Polytopic LPV Luenberger slip-angle observer, nominal 4-vertex design with decay rate sigma."""

    name = "lpv_wang"
    citation = "Y. Wang, PhD dissertation, Auburn University 2014, ch. 3, eqs. (3.19)-(3.28)"
    inputs = ("delta_rad", "yaw_rate_radps", "vx_mps", "ax_mps2")
    states = ("alpha_f_rad", "alpha_r_rad", "beta_rad", "vy_mps")
    variant = "nominal"
    structure = LUENBERGER   # the kernel's observer form (lpv_wang_loop)
    default_options = {**_COMMON, "decay_rate_radps": None, "decay_fraction": 0.9, "max_gain_per_s": 50.0}

    def _setup(self) -> None:
        v = self.vehicle
        A1, _ = slip_model_terms(v)
        self._A1 = tuple(float(a) for a in A1.reshape(-1))
        self._lf, self._lr = v.lf_m, v.lr_m
        self._vlo, self._vhi = (float(x) for x in self.options["vx_range_mps"])
        self._alo, self._ahi = (float(x) for x in self.options["ax_range_mps2"])
        if not (0.0 < self._vlo < self._vhi and self._alo <= self._ahi):
            from roadtruth.harness.errors import InputError
            raise InputError(f"bad design domain v {self.options['vx_range_mps']}, a {self.options['ax_range_mps2']}",
                             field=f"observer {self.name}")
        self._hold = float(self.options["hold_s"])
        self._vmin = float(self.options["vx_min_output_mps"])
        self._eps1, self._eps2 = scheduling_error(self.options["scheduling_error"], f"observer {self.name}")
        self._L: tuple[float, ...] | None = None
        # the kernel's constants (roadtruth.observers.lpv_wang_loop); gains filled in when first needed
        self._par = parameters(self.structure, self._A1, self._lf, self._lr, (self._vlo, self._vhi),
                               (self._alo, self._ahi), self._hold, self._vmin, (self._eps1, self._eps2))
        self._par_has_gains = False

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.lpv_wang_design import design_for
        return design_for(self.design_request())

    def gains(self) -> tuple[float, ...]:
        """``(L0, L1, L2)`` flattened to 6 floats; raises :class:`DesignFailed` without usable gains."""
        if self._L is None:
            self._L = usable_gains(self.name, self.design(), ("L0", "L1", "L2"))
        return self._L

    # internal state: [alpha_f, alpha_r] until the first delta, then [z1 = alpha_f - delta, alpha_r]
    def _initial_state(self) -> list[float]:
        return [0.0, 0.0]

    def _reset_extra(self) -> None:
        self._ku = np.full(4, math.nan)       # held (delta, r, v_x, a_x)
        self._ktl = np.full(4, -math.inf)     # their arrival times [s]
        self._kz = np.array(self._z, dtype=float)
        self._ks = np.array([self._t, 0.0])   # (t_cur, have_delta)
        self._last = np.array([self._kz[0], self._kz[1], 0.0, 0.0])

    def _compiled(self, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Advance through ``t`` (n,) [s], ``Y`` (n, 4) in the shared kernel; the estimates (n, 4)."""
        n = t.shape[0]
        if n and not self._par_has_gains:
            set_gains(self._par, self.gains())   # a failed design raises here, on the first sample
            self._par_has_gains = True
        x = np.empty((n, 4))
        lpv_run(t, Y, self._ku, self._ktl, self._kz, self._ks, self._par, x)
        if n:
            self._last = x[-1].copy()
        return x

    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        """One sample through the compiled kernel (the same code ``run()`` loops in, so the same bits)."""
        x = self._compiled(np.array([float(t_s)]), np.ascontiguousarray(np.asarray(y, dtype=float).reshape(1, 4)))
        return StepOutput(x[0])

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        """Reset at ``t[0]`` and advance through the whole log in one compiled call (equal to stepping)."""
        t = np.ascontiguousarray(t, dtype=float)
        Y = np.ascontiguousarray(np.asarray(Y, dtype=float).reshape(len(t), len(self.inputs)))
        if len(t):
            self.reset(float(t[0]), x0)
        return EstimateTrack(self.name, tuple(self.states), t, self._compiled(t, Y))

    def _advance(self, t_s: float, y: list[float]) -> None:
        self.step(t_s, np.array(y, dtype=float))

    def _values(self) -> list[float]:
        return self._last.tolist()


@register
class LPVWangHinf(LPVWang):
    """Robust H-infinity LPV Luenberger slip-angle observer (3.43), 16 vertices (Lemma 10)."""

    name = "lpv_wang_hinf"
    citation = "Y. Wang, PhD dissertation, Auburn University 2014, ch. 3, eq. (3.43), Lemma 10"
    variant = "hinf"
    default_options = {**_COMMON, "eps1_range": (-0.1, 0.1), "eps2_range": (-0.2, 0.2), "gamma_slack": 1.01}


@register
class LPVWangPrinted(LPVWang):
    """Nominal LPV slip-angle observer with the gains as printed in the dissertation (sec. 3.3)."""

    name = "lpv_wang_printed"
    citation = "Y. Wang, PhD dissertation, Auburn University 2014, sec. 3.3 (printed nominal gains)"
    variant = "nominal_printed"
    default_options = dict(_COMMON)


@register
class LPVWangHinfPrinted(LPVWang):
    """H-infinity LPV slip-angle observer with the gains as printed in the dissertation (sec. 3.3)."""

    name = "lpv_wang_hinf_printed"
    citation = "Y. Wang, PhD dissertation, Auburn University 2014, sec. 3.3 (printed H-infinity gains)"
    variant = "hinf_printed"
    default_options = {**_COMMON, "eps1_range": (-0.1, 0.1), "eps2_range": (-0.2, 0.2)}
