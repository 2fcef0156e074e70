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

The whole per-sample update runs in one compiled kernel (:mod:`roadtruth.observers.algebraic_vy_loop`)
that ``step()`` calls with one sample and ``run()`` with the whole log: both give the same bits.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.observers import algebraic_vy_loop as loop
from roadtruth.observers.algebraic_vy_loop import levant_table
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver, StepOutput
from roadtruth.observers.levant_differentiator import LAMBDAS
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
        # the kernel's constants (roadtruth.observers.algebraic_vy_loop)
        self._par = np.array([float(o["lookahead_m"]), float(o["camera_timeout_s"]),
                              float(o["differentiator_settle_s"]), 1.0 if o["lane_heading_at"] == "cg" else 0.0])
        assert self._par.shape == (loop.N_PAR,)

    def _initial_state(self) -> list[float]:
        return [math.nan]

    def _internal_from_x0(self, z: list[float], x0: Mapping[str, float]) -> list[float]:
        raise InputError("an algebraic estimator has no initial state", field=f"observer {self.name} x0")

    def _reset_extra(self) -> None:
        o = self.options
        k = int(o["differentiator_order"])
        self._lev = levant_table(k, float(o["lipschitz_y_lane"]), float(o["lipschitz_psi_lane"]))
        self._ku = np.full(4, math.nan)                          # held (r, v_x, y_L, psi_L)
        self._ks = np.array([self._t, -math.inf, math.inf, math.nan])   # (t_cur, t_cam, t_start, v_y)
        self._kdy, self._kdp = np.zeros(k + 3), np.zeros(k + 3)  # the differentiators of y_L, psi_L
        self._last = np.array([math.nan, math.nan])

    def _compiled(self, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Advance through ``t`` (n,) [s], ``Y`` (n, 4) in the shared kernel; ``(v_y, beta)`` (n, 2)."""
        x = np.empty((t.shape[0], 2))
        loop.algebraic_run(t, Y, self._ku, self._ks, self._kdy, self._kdp, self._lev, self._par, x)
        if t.shape[0]:
            self._last = x[-1].copy()
        self._t = float(self._ks[0])
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
