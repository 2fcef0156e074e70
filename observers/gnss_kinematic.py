r"""GNSS kinematic estimation: generalized high-gain observers and an EKF (H. Bessafa, PhD thesis 2024, sec. 5.3).

H. Bessafa, "Advanced Estimation Algorithms for Connected and Autonomous Vehicle Applications", PhD
thesis, Université de Lorraine (CRAN), 2024, HAL tel-04744305: kinematic model (5.4), its
triangular form (5.6)-(5.12) (model M8), Thm 4.3.4 with the constraint outputs (5.13)-(5.14) (sec.
5.3.3) and with the IMU yaw rate (5.15)-(5.16) (sec. 5.3.5); the EKF comparison of sec. 5.3.5.

Model: ``z = (X, X', X'', Y, Y', Y'')``, ``z' = A z + B f(z)``, ``f = -gamma(z)^2 (z2, z5)``,
``gamma = (z2 z6 - z5 z3)/(z2^2 + z5^2)``; outputs ``y = (X, Y)`` (GNSS position), ``h1 = |v|``
(GNSS speed), ``h2 = z2 z3 + z5 z6 = 0`` (pseudo-measurement: constant speed, always available) and,
fused, ``h3 = gamma`` (gyro). Observer (4.45)-(4.46):
``z_hat' = A z_hat + B f(z_hat) + T(theta) K (y - C z_hat) + T(theta) N theta^-3 (z - h(z_hat))``,
``T = blkdiag(diag(theta, theta^2, theta^3) x 2)``. Gains: :mod:`roadtruth.observers.gnss_kinematic_design`.
Outputs: ``psi = atan2(z5, z2)`` (5.12, atan2 not atan; unwrapped), speed ``hypot(z2, z5)`` scored as
``vx_mps`` (the kinematic model has no sideslip: ``v = v_x`` up to ``cos beta``), ``gamma`` as the yaw rate.

CORRECTIONS implemented: ``z6' = -gamma^2 z5`` (printed ``+``); ``f = -gamma^2 (z2, z5)`` (printed
``(-z5 gamma, z2 gamma)``, which is ``(z3, z6)`` and makes the chain wrong); ``psi = atan2``.

Sampled, delayed data (choices the thesis, working offline with interpolation, does not need):

* The observer runs on a **delayed time axis** ``t - gnss_latency_s``: a GNSS sample arriving at ``t``
  was taken at ``t - latency``; feeding it to a state at ``t`` would inject a 0.1 s-old position (2.5 m
  at 25 m/s) through gains of hundreds of rad/s. The estimate at ``t`` is the chain predicted
  forward over the latency (``X + L X' + L^2/2 X''``). Gyro samples (latency ``yaw_rate_latency_s``)
  wait in a small queue until the delayed axis reaches their sample time.
* Between samples the position and speed are first-order holds through their last two samples
  (slope from the data, never from the estimate); a sample older than ``hold_s`` is not used (its
  injection is dropped: "position lost", as in the thesis's dropout runs). Consequence, measured on
  the design model (tests): the fast observer follows the straight hold segments, so in a turn its
  curvature (yaw rate) is biased towards 0. An inter-sample output predictor (``w(t_k) = y_k``,
  ``w' = C z_hat'``; Karafyllis & Kravaris, 2009) removes that bias in principle but diverged at
  10 Hz with the certified theta: per sample it corrects the velocity by ``theta K2/K1`` times the
  position innovation, several times the ``1/T`` a 10 Hz loop tolerates.
* Lever arm: the GNSS antenna sits ``antenna_x_m`` ahead of the CG (the automotive preset's -0.5 m);
  ``x_cg = X - antenna_x cos psi`` (lateral and height offsets ignored).
* Start: the first position sample sets ``X, Y``; the velocity starts along ``+x`` with the measured
  speed (the heading is not measured); before it the placeholder is the origin.
* At standstill the heading is unobservable from a velocity: below ``v_min_mps`` the reported heading
  is held.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.tire import jit
from roadtruth.observers.base import EstimateTrack, Observer, StepOutput
from roadtruth.observers.lmi import DesignResult, usable_gains
from roadtruth.observers.registry import register

STATES = ("x_m", "y_m", "psi_rad", "vx_mps", "yaw_rate_radps")
RING = 64  # gyro samples waiting for the delayed axis (0.09 s at 100 Hz = 9)

# parameter vector indices (both kernels)
(P_LG, P_LR, P_HOLD, P_HOLDR, P_SLOPE_GAP, P_ANT, P_VMIN, P_RMAX, P_HMAX, P_FUSED, P_Q1, P_Q2, P_Q3, P_RPOS,
 P_RV, P_RR, P_INITV, N_PAR) = range(18)
# memory indices
(M_TD, M_STARTED, M_PX, M_PY, M_PT, M_SX, M_SY, M_V, M_VT, M_SV, M_R, M_RT, M_PSI, M_RHEAD, M_RTAIL,
 M_LASTX, M_LASTY, N_MEM) = range(18)  # M_LASTX: HGO diverged flag


@jit
def _gamma(z1: float, z2: float, z4: float, z5: float, vmin: float, rmax: float) -> float:
    v2 = z1 * z1 + z4 * z4
    if v2 < vmin * vmin:
        v2 = vmin * vmin
    g = (z1 * z5 - z4 * z2) / v2
    return -rmax if g < -rmax else (rmax if g > rmax else g)


@jit
def _latch(mem: np.ndarray, ring: np.ndarray, t: float, y: np.ndarray, par: np.ndarray) -> None:
    """Store new samples with their sample times (arrival minus latency) and data slopes."""
    ts = t - par[P_LG]
    if y[0] == y[0] and y[1] == y[1]:
        dt = ts - mem[M_PT]
        if mem[M_PT] > -1e300 and 0.0 < dt <= par[P_SLOPE_GAP]:
            mem[M_SX] = (y[0] - mem[M_PX]) / dt
            mem[M_SY] = (y[1] - mem[M_PY]) / dt
        else:
            mem[M_SX] = 0.0
            mem[M_SY] = 0.0
        mem[M_PX], mem[M_PY], mem[M_PT] = y[0], y[1], ts
    if y[2] == y[2]:
        dt = ts - mem[M_VT]
        mem[M_SV] = (y[2] - mem[M_V]) / dt if (mem[M_VT] > -1e300 and 0.0 < dt <= par[P_SLOPE_GAP]) else 0.0
        mem[M_V], mem[M_VT] = y[2], ts
    if par[P_FUSED] > 0.5 and y[3] == y[3]:
        tail = int(mem[M_RTAIL])
        if tail - int(mem[M_RHEAD]) >= RING:  # queue full: drop the oldest
            mem[M_RHEAD] += 1.0
        ring[tail % RING, 0] = t - par[P_LR]
        ring[tail % RING, 1] = y[3]
        mem[M_RTAIL] = tail + 1.0


@jit
def _pop_gyro(mem: np.ndarray, ring: np.ndarray, td: float) -> int:
    """Move gyro samples taken at or before ``td`` into the held value; returns how many."""
    k = 0
    while int(mem[M_RHEAD]) < int(mem[M_RTAIL]):
        i = int(mem[M_RHEAD]) % RING
        if ring[i, 0] > td:
            break
        mem[M_R], mem[M_RT] = ring[i, 1], ring[i, 0]
        mem[M_RHEAD] += 1.0
        k += 1
    return k


@jit
def _hgo_rhs(z: np.ndarray, tau: float, mem: np.ndarray, L: np.ndarray, M: np.ndarray, par: np.ndarray,
             out: np.ndarray) -> None:
    vmin, rmax = par[P_VMIN], par[P_RMAX]
    g = _gamma(z[1], z[2], z[4], z[5], vmin, rmax)
    out[0], out[1], out[2] = z[1], z[2], -g * g * z[1]
    out[3], out[4], out[5] = z[4], z[5], -g * g * z[4]
    age = tau - mem[M_PT]
    if 0.0 <= age <= par[P_HOLD]:
        ex = mem[M_PX] + mem[M_SX] * age - z[0]
        ey = mem[M_PY] + mem[M_SY] * age - z[3]
        for j in range(6):
            out[j] += L[j, 0] * ex + L[j, 1] * ey
    v = math.sqrt(z[1] * z[1] + z[4] * z[4])
    age = tau - mem[M_VT]
    if 0.0 <= age <= par[P_HOLD]:
        ev = mem[M_V] + mem[M_SV] * age - v
        for j in range(6):
            out[j] += M[j, 0] * ev
    eo = -(z[1] * z[2] + z[4] * z[5])  # pseudo-measurement 0 minus h2
    for j in range(6):
        out[j] += M[j, 1] * eo
    if par[P_FUSED] > 0.5:
        age = tau - mem[M_RT]
        if 0.0 <= age <= par[P_HOLDR]:
            v2 = v * v if v > vmin else vmin * vmin
            er = mem[M_R] - (z[1] * z[5] - z[4] * z[2]) / v2
            for j in range(6):
                out[j] += M[j, 2] * er
    out[6] = 0.0  # spare slots (kept zero)
    out[7] = 0.0


@jit
def _start(z: np.ndarray, mem: np.ndarray, par: np.ndarray) -> bool:
    if mem[M_STARTED] > 0.5:
        return True
    if mem[M_PT] < -1e300:
        return False
    v0 = mem[M_V] if mem[M_VT] > -1e300 else par[P_INITV]
    z[:] = 0.0
    z[0], z[3], z[1] = mem[M_PX], mem[M_PY], v0
    mem[M_STARTED] = 1.0
    return False


@jit
def hgo_advance(z: np.ndarray, mem: np.ndarray, ring: np.ndarray, t: float, y: np.ndarray, L: np.ndarray,
                M: np.ndarray, par: np.ndarray, k1: np.ndarray, k2: np.ndarray, k3: np.ndarray,
                k4: np.ndarray, zt: np.ndarray) -> None:
    """One row: latch samples, integrate the HGO on the delayed axis up to ``t - gnss_latency`` (RK4)."""
    _latch(mem, ring, t, y, par)
    td = t - par[P_LG]
    t0 = mem[M_TD]
    mem[M_TD] = td
    _pop_gyro(mem, ring, td)
    if mem[M_LASTX] > 0.5 or not _start(z, mem, par):  # diverged (frozen) or not started
        return
    h = td - t0
    if not h > 0.0:
        return
    n = int(math.ceil(h / par[P_HMAX]))
    hs = h / n
    tau = t0
    for _ in range(n):
        _hgo_rhs(z, tau, mem, L, M, par, k1)
        for j in range(8):
            zt[j] = z[j] + 0.5 * hs * k1[j]
        _hgo_rhs(zt, tau + 0.5 * hs, mem, L, M, par, k2)
        for j in range(8):
            zt[j] = z[j] + 0.5 * hs * k2[j]
        _hgo_rhs(zt, tau + 0.5 * hs, mem, L, M, par, k3)
        for j in range(8):
            zt[j] = z[j] + hs * k3[j]
        _hgo_rhs(zt, tau + hs, mem, L, M, par, k4)
        for j in range(8):
            z[j] += hs / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
        tau += hs
    for j in range(6):
        if not abs(z[j]) < 1e12:
            # An uncertified (printed) design can diverge: freeze the estimate at a finite absurd
            # value (the harness reports it as diverged) instead of restarting as if nothing happened.
            for i in range(6):
                zi = z[i]
                z[i] = 1e12 if not zi < 1e12 else (-1e12 if not zi > -1e12 else zi)
            mem[M_LASTX] = 1.0
            break


@jit
def _report(x: float, y: float, vxw: float, vyw: float, r: float, mem: np.ndarray, par: np.ndarray,
            out: np.ndarray) -> None:
    """Heading (unwrapped, held below v_min), CG position from the antenna, speed, yaw rate."""
    v = math.sqrt(vxw * vxw + vyw * vyw)
    psi = mem[M_PSI]
    if v >= par[P_VMIN]:
        raw = math.atan2(vyw, vxw)
        psi = raw + 2.0 * math.pi * round((psi - raw) / (2.0 * math.pi))
        mem[M_PSI] = psi
    a = par[P_ANT]
    out[0] = x - a * math.cos(psi)
    out[1] = y - a * math.sin(psi)
    out[2] = psi
    out[3] = v
    out[4] = r


@jit
def hgo_output(z: np.ndarray, mem: np.ndarray, par: np.ndarray, out: np.ndarray) -> None:
    """Estimate at the current time: the chain predicted over the GNSS latency."""
    lg = par[P_LG]
    x = z[0] + lg * z[1] + 0.5 * lg * lg * z[2]
    y = z[3] + lg * z[4] + 0.5 * lg * lg * z[5]
    vx, ax = z[1] + lg * z[2], z[2]
    vy, ay = z[4] + lg * z[5], z[5]
    r = _gamma(vx, ax, vy, ay, par[P_VMIN], par[P_RMAX])
    _report(x, y, vx, vy, r, mem, par, out)


@jit
def hgo_run(t: np.ndarray, Y: np.ndarray, z: np.ndarray, mem: np.ndarray, ring: np.ndarray, L: np.ndarray,
            M: np.ndarray, par: np.ndarray) -> np.ndarray:
    n = t.size
    X = np.empty((n, 5))
    k1, k2, k3, k4, zt = np.empty(8), np.empty(8), np.empty(8), np.empty(8), np.empty(8)
    out = np.empty(5)
    for i in range(n):
        hgo_advance(z, mem, ring, t[i], Y[i], L, M, par, k1, k2, k3, k4, zt)
        hgo_output(z, mem, par, out)
        X[i] = out
    return X


# ---- EKF on the kinematic model (5.4) with acceleration: s = (X, Y, psi, v, a, r) ----------------------

@jit
def _ekf_predict(s: np.ndarray, P: np.ndarray, h: float, par: np.ndarray) -> None:
    c, sn = math.cos(s[2]), math.sin(s[2])
    v = s[3]
    F = np.eye(6)
    F[0, 2], F[0, 3] = -v * sn * h, c * h
    F[1, 2], F[1, 3] = v * c * h, sn * h
    F[2, 5] = h
    F[3, 4] = h
    s[0] += v * c * h
    s[1] += v * sn * h
    s[2] += s[5] * h
    s[3] += s[4] * h
    P[:, :] = F @ P @ F.T
    P[0, 0] += par[P_Q1] * h
    P[1, 1] += par[P_Q1] * h
    P[2, 2] += 1e-6 * h
    P[3, 3] += 1e-4 * h
    P[4, 4] += par[P_Q2] * h
    P[5, 5] += par[P_Q3] * h
    for i in range(6):
        for j in range(i + 1, 6):
            m = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = m
            P[j, i] = m


@jit
def _ekf_update(s: np.ndarray, P: np.ndarray, H: np.ndarray, resid: float, R: float) -> None:
    """Scalar update in Joseph form."""
    PH = P @ H
    S = H @ PH + R
    K = PH / S
    for j in range(6):
        s[j] += K[j] * resid
    IKH = np.eye(6) - np.outer(K, H)
    P[:, :] = IKH @ P @ IKH.T + np.outer(K, K) * R


@jit
def ekf_advance(s: np.ndarray, P: np.ndarray, mem: np.ndarray, ring: np.ndarray, t: float, y: np.ndarray,
                par: np.ndarray) -> None:
    """One row: latch, predict on the delayed axis, update with the samples taken by then."""
    new_pos = y[0] == y[0] and y[1] == y[1]
    new_v = y[2] == y[2]
    _latch(mem, ring, t, y, par)
    td = t - par[P_LG]
    t0 = mem[M_TD]
    mem[M_TD] = td
    k = _pop_gyro(mem, ring, td)
    if mem[M_STARTED] < 0.5:
        if mem[M_PT] < -1e300:
            return
        s[:] = 0.0
        s[0], s[1] = mem[M_PX], mem[M_PY]
        s[3] = mem[M_V] if mem[M_VT] > -1e300 else par[P_INITV]
        P[:, :] = 0.0
        P[0, 0] = P[1, 1] = par[P_RPOS]
        P[2, 2] = math.pi ** 2      # the heading is not measured: uniform-ish prior
        P[3, 3], P[4, 4], P[5, 5] = 4.0, 4.0, 0.25
        mem[M_STARTED] = 1.0
        return
    h = td - t0
    if h > 0.0:
        n = int(math.ceil(h / 0.01))
        for _ in range(n):
            _ekf_predict(s, P, h / n, par)
    H = np.zeros(6)
    if new_pos:
        H[:] = 0.0
        H[0] = 1.0
        _ekf_update(s, P, H, mem[M_PX] - s[0], par[P_RPOS])
        H[:] = 0.0
        H[1] = 1.0
        _ekf_update(s, P, H, mem[M_PY] - s[1], par[P_RPOS])
    if new_v:
        H[:] = 0.0
        H[3] = 1.0
        _ekf_update(s, P, H, mem[M_V] - s[3], par[P_RV])
    if par[P_FUSED] > 0.5 and k > 0:
        H[:] = 0.0
        H[5] = 1.0
        _ekf_update(s, P, H, mem[M_R] - s[5], par[P_RR])
    for j in range(6):
        if not (s[j] - s[j] == 0.0):
            s[:] = 0.0
            s[0], s[1] = mem[M_PX], mem[M_PY]
            break


@jit
def ekf_output(s: np.ndarray, mem: np.ndarray, par: np.ndarray, out: np.ndarray) -> None:
    """Estimate at the current time: the model predicted over the GNSS latency (Euler, 10 ms steps)."""
    x, y, psi, v = s[0], s[1], s[2], s[3]
    n = int(math.ceil(par[P_LG] / 0.01)) if par[P_LG] > 0.0 else 0
    h = par[P_LG] / n if n > 0 else 0.0
    for _ in range(n):
        x += v * math.cos(psi) * h
        y += v * math.sin(psi) * h
        psi += s[5] * h
        v += s[4] * h
    # report through the same heading logic (velocity vector of the predicted state)
    _report(x, y, v * math.cos(psi), v * math.sin(psi), s[5], mem, par, out)


@jit
def ekf_run(t: np.ndarray, Y: np.ndarray, s: np.ndarray, P: np.ndarray, mem: np.ndarray, ring: np.ndarray,
            par: np.ndarray) -> np.ndarray:
    n = t.size
    X = np.empty((n, 5))
    out = np.empty(5)
    for i in range(n):
        ekf_advance(s, P, mem, ring, t[i], Y[i], par)
        ekf_output(s, mem, par, out)
        X[i] = out
    return X


# ---- observer classes ------------------------------------------------------------------------------

_COMMON: dict[str, Any] = {
    "gnss_latency_s": 0.1,      # automotive preset; 0 on data without latency
    "yaw_rate_latency_s": 0.01,
    "hold_s": 0.12,             # a GNSS sample is used for at most this long [s]
    "slope_gap_s": 0.5,         # first-order hold only through samples at most this far apart [s]
    "antenna_x_m": -0.5,        # antenna ahead of the CG [m] (automotive preset: 0.5 m behind)
    "v_min_mps": 2.0,           # design box; below it gamma uses v_min and the heading is held
    "v_max_mps": 30.0,
    "a_max_mps2": 6.0,
    "r_max_radps": 0.6,
    "init_speed_mps": 2.0,      # initial speed when no speed sample has arrived
}
_HGO: dict[str, Any] = {**_COMMON, "lambda_": 1.0, "sigma": 5.0, "z_min": 1.0, "theta_factor": 2.0,
                        "use_cache": True}
_EKF: dict[str, Any] = {**_COMMON, "q_pos_m2ps": 0.01, "q_accel_m2ps5": 4.0, "q_yaw_acc_rad2ps3": 0.25,
                        "r_pos_m": 1.55, "r_speed_mps": 0.1, "r_yaw_rate_radps": 0.005}


class _GnssKinematicBase(Observer):
    """Shared option parsing, reset and run/step plumbing of the GNSS kinematic observers."""

    states = STATES
    fused = False

    def __init__(self, vehicle: Any, **options: Any) -> None:
        super().__init__(vehicle, **options)
        try:
            vals = {k: float(self.options[k]) for k in _COMMON}
        except (TypeError, ValueError) as exc:
            raise InputError(f"bad option value ({exc})", field=f"observer {self.name}") from exc
        if not (vals["gnss_latency_s"] >= 0 and vals["yaw_rate_latency_s"] >= 0 and vals["hold_s"] > 0
                and 0 < vals["v_min_mps"] < vals["v_max_mps"] and vals["a_max_mps2"] > 0 and vals["r_max_radps"] > 0
                and vals["yaw_rate_latency_s"] <= vals["gnss_latency_s"] + 1.0):
            raise InputError("bad option: need latencies >= 0, hold_s > 0, 0 < v_min < v_max, a_max, r_max > 0",
                             field=f"observer {self.name}")
        self._vals = vals
        self._par: np.ndarray | None = None
        self.reset(0.0)

    def _params(self) -> np.ndarray:
        v = self._vals
        par = np.zeros(N_PAR)
        par[P_LG], par[P_LR] = v["gnss_latency_s"], v["yaw_rate_latency_s"]
        par[P_HOLD], par[P_HOLDR], par[P_SLOPE_GAP] = v["hold_s"], 0.05, v["slope_gap_s"]
        par[P_ANT], par[P_VMIN], par[P_RMAX] = v["antenna_x_m"], v["v_min_mps"], v["r_max_radps"]
        par[P_FUSED], par[P_INITV] = 1.0 if self.fused else 0.0, v["init_speed_mps"]
        par[P_HMAX] = 1e-3
        return par

    def reset(self, t0_s: float, x0: Mapping[str, float] | None = None) -> None:
        if x0:
            bad = sorted(set(x0) - set(STATES[:4]))
            if bad:
                raise InputError(f"cannot initialise state {bad[0]!r} (settable: {', '.join(STATES[:4])})",
                                 field=f"observer {self.name} x0")
        self._mem = np.zeros(N_MEM)
        self._mem[[M_PT, M_VT, M_RT]] = -1e308
        self._mem[M_TD] = float(t0_s) - self._vals["gnss_latency_s"]
        self._ring = np.zeros((RING, 2))
        self._x0 = dict(x0) if x0 else None
        self._reset_state()

    def _reset_state(self) -> None:
        raise NotImplementedError

    def _apply_x0(self) -> None:
        """Start from ``x0`` (x_m, y_m, psi_rad, vx_mps at the reset time) instead of the first sample."""
        raise NotImplementedError

    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        out = self._step(float(t_s), np.asarray(y, dtype=float).reshape(len(self.inputs)))
        return StepOutput(out)

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        t = np.asarray(t, dtype=float)
        Y = np.ascontiguousarray(np.asarray(Y, dtype=float).reshape(len(t), len(self.inputs)))
        if len(t):
            self.reset(float(t[0]), x0)
        X = self._run(t, Y) if len(t) else np.zeros((0, len(STATES)))
        return EstimateTrack(self.name, STATES, t, X)


class _HgoBase(_GnssKinematicBase):
    default_options = dict(_HGO)

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.gnss_kinematic_design import design_for
        keys = ("lambda_", "sigma", "z_min", "theta_factor", "v_min_mps", "v_max_mps", "a_max_mps2", "r_max_radps")
        opts = {k: float(self.options[k]) for k in keys}
        return design_for(self.name, self.variant, opts, use_cache=bool(self.options["use_cache"]))

    def gains(self) -> tuple[np.ndarray, np.ndarray, float]:
        """``(L (6, 2), M (6, p_z), theta)``: ``L = T(theta) K``, ``M = T(theta) N / theta^3``."""
        d = self.design()
        usable_gains(self.name, d, ("K", "N", "theta"))
        th = float(d.gain("theta")[0])
        T = np.array([th, th ** 2, th ** 3] * 2).reshape(6, 1)
        N = d.gain("N").reshape(6, -1)
        M = np.zeros((6, 3))
        M[:, : N.shape[1]] = T * N / th ** 3
        return T * d.gain("K").reshape(6, 2), M, th

    def _reset_state(self) -> None:
        self._z = np.zeros(8)  # z_hat (6) and two spare slots
        self._tmp = [np.empty(8) for _ in range(5)]
        self._out = np.empty(5)
        if self._x0:
            self._apply_x0()

    def _apply_x0(self) -> None:
        x0 = self._x0 or {}
        psi, v = x0.get("psi_rad", 0.0), x0.get("vx_mps", self._vals["init_speed_mps"])
        a = self._vals["antenna_x_m"]
        self._z[:] = [x0.get("x_m", 0.0) + a * math.cos(psi), v * math.cos(psi), 0.0,
                      x0.get("y_m", 0.0) + a * math.sin(psi), v * math.sin(psi), 0.0, 0.0, 0.0]
        self._mem[M_STARTED] = 1.0
        self._mem[M_PSI] = psi

    def _ensure(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._par is None:
            L, M, _ = self.gains()
            par = self._params()
            rho = float(np.abs(np.linalg.eigvals(np.kron(np.eye(2), np.diag([1.0, 1.0], k=1))
                                                 - L @ np.kron(np.eye(2), [[1.0, 0.0, 0.0]]))).max())
            par[P_HMAX] = min(0.01, 1.0 / max(rho, 1e-9))  # RK4 is stable to 2.78 / rho
            self._par, self._L, self._M = par, np.ascontiguousarray(L), np.ascontiguousarray(M)
        return self._par, self._L, self._M

    def _step(self, t: float, y: np.ndarray) -> np.ndarray:
        par, L, M = self._ensure()
        k1, k2, k3, k4, zt = self._tmp
        hgo_advance(self._z, self._mem, self._ring, t, y if self.fused else np.append(y, np.nan), L, M, par,
                    k1, k2, k3, k4, zt)
        hgo_output(self._z, self._mem, par, self._out)
        return self._out.copy()

    def _run(self, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
        par, L, M = self._ensure()
        Yf = Y if self.fused else np.column_stack([Y, np.full(len(t), np.nan)])
        return hgo_run(t, np.ascontiguousarray(Yf), self._z, self._mem, self._ring, L, M, par)

    def internal_state(self) -> np.ndarray:
        """``z_hat`` (6,) on the delayed axis: X [m], X' [m/s], X'' [m/s^2], Y, Y', Y''."""
        return self._z[:6].copy()


@register
class HgoGnssKinematic(_HgoBase):
    """Generalized HGO (Thm 4.3.4) on the kinematic chains from GNSS position + speed (+ orthogonality)."""

    name = "hgo_gnss_kinematic"
    citation = ("H. Bessafa, PhD thesis, Univ. Lorraine 2024, Thm 4.3.4 (4.44)-(4.60) on model (5.6)-(5.14), "
                "sec. 5.3.3")
    inputs = ("gnss_x_m", "gnss_y_m", "gnss_speed_mps")
    variant = "base"


@register
class HgoGnssKinematicPrinted(HgoGnssKinematic):
    """Same observer with the gains printed in sec. 5.3.3 (K, N, theta = 5.2)."""

    name = "hgo_gnss_kinematic_printed"
    citation = "H. Bessafa, PhD thesis, Univ. Lorraine 2024, sec. 5.3.3 (printed K, N, theta = 5.2)"
    variant = "base_printed"


@register
class HgoGnssKinematicImu(_HgoBase):
    """Generalized HGO fused with the IMU yaw rate (h3 = gamma, sec. 5.3.5)."""

    name = "hgo_gnss_kinematic_imu"
    citation = ("H. Bessafa, PhD thesis, Univ. Lorraine 2024, Thm 4.3.4 on model (5.6)-(5.16) with the yaw "
                "rate, sec. 5.3.5")
    inputs = ("gnss_x_m", "gnss_y_m", "gnss_speed_mps", "yaw_rate_radps")
    variant = "fused"
    fused = True


@register
class HgoGnssKinematicImuPrinted(HgoGnssKinematicImu):
    """Fused HGO with the gains printed in sec. 5.3.5 (K, N, theta = 3)."""

    name = "hgo_gnss_kinematic_imu_printed"
    citation = "H. Bessafa, PhD thesis, Univ. Lorraine 2024, sec. 5.3.5 (printed fusion K, N, theta = 3)"
    variant = "fused_printed"


@register
class EkfGnssKinematic(_GnssKinematicBase):
    """EKF on the kinematic model (5.4) with acceleration, from GNSS position and speed (sec. 5.3.5)."""

    name = "ekf_gnss_kinematic"
    citation = "H. Bessafa, PhD thesis, Univ. Lorraine 2024, sec. 5.3.5 (EKF on model (5.4) with acceleration)"
    inputs = ("gnss_x_m", "gnss_y_m", "gnss_speed_mps")
    default_options = dict(_EKF)

    def _params(self) -> np.ndarray:
        par = super()._params()
        o = self.options
        par[P_Q1], par[P_Q2], par[P_Q3] = (float(o[k]) for k in ("q_pos_m2ps", "q_accel_m2ps5", "q_yaw_acc_rad2ps3"))
        par[P_RPOS], par[P_RV], par[P_RR] = (float(o[k]) ** 2 for k in ("r_pos_m", "r_speed_mps", "r_yaw_rate_radps"))
        return par

    def _reset_state(self) -> None:
        self._s = np.zeros(6)
        self._P = np.eye(6)
        self._out = np.empty(5)
        if self._par is None:
            self._par = self._params()
        if self._x0:
            x0 = self._x0
            psi = x0.get("psi_rad", 0.0)
            a = self._vals["antenna_x_m"]
            self._s[:] = [x0.get("x_m", 0.0) + a * math.cos(psi), x0.get("y_m", 0.0) + a * math.sin(psi), psi,
                          x0.get("vx_mps", self._vals["init_speed_mps"]), 0.0, 0.0]
            self._P = np.diag([1.0, 1.0, 0.01, 0.25, 1.0, 0.01])
            self._mem[M_STARTED] = 1.0
            self._mem[M_PSI] = psi

    def _step(self, t: float, y: np.ndarray) -> np.ndarray:
        ekf_advance(self._s, self._P, self._mem, self._ring, t, y if self.fused else np.append(y, np.nan),
                    self._par)
        ekf_output(self._s, self._mem, self._par, self._out)
        return self._out.copy()

    def _run(self, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
        Yf = Y if self.fused else np.column_stack([Y, np.full(len(t), np.nan)])
        return ekf_run(t, np.ascontiguousarray(Yf), self._s, self._P, self._mem, self._ring, self._par)


@register
class EkfGnssKinematicImu(EkfGnssKinematic):
    """EKF on the same model also updated with the IMU yaw rate (the fusion comparison of sec. 5.3.5)."""

    name = "ekf_gnss_kinematic_imu"
    citation = "H. Bessafa, PhD thesis, Univ. Lorraine 2024, sec. 5.3.5 (EKF with GNSS and IMU yaw rate)"
    inputs = ("gnss_x_m", "gnss_y_m", "gnss_speed_mps", "yaw_rate_radps")
    fused = True
