r"""Switched unknown-input interval observer of Ifqir et al. (ACC 2018), in a sound derivative-free form.

S. Ifqir, N. Aït Oufroukh, D. Ichalal, S. Mammar, "Vehicle Lateral Dynamics Estimation using Switched
Unknown Inputs Interval Observers: Experimental Validation", ACC 2018, pp. 1138-1143,
doi:10.23919/ACC.2018.8431486.

Guaranteed bounds ``x^- <= x <= x^+`` for ``x = [v_y, r, psi_L, y_L]`` of the linear bicycle + lane model
(12)-(16) (corrected (10)-(11), see :mod:`roadtruth.observers.switched_interval_design`), with road curvature
``rho`` an unknown input removed by decoupling (``P_i E_i = 0``, (24)-(25)), cornering stiffness
``c = c_0 (1 ± unc)`` and ``N = 3`` speed modes (35) with gains from the Theorem 2 SDP.

Runtime form (derivative-free and sound; it replaces the printed eq. (19), which is not an inclusion:
its ``|x^±|`` corrections are sign-inconsistent): in ``z = P_i x = x + H_i y``,

.. math::

    \dot z^\pm = N_{0,i} z^\pm + (K_i - N_{0,i}H_i)\,y + G_i u + P_i (A_{kin}(v_x) - A_{kin}(v_i)) x
    \pm P_i\big(D_i \bar X + b(|u| + \zeta)\big),\qquad x^\pm = z^\pm - H_i y,

``N_0 = P A_0 - K C`` Metzler, ``G = P B_0``, ``D = (A^+ - A^-)/2``, ``\bar X = \max(|x^+|, |x^-|)``,
``b = unc [c_{f0}/m, c_{f0} l_f / I_z, 0, 0]``. Every product of a known matrix with an interval (``y``
within its noise bound, the kinematic term ``(v_i - v_x) r``) uses Lemma 3(1). Steps are the exact ZOH of
the Metzler ``N_0`` block (``e^{N_0 h} >= 0``), forcing held over the step.

Structure (design constraints, see the design module): ``P = [e_1, e_2 + h, 0, 0]`` with ``h_3 = h_4 = 0``
and the camera columns of ``K`` zero in rows 1-2. So the ``(v_y, r)`` bounds run on ``r``, ``delta``, ``v_x``
only (the camera cannot tighten ``v_y`` when ``P >= 0``), ``z_3 = z_4 = 0`` exactly and the
lane bounds are the camera sample ± its noise bound (``x_3 = z_3 - (H y)_3 = psi_L``). Between camera
samples (NaN, 20 Hz cameras, marking gaps) the lane bounds are propagated open loop (they widen) with
``psi_L' = r - v_x rho``, ``y_L' = v_y + l_s r + v_x psi_L - l_s v_x rho``, ``|rho| <= curvature_bound_1pm``
(the unknown input needs a bound only there). A missing gyro sample is replaced by the interval
``[r^-, r^+]``.

Modes: ``sigma = i`` while ``v_x`` stays in ``[v_i - dV, v_i + dV]`` (overlapping bands = hysteresis);
on leaving, the mode whose band holds ``v_x`` with the nearest centre. ``x^±`` is kept and ``z^±``
re-initialised. With a common ``Q`` (default) the dwell time is 0 (arbitrary switching, Remark 1);
otherwise a switch sooner than ``tau_a = ln(mu)/epsilon`` after the previous one is counted in
``dwell_violations`` (the band must be left, so it cannot be postponed soundly), a speed outside
every band in ``out_of_band_steps`` (no guarantee there), and a model bound on ``r`` disjoint from the
gyro's in ``inconsistent_steps`` (the measurement interval is kept: the plant has left the model).

Sampled data (runner at 100 Hz): over a step, ``r``, ``delta`` and ``v_x`` are taken in the hull of their
two end samples (exact for signals monotone over the step). Sensor latency is not modelled for the gyro;
camera samples are aged by ``camera_latency_s`` (their bounds widened by the drift over that age).

``beta_rad`` bounds: ``atan(v_y^± / v_x)`` with ``v_x`` in ``[v_x - V_v, v_x + V_v]`` (monotone in both).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver, StepOutput
from roadtruth.observers.lmi import DesignFailed, DesignResult, DesignStatus
from roadtruth.observers.registry import register
from roadtruth.observers.switched_interval_loop import (
    DWELL_VIOLATIONS,
    E_H,
    E_MODE,
    FW1,
    FW2,
    INCONSISTENT,
    MODE,
    N_PAR,
    N_STATE,
    OUT_OF_BAND,
    P_DWELL,
    SWITCHES,
    T_CUR,
    T_SWITCH,
    bounds,
    switched_run,
)


@register
class SwitchedIntervalIfqir(ScalarLoopObserver):
    """Switched unknown-input interval observer of Ifqir et al. (ACC 2018), sound derivative-free form."""

    name = "switched_interval_ifqir"
    citation = ("S. Ifqir, N. Ait Oufroukh, D. Ichalal, S. Mammar, ACC 2018, pp. 1138-1143, "
                "eqs. (12)-(29), Theorem 2; derivative-free sound form (the printed eq. (19) is not an inclusion)")
    inputs = ("yaw_rate_radps", "delta_rad", "vx_mps", "psi_lane_rad", "y_lane_m")
    states = ("vy_mps", "yaw_rate_radps", "psi_lane_rad", "y_lane_m", "beta_rad")
    has_bounds = True
    variant = "sound"
    default_options: dict[str, Any] = {
        "mode_speeds_mps": (13.5, 20.0, 26.5),   # v_x^i (not given by the paper)
        "mode_halfwidth_mps": 4.0,               # dV: bands 9.5-17.5, 16-24, 22.5-30.5 m/s (overlap = hysteresis)
        "stiffness_uncertainty": 0.1,            # |dc_i| <= 10 % c_i0 (the paper's value)
        "lookahead_m": 0.5,                      # camera look-ahead l_s
        "epsilon": 0.5,                          # ISS decay rate in (27) [1/s]
        "eta": 100.0,                            # Metzler shift in (28) [1/s]
        "common_Q": True,                        # one Q for all modes: mu = 1, no dwell time needed
        "input_bound_rad": 0.002,                # zeta: |delta_meas - delta| (A2)
        "noise_bound_r_radps": 0.012,            # gyro noise + bias bound
        "noise_bound_psi_rad": 0.006,            # camera heading noise bound
        "noise_bound_y_m": 0.15,                 # camera offset noise bound
        "noise_bound_vx_mps": 0.1,               # speed error bound
        "camera_latency_s": 0.05,                # age of a camera sample (Mobileye class): widen by the drift
        "curvature_bound_1pm": 0.02,             # |rho| bound, used only between camera samples
        "initial_vy_halfwidth_mps": 1.0,
        "initial_r_halfwidth_radps": 0.5,
        "initial_psi_halfwidth_rad": 0.2,
        "initial_y_halfwidth_m": 2.0,
        "vx_min_mps": 1.0,                       # floor of v_x in beta
        "use_cache": True,
    }

    def _setup(self) -> None:
        o = self.options
        speeds = tuple(float(v) for v in o["mode_speeds_mps"])
        dv, unc = float(o["mode_halfwidth_mps"]), float(o["stiffness_uncertainty"])
        if not speeds or min(speeds) - dv <= 0.0 or dv <= 0.0:
            raise InputError(f"bad modes {o['mode_speeds_mps']} ± {dv}: every band must be > 0 m/s",
                             field=f"observer {self.name} mode_speeds_mps")
        if not 0.0 <= unc < 1.0:
            raise InputError(f"stiffness_uncertainty {unc} not in [0, 1)", field=f"observer {self.name}")
        for key in ("input_bound_rad", "noise_bound_r_radps", "noise_bound_psi_rad", "noise_bound_y_m",
                    "noise_bound_vx_mps", "camera_latency_s", "curvature_bound_1pm", "lookahead_m"):
            if not float(o[key]) >= 0.0:
                raise InputError(f"{key} = {o[key]} must be >= 0", field=f"observer {self.name} {key}")
        self._zeta, self._vr = float(o["input_bound_rad"]), float(o["noise_bound_r_radps"])
        self._vpsi, self._vyl = float(o["noise_bound_psi_rad"]), float(o["noise_bound_y_m"])
        self._vv, self._lat = float(o["noise_bound_vx_mps"]), float(o["camera_latency_s"])
        self._rho, self._ls = float(o["curvature_bound_1pm"]), float(o["lookahead_m"])
        self._vmin = float(o["vx_min_mps"])
        self._modes: list[tuple[float, ...]] | None = None
        self.dwell_time_s = 0.0
        # the kernel's scalar parameters (layout P_* of roadtruth.observers.switched_interval_loop)
        self._par = np.array([self._vr, self._vpsi, self._vyl, self._vv, self._lat, self._rho, self._ls,
                              self._vmin, self._zeta, 0.0])
        assert self._par.shape == (N_PAR,)

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.switched_interval_design import design_for
        return design_for(self.design_request())

    def mode_constants(self) -> list[tuple[float, ...]]:
        """Per mode the runtime scalars (see :meth:`_load`); raises :class:`DesignFailed` if uncertified."""
        if self._modes is None:
            self._load()
        assert self._modes is not None
        return self._modes

    def _load(self) -> None:
        d = self.design()
        if d.status is not DesignStatus.CERTIFIED:
            raise DesignFailed(f"{self.name}: design {d.status.value}: {d.reason}")
        C = d.gain("C")
        B0, b = d.gain("B0"), d.gain("b")
        modes = []
        i = 0
        while f"K{i}" in d.gains:
            K, H, P = d.gain(f"K{i}"), d.gain(f"H{i}"), d.gain(f"P{i}")
            A0, D = d.gain(f"A0{i}"), d.gain(f"D{i}")
            v_c, v_lo, v_hi = (float(x) for x in d.gains[f"mode{i}"])
            N0 = P @ A0 - K @ C
            M = K - N0 @ H
            G, PD, Pb = P @ B0, P @ D, P @ b
            if np.abs(N0[:2, 2:]).max() > 1e-9 or np.abs(M[:2, 1:]).max() > 1e-9 or np.abs(H[:2, 1:]).max() > 0:
                raise DesignFailed(f"{self.name}: mode {i} rows 1-2 are not camera-free")
            modes.append((v_c, v_lo, v_hi, N0[0, 0], N0[0, 1], N0[1, 0], N0[1, 1], M[0, 0], M[1, 0], G[0], G[1],
                          H[0, 0], H[1, 0], PD[0, 0], PD[0, 1], PD[1, 0], PD[1, 1], Pb[0], Pb[1], P[0, 0], P[1, 0]))
            i += 1
        self.dwell_time_s = float(d.margins["dwell_time_s"])
        self._modes = [tuple(float(x) for x in m) for m in modes]
        self._modes_arr = np.ascontiguousarray(np.array(self._modes, dtype=float).reshape(len(modes), 21))
        self._par[P_DWELL] = self.dwell_time_s

    # ---- state -------------------------------------------------------------------------------------
    def _initial_state(self) -> list[float]:
        return [0.0, 0.0, 0.0, 0.0]

    def _reset_extra(self) -> None:
        o = self.options
        c = self._z
        hw = (float(o["initial_vy_halfwidth_mps"]), float(o["initial_r_halfwidth_radps"]),
              float(o["initial_psi_halfwidth_rad"]), float(o["initial_y_halfwidth_m"]))
        # the kernel's carried state (roadtruth.observers.switched_interval_loop.switched_run), in place
        self._ku, self._kfresh, self._ktl = np.full(5, math.nan), np.zeros(5, dtype=np.bool_), np.full(5, -math.inf)
        self._lo = np.array([c[k] - hw[k] for k in range(4)])
        self._hi = np.array([c[k] + hw[k] for k in range(4)])
        self._zl, self._zh = np.zeros(2), np.zeros(2)
        self._ks = np.zeros(N_STATE)
        self._ks[T_CUR], self._ks[MODE], self._ks[T_SWITCH] = self._t, -1.0, -math.inf
        self._ks[E_MODE], self._ks[E_H] = -1.0, math.nan
        self._eg = np.zeros(8)
        blo, bhi = np.empty(5), np.empty(5)
        bounds(math.nan, self._lo, self._hi, self._par, blo, bhi)  # the initial box
        self._last = (0.5 * (blo + bhi), blo, bhi)

    # counters of the carried state (see the module docstring)
    @property
    def dwell_violations(self) -> int:
        """Switches sooner than the dwell time after the previous one."""
        return int(self._ks[DWELL_VIOLATIONS])

    @property
    def out_of_band_steps(self) -> int:
        """Steps with ``v_x`` outside every mode's band (no guarantee there)."""
        return int(self._ks[OUT_OF_BAND])

    @property
    def inconsistent_steps(self) -> int:
        """Steps where the model's bound on ``r`` was disjoint from the gyro's (measurement kept)."""
        return int(self._ks[INCONSISTENT])

    @property
    def switches(self) -> int:
        """Mode switches so far."""
        return int(self._ks[SWITCHES])

    def z_bounds(self) -> tuple[list[float], list[float]]:
        """Bounds of ``z_1, z_2`` (the ``(v_y, r)`` rows of ``z = P x``) of the current mode."""
        return self._zl.tolist(), self._zh.tolist()

    def forcing_width(self) -> tuple[float, float]:
        """Width ``Delta`` of the forcing of ``z_1, z_2`` over the last step (the ISS input of (29))."""
        return float(self._ks[FW1]), float(self._ks[FW2])

    def mode(self) -> int:
        """Active mode index (-1 before the first step with ``delta``, ``r``, ``v_x``)."""
        return int(self._ks[MODE])

    def _compiled(self, t: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance through ``t`` (n,) [s], ``Y`` (n, 5) in the shared kernel; (x, lo, hi), each (n, 5)."""
        if self._modes is None:
            self._load()   # a failed design raises here
        n = t.shape[0]
        x, lo, hi = np.empty((n, 5)), np.empty((n, 5)), np.empty((n, 5))
        switched_run(t, Y, self._ku, self._kfresh, self._ktl, self._lo, self._hi, self._zl, self._zh, self._ks,
                     self._eg, self._modes_arr, self._par, x, lo, hi)
        if n:
            self._last = (x[-1].copy(), lo[-1].copy(), hi[-1].copy())
        return x, lo, hi

    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        """One sample through the compiled kernel (the same code ``run()`` loops in, so the same bits)."""
        x, lo, hi = self._compiled(np.array([float(t_s)]),
                                   np.ascontiguousarray(np.asarray(y, dtype=float).reshape(1, 5)))
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

    def _bounds(self) -> tuple[list[float], list[float]]:
        return self._last[1].tolist(), self._last[2].tolist()

    def _values(self) -> list[float]:
        return self._last[0].tolist()
