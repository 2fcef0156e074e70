r"""Kalman-filter baselines on the bicycle model: linear KF, EKF and UKF.

State ``x = (v_y, r)``; inputs ``delta`` and ``v_x`` drive the model, ``r`` (gyro) and ``a_y``
(accelerometer) correct it, each only when a new sample arrives.

* ``kf_bicycle``: linear speed-scheduled model (3.17), exact ZOH per step (closed form,
  :func:`observers.bicycle.expm2_zoh`), ``a_y = (F_yf + F_yr)/m = C(v_x) x + D delta``.
* ``ekf_bicycle`` / ``ukf_bicycle``: nonlinear axle forces by the Magic Formula
  ``F = D sin(C atan(B a - E(B a - atan(B a))))`` with the vehicle's per-axle shape, ``D = F_z`` at
  static load and mu = 1, slip angles by the CONTRACT definitions,
  ``m (v_y' + v_x r) = F_yf cos(delta) + F_yr``, ``I_z r' = l_f F_yf cos(delta) - l_r F_yr``;
  RK4 with enough sub-steps for the model's stiffness.

Process noise: white accelerations with spectral densities ``q = std^2`` [(m/s^2)^2/Hz,
(rad/s^2)^2/Hz], discretised as ``Q_d = diag(q) h``. Numerical robustness (named choices): Joseph-form
updates, covariances kept symmetric by construction, the 2x2 correlation clipped to
``|p12| <= sqrt(p11 p22)``, and (UKF) sigma points from an eigendecomposition with eigenvalues
clipped at a floor, so no Cholesky factorisation can fail. Derived outputs ``beta``, ``alpha_f``,
``alpha_r`` carry first-order propagated variances.
"""

from __future__ import annotations

import math

import numpy as np

from observers.base import ScalarLoopObserver
from observers.bicycle import axle_stiffness, expm2_zoh
from observers.registry import register

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
_PSD_FLOOR = 1e-12


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


def _joseph(x1: float, x2: float, p11: float, p12: float, p22: float, h1: float, h2: float,
            resid: float, R: float) -> tuple[float, float, float, float, float]:
    """Scalar measurement update ``z = h1 x1 + h2 x2 + v`` in Joseph form; returns x and P."""
    ph1 = p11 * h1 + p12 * h2
    ph2 = p12 * h1 + p22 * h2
    S = h1 * ph1 + h2 * ph2 + R
    k1, k2 = ph1 / S, ph2 / S
    a11, a12, a21, a22 = 1.0 - k1 * h1, -k1 * h2, -k2 * h1, 1.0 - k2 * h2
    m11, m12 = a11 * p11 + a12 * p12, a11 * p12 + a12 * p22
    m21, m22 = a21 * p11 + a22 * p12, a21 * p12 + a22 * p22
    n11 = m11 * a11 + m12 * a12 + k1 * k1 * R
    n12 = m11 * a21 + m12 * a22 + k1 * k2 * R
    n22 = m21 * a21 + m22 * a22 + k2 * k2 * R
    n11, n12, n22 = _psd2(n11, n12, n22)
    return x1 + k1 * resid, x2 + k2 * resid, n11, n12, n22


def _propagate_cov(E: tuple[float, float, float, float], p11: float, p12: float, p22: float,
                   q1: float, q2: float) -> tuple[float, float, float]:
    """``E P E^T + diag(q1, q2)``."""
    m11, m12 = E[0] * p11 + E[1] * p12, E[0] * p12 + E[1] * p22
    m21, m22 = E[2] * p11 + E[3] * p12, E[2] * p12 + E[3] * p22
    return _psd2(m11 * E[0] + m12 * E[1] + q1, m11 * E[2] + m12 * E[3], m21 * E[2] + m22 * E[3] + q2)


