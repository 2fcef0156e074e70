"""The compiled kernel of the model-only baselines (:mod:`roadtruth.observers.open_loop`), shared by step() and run().

:func:`open_loop_run` is a baseline's whole per-sample update (latching the inputs as the zero-order
hold of ``ScalarLoopObserver._tick``, the step ``h`` since the last sample, the exact-ZOH step of the
linear bicycle or the trapezoidal step of the kinematic integration, the derived outputs) on arrays
carried between calls. ``step()`` calls it with one sample and ``run()`` with the whole log, so both
execute the same compiled code on the same state and agree bit for bit
(``tests/test_observers_bicycle.py``).

Carried state: ``u`` (k,) the held inputs in the observer's ``inputs`` order; ``s`` =
``(t_cur, z_1, z_2, f_prev)`` with ``z = (v_y, r)`` of the bicycle or ``z_1 = v_y`` of the kinematic
integration, and ``f_prev`` the previous ``a_y - r v_x`` [m/s^2] (NaN until the first one).
``par`` = ``(m, I_z, l_f, l_r, C_f, C_r, v_min)`` (:data:`N_PAR` floats; SI units).

numba caches each kernel per source file: after editing this file (or ``observers/bicycle.py``)
delete ``observers/__pycache__/open_loop_loop*.nbi, *.nbc`` and ``bicycle*.nbi, *.nbc``.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit
from roadtruth.observers.bicycle import expm2_zoh

#: ``kind`` of :func:`open_loop_run`.
BICYCLE, KINEMATIC = 0, 1
N_PAR = 7
_expm2 = jit(expm2_zoh)


@jit
def _bicycle_step(s: np.ndarray, h: float, delta: float, vx: float, p: np.ndarray) -> None:
    """``OpenLoopBicycle``: exact ZOH of ``x' = A(v_x) x + B delta`` (Wang 2014, (3.17)) over ``h`` [s]."""
    m, iz, lf, lr, cf, cr, vmin = p[0], p[1], p[2], p[3], p[4], p[5], p[6]
    v = vmin if vx < vmin else vx   # the model is singular at v_x = 0: held at v_min below it
    a11 = -(cf + cr) / (m * v)
    a12 = -(lf * cf - lr * cr) / (m * v) - v
    a21 = -(lf * cf - lr * cr) / (iz * v)
    a22 = -(lf * lf * cf + lr * lr * cr) / (iz * v)
    E, G = _expm2(a11, a12, a21, a22, h)
    g1, g2 = cf / m * delta, lf * cf / iz * delta
    vy, r = s[1], s[2]
    s[1] = E[0] * vy + E[1] * r + G[0] * g1 + G[1] * g2
    s[2] = E[2] * vy + E[3] * r + G[2] * g1 + G[3] * g2


@jit
def open_loop_run(t: np.ndarray, Y: np.ndarray, kind: int, u: np.ndarray, s: np.ndarray, p: np.ndarray,
                  x: np.ndarray) -> None:
    """The baseline ``kind`` over ``t`` (n,) [s], ``Y`` (n, k); writes the estimates to ``x`` in the
    observer's ``states`` order: ``(v_y, r, beta, alpha_f, alpha_r)`` (n, 5) for :data:`BICYCLE`,
    ``(v_y, beta)`` (n, 2) for :data:`KINEMATIC` (state arrays: module docstring)."""
    lf, lr = p[2], p[3]
    k = Y.shape[1]
    for i in range(t.shape[0]):
        ts = t[i]
        for j in range(k):
            v = Y[i, j]
            if v == v:
                u[j] = v
        h = ts - s[0]
        if h > 0.0:
            s[0] = ts
        else:
            h = 0.0   # repeated (or earlier) time stamp: latch only
        if kind == BICYCLE:
            delta, vx = u[0], u[1]
            if h > 0.0 and vx == vx and delta == delta:
                _bicycle_step(s, h, delta, vx, p)
            vy, r = s[1], s[2]
            x[i, 0], x[i, 1] = vy, r
            if vx != vx or vx <= 0.0:
                x[i, 2], x[i, 3], x[i, 4] = 0.0, 0.0, 0.0
            else:
                d = delta if delta == delta else 0.0
                x[i, 2] = math.atan2(vy, vx)
                x[i, 3] = d - math.atan((vy + lf * r) / vx)   # CONTRACT slip definitions
                x[i, 4] = -math.atan((vy - lr * r) / vx)
        else:
            ay, r, vx = u[0], u[1], u[2]
            f = ay - r * vx   # v_y' = a_y - r v_x
            if f == f:
                if h > 0.0:
                    fp = s[3] if s[3] == s[3] else f   # first sample: rectangle, no earlier value
                    s[1] += 0.5 * h * (fp + f)
                s[3] = f
            vy = s[1]
            x[i, 0] = vy
            x[i, 1] = math.atan2(vy, vx) if vx == vx and vx > 0.0 else 0.0
