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
"""

from __future__ import annotations

import math
from typing import Any

from roadtruth.observers.base import ScalarLoopObserver
from roadtruth.observers.bicycle import expm2_zoh, slip_model_terms
from roadtruth.observers.lmi import DesignResult, usable_gains
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
        self._have_delta = False

    def _advance(self, t_s: float, y: list[float]) -> None:
        h = self._tick(t_s, y)
        delta, r, vx, ax = self._u
        if delta != delta:
            return
        z = self._z
        if not self._have_delta:
            z[0] -= delta
            self._have_delta = True
        if h <= 0.0 or r != r or vx != vx or ax != ax:
            return
        l0a, l0b, l1a, l1b, l2a, l2b = self._L if self._L is not None else self.gains()
        A = self._A1
        vc, ac = self._scheduling(vx, ax)
        th1 = 1.0 / vc
        th2 = ac * th1
        a11, a12, a21, a22 = th1 * A[0] - th2, th1 * A[1], th1 * A[2], th1 * A[3] - th2
        g1 = th1 * A[0] * delta + r
        g2 = th1 * A[2] * delta + r
        tl = self._t_last
        if t_s - min(tl[0], tl[1], tl[2]) <= self._hold:
            yp = -(self._lf + self._lr) * r / (vx if vx > self._vmin else self._vmin)  # y - delta
            la = l0a + th1 * l1a + th2 * l2a
            lb = l0b + th1 * l1b + th2 * l2b
            a11 -= la
            a12 += la
            a21 -= lb
            a22 += lb
            g1 += la * yp
            g2 += lb * yp
        E, G = expm2_zoh(a11, a12, a21, a22, h)
        z0, z1 = z
        self._z = [E[0] * z0 + E[1] * z1 + G[0] * g1 + G[1] * g2, E[2] * z0 + E[3] * z1 + G[2] * g1 + G[3] * g2]

    def _scheduling(self, vx: float, ax: float) -> tuple[float, float]:
        """Scheduling ``(v_m, a_m)`` [m/s, m/s^2]: the measured values times ``(1 + eps)``, clamped
        into the design domain (the polytope's guarantees hold only inside it)."""
        vx = vx * (1.0 + self._eps1)
        ax = ax * (1.0 + self._eps2)
        vc = self._vlo if vx < self._vlo else (self._vhi if vx > self._vhi else vx)
        ac = self._alo if ax < self._alo else (self._ahi if ax > self._ahi else ax)
        return vc, ac

    def _values(self) -> list[float]:
        delta, r, vx, _ = self._u
        af = self._z[0] + delta if self._have_delta else self._z[0]
        ar = self._z[1]
        if not self._have_delta or r != r or vx != vx:
            return [af, ar, 0.0, 0.0]
        v = vx if vx > self._vmin else self._vmin
        vy = 0.5 * (v * math.tan(delta - af) - self._lf * r - v * math.tan(ar) + self._lr * r)
        return [af, ar, math.atan2(vy, v), vy]


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