class _BicycleFilter(ScalarLoopObserver):
    """Shared parts: options, held inputs, derived outputs and their variances."""

    inputs = ("delta_rad", "vx_mps", "yaw_rate_radps", "ay_mps2")
    states = _STATES
    has_covariance = True
    default_options = dict(_OPTIONS)

    def _setup(self) -> None:
        v, o = self.vehicle, self.options
        self._m, self._iz, self._lf, self._lr = v.mass_kg, v.yaw_inertia_kgm2, v.lf_m, v.lr_m
        self._cf, self._cr = axle_stiffness(v)
        self._q1, self._q2 = float(o["process_std_vy_mps2"]) ** 2, float(o["process_std_r_radps2"]) ** 2
        self._Rr, self._Ray = float(o["meas_std_r_radps"]) ** 2, float(o["meas_std_ay_mps2"]) ** 2
        self._vmin = float(o["vx_min_mps"])
        tf, tr = v.tires.front, v.tires.rear
        self._mf = (tf.By, tf.Cy, tf.Ey, v.fz_front_static_N)
        self._mr = (tr.By, tr.Cy, tr.Ey, v.fz_rear_static_N)

    def _initial_state(self) -> list[float]:
        return [0.0, 0.0]

    def _reset_extra(self) -> None:
        o = self.options
        self._P = [float(o["init_std_vy_mps"]) ** 2, 0.0, float(o["init_std_r_radps"]) ** 2]

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
    citation = "Kalman filter on the linear single-track model (e.g. Leanza et al., Sensors 21(16):5409, 2021)"

    def discrete_model(self, vx_mps: float, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A_d, B_d, Q_d)`` of one step: (2, 2), (2,), (2, 2) arrays."""
        a11, a12, a21, a22, b1, b2 = self._continuous(max(vx_mps, self._vmin))
        E, G = expm2_zoh(a11, a12, a21, a22, h)
        return (np.array(E).reshape(2, 2), np.array(G).reshape(2, 2) @ np.array([b1, b2]),
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

    def _advance(self, t_s: float, y: list[float]) -> None:
        h = self._tick(t_s, y)
        delta, vx, r_meas, ay_meas = self._u
        if delta != delta or vx != vx:
            return
        v = vx if vx > self._vmin else self._vmin
        x1, x2 = self._z
        p11, p12, p22 = self._P
        if h > 0.0:
            a11, a12, a21, a22, b1, b2 = self._continuous(v)
            E, G = expm2_zoh(a11, a12, a21, a22, h)
            g1, g2 = b1 * delta, b2 * delta
            x1, x2 = E[0] * x1 + E[1] * x2 + G[0] * g1 + G[1] * g2, E[2] * x1 + E[3] * x2 + G[2] * g1 + G[3] * g2
            p11, p12, p22 = _propagate_cov(E, p11, p12, p22, self._q1 * h, self._q2 * h)
        fresh = self._fresh
        if fresh[2]:
            x1, x2, p11, p12, p22 = _joseph(x1, x2, p11, p12, p22, 0.0, 1.0, r_meas - x2, self._Rr)
        if fresh[3]:
            c1, c2, d = self._ay_row(v)
            x1, x2, p11, p12, p22 = _joseph(x1, x2, p11, p12, p22, c1, c2, ay_meas - c1 * x1 - c2 * x2 - d * delta,
                                            self._Ray)
        self._z = [x1, x2]
        self._P = [p11, p12, p22]


# ---- nonlinear model -----------------------------------------------------------------------------

def magic_formula(alpha: float, B: float, C: float, E: float, D: float) -> tuple[float, float]:
    """Pure-slip lateral force and its slope: ``(F [N], dF/dalpha [N/rad])``."""
    ba = B * alpha
    u = ba - E * (ba - math.atan(ba))
    phi = math.atan(u)
    du = B - E * (B - B / (1.0 + ba * ba))
    return D * math.sin(C * phi), D * math.cos(C * phi) * C * du / (1.0 + u * u)


class _NonlinearBicycle(_BicycleFilter):
    def _forces(self, vy: float, r: float, delta: float, v: float) -> tuple[float, ...]:
        """``(ay, v_y', r', dF_f/da_f, dF_r/da_r, k_f, k_r, cos delta)`` of the nonlinear model."""
        lf, lr = self._lf, self._lr
        af = delta - math.atan((vy + lf * r) / v)
        ar = -math.atan((vy - lr * r) / v)
        ff, dff = magic_formula(af, *self._mf)
        fr, dfr = magic_formula(ar, *self._mr)
        cd = math.cos(delta)
        ay = (ff * cd + fr) / self._m
        kf = -v / (v * v + (vy + lf * r) ** 2)
        kr = -v / (v * v + (vy - lr * r) ** 2)
        return ay, ay - v * r, (lf * ff * cd - lr * fr) / self._iz, dff, dfr, kf, kr, cd

    def _substeps(self, h: float, v: float) -> int:
        lam = ((self._cf + self._cr) / self._m + (self._lf ** 2 * self._cf + self._lr ** 2 * self._cr) / self._iz) / v
        return min(50, max(1, math.ceil(h * lam / 0.5)))

    def _rk4(self, vy: float, r: float, delta: float, v: float, h: float) -> tuple[float, float]:
        f = self._forces
        _, k1a, k1b, *_ = f(vy, r, delta, v)
        _, k2a, k2b, *_ = f(vy + 0.5 * h * k1a, r + 0.5 * h * k1b, delta, v)
        _, k3a, k3b, *_ = f(vy + 0.5 * h * k2a, r + 0.5 * h * k2b, delta, v)
        _, k4a, k4b, *_ = f(vy + h * k3a, r + h * k3b, delta, v)
        return (vy + h / 6.0 * (k1a + 2 * k2a + 2 * k3a + k4a), r + h / 6.0 * (k1b + 2 * k2b + 2 * k3b + k4b))

    def simulate_step(self, x: tuple[float, float], delta: float, vx: float, h: float) -> tuple[float, float]:
        """The filter's own mean propagation of ``x = (v_y, r)`` over ``h`` [s] (for tests)."""
        v = max(vx, self._vmin)
        n = self._substeps(h, v)
        vy, r = x
        for _ in range(n):
            vy, r = self._rk4(vy, r, delta, v, h / n)
        return vy, r


