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

*Compiled.* ``step()`` and ``run()`` call the same numba kernel (:mod:`roadtruth.observers.nonlinear_wang_loop`),
with one sample or the whole log, so they agree bit for bit; the five variants share that one kernel
(their gains and the basis of ``L2`` are entries of its parameter vector).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver, StepOutput
from roadtruth.observers.bicycle import slip_model_terms
from roadtruth.observers.lmi import DesignResult, usable_gains
from roadtruth.observers.nonlinear_wang_loop import (
    N_PAR,
    P_A11,
    P_A22,
    P_AHI,
    P_ALO,
    P_B11,
    P_B22,
    P_BASIS2,
    P_C1F,
    P_C1R,
    P_ELL,
    P_HOLD,
    P_K1F,
    P_K1R,
    P_L1,
    P_L2,
    P_LF,
    P_LR,
    P_THF,
    P_THR,
    P_VHI,
    P_VLO,
    P_VMIN,
    nonlinear_run,
)
from roadtruth.observers.registry import register

KMH = 1.0 / 3.6

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
        p[P_LF], p[P_LR] = v.lf_m, v.lr_m
        p[P_HOLD] = float(self.options["hold_s"])
        assert p.shape == (N_PAR,)
        self._p = p
        self._gains_set = False

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
        self._ku = np.full(4, math.nan)       # held (delta, r, v_x, a_x)
        self._ktl = np.full(4, -math.inf)     # their arrival times [s]
        self._kz = np.array(self._z, dtype=float)
        self._ks = np.array([self._t, 0.0])   # (t_cur, have_delta)
        self._last = np.array([self._z[0], self._z[1], 0.0, 0.0])   # before any sample: no v_y, beta

    def _compiled(self, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Advance through ``t`` (n,) [s], ``Y`` (n, 4) in the shared kernel; the estimates (n, 4)."""
        if not self._gains_set:
            self._set_gains()   # a failed design raises here, on the first sample
        x = np.empty((t.shape[0], 4))
        nonlinear_run(t, Y, self._ku, self._ktl, self._kz, self._ks, self._p, x)
        if t.shape[0]:
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
