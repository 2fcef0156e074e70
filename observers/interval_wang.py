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
16 vertex pairs (Theorem 5, :mod:`observers.interval_wang_design`), so ``x- <= x <= x+`` is kept.

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

Variants: ``interval_wang`` (fresh Theorem 5 design, certified) and ``interval_wang_printed`` (the
gain printed in (4.47), which is not Metzler at any vertex pair: it runs with the same equations,
``certified = False`` and the reason in the run's status; its bounds carry no guarantee).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from harness.errors import InputError
from observers.base import ScalarLoopObserver
from observers.bicycle import axle_stiffness, expm2_zoh, slip_model_terms
from observers.lmi import DesignResult, usable_gains
from observers.registry import register

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

    def _compute_design(self) -> DesignResult:
        from observers.interval_wang_design import design_for
        return design_for(self)

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
        self._have_delta = False
        self._derive()

    def _fallback(self, delta: float) -> None:
        b = self._ab
        self._z = [b - delta, b, -b - delta, -b]

    def _advance(self, t_s: float, y: list[float]) -> None:
        h = self._tick(t_s, y)
        delta, r, vx, ax = self._u
        if delta != delta:
            self._derive()
            return
        z = self._z
        if not self._have_delta:
            z[0] -= delta
            z[2] -= delta
            self._have_delta = True
        tl = self._t_last
        if (r != r or vx != vx or ax != ax or t_s - min(tl[0], tl[1], tl[2]) > self._hold
                or vx < self._vlo or vx > self._vhi):
            self._fallback(delta)
        elif h > 0.0:
            self._integrate(h, delta, r, vx, ax)
        self._derive()

    def _integrate(self, h: float, delta: float, r: float, vx: float, ax: float) -> None:
        l0a, l0b, l1a, l1b, l2a, l2b = self._L if self._L is not None else self.gains()
        A, B, lip = self._A1, self._bf0, self._lip
        vm0, vm1 = self._vm
        vp0, vp1 = self._vp
        ac = self._alo if ax < self._alo else (self._ahi if ax > self._ahi else ax)
        e1 = 1.0 / vx
        e2 = ac * e1
        la = l0a + e1 * l1a + e2 * l2a
        lb = l0b + e1 * l1b + e2 * l2b
        # A_L(eta, xi0) = A(eta, xi0) - L(eta) [1, -1]
        a11, a12 = e1 * A[0] - e2 - la, e1 * A[1] + la
        a21, a22 = e1 * A[2] - lb, e1 * A[3] - e2 + lb
        yp = -(self._lf + self._lr) * r / (vx if vx > self._vmin else self._vmin)  # y - delta
        g1 = e1 * A[0] * delta + r + la * yp
        g2 = e1 * A[2] * delta + r + lb * yp
        k11, k12, k21, k22 = e1 * lip[0], e1 * lip[1], e1 * lip[2], e1 * lip[3]
        # bounded input errors enter the error dynamics as (dr) (1, 1) + L(eta) d(y - delta)
        n1 = self._nr + abs(la) * self._ny
        n2 = self._nr + abs(lb) * self._ny
        n = 1
        while True:
            hs = h / n
            E, G = expm2_zoh(a11, a12, a21, a22, hs)
            q11, q12, q21, q22 = abs(G[0]), abs(G[1]), abs(G[2]), abs(G[3])
            # M = |G| Lambda; (I - M)^-1 >= 0 needs m11 < 1, m22 < 1 and det > 0
            m11, m12 = q11 * k11 + q12 * k21, q11 * k12 + q12 * k22
            m21, m22 = q21 * k11 + q22 * k21, q21 * k12 + q22 * k22
            det = (1.0 - m11) * (1.0 - m22) - m12 * m21
            if (m11 < 1.0 and m22 < 1.0 and det > 0.0) or n >= 1024:
                break
            n *= 2
        c11, c12, c21, c22 = (1.0 - m22) / det, m12 / det, m21 / det, (1.0 - m11) / det
        z = self._z
        for _ in range(n):
            out: list[float] = []
            for up in (True, False):
                s1, s2 = (z[0], z[1]) if up else (z[2], z[3])
                af, ar = s1 + delta, s2
                # Lemma 12 with T = eta1 Bf0 diag(alpha): row sums of max / min over v in [v-, v+]
                t11, t12, t21, t22 = e1 * B[0] * af, e1 * B[1] * ar, e1 * B[2] * af, e1 * B[3] * ar
                if up:
                    w1 = (t11 * vp0 if t11 >= 0.0 else t11 * vm0) + (t12 * vp1 if t12 >= 0.0 else t12 * vm1)
                    w2 = (t21 * vp0 if t21 >= 0.0 else t21 * vm0) + (t22 * vp1 if t22 >= 0.0 else t22 * vm1)
                else:
                    w1 = (t11 * vm0 if t11 >= 0.0 else t11 * vp0) + (t12 * vm1 if t12 >= 0.0 else t12 * vp1)
                    w2 = (t21 * vm0 if t21 >= 0.0 else t21 * vp0) + (t22 * vm1 if t22 >= 0.0 else t22 * vp1)
                f1 = abs(a11 * s1 + a12 * s2 + g1 + w1) + n1
                f2 = abs(a21 * s1 + a22 * s2 + g2 + w2) + n2
                p1, p2 = q11 * f1 + q12 * f2, q21 * f1 + q22 * f2
                d1, d2 = c11 * p1 + c12 * p2, c21 * p1 + c22 * p2   # drift bound D over the step
                i1, i2 = k11 * d1 + k12 * d2, k21 * d1 + k22 * d2
                if up:
                    u1, u2 = g1 + w1 + i1 + n1, g2 + w2 + i2 + n2
                else:
                    u1, u2 = g1 + w1 - i1 - n1, g2 + w2 - i2 - n2
                out += [E[0] * s1 + E[1] * s2 + G[0] * u1 + G[1] * u2,
                        E[2] * s1 + E[3] * s2 + G[2] * u1 + G[3] * u2]
            z = out
        self._z = z

    def _derive(self) -> None:
        """Slip bounds in alpha coordinates and the derived v_y, beta bounds; midpoints as estimates."""
        delta, r, vx, _ = self._u
        zu1, zu2, zl1, zl2 = self._z
        d = delta if self._have_delta else 0.0
        afu, afl, aru, arl = zu1 + d, zl1 + d, zu2, zl2
        if self._have_delta and r == r and vx == vx:
            v = vx if vx > self._vmin else self._vmin
            lim = 1.5
            fl = v * math.tan(max(-lim, min(lim, d - afu))) - self._lf * r
            fh = v * math.tan(max(-lim, min(lim, d - afl))) - self._lf * r
            rl = self._lr * r - v * math.tan(max(-lim, min(lim, aru)))
            rh = self._lr * r - v * math.tan(max(-lim, min(lim, arl)))
            vyl, vyh = max(fl, rl), min(fh, rh)
            if vyl > vyh:  # disjoint: inclusion already lost somewhere; report the hull
                vyl, vyh = min(fl, rl), max(fh, rh)
            bl, bh = math.atan(vyl / v), math.atan(vyh / v)
        else:
            vyl, vyh, bl, bh = -self._vhi, self._vhi, -0.5 * math.pi, 0.5 * math.pi
        self._lo = [afl, arl, bl, vyl]
        self._hi = [afu, aru, bh, vyh]
        self._x = [0.5 * (afl + afu), 0.5 * (arl + aru), 0.5 * (bl + bh), 0.5 * (vyl + vyh)]

    def _values(self) -> list[float]:
        return self._x

    def _bounds(self) -> tuple[list[float], list[float]]:
        return self._lo, self._hi


@register
class IntervalWangPrinted(IntervalWang):
    """Interval observer with the gain printed in (4.47): not Metzler, runs uncertified."""

    name = "interval_wang_printed"
    citation = "Y. Wang, PhD dissertation, Auburn University 2014, eq. (4.47) (printed interval observer gain)"
    variant = "printed"
    default_options = dict(_COMMON)