@register
class EKFBicycle(_NonlinearBicycle):
    """Extended Kalman filter on a nonlinear-tire (Magic Formula) bicycle model; measures r and a_y."""

    name = "ekf_bicycle"
    citation = "EKF on the single-track model with Magic Formula axle forces (Pacejka, Tire and Vehicle Dynamics)"

    def _advance(self, t_s: float, y: list[float]) -> None:
        h = self._tick(t_s, y)
        delta, vx, r_meas, ay_meas = self._u
        if delta != delta or vx != vx:
            return
        v = vx if vx > self._vmin else self._vmin
        vy, r = self._z
        p11, p12, p22 = self._P
        lf, lr, iz, m = self._lf, self._lr, self._iz, self._m
        if h > 0.0:
            n = self._substeps(h, v)
            hs = h / n
            for _ in range(n):
                _, _, _, dff, dfr, kf, kr, cd = self._forces(vy, r, delta, v)
                j11 = (cd * dff * kf + dfr * kr) / m
                j12 = (cd * dff * lf * kf - dfr * lr * kr) / m - v
                j21 = (lf * cd * dff * kf - lr * dfr * kr) / iz
                j22 = (lf * lf * cd * dff * kf + lr * lr * dfr * kr) / iz
                E, _ = expm2_zoh(j11, j12, j21, j22, hs)
                p11, p12, p22 = _propagate_cov(E, p11, p12, p22, self._q1 * hs, self._q2 * hs)
                vy, r = self._rk4(vy, r, delta, v, hs)
        fresh = self._fresh
        if fresh[2]:
            vy, r, p11, p12, p22 = _joseph(vy, r, p11, p12, p22, 0.0, 1.0, r_meas - r, self._Rr)
        if fresh[3]:
            ay, _, _, dff, dfr, kf, kr, cd = self._forces(vy, r, delta, v)
            h1 = (cd * dff * kf + dfr * kr) / m
            h2 = (cd * dff * lf * kf - dfr * lr * kr) / m
            vy, r, p11, p12, p22 = _joseph(vy, r, p11, p12, p22, h1, h2, ay_meas - ay, self._Ray)
        self._z = [vy, r]
        self._P = [p11, p12, p22]


