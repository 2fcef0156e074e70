r"""Proportional-integral unknown-input observer: the baseline of Nguyen's neural adaptive observer.

Q. H. Nguyen, PhD thesis draft (Université de Lorraine, CRAN), ch. 1, sec. 7.3 compares the neural
adaptive observer against "a PI observer" without giving its form or gains. This is the classical
PI observer (Wojciechowski 1978; Söffker, Yu & Müller 1995) on the chapter's vehicle (1.55)-(1.56):

.. math::

    \dot{\hat x} = A(\rho)\hat x + B_u u + B_\mu\hat\mu + L_P(y - C\hat x),\qquad
    \dot{\hat\mu} = -\kappa\hat\mu + L_I(y - C\hat x),

``x = (v_x, v_y, psi, r)``, ``mu = (f_yf, f_yr)`` [kN], ``y = (v_x, psi_m, r)``; gains from the
certified decay + disk LMIs of :mod:`roadtruth.observers.pi_observer_design`. The leakage ``kappa`` is
required: without it the integrated unknown input has an unobservable mode at ``s = 0`` for this
``C``. Measurements and heading as in ``uio_nguyen``: ``a <- ax_mps2``, ``psi_m`` is the
trapezoidal integral of the gyro (re-centred to (-pi, pi] with ``psi_hat``). Between samples the
affine ODE is integrated by RK4 (first-order hold of the inputs, sub-steps ``||M|| h <= 0.5``);
without fresh ``v_x`` and ``r`` (older than ``hold_s``) it predicts without correction.

*Compiled.* ``step()`` and ``run()`` call the same numba kernel (:mod:`roadtruth.observers.pi_observer_loop`),
with one sample or the whole log, so they agree bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver, StepOutput
from roadtruth.observers.lmi import DesignResult, usable_gains
from roadtruth.observers.pi_observer_loop import N_PAR, N_STATE, pi_run
from roadtruth.observers.registry import register
from roadtruth.observers.uio_nguyen_design import MU_SCALE_N, N_MU, N_X, N_Y, scheduling_points, vehicle_model

N_A = N_X + N_MU


@register
class PIObserverNguyen(ScalarLoopObserver):
    """Leaky PI unknown-input observer on Nguyen's LPV vehicle (baseline of ch. 1, sec. 7.3)."""

    name = "pi_observer_nguyen"
    citation = ("Q. H. Nguyen, PhD thesis draft, Univ. de Lorraine (CRAN), ch. 1, sec. 7.3 (PI baseline), "
                "vehicle (1.55)-(1.56); PI observer form of Söffker, Yu and Müller, 1995")
    inputs = ("vx_mps", "yaw_rate_radps", "ax_mps2", "delta_rad")
    states = ("vy_mps", "yaw_rate_radps", "beta_rad")
    variant = "leaky_pi"
    default_options: Mapping[str, Any] = {
        "kappa": 0.2,                  # leakage of the unknown-input integrator [1/s]
        "decay_rate": 0.1,             # certified decay rate alpha < kappa [1/s]
        "pole_radius": 50.0,           # certified bound on |pole| [1/s]
        "vx_range_mps": (5.0, 30.0),   # design domain; v_x is clamped into it
        "grid_points": 101,
        "hold_s": 0.1,
        "use_cache": True,
    }

    def _setup(self) -> None:
        o = self.options
        try:
            lo, hi = (float(x) for x in o["vx_range_mps"])
            kappa, alpha, radius = float(o["kappa"]), float(o["decay_rate"]), float(o["pole_radius"])
            ngrid, hold = int(o["grid_points"]), float(o["hold_s"])
        except (TypeError, ValueError) as exc:
            raise InputError(f"bad option value ({exc})", field=f"observer {self.name}") from exc
        if not (0.0 < lo < hi) or not (0.0 < alpha < kappa) or radius <= alpha or ngrid < 2 or hold <= 0.0:
            raise InputError(f"bad options vx_range_mps={o['vx_range_mps']}, kappa={kappa}, decay_rate={alpha}, "
                             f"pole_radius={radius}, grid_points={ngrid}, hold_s={hold} (need 0 < decay_rate "
                             f"< kappa < pole_radius)", field=f"observer {self.name}")
        self._vlo, self._vhi, self._hold, self._kappa = lo, hi, hold, kappa
        self._model = vehicle_model(self.vehicle)
        self._consts: tuple[np.ndarray, ...] | None = None
        self._par: np.ndarray | None = None   # the kernel's (v_lo, v_hi, hold_s, rate bounds)

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.pi_observer_design import design_for
        return design_for(self.design_request())

    def constants(self) -> tuple[np.ndarray, ...]:
        """``(Fs, Gs, Fp, Gp, bounds)`` of the corrected and the prediction ODEs (affine in rho)."""
        if self._consts is None:
            L = np.array(usable_gains(self.name, self.design(), ["L"])).reshape(N_A, N_Y)
            mdl = self._model
            Fp = np.zeros((3, N_A, N_A))
            for i, Ai in enumerate((mdl.A0, mdl.A1, mdl.A2)):
                Fp[i, :N_X, :N_X] = Ai
            Fp[0, :N_X, N_X:] = mdl.Bmu
            Fp[0, N_X:, N_X:] = -self._kappa * np.eye(N_MU)
            Ca = np.hstack([mdl.C, np.zeros((N_Y, N_MU))])
            Fs = Fp.copy()
            Fs[0] -= L @ Ca
            Bua = np.vstack([mdl.Bu, np.zeros((N_MU, 2))])
            Gs = np.zeros((3, N_A, N_Y + 2))
            Gs[0] = np.hstack([L, Bua])
            Gp = np.zeros((3, N_A, N_Y + 2))
            Gp[0, :, N_Y:] = Bua
            _, grid = scheduling_points((self._vlo, self._vhi), 41)
            bounds = np.array([max(np.linalg.norm(S[0] + a * S[1] + b * S[2], 2) for a, b in grid) for S in (Fs, Fp)])
            self._consts = (Fs, Gs, Fp, Gp, bounds)
        return self._consts

    def _initial_state(self) -> list[float]:
        return [0.0] * N_A

    def _internal_from_x0(self, z: list[float], x0: Mapping[str, float]) -> list[float]:
        slots = {"vy_mps": 1, "yaw_rate_radps": 3}
        for key, value in x0.items():
            if key not in slots:
                raise InputError(f"cannot initialise state {key!r} (settable: {', '.join(slots)})",
                                 field=f"observer {self.name} x0")
            z[slots[key]] = float(value)
        return z

    def _reset_extra(self) -> None:
        self._ku = np.full(4, math.nan)       # held (v_x, r, a_x, delta)
        self._ktl = np.full(4, -math.inf)     # their arrival times [s]
        self._zh = np.array(self._z, dtype=float)
        # (t_cur, started, psi_m, r_prev, t_r_prev, have_w_prev): see pi_observer_loop
        self._ks = np.array([self._t, 0.0, 0.0, math.nan, math.nan, 0.0])
        assert self._ks.shape == (N_STATE,)
        self._kw = np.zeros(5)                # ODE input at the end of the previous step
        vy = float(self._zh[1])
        self._last = np.array([vy, float(self._zh[3]), math.atan2(vy, self._zh[0]) if self._zh[0] > 0.0 else 0.0])

    def _compiled(self, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Advance through ``t`` (n,) [s], ``Y`` (n, 4) in the shared kernel; the estimates (n, 3)."""
        Fs, Gs, Fp, Gp, bounds = self._consts if self._consts is not None else self.constants()
        if self._par is None:   # a failed design raises in constants(), on the first sample
            self._par = np.array([self._vlo, self._vhi, self._hold, bounds[0], bounds[1]])
            assert self._par.shape == (N_PAR,)
        x = np.empty((t.shape[0], 3))
        pi_run(t, Y, self._ku, self._ktl, self._zh, self._ks, self._kw, Fs, Gs, Fp, Gp, self._par, x)
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

    def state_hat(self) -> np.ndarray:
        """Copy of ``(v_x, v_y, psi_hat, r, f_yf [kN], f_yr [kN])``: (6,) array."""
        return self._zh.copy()

    def unknown_input_N(self) -> tuple[float, float, float]:
        """Current ``(f_yf, f_yr, l_f f_yf - l_r f_yr)`` [N, N, N m] (non-scored extra)."""
        f, rr = float(self._zh[4]) * MU_SCALE_N, float(self._zh[5]) * MU_SCALE_N
        v = self.vehicle
        return f, rr, v.lf_m * f - v.lr_m * rr
