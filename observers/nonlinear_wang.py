r"""Nonlinear slip-angle observers of Y. Wang (2014, ch. 5) on the brush tire (5.63).

Plant (5.37), (5.64)-(5.72), states ``x = (alpha_f, alpha_r)``, ``lambda = (1/v_x, a_x/v_x)``:

.. math::

    \dot x = A(\lambda) x + B_f(\lambda) f(x) + \Phi(y, u),\quad
    A = \lambda_1 B_{f0}\,\mathrm{diag}(c_{1f}, c_{1r}) - \lambda_2 I,\quad B_f = \lambda_1 B_{f0},

``f_i(alpha) = F_y(alpha) - c1_i alpha`` the nonlinear part of the axle force (5.63) *with* its
saturation branch, ``F_y = mu F_z (3 s - 3 s^2 + s^3) sgn(alpha)``, ``s = min(1, theta_t |alpha|)``,
``c1 = 3 mu F_z theta_t`` the vehicle's axle cornering stiffness (so ``theta_t = c1 / (3 mu F_z)`` with
the static axle load and ``mu`` = tire grip x option ``mu``), ``y = delta - (l_f + l_r) r / v_x = x1 - x2``.

Observer, two-degree-of-freedom form (5.21)/(5.38), ``y~ = y - C x``:

.. math::

    \dot{\hat x} = A \hat x + B_f f(\hat x + L_2 \tilde y) + \Phi + (L_1 - B_f K_1 L_2)\tilde y,

with ``K1 = diag(k1)``, ``k1 = -c1 (2 s_m - s_m^2)``, ``s_m = theta_t alpha_max``: the slope bounds of
``f`` on the slip domain ``|alpha| <= alpha_max`` (``K2 = 0``). The guarantee (decay of
``e^T P e`` at the certified rate) holds while true and estimated slips stay in that domain.

Variants (design in :mod:`roadtruth.observers.nonlinear_wang_design`):

* ``nonlinear_wang_luenberger``: extended Luenberger (5.2), Lemma 17 (``L2 = 0``), constant ``L1``;
* ``nonlinear_wang_arcak``: Arcak two-DOF, Theorem 7, constant ``L1, L2``;
* ``nonlinear_wang_l2``: L2-optimal two-DOF, Theorem 8 with the gain-norm limits (5.33)-(5.36);
* ``nonlinear_wang``: gain-scheduled PVNL two-DOF, Theorem 10 (L2-optimal), ``L1`` affine in
  lambda, ``L2`` affine in ``(v_x, a_x)``, with gain-norm limits;
* ``nonlinear_wang_printed``: the gains printed in (5.73) (``L1``, ``L2`` affine in lambda).

As in :mod:`roadtruth.observers.lpv_wang` the state ``z1 = alpha_f - delta`` removes the steering rate, and
``v_y`` / ``beta`` are derived from the CONTRACT slip definitions.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from roadtruth.harness.truth.tire import jit
from roadtruth.observers.base import ScalarLoopObserver
from roadtruth.observers.bicycle import slip_model_terms
from roadtruth.observers.lmi import DesignResult, usable_gains
from roadtruth.observers.registry import register

KMH = 1.0 / 3.6
#: Index layout of the parameter array of the compiled step.
(P_C1F, P_C1R, P_THF, P_THR, P_K1F, P_K1R, P_A11, P_A12, P_A21, P_A22, P_B11, P_B12, P_B21, P_B22,
 P_ELL, P_VLO, P_VHI, P_ALO, P_AHI, P_VMIN, P_L1, P_L2, P_BASIS2, N_PAR) = (
    0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 29, 38, 39)
#: Largest RK4 sub-steps per step (bounds the cost at very low speed).
MAX_SUBSTEPS = 64


@jit
def brush_nonlinear_part(alpha: float, c1: float, theta: float) -> float:
    """``F_y(alpha) - c1 alpha`` [N] of (5.63) with saturation beyond ``1/theta``."""
    s = theta * abs(alpha)
    if s > 1.0:
        s = 1.0
    mu_fz = c1 / (3.0 * theta)
    fy = mu_fz * (3.0 * s - 3.0 * s * s + s * s * s)
    return (fy if alpha >= 0.0 else -fy) - c1 * alpha


@jit
def _rhs(z1: float, ar: float, p: np.ndarray, delta: float, r: float, th1: float, th2: float,
         ytil_off: float, l1a: float, l1b: float, l2a: float, l2b: float, correct: bool) -> tuple[float, float]:
    af = z1 + delta
    if correct:
        yt = ytil_off - (z1 - ar)  # y - C x, with y - delta = ytil_off
    else:
        yt = 0.0
    fa = brush_nonlinear_part(af + l2a * yt, p[P_C1F], p[P_THF])
    fb = brush_nonlinear_part(ar + l2b * yt, p[P_C1R], p[P_THR])
    # A x + B_f f + (L1 - B_f K1 L2) y~ + Phi (without delta', absorbed by z1)
    lin_a = th1 * (p[P_A11] * af + p[P_A12] * ar) - th2 * af
    lin_b = th1 * (p[P_A21] * af + p[P_A22] * ar) - th2 * ar
    nf_a = th1 * (p[P_B11] * fa + p[P_B12] * fb)
    nf_b = th1 * (p[P_B21] * fa + p[P_B22] * fb)
    kl_a = p[P_K1F] * l2a * yt
    kl_b = p[P_K1R] * l2b * yt
    bk_a = th1 * (p[P_B11] * kl_a + p[P_B12] * kl_b)
    bk_b = th1 * (p[P_B21] * kl_a + p[P_B22] * kl_b)
    da = lin_a + nf_a + (l1a * yt - bk_a) + th2 * delta + r
    db = lin_b + nf_b + (l1b * yt - bk_b) + r
    return da, db


@jit
def observer_step(z: np.ndarray, p: np.ndarray, delta: float, r: float, vx: float, ax: float, h: float,
                  correct: bool) -> None:
    """Advance ``z = (alpha_f - delta, alpha_r)`` by ``h`` [s] with held inputs (RK4, sub-stepped)."""
    vc = min(max(vx, p[P_VLO]), p[P_VHI])
    ac = min(max(ax, p[P_ALO]), p[P_AHI])
    th1 = 1.0 / vc
    th2 = ac * th1
    l1a = p[P_L1] + th1 * p[P_L1 + 2] + th2 * p[P_L1 + 4]
    l1b = p[P_L1 + 1] + th1 * p[P_L1 + 3] + th2 * p[P_L1 + 5]
    if p[P_BASIS2] > 0.5:      # L2 affine in (v_x, a_x)
        b1, b2 = vc, ac
    else:                      # L2 affine in lambda
        b1, b2 = th1, th2
    l2a = p[P_L2] + b1 * p[P_L2 + 2] + b2 * p[P_L2 + 4]
    l2b = p[P_L2 + 1] + b1 * p[P_L2 + 3] + b2 * p[P_L2 + 5]
    vm = vx if vx > p[P_VMIN] else p[P_VMIN]
    yoff = -p[P_ELL] * r / vm
    # stiffness bound of the right-hand side [1/s], for the sub-step count (h * rate <= 0.5)
    c1m = max(p[P_C1F], p[P_C1R])
    bnorm = max(abs(p[P_B11]) + abs(p[P_B12]), abs(p[P_B21]) + abs(p[P_B22]))
    rate = (th1 * c1m * bnorm * (1.0 + 2.0 * (abs(l2a) + abs(l2b))) + abs(th2)
            + (2.0 * (abs(l1a) + abs(l1b)) if correct else 0.0))
    n = int(math.ceil(h * rate / 0.5))
    n = 1 if n < 1 else (MAX_SUBSTEPS if n > MAX_SUBSTEPS else n)
    dt = h / n
    a, b = z[0], z[1]
    for _ in range(n):
        k1a, k1b = _rhs(a, b, p, delta, r, th1, th2, yoff, l1a, l1b, l2a, l2b, correct)
        k2a, k2b = _rhs(a + 0.5 * dt * k1a, b + 0.5 * dt * k1b, p, delta, r, th1, th2, yoff, l1a, l1b, l2a, l2b,
                        correct)
        k3a, k3b = _rhs(a + 0.5 * dt * k2a, b + 0.5 * dt * k2b, p, delta, r, th1, th2, yoff, l1a, l1b, l2a, l2b,
                        correct)
        k4a, k4b = _rhs(a + dt * k3a, b + dt * k3b, p, delta, r, th1, th2, yoff, l1a, l1b, l2a, l2b, correct)
        a += dt * (k1a + 2.0 * k2a + 2.0 * k3a + k4a) / 6.0
        b += dt * (k1b + 2.0 * k2b + 2.0 * k3b + k4b) / 6.0
    z[0] = a
    z[1] = b


_COMMON: dict[str, Any] = {
    "vx_range_mps": (15.0 * KMH, 150.0 * KMH),  # design domain (5.70); v_x is clamped into it
    "ax_range_mps2": (-8.0, 8.0),
    "slip_domain_rad": 0.10,     # alpha_max of the sector bounds (not given in the dissertation)
    "mu": 1.0,                   # road friction the tire model assumes (times the tire grip)
    "decay_fraction": 0.5,       # certified rate = this x the largest feasible rate
    "max_gain_L1_per_s": 60.0,   # (5.33): ||L1|| <= this
    "max_gain_L2": 2.0,          # (5.33): ||L2|| <= this
    "hold_s": 0.1,               # correct only while delta, r, v_x are younger than this [s]
    "vx_min_output_mps": 1.0,    # floor of v_x in the pseudo-output and derived v_y
    "use_cache": True,
}


@register
class NonlinearWang(ScalarLoopObserver):
    """Gain-scheduled (PVNL) two-DOF nonlinear slip-angle observer, L2-optimal (Wang 2014, Thm 10)."""

    name = "nonlinear_wang"
    citation = "Y. Wang, PhD dissertation, Auburn University 2014, ch. 5, eqs. (5.38)-(5.43), (5.63)-(5.72), Thm 10"
    inputs = ("delta_rad", "yaw_rate_radps", "vx_mps", "ax_mps2")
    states = ("alpha_f_rad", "alpha_r_rad", "beta_rad", "vy_mps")
    variant = "scheduled"
    default_options = dict(_COMMON)

    def _setup(self) -> None:
        from roadtruth.harness.errors import InputError
        from roadtruth.observers.nonlinear_wang_design import tire_data
        v = self.vehicle
        lo_v, hi_v = (float(x) for x in self.options["vx_range_mps"])
        lo_a, hi_a = (float(x) for x in self.options["ax_range_mps2"])
        am = self.options["slip_domain_rad"]
        if not (0.0 < lo_v < hi_v and lo_a <= hi_a):
            raise InputError(f"bad design domain v {self.options['vx_range_mps']}, a {self.options['ax_range_mps2']}",
                             field=f"observer {self.name}")
        if not (isinstance(am, int | float) and 0.0 < am < 1.0):
            raise InputError(f"slip_domain_rad must be a number in (0, 1) rad, got {am!r}", field=f"observer {self.name}")
        c1, theta, k1 = tire_data(v, float(self.options["mu"]), float(am))
        A1, Bf0 = slip_model_terms(v)
        p = np.zeros(N_PAR)
        p[P_C1F], p[P_C1R], p[P_THF], p[P_THR], p[P_K1F], p[P_K1R] = c1[0], c1[1], theta[0], theta[1], k1[0], k1[1]
        p[P_A11:P_A22 + 1] = A1.reshape(-1)
        p[P_B11:P_B22 + 1] = Bf0.reshape(-1)
        p[P_ELL] = v.lf_m + v.lr_m
        p[P_VLO], p[P_VHI], p[P_ALO], p[P_AHI] = lo_v, hi_v, lo_a, hi_a
        p[P_VMIN] = float(self.options["vx_min_output_mps"])
        p[P_BASIS2] = 1.0 if self.variant == "scheduled" else 0.0
        self._p = p
        self._hold = float(self.options["hold_s"])
        self._gains_set = False
        self._zarr = np.zeros(2)

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.nonlinear_wang_design import design_for
        return design_for(self)

    def gain_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(L1, L2)`` coefficient arrays (3, 2): rows = basis functions (missing ones are zero).

        Raises :class:`DesignFailed` without usable gains."""
        d = self.design()
        L1 = np.zeros((3, 2))
        L2 = np.zeros((3, 2))
        for i in range(3):
            if f"L1_{i}" in d.gains:
                L1[i] = usable_gains(self.name, d, (f"L1_{i}",))
            if f"L2_{i}" in d.gains:
                L2[i] = usable_gains(self.name, d, (f"L2_{i}",))
        if "L1_0" not in d.gains:
            usable_gains(self.name, d, ("L1_0",))  # raises DesignFailed with the design's reason
        return L1, L2

    def _set_gains(self) -> None:
        L1, L2 = self.gain_arrays()
        # layout: (const_f, const_r, b1_f, b1_r, b2_f, b2_r)
        self._p[P_L1:P_L1 + 6] = L1.reshape(-1)
        self._p[P_L2:P_L2 + 6] = L2.reshape(-1)
        self._gains_set = True

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
        if not self._gains_set:
            self._set_gains()
        tl = self._t_last
        correct = t_s - min(tl[0], tl[1], tl[2]) <= self._hold
        za = self._zarr
        za[0], za[1] = z[0], z[1]
        observer_step(za, self._p, delta, r, vx, ax, h, correct)
        z[0], z[1] = float(za[0]), float(za[1])

    def _values(self) -> list[float]:
        delta, r, vx, _ = self._u
        af = self._z[0] + delta if self._have_delta else self._z[0]
        ar = self._z[1]
        if not self._have_delta or r != r or vx != vx:
            return [af, ar, 0.0, 0.0]
        lf, lr = self.vehicle.lf_m, self.vehicle.lr_m
        v = vx if vx > self._p[P_VMIN] else float(self._p[P_VMIN])
        vy = 0.5 * (v * math.tan(delta - af) - lf * r - v * math.tan(ar) + lr * r)
        return [af, ar, math.atan2(vy, v), vy]