@register
class UKFBicycle(_NonlinearBicycle):
    """Unscented Kalman filter on the nonlinear-tire bicycle model (5 sigma points, kappa = 1)."""

    name = "ukf_bicycle"
    citation = "UKF (Julier & Uhlmann, Proc. IEEE 92(3), 2004) on the Magic Formula single-track model"

    _KAPPA = 1.0
    _W = np.array([1.0 / 3.0, 1.0 / 6.0, 1.0 / 6.0, 1.0 / 6.0, 1.0 / 6.0])  # kappa/(n+kappa), 1/(2(n+kappa))

    def _sigma(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        w, V = np.linalg.eigh(0.5 * (P + P.T))
        w = np.maximum(w, _PSD_FLOOR + 1e-12 * max(float(w.max()), 0.0))
        S = V * np.sqrt((2.0 + self._KAPPA) * w)
        return np.vstack([x, x + S.T, x - S.T])

    def _moments(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mean = self._W @ X
        d = X - mean
        return mean, (d.T * self._W) @ d

    def _deriv_vec(self, X: np.ndarray, delta: float, v: float) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised model over sigma points X: (k, 2) -> (state derivative (k, 2), a_y (k,))."""
        lf, lr = self._lf, self._lr
        vy, r = X[:, 0], X[:, 1]
        alpha = np.stack([delta - np.arctan((vy + lf * r) / v), -np.arctan((vy - lr * r) / v)])
        ba = self._B * alpha
        F = self._D * np.sin(self._C * np.arctan(ba - self._E * (ba - np.arctan(ba))))
        cd = math.cos(delta)
        ay = (F[0] * cd + F[1]) / self._m
        return np.column_stack([ay - v * r, (lf * cd * F[0] - lr * F[1]) / self._iz]), ay

    def _propagate_vec(self, X: np.ndarray, delta: float, v: float, h: float) -> np.ndarray:
        n = self._substeps(h, v)
        hs = h / n
        f = self._deriv_vec
        for _ in range(n):
            k1 = f(X, delta, v)[0]
            k2 = f(X + 0.5 * hs * k1, delta, v)[0]
            k3 = f(X + 0.5 * hs * k2, delta, v)[0]
            k4 = f(X + hs * k3, delta, v)[0]
            X = X + hs / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return X

    def _setup(self) -> None:
        super()._setup()
        mf, mr = self._mf, self._mr
        self._B, self._C, self._E, self._D = (np.array([[mf[i]], [mr[i]]]) for i in range(4))

    def _advance(self, t_s: float, y: list[float]) -> None:
        h = self._tick(t_s, y)
        delta, vx, r_meas, ay_meas = self._u
        if delta != delta or vx != vx:
            return
        v = vx if vx > self._vmin else self._vmin
        x = np.array(self._z)
        p11, p12, p22 = self._P
        P = np.array([[p11, p12], [p12, p22]])
        if h > 0.0:
            X = self._sigma(x, P)
            Xp = self._propagate_vec(X, delta, v, h)
            x, P = self._moments(Xp)
            P = P + np.diag([self._q1 * h, self._q2 * h])
        fresh = self._fresh
        rows = [i for i, f in ((0, fresh[2]), (1, fresh[3])) if f]
        if rows:
            X = self._sigma(x, P)
            Z = np.column_stack([X[:, 1], self._deriv_vec(X, delta, v)[1]])[:, rows]
            z_mean, Pzz = self._moments(Z)
            Pzz = Pzz + np.diag([self._Rr, self._Ray])[np.ix_(rows, rows)]
            Pxz = ((X - x).T * self._W) @ (Z - z_mean)
            K = np.linalg.solve(Pzz, Pxz.T).T
            x = x + K @ (np.array([r_meas, ay_meas])[rows] - z_mean)
            P = P - K @ Pzz @ K.T
        q11, q12, q22 = _psd2(float(P[0, 0]), 0.5 * float(P[0, 1] + P[1, 0]), float(P[1, 1]))
        self._z = [float(x[0]), float(x[1])]
        self._P = [q11, q12, q22]
