r"""Kalman-filter baselines on the bicycle model: linear KF, EKF and UKF.

State ``x = (v_y, r)``; inputs ``delta`` and ``v_x`` drive the model, ``r`` (gyro) and ``a_y``
(accelerometer) correct it, each only when a new sample arrives.

* ``kf_bicycle``: linear speed-scheduled model (3.17), exact ZOH per step (closed form,
  :func:`roadtruth.observers.bicycle.expm2_zoh`), ``a_y = (F_yf + F_yr)/m = C(v_x) x + D delta``.
* ``ekf_bicycle`` / ``ukf_bicycle``: the nonlinear single-track model of
  :mod:`roadtruth.observers.tire_curves` (Magic Formula axle forces with peak ``grip * mu * F_z,static``:
  the vehicle's tire grip times the assumed road friction, option ``mu``; cornering stiffness kept).

Process noise: white accelerations with spectral densities ``q = std^2`` [(m/s^2)^2/Hz,
(rad/s^2)^2/Hz], discretised as ``Q_d = diag(q) h``. Numerical robustness (named choices): Joseph-form
updates, covariances kept symmetric by construction, the 2x2 correlation clipped to
``|p12| <= sqrt(p11 p22)``, and (UKF) sigma points from a closed-form eigendecomposition with
eigenvalues clipped at a floor, so no Cholesky factorisation can fail. Derived outputs ``beta``,
``alpha_f``, ``alpha_r`` carry first-order propagated variances.

Robustness of the nonlinear filters on real data (a tire model is never exactly the car's):

* **State constraints by estimate projection** (D. Simon, "Kalman filtering with state constraints:
  a survey of linear and nonlinear algorithms", IET Control Theory Appl. 4(8):1303-1318, 2010):
  after every step the estimate is projected onto the physically plausible box
  ``|v_y| <= tan(beta_max) v_x``, ``|r| <= (1 + margin) min(v_x tan(delta_max)/L, grip mu g / v_x)``
  (kinematic turning limit at low speed, friction limit at high speed) with the weight
  ``W = P^-1`` (the maximum-probability projection: a clipped ``v_y`` drags ``r`` along its
  correlation). ``P`` is kept, a conservative choice (projecting onto a convex set that holds the
  true state never moves the estimate away from it), except that its diagonal is capped at the
  squared half-widths of the box (no distribution on the box has a larger variance), which also
  stops an unstable linearisation past the tire peak from inflating it without bound.
* **Innovation clipping**: each scalar innovation is clipped to ``innovation_gate`` standard
  deviations of its predicted spread ``sqrt(S)`` before the gain is applied (a simplified
  Huber-type update; cf. Karlgaard & Schaub, "Huber-based divided difference filtering", J. Guid.
  Control Dyn. 30(3), 2007). A persistent model-mismatch innovation (measured ``a_y`` beyond the
  model's peak) then moves the state a bounded amount per sample instead of driving it past the
  tire peak, where the model's slope has the wrong sign and the filter runs away. On the Revs log
  with the tire curves capped at 1 g this clipping alone keeps both filters bounded; the box alone
  only holds them at its edge.

The EKF and UKF steps are compiled kernels (``ekf_advance``, ``ukf_advance``) on floats; their
``py_func`` is the plain-Python twin, tested equal. ``step()`` and ``run()`` of every filter call the
same compiled loop (:mod:`roadtruth.observers.kalman_loop`, one sample or the whole log), so they agree bit for bit. numba caches each kernel per source file: after
editing ``observers/tire_curves.py`` (or ``expm2_zoh``) delete ``observers/__pycache__/*.nbi, *.nbc``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.tire import jit
from roadtruth.harness.truth.vehicle import G
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver, StepOutput
from roadtruth.observers.bicycle import axle_stiffness, expm2_zoh
from roadtruth.observers.registry import register
from roadtruth.observers.tire_curves import (
    M_GRIP,
    M_IZ,
    M_LF,
    M_LR,
    M_MASS,
    model_array,
    peak_scale,
    propagate,
    rk4,
    set_grip,
    single_track,
    substeps,
)

_STATES = ("vy_mps", "yaw_rate_radps", "beta_rad", "alpha_f_rad", "alpha_r_rad")
_OPTIONS: dict[str, float] = {
    "process_std_vy_mps2": 0.5,     # sqrt of the spectral density of the v_y' model error
    "process_std_r_radps2": 0.1,    # same for r'
    "meas_std_r_radps": 0.01,
    "meas_std_ay_mps2": 0.3,
    "init_std_vy_mps": 1.0,         # the default initial state (v_y = 0, r = 0) is deliberately neutral
    "init_std_r_radps": 0.1,
    "vx_min_mps": 2.0,              # the models are singular at v_x = 0
}
_NONLINEAR_OPTIONS: dict[str, float] = {
    **_OPTIONS,
    "mu": 1.0,                      # road friction the tire curves assume (peak = grip * mu * F_z)
    "beta_max_rad": 0.5,            # plausible set: |v_y| <= tan(beta_max) v_x
    "constraint_margin": 0.5,       # |r| <= (1 + margin) x (kinematic / friction limit)
    "innovation_gate": 3.0,         # innovations clipped to this many predicted std (inf: off)
    "grip_headroom": 1.1,           # curve peak >= this x low-passed measured |a_y| (0: grip not adapted)
    "grip_filter_s": 0.2,           # time constant of that low-pass [s]
    "grip_recovery_s": 30.0,        # time constant of the return to the configured peak [s]
    "grip_max": 3.0,                # largest peak scale the adaptation gives [1] (x m g of lateral force)
}
_PSD_FLOOR = 1e-12

# Indices of the filter parameter array of the compiled kernels.
(F_Q1, F_Q2, F_RR, F_RAY, F_GATE, F_TANB, F_RKIN, F_ALIM, F_K0, F_HEAD, F_TGF, F_TREC, F_KMAX, F_MARGIN,
 N_FILT) = range(15)
_W0, _WI = 1.0 / 3.0, 1.0 / 6.0  # UKF weights, n = 2, kappa = 1: kappa/(n+kappa), 1/(2(n+kappa))
_SIGMA_SCALE = 3.0               # n + kappa

_expm2 = jit(expm2_zoh)


# ---- scalar 2x2 filter algebra (compiled; the linear KF calls the same functions) --------------------

@jit
def _psd2(p11: float, p12: float, p22: float) -> tuple[float, float, float]:
    """Keep a symmetric 2x2 covariance positive semidefinite (diagonal floor, correlation clip)."""
    p11 = p11 if p11 > _PSD_FLOOR else _PSD_FLOOR
    p22 = p22 if p22 > _PSD_FLOOR else _PSD_FLOOR
    lim = math.sqrt(p11 * p22) * (1.0 - 1e-9)
    if p12 > lim:
        p12 = lim
    elif p12 < -lim:
        p12 = -lim
    return p11, p12, p22


@jit
def _joseph(x1: float, x2: float, p11: float, p12: float, p22: float, h1: float, h2: float,
            resid: float, R: float, gate: float) -> tuple[float, float, float, float, float]:
    """Scalar update ``z = h1 x1 + h2 x2 + v`` in Joseph form, innovation clipped to ``gate sqrt(S)``."""
    ph1 = p11 * h1 + p12 * h2
    ph2 = p12 * h1 + p22 * h2
    S = h1 * ph1 + h2 * ph2 + R
    lim = gate * math.sqrt(S)
    if resid > lim:
        resid = lim
    elif resid < -lim:
        resid = -lim
    k1, k2 = ph1 / S, ph2 / S
    a11, a12, a21, a22 = 1.0 - k1 * h1, -k1 * h2, -k2 * h1, 1.0 - k2 * h2
    m11, m12 = a11 * p11 + a12 * p12, a11 * p12 + a12 * p22
    m21, m22 = a21 * p11 + a22 * p12, a21 * p12 + a22 * p22
    n11 = m11 * a11 + m12 * a12 + k1 * k1 * R
    n12 = m11 * a21 + m12 * a22 + k1 * k2 * R
    n22 = m21 * a21 + m22 * a22 + k2 * k2 * R
    n11, n12, n22 = _psd2(n11, n12, n22)
    return x1 + k1 * resid, x2 + k2 * resid, n11, n12, n22


@jit
def _propagate_cov(E: tuple[float, float, float, float], p11: float, p12: float, p22: float,
                   q1: float, q2: float) -> tuple[float, float, float]:
    """``E P E^T + diag(q1, q2)``."""
    m11, m12 = E[0] * p11 + E[1] * p12, E[0] * p12 + E[1] * p22
    m21, m22 = E[2] * p11 + E[3] * p12, E[2] * p12 + E[3] * p22
    return _psd2(m11 * E[0] + m12 * E[1] + q1, m11 * E[2] + m12 * E[3], m21 * E[2] + m22 * E[3] + q2)


# ---- state constraints (Simon 2010, estimate projection) ------------------------------------------

@jit
def plausible_box(v: float, filt: np.ndarray) -> tuple[float, float]:
    """Half-widths ``(v_y,max [m/s], r_max [rad/s])`` of the plausible set at speed ``v`` > 0."""
    return filt[F_TANB] * v, min(filt[F_RKIN] * v, filt[F_ALIM] / v)


@jit
def project_box(vy: float, r: float, p11: float, p12: float, p22: float, a: float,
                b: float) -> tuple[float, float]:
    """``argmin (x - x_hat)^T P^-1 (x - x_hat)`` over ``|v_y| <= a``, ``|r| <= b``.

    The minimiser of a convex quadratic over a box lies inside, in the relative interior of a face
    (the unconstrained projection onto that face's line) or at a corner: every feasible candidate is
    evaluated and the cheapest kept. ``P`` must be positive definite (``_psd2`` guarantees it).
    """
    if -a <= vy <= a and -b <= r <= b:
        return vy, r
    slack = 1e-12 * (a + b)
    best, bx, by = math.inf, vy, r
    for k in range(8):
        if k < 2:       # face v_y = +-a; r moves along the correlation
            cx = a if k == 0 else -a
            cy = r + p12 / p11 * (cx - vy)
        elif k < 4:     # face r = +-b
            cy = b if k == 2 else -b
            cx = vy + p12 / p22 * (cy - r)
        else:           # corners
            cx = a if k % 2 == 0 else -a
            cy = b if k < 6 else -b
        if abs(cx) > a + slack or abs(cy) > b + slack:
            continue
        dx, dy = cx - vy, cy - r
        cost = p22 * dx * dx - 2.0 * p12 * dx * dy + p11 * dy * dy  # det(P) x Mahalanobis^2
        if cost < best:
            best, bx, by = cost, cx, cy
    return min(max(bx, -a), a), min(max(by, -b), b)


@jit
def _constrain(vy: float, r: float, p11: float, p12: float, p22: float, v: float,
               filt: np.ndarray) -> tuple[float, float, float, float, float]:
    """Project the estimate onto the plausible box and cap the variances at its squared half-widths."""
    a, b = plausible_box(v, filt)
    vy, r = project_box(vy, r, p11, p12, p22, a, b)
    # Capping a diagonal entry scales its row and column (a congruence): the correlation is kept.
    if p11 > a * a:
        p12 *= a / math.sqrt(p11)
        p11 = a * a
    if p22 > b * b:
        p12 *= b / math.sqrt(p22)
        p22 = b * b
    return vy, r, p11, p12, p22


# ---- grip the car shows (adaptive tire curves) -----------------------------------------------------

@jit
def adapt_grip(ay_lp: float, ay_meas: float, fresh_ay: bool, h: float, model: np.ndarray,
               filt: np.ndarray) -> float:
    """Raise the tire curves to the grip the car shows; returns the new low-passed ``a_y`` [m/s^2].

    A measured lateral acceleration is a lower bound of the friction the tires deliver (the axle forces
    sum to ``m a_y``), so the curves' peak scale is kept at ``k >= headroom |a_y,lp| / g`` (``a_y``
    low-passed with ``grip_filter_s`` against noise and kerb spikes). Above that floor ``k`` relaxes to
    the configured ``grip * mu`` with ``grip_recovery_s``. The cornering stiffness is kept (``set_grip``),
    so the linear range, and every estimate made there, does not change; only the saturation moves.
    The friction box's yaw-rate limit follows ``k``. A road slipperier than configured is not detected:
    until the tires saturate nothing in ``(r, a_y)`` shows it.
    """
    if filt[F_HEAD] <= 0.0:
        return ay_lp
    if fresh_ay and h > 0.0:
        ay_lp += h / (filt[F_TGF] + h) * (ay_meas - ay_lp)
    k0, k = filt[F_K0], model[M_GRIP]
    if h > 0.0:
        k += h / (filt[F_TREC] + h) * (k0 - k)
    floor = filt[F_HEAD] * abs(ay_lp) / G
    k = max(k, floor, k0)
    k = min(k, max(filt[F_KMAX], k0))
    set_grip(model, k)
    filt[F_ALIM] = (1.0 + filt[F_MARGIN]) * k * G
    return ay_lp


# ---- compiled filter steps -------------------------------------------------------------------------

@jit
def ekf_advance(vy: float, r: float, p11: float, p12: float, p22: float, delta: float, v: float, h: float,
                r_meas: float, ay_meas: float, fresh_r: bool, fresh_ay: bool, model: np.ndarray,
                filt: np.ndarray) -> tuple[float, float, float, float, float]:
    """One EKF step: predict over ``h`` [s] (RK4 mean, exact ZOH of the Jacobian per sub-step for P),
    then the gyro and accelerometer updates that arrived, then the constraints. Returns ``(x, P)``."""
    lf, lr, iz, m = model[M_LF], model[M_LR], model[M_IZ], model[M_MASS]
    if h > 0.0:
        n = substeps(h, v, model)
        hs = h / n
        for _ in range(n):
            _, _, _, dff, dfr, kf, kr, cd = single_track(vy, r, delta, v, model)
            j11 = (cd * dff * kf + dfr * kr) / m
            j12 = (cd * dff * lf * kf - dfr * lr * kr) / m - v
            j21 = (lf * cd * dff * kf - lr * dfr * kr) / iz
            j22 = (lf * lf * cd * dff * kf + lr * lr * dfr * kr) / iz
            E, _ = _expm2(j11, j12, j21, j22, hs)
            p11, p12, p22 = _propagate_cov(E, p11, p12, p22, filt[F_Q1] * hs, filt[F_Q2] * hs)
            vy, r = rk4(vy, r, delta, v, hs, model)
    if fresh_r:
        vy, r, p11, p12, p22 = _joseph(vy, r, p11, p12, p22, 0.0, 1.0, r_meas - r, filt[F_RR], filt[F_GATE])
    if fresh_ay:
        ay, _, _, dff, dfr, kf, kr, cd = single_track(vy, r, delta, v, model)
        h1 = (cd * dff * kf + dfr * kr) / m
        h2 = (cd * dff * lf * kf - dfr * lr * kr) / m
        vy, r, p11, p12, p22 = _joseph(vy, r, p11, p12, p22, h1, h2, ay_meas - ay, filt[F_RAY], filt[F_GATE])
    return _constrain(vy, r, p11, p12, p22, v, filt)


@jit
def sigma_columns(p11: float, p12: float, p22: float) -> tuple[float, float, float, float]:
    """Columns ``(s1, s2)`` of ``sqrt((n + kappa) P)`` from the closed-form eigendecomposition of the
    2x2 ``P`` (eigenvalues clipped at a floor); sigma points are ``x``, ``x +- s1``, ``x +- s2``."""
    mid = 0.5 * (p11 + p22)
    rad = math.sqrt(0.25 * (p11 - p22) * (p11 - p22) + p12 * p12)
    l1, l2 = mid + rad, mid - rad
    floor = _PSD_FLOOR + 1e-12 * max(l1, 0.0)
    l1, l2 = max(l1, floor), max(l2, floor)
    th = 0.5 * math.atan2(2.0 * p12, p11 - p22)
    c, s = math.cos(th), math.sin(th)
    a1, a2 = math.sqrt(_SIGMA_SCALE * l1), math.sqrt(_SIGMA_SCALE * l2)
    return a1 * c, a1 * s, -a2 * s, a2 * c


@jit
def ukf_advance(vy: float, r: float, p11: float, p12: float, p22: float, delta: float, v: float, h: float,
                r_meas: float, ay_meas: float, fresh_r: bool, fresh_ay: bool, model: np.ndarray,
                filt: np.ndarray) -> tuple[float, float, float, float, float]:
    """One UKF step (5 sigma points, kappa = 1): sigma-point prediction through the RK4 model, the gyro
    update (linear: exact scalar update), the accelerometer update from fresh sigma points, then the
    constraints. Sequential updates are exact here because the two sensor noises are independent."""
    if h > 0.0:
        s1x, s1y, s2x, s2y = sigma_columns(p11, p12, p22)
        x0, y0 = propagate(vy, r, delta, v, h, model)
        x1, y1 = propagate(vy + s1x, r + s1y, delta, v, h, model)
        x2, y2 = propagate(vy - s1x, r - s1y, delta, v, h, model)
        x3, y3 = propagate(vy + s2x, r + s2y, delta, v, h, model)
        x4, y4 = propagate(vy - s2x, r - s2y, delta, v, h, model)
        vy = _W0 * x0 + _WI * (x1 + x2 + x3 + x4)
        r = _W0 * y0 + _WI * (y1 + y2 + y3 + y4)
        d0x, d1x, d2x, d3x, d4x = x0 - vy, x1 - vy, x2 - vy, x3 - vy, x4 - vy
        d0y, d1y, d2y, d3y, d4y = y0 - r, y1 - r, y2 - r, y3 - r, y4 - r
        p11 = _W0 * d0x * d0x + _WI * (d1x * d1x + d2x * d2x + d3x * d3x + d4x * d4x) + filt[F_Q1] * h
        p12 = _W0 * d0x * d0y + _WI * (d1x * d1y + d2x * d2y + d3x * d3y + d4x * d4y)
        p22 = _W0 * d0y * d0y + _WI * (d1y * d1y + d2y * d2y + d3y * d3y + d4y * d4y) + filt[F_Q2] * h
        p11, p12, p22 = _psd2(p11, p12, p22)
    if fresh_r:
        vy, r, p11, p12, p22 = _joseph(vy, r, p11, p12, p22, 0.0, 1.0, r_meas - r, filt[F_RR], filt[F_GATE])
    if fresh_ay:
        s1x, s1y, s2x, s2y = sigma_columns(p11, p12, p22)
        z0 = single_track(vy, r, delta, v, model)[0]
        z1 = single_track(vy + s1x, r + s1y, delta, v, model)[0]
        z2 = single_track(vy - s1x, r - s1y, delta, v, model)[0]
        z3 = single_track(vy + s2x, r + s2y, delta, v, model)[0]
        z4 = single_track(vy - s2x, r - s2y, delta, v, model)[0]
        zm = _W0 * z0 + _WI * (z1 + z2 + z3 + z4)
        e0, e1, e2, e3, e4 = z0 - zm, z1 - zm, z2 - zm, z3 - zm, z4 - zm
        S = _W0 * e0 * e0 + _WI * (e1 * e1 + e2 * e2 + e3 * e3 + e4 * e4) + filt[F_RAY]
        cx = _WI * (s1x * (e1 - e2) + s2x * (e3 - e4))   # P_xz; the centre point has zero deviation
        cy = _WI * (s1y * (e1 - e2) + s2y * (e3 - e4))
        resid = ay_meas - zm
        lim = filt[F_GATE] * math.sqrt(S)
        resid = min(max(resid, -lim), lim)
        k1, k2 = cx / S, cy / S
        vy, r = vy + k1 * resid, r + k2 * resid
        p11, p12, p22 = _psd2(p11 - k1 * k1 * S, p12 - k1 * k2 * S, p22 - k2 * k2 * S)
    return _constrain(vy, r, p11, p12, p22, v, filt)


# ---- observers -------------------------------------------------------------------------------------


class _BicycleFilter(ScalarLoopObserver):
    """Shared parts: options, held inputs, derived outputs and their variances."""

    inputs = ("delta_rad", "vx_mps", "yaw_rate_radps", "ay_mps2")
    states = _STATES
    has_covariance = True
    default_options = dict(_OPTIONS)
    _kind: ClassVar[int]   # which filter roadtruth.observers.kalman_loop.filter_run runs

    def _setup(self) -> None:
        v, o = self.vehicle, self.options
        self._m, self._iz, self._lf, self._lr = v.mass_kg, v.yaw_inertia_kgm2, v.lf_m, v.lr_m
        self._cf, self._cr = axle_stiffness(v)
        self._q1, self._q2 = float(o["process_std_vy_mps2"]) ** 2, float(o["process_std_r_radps2"]) ** 2
        self._Rr, self._Ray = float(o["meas_std_r_radps"]) ** 2, float(o["meas_std_ay_mps2"]) ** 2
        self._vmin = float(o["vx_min_mps"])
        # constants of the compiled loop (roadtruth.observers.kalman_loop)
        self._kp = np.array([self._m, self._iz, self._lf, self._lr, self._cf, self._cr, self._vmin, self._q1,
                             self._q2, self._Rr, self._Ray])
        self._model = np.zeros(1)    # tire curves and filter arrays: the nonlinear filters' own
        self._filt = np.zeros(N_FILT)

    def _initial_state(self) -> list[float]:
        return [0.0, 0.0]

    def _compiled(self, t: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Advance through ``t`` (n,) [s], ``Y`` (n, 4) in the shared kernel; (x, var), each (n, 5)."""
        from roadtruth.observers.kalman_loop import filter_run

        u, fresh, tl = np.array(self._u), np.array(self._fresh, dtype=np.bool_), np.array(self._t_last)
        st = np.array([self._t, self._z[0], self._z[1], self._P[0], self._P[1], self._P[2], self._ay_lp])
        n = t.shape[0]
        x, var = np.empty((n, 5)), np.empty((n, 5))
        filter_run(t, Y, self._kind, u, fresh, tl, st, self._model, self._filt, self._kp, x, var)
        self._u, self._fresh, self._t_last = u.tolist(), fresh.tolist(), tl.tolist()
        self._t, self._z, self._P, self._ay_lp = float(st[0]), st[1:3].tolist(), st[3:6].tolist(), float(st[6])
        return x, var

    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        """One sample through the compiled kernel (the same code ``run()`` loops in, so the same bits)."""
        x, _ = self._compiled(np.array([float(t_s)]), np.ascontiguousarray(np.asarray(y, dtype=float).reshape(1, 4)))
        return StepOutput(x[0], cov=self._covariance())

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        """Reset at ``t[0]`` and advance through the whole log in one compiled call (equal to stepping)."""
        t = np.ascontiguousarray(t, dtype=float)
        Y = np.ascontiguousarray(np.asarray(Y, dtype=float).reshape(len(t), len(self.inputs)))
        if len(t):
            self.reset(float(t[0]), x0)
        x, var = self._compiled(t, Y)
        return EstimateTrack(self.name, tuple(self.states), t, x, var=var)

    def _advance(self, t_s: float, y: list[float]) -> None:
        self.step(t_s, np.array(y, dtype=float))

    def _reset_extra(self) -> None:
        o = self.options
        self._P = [float(o["init_std_vy_mps"]) ** 2, 0.0, float(o["init_std_r_radps"]) ** 2]
        self._ay_lp = 0.0   # low-passed measured a_y of the grip adaptation [m/s^2] (nonlinear filters)

    def _vx(self) -> float:
        vx = self._u[1]
        return vx if vx > self._vmin else self._vmin

    def _values(self) -> list[float]:
        vy, r = self._z
        delta = self._u[0] if self._u[0] == self._u[0] else 0.0
        v = self._vx() if self._u[1] == self._u[1] else self._vmin
        return [vy, r, math.atan2(vy, v), delta - math.atan((vy + self._lf * r) / v),
                -math.atan((vy - self._lr * r) / v)]

    def _jacobian_rows(self) -> list[tuple[float, float]]:
        vy, r = self._z
        v = self._vx() if self._u[1] == self._u[1] else self._vmin
        kf = -v / (v * v + (vy + self._lf * r) ** 2)
        kr = -v / (v * v + (vy - self._lr * r) ** 2)
        return [(1.0, 0.0), (0.0, 1.0), (v / (v * v + vy * vy), 0.0), (kf, self._lf * kf), (kr, -self._lr * kr)]

    def _variances(self) -> list[float]:
        p11, p12, p22 = self._P
        return [j1 * j1 * p11 + 2.0 * j1 * j2 * p12 + j2 * j2 * p22 for j1, j2 in self._jacobian_rows()]

    def _covariance(self) -> np.ndarray:
        p11, p12, p22 = self._P
        J = np.array(self._jacobian_rows())
        return J @ np.array([[p11, p12], [p12, p22]]) @ J.T

    def state_covariance(self) -> np.ndarray:
        """Covariance of the internal state ``(v_y, r)``: (2, 2) array."""
        p11, p12, p22 = self._P
        return np.array([[p11, p12], [p12, p22]])