@register
class NonlinearWangPrinted(NonlinearWang):
    """Gain-scheduled nonlinear slip-angle observer with the gains printed in (5.73) (Wang 2014)."""

    name = "nonlinear_wang_printed"
    citation = "Y. Wang, PhD dissertation, Auburn University 2014, ch. 5, eq. (5.73) (printed gains)"
    variant = "scheduled_printed"


@register
class NonlinearWangL2(NonlinearWang):
    """L2-optimal two-DOF nonlinear slip-angle observer, constant gains (Wang 2014, Thm 8, (5.33)-(5.36))."""

    name = "nonlinear_wang_l2"
    citation = "Y. Wang, PhD dissertation, Auburn University 2014, ch. 5, Thm 8, eqs. (5.28)-(5.36)"
    variant = "l2"


@register
class NonlinearWangArcak(NonlinearWang):
    """Arcak two-DOF nonlinear slip-angle observer, constant gains (Wang 2014, Lemma 18, Thm 7)."""

    name = "nonlinear_wang_arcak"
    citation = "Y. Wang, PhD dissertation, Auburn University 2014, ch. 5, Thm 7, eqs. (5.21)-(5.27)"
    variant = "arcak"


@register
class NonlinearWangLuenberger(NonlinearWang):
    """Extended Luenberger nonlinear slip-angle observer, constant gain (Wang 2014, Lemma 17, (5.2))."""

    name = "nonlinear_wang_luenberger"
    citation = "Y. Wang, PhD dissertation, Auburn University 2014, ch. 5, Lemma 17, eqs. (5.2), (5.19)"
    variant = "luenberger"
