r"""Algebraic lateral velocity from the lane camera (Yacine et al. 2015, eqs. (25)-(26)) as an estimator.

Z. Yacine, D. Ichalal, N. Ait-Oufroukh, S. Mammar, S. Djennoune, "Takagi-Sugeno Observers:
Experimental Application for Vehicle Lateral Dynamics Estimation", IEEE Trans. Control Systems
Technology 23(2):754-761, 2015. The paper uses this value only inside the rule weights of its TS
observer (``ts_yacine``); here it is scored on its own, so the harness shows how good the premise is
that the TS observer is built on.

Lane kinematics (5)/(9): ``y_L' = v_y + v_x psi_L + l_s psi_L'`` with the heading ``psi_L`` relative
to the road tangent at the CG, hence (26)

.. math::

    \hat v_y = \dot y_{L,e} - v_x \psi_L - l_s \dot\psi_{L,e},

``y_L'``, ``psi_L'`` from Levant differentiators (order 2, the paper's "third-order" HOSMD;
:mod:`roadtruth.observers.levant_differentiator`) run at the camera's own rate. roadtruth's camera (like a
real one) reports ``psi_L`` relative to the road at the look-ahead point; then exactly
``y_L' = v_x sin psi_L + (v_y + l_s r) cos psi_L`` and the default ``lane_heading_at="lookahead"``
uses ``v_y = (y_L' - v_x sin psi_L) / cos psi_L - l_s r`` (the gyro replaces the differentiated
heading; the printed form differs by ``l_s v_x rho``, see ``ts_yacine``). ``"cg"`` is (26) as printed.

No model, no gains, no feedback: the estimate is exact once the differentiator has converged on a
noise-free camera (finite time, Levant 2003) and otherwise carries the differentiator's
``O(L^(1/3) eps^(2/3))`` noise error. Before the differentiator has run ``differentiator_settle_s``
and when the camera is silent for more than ``camera_timeout_s`` there is no estimate (NaN).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from roadtruth.harness.errors import InputError
from roadtruth.observers.base import ScalarLoopObserver
from roadtruth.observers.levant_differentiator import LAMBDAS, LevantDifferentiator
from roadtruth.observers.registry import register


@register
class AlgebraicVyYacine(ScalarLoopObserver):
    """Camera-kinematic algebraic lateral velocity (Yacine et al. 2015, (26)); no model, no feedback."""

    name = "algebraic_vy_yacine"
    citation = "Z. Yacine et al., IEEE Trans. Control Syst. Technol. 23(2):754-761, 2015, eqs. (9), (25)-(26)"
    inputs = ("yaw_rate_radps", "vx_mps", "y_lane_m", "psi_lane_rad")
    withholds_estimates = True  # an algebraic estimate: no camera, no estimate (never a prediction)
    states = ("vy_mps", "beta_rad")
    variant = "algebraic"
    # The differentiator defaults are those of ts_yacine (tuned for the automotive 20 Hz camera), so
    # this estimator scores exactly the premise that observer uses.
    default_options: Mapping[str, Any] = {
        "lookahead_m": 0.5,                # l_s (Yacine et al. Table I)
        "differentiator_order": 2,         # Levant k
        "lipschitz_y_lane": 1.0,           # bound on |y_L'''| [m/s^3]
        "lipschitz_psi_lane": 0.5,         # bound on |psi_L'''| [rad/s^3]
        "lane_heading_at": "lookahead",    # "lookahead" (roadtruth camera) | "cg" ((26) as printed)
        "camera_timeout_s": 0.3,           # longer camera silence: no estimate, differentiators re-armed
        "differentiator_settle_s": 0.5,    # run time before the differentiated value is trusted [s]
    }

    def _setup(self) -> None:
        o = self.options
        for key, lo, hi in (("lookahead_m", 0.0, 50.0), ("lipschitz_y_lane", 1e-6, 1e6),
                            ("lipschitz_psi_lane", 1e-6, 1e6), ("camera_timeout_s", 1e-3, 10.0),
                            ("differentiator_settle_s", 0.0, 10.0)):
            val = o[key]
            if not (isinstance(val, int | float) and math.isfinite(val) and lo <= val <= hi):
                raise InputError(f"option {key} = {val!r}: needs a number in [{lo}, {hi}]",
                                 field=f"observer {self.name}")
        if o["lane_heading_at"] not in ("lookahead", "cg"):
            raise InputError(f"option lane_heading_at = {o['lane_heading_at']!r}: needs 'lookahead' or 'cg'",
                             field=f"observer {self.name}")
        if o["differentiator_order"] not in LAMBDAS:
            raise InputError(f"option differentiator_order = {o['differentiator_order']!r}: needs one of "
                             f"{sorted(LAMBDAS)}", field=f"observer {self.name}")
        self._cg = o["lane_heading_at"] == "cg"

    def _initial_state(self) -> list[float]:
        return [math.nan]

    def _internal_from_x0(self, z: list[float], x0: Mapping[str, float]) -> list[float]:
        raise InputError("an algebraic estimator has no initial state", field=f"observer {self.name} x0")

    def _reset_extra(self) -> None:
        o = self.options
        k = int(o["differentiator_order"])
        self.diff_y = LevantDifferentiator(k, float(o["lipschitz_y_lane"]))
        self.diff_psi = LevantDifferentiator(k, float(o["lipschitz_psi_lane"]))
        self._t_cam = -math.inf
        self._t_start = math.inf
        self._vy = math.nan

    def _advance(self, t_s: float, y: list[float]) -> None:
        self._tick(t_s, y)
        r, vx, yl, pl = self._u
        o = self.options
        if self._fresh[2] and self._fresh[3]:
            tau = t_s - self._t_cam
            if tau > o["camera_timeout_s"] or not self.diff_y.initialized:
                self.diff_y.reset(yl)
                self.diff_psi.reset(pl)
                self._t_start = t_s
            else:
                self.diff_y.update(yl, tau)
                self.diff_psi.update(pl, tau)
            self._t_cam = t_s
        ready = (t_s - self._t_start >= o["differentiator_settle_s"] and t_s - self._t_cam <= o["camera_timeout_s"]
                 and vx == vx)
        if not ready:
            self._vy = math.nan
            return
        dy = self.diff_y.z[1]
        ls = float(o["lookahead_m"])
        if self._cg:
            self._vy = dy - vx * pl - ls * self.diff_psi.z[1]                       # (26) as printed
        elif r == r:
            self._vy = (dy - vx * math.sin(pl)) / math.cos(pl) - ls * r             # exact, look-ahead heading
        else:
            self._vy = math.nan

    def _values(self) -> list[float]:
        vy, vx = self._vy, self._u[1]
        return [vy, math.atan2(vy, vx) if vy == vy and vx == vx and vx > 0.1 else math.nan]