@register
class KalmanBicycle(_BicycleFilter):
    """Linear Kalman filter on the speed-scheduled linear bicycle model (v_y, r); measures r and a_y."""

    name = "kf_bicycle"
    _kind = 0   # kalman_loop.LINEAR_KF
    citation = "Kalman filter on the linear single-track model (e.g. Leanza et al., Sensors 21(16):5409, 2021)"

    def discrete_model(self, vx_mps: float, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A_d, B_d, Q_d)`` of one step: (2, 2), (2,), (2, 2) arrays."""
        a11, a12, a21, a22, b1, b2 = self._continuous(max(vx_mps, self._vmin))
        E, G_ = expm2_zoh(a11, a12, a21, a22, h)
        return (np.array(E).reshape(2, 2), np.array(G_).reshape(2, 2) @ np.array([b1, b2]),
                np.diag([self._q1 * h, self._q2 * h]))

    def measurement_model(self, vx_mps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(H, D, R)``: rows (r, a_y); z = H x + D delta + v."""
        c1, c2, d = self._ay_row(max(vx_mps, self._vmin))
        return np.array([[0.0, 1.0], [c1, c2]]), np.array([0.0, d]), np.diag([self._Rr, self._Ray])

    def _continuous(self, v: float) -> tuple[float, ...]:
        m, iz, lf, lr, cf, cr = self._m, self._iz, self._lf, self._lr, self._cf, self._cr
        return (-(cf + cr) / (m * v), -(lf * cf - lr * cr) / (m * v) - v, -(lf * cf - lr * cr) / (iz * v),
                -(lf * lf * cf + lr * lr * cr) / (iz * v), cf / m, lf * cf / iz)

    def _ay_row(self, v: float) -> tuple[float, float, float]:
        m, lf, lr, cf, cr = self._m, self._lf, self._lr, self._cf, self._cr
        return -(cf + cr) / (m * v), -(lf * cf - lr * cr) / (m * v), cf / m


