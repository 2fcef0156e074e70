"""The compiled kernel of the Kalman-filter baselines (:mod:`roadtruth.observers.kalman`), shared by step() and run().

:func:`filter_run` is a filter's whole per-sample update (latching the inputs, the linear KF step or
the compiled EKF / UKF step with grip adaptation, the derived outputs and their first-order variances)
over arrays carried between calls. ``step()`` calls it with one sample and ``run()`` with the whole
log, so both execute the same compiled code on the same state and agree bit for bit
(``tests/test_observers_kalman.py``).

Carried state: ``u``/``tl`` (4,) held ``(delta, v_x, r, a_y)`` and their arrival times [s], ``fresh``
(4,) bool; ``s`` = ``(t_cur, v_y, r, p11, p12, p22, a_y_lp)``; ``model``/``filt`` the tire-curve and
filter arrays of :mod:`roadtruth.observers.tire_curves` / :mod:`roadtruth.observers.kalman` (the grip adaptation changes
them in place). ``kp`` = ``(m, I_z, l_f, l_r, C_f, C_r, v_min, q1, q2, R_r, R_ay)``.

numba caches each kernel per source file: after editing this file or ``observers/kalman.py`` delete
``observers/__pycache__/kalman*.nbi, *.nbc``.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit
from roadtruth.observers.kalman import _expm2, _joseph, _propagate_cov, adapt_grip, ekf_advance, ukf_advance

#: ``kind`` of :func:`filter_run`.
LINEAR_KF, EKF, UKF = 0, 1, 2


@jit
def _linear_kf(s: np.ndarray, fresh: np.ndarray, delta: float, v: float, h: float, r_meas: float,
               ay_meas: float, kp: np.ndarray) -> None:
    """``KalmanBicycle`` step: exact ZOH of the linear bicycle (3.17), Joseph updates of ``r`` and ``a_y``."""
    m, iz, lf, lr, cf, cr = kp[0], kp[1], kp[2], kp[3], kp[4], kp[5]
    q1, q2, Rr, Ray = kp[7], kp[8], kp[9], kp[10]
    x1, x2, p11, p12, p22 = s[1], s[2], s[3], s[4], s[5]
    if h > 0.0:
        a11, a12 = -(cf + cr) / (m * v), -(lf * cf - lr * cr) / (m * v) - v
        a21, a22 = -(lf * cf - lr * cr) / (iz * v), -(lf * lf * cf + lr * lr * cr) / (iz * v)
        b1, b2 = cf / m, lf * cf / iz
        E, G_ = _expm2(a11, a12, a21, a22, h)
        g1, g2 = b1 * delta, b2 * delta
        x1, x2 = E[0] * x1 + E[1] * x2 + G_[0] * g1 + G_[1] * g2, E[2] * x1 + E[3] * x2 + G_[2] * g1 + G_[3] * g2
        p11, p12, p22 = _propagate_cov(E, p11, p12, p22, q1 * h, q2 * h)
    if fresh[2]:
        x1, x2, p11, p12, p22 = _joseph(x1, x2, p11, p12, p22, 0.0, 1.0, r_meas - x2, Rr, math.inf)
    if fresh[3]:
        c1, c2, d = -(cf + cr) / (m * v), -(lf * cf - lr * cr) / (m * v), cf / m
        resid = ay_meas - c1 * x1 - c2 * x2 - d * delta
        x1, x2, p11, p12, p22 = _joseph(x1, x2, p11, p12, p22, c1, c2, resid, Ray, math.inf)
    s[1], s[2], s[3], s[4], s[5] = x1, x2, p11, p12, p22


@jit
def _outputs(s: np.ndarray, u: np.ndarray, kp: np.ndarray, x: np.ndarray, var: np.ndarray) -> None:
    """``(v_y, r, beta, alpha_f, alpha_r)`` and their variances ``J P J^T`` (diagonal) into ``x``, ``var``."""
    lf, lr, vmin = kp[2], kp[3], kp[6]
    vy, r, p11, p12, p22 = s[1], s[2], s[3], s[4], s[5]
    delta = u[0] if u[0] == u[0] else 0.0
    vx = u[1]
    v = (vx if vx > vmin else vmin) if vx == vx else vmin
    x[0], x[1] = vy, r
    x[2] = math.atan2(vy, v)
    x[3] = delta - math.atan((vy + lf * r) / v)
    x[4] = -math.atan((vy - lr * r) / v)
    kf = -v / (v * v + (vy + lf * r) ** 2)
    kr = -v / (v * v + (vy - lr * r) ** 2)
    rows = ((1.0, 0.0), (0.0, 1.0), (v / (v * v + vy * vy), 0.0), (kf, lf * kf), (kr, -lr * kr))
    for k in range(5):
        j1, j2 = rows[k]
        var[k] = j1 * j1 * p11 + 2.0 * j1 * j2 * p12 + j2 * j2 * p22


@jit
def filter_run(t: np.ndarray, Y: np.ndarray, kind: int, u: np.ndarray, fresh: np.ndarray, tl: np.ndarray,
               s: np.ndarray, model: np.ndarray, filt: np.ndarray, kp: np.ndarray, x: np.ndarray,
               var: np.ndarray) -> None:
    """The filter ``kind`` over ``t`` (n,) [s], ``Y`` (n, 4); writes estimates and variances to ``x``,
    ``var`` (n, 5) in ``states`` order (state arrays: module docstring)."""
    vmin = kp[6]
    for i in range(t.shape[0]):
        ts = t[i]
        for j in range(4):
            yj = Y[i, j]
            if yj == yj:
                u[j] = yj
                fresh[j] = True
                tl[j] = ts
            else:
                fresh[j] = False
        h = ts - s[0]
        if h > 0.0:
            s[0] = ts
        else:
            h = 0.0
        delta, vx, r_meas, ay_meas = u[0], u[1], u[2], u[3]
        if delta == delta and vx == vx:
            v = vx if vx > vmin else vmin
            if kind == LINEAR_KF:
                _linear_kf(s, fresh, delta, v, h, r_meas, ay_meas, kp)
            else:
                s[6] = adapt_grip(s[6], ay_meas, fresh[3], h, model, filt)
                if kind == EKF:
                    out = ekf_advance(s[1], s[2], s[3], s[4], s[5], delta, v, h, r_meas, ay_meas, fresh[2],
                                      fresh[3], model, filt)
                else:
                    out = ukf_advance(s[1], s[2], s[3], s[4], s[5], delta, v, h, r_meas, ay_meas, fresh[2],
                                      fresh[3], model, filt)
                s[1], s[2], s[3], s[4], s[5] = out
        _outputs(s, u, kp, x[i], var[i])
