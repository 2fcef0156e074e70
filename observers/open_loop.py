r"""The two model-only baselines: the open-loop linear bicycle and the kinematic ``v_y`` integration.

Neither corrects with a measurement; they show what a model alone (or an accelerometer alone) gives,
the floor every observer of the suite has to beat.

* ``open_loop_bicycle``: the linear single-track model in ``(v_y, r)`` (Y. Wang, PhD dissertation,
  Auburn 2014, eq. (3.17); :mod:`roadtruth.observers.bicycle`) driven by the measured ``delta`` and
  ``v_x``, exact zero-order-hold step with the latest inputs.
* ``kinematic_vy``: ``v_y' = a_y - r v_x`` integrated by the trapezoidal rule (Kiencke & Nielsen
  2000, sec. 7.3); an accelerometer bias ``b`` makes the error grow as ``b t``.

Both run their whole per-sample update in one compiled kernel
(:func:`roadtruth.observers.open_loop_loop.open_loop_run`) that ``step()`` calls with one sample and
``run()`` with the whole log, so the two agree bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from roadtruth.observers import open_loop_loop as loop
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver, StepOutput
from roadtruth.observers.bicycle import axle_stiffness
from roadtruth.observers.registry import register

_VY_R_STATES = ("vy_mps", "yaw_rate_radps", "beta_rad", "alpha_f_rad", "alpha_r_rad")


class _CompiledBaseline(ScalarLoopObserver):
    """Common step()/run() of the two baselines on the shared kernel; subclasses set ``_kind``."""

    _kind: ClassVar[int]   # which baseline open_loop_loop.open_loop_run runs

    def _setup(self) -> None:
        v = self.vehicle
        cf, cr = axle_stiffness(v)
        vmin = float(self.options.get("vx_min_mps", 0.0))
        self._par = np.array([v.mass_kg, v.yaw_inertia_kgm2, v.lf_m, v.lr_m, cf, cr, vmin])
        assert self._par.shape == (loop.N_PAR,)

    def _reset_extra(self) -> None:
        z = [*self._z, 0.0][:2]
        self._ku = np.full(len(self.inputs), math.nan)      # held inputs (zero-order hold)
        self._ks = np.array([self._t, z[0], z[1], math.nan])  # (t_cur, z_1, z_2, f_prev)
        self._last = np.array([*self._z, *[0.0] * (len(self.states) - len(self._z))])

    def _compiled(self, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Advance through ``t`` (n,) [s], ``Y`` (n, len(inputs)) in the shared kernel; estimates (n, k)."""
        x = np.empty((t.shape[0], len(self.states)))
        loop.open_loop_run(t, Y, self._kind, self._ku, self._ks, self._par, x)
        if t.shape[0]:
            self._last = x[-1].copy()
        self._t = float(self._ks[0])
        self._z = self._ks[1:1 + len(self._z)].tolist()
        return x

    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        """One sample through the compiled kernel (the same code ``run()`` loops in, so the same bits)."""
        x = self._compiled(np.array([float(t_s)]),
                           np.ascontiguousarray(np.asarray(y, dtype=float).reshape(1, len(self.inputs))))
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
class OpenLoopBicycle(_CompiledBaseline):
    """Open-loop linear bicycle model driven by measured delta and v_x; no correction.

    ``x' = A(v_x) x + B delta`` for ``x = (v_y, r)`` (eq. (3.17)), exact ZOH per step with the
    latest inputs (``v_x`` held at ``vx_min_mps`` [m/s] below it). ``beta = atan2(v_y, v_x)``; slip
    angles by the CONTRACT definitions.
    """

    name = "open_loop_bicycle"
    citation = "Linear single-track model (Y. Wang, PhD dissertation, Auburn 2014, eq. (3.17); Rajamani 2012, sec. 2.3)"
    inputs = ("delta_rad", "vx_mps")
    states = _VY_R_STATES
    default_options = {"vx_min_mps": 2.0}
    _kind = loop.BICYCLE

    def _initial_state(self) -> list[float]:
        return [0.0, 0.0]


@register
class KinematicVy(_CompiledBaseline):
    """Kinematic integration of the lateral velocity, ``v_y' = a_y - r v_x``.

    Trapezoidal rule between consecutive input samples. No model, no correction: an accelerometer
    bias ``b`` makes the error grow as ``b t`` (and roll-induced gravity leaks in the same way),
    which is the point of this baseline.
    """

    name = "kinematic_vy"
    citation = "Kinematic model v_y' = a_y - r v_x (e.g. Kiencke & Nielsen 2000, sec. 7.3)"
    inputs = ("ay_mps2", "yaw_rate_radps", "vx_mps")
    states = ("vy_mps", "beta_rad")
    default_options: dict[str, object] = {}
    _kind = loop.KINEMATIC

    def _initial_state(self) -> list[float]:
        return [0.0]