class _NonlinearBicycle(_BicycleFilter):
    """EKF/UKF shell: options, model and filter arrays; the step is a compiled kernel."""

    default_options = dict(_NONLINEAR_OPTIONS)
    #: The projection onto |v_y| <= tan(beta_max) v_x pins the sideslip output atan2(v_y, v_x) at
    #: +-beta_max exactly (same v_x); the yaw-rate face of the box moves with speed and is not a
    #: static bound. ``_setup`` replaces this default by the instance's own ``beta_max_rad``.
    state_bounds = {"beta_rad": (-_NONLINEAR_OPTIONS["beta_max_rad"], _NONLINEAR_OPTIONS["beta_max_rad"])}

    def _option(self, key: str, lo: float, hi: float) -> float:
        value: Any = self.options[key]
        if not (isinstance(value, int | float) and not isinstance(value, bool) and lo <= value <= hi):
            raise InputError(f"must be a number in [{lo:g}, {hi:g}] (got {value!r})",
                             field=f"observer {self.name} option {key}")
        return float(value)

    def _setup(self) -> None:
        super()._setup()
        v = self.vehicle
        mu = self._option("mu", 0.05, 2.0)
        beta_max = self._option("beta_max_rad", 0.01, 1.5)
        self.state_bounds = {"beta_rad": (-beta_max, beta_max)}
        margin = self._option("constraint_margin", 0.0, 10.0)
        gate = self._option("innovation_gate", 0.5, math.inf)
        headroom = self._option("grip_headroom", 0.0, 3.0)
        if 0.0 < headroom < 1.0:
            raise InputError(f"must be 0 (off) or at least 1 (got {headroom!r}): a curve below the measured "
                             "a_y cannot explain it", field=f"observer {self.name} option grip_headroom")
        self._model0 = model_array(v, mu)
        self._model = self._model0.copy()
        filt = np.zeros(N_FILT)
        filt[F_Q1], filt[F_Q2], filt[F_RR], filt[F_RAY] = self._q1, self._q2, self._Rr, self._Ray
        filt[F_GATE] = gate
        filt[F_TANB] = math.tan(beta_max)
        filt[F_RKIN] = (1.0 + margin) * math.tan(v.steering.max_road_wheel_angle_rad) / v.wheelbase_m
        filt[F_ALIM] = (1.0 + margin) * peak_scale(v, mu) * G
        filt[F_K0], filt[F_HEAD], filt[F_MARGIN] = peak_scale(v, mu), headroom, margin
        filt[F_TGF] = self._option("grip_filter_s", 0.0, 60.0)
        filt[F_TREC] = self._option("grip_recovery_s", 0.0, math.inf)
        filt[F_KMAX] = self._option("grip_max", 0.1, 10.0)
        self._filt0 = filt
        self._filt = filt.copy()

    def _reset_extra(self) -> None:
        super()._reset_extra()
        # the adapted curves start from the configured ones at every reset (a new log segment)
        if hasattr(self, "_model0"):
            self._model[:] = self._model0
            self._filt[:] = self._filt0

    def grip(self) -> float:
        """The peak scale the tire curves have now, ``k`` [1] (peak lateral force ``k m g``)."""
        return float(self._model[M_GRIP])

    def simulate_step(self, x: tuple[float, float], delta: float, vx: float, h: float) -> tuple[float, float]:
        """The filter's own mean propagation of ``x = (v_y, r)`` over ``h`` [s] (for tests)."""
        return propagate(float(x[0]), float(x[1]), float(delta), max(float(vx), self._vmin), float(h), self._model)

    def model_ay(self, vy: float, r: float, delta: float, vx: float) -> float:
        """The model's lateral acceleration at ``(v_y, r)`` [m/s^2] (the accelerometer prediction)."""
        return single_track(float(vy), float(r), float(delta), max(float(vx), self._vmin), self._model)[0]

    def plausible_box(self, vx: float) -> tuple[float, float]:
        """Half-widths ``(v_y,max [m/s], r_max [rad/s])`` of the constraint set at ``vx`` [m/s]."""
        return plausible_box(max(float(vx), self._vmin), self._filt)


@register
class EKFBicycle(_NonlinearBicycle):
    """Extended Kalman filter on a nonlinear-tire (Magic Formula) bicycle model; measures r and a_y."""

    name = "ekf_bicycle"
    citation = ("EKF on the single-track model with Magic Formula axle forces "
                "(H. B. Pacejka, Tire and Vehicle Dynamics, 3rd ed., 2012, ch. 4)")

    _kind = 1   # kalman_loop.EKF


@register
class UKFBicycle(_NonlinearBicycle):
    """Unscented Kalman filter on the nonlinear-tire bicycle model (5 sigma points, kappa = 1)."""

    name = "ukf_bicycle"
    citation = "UKF (Julier & Uhlmann, Proc. IEEE 92(3), 2004) on the Magic Formula single-track model"

    _kind = 2   # kalman_loop.UKF
