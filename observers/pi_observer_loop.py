"""The compiled kernel of the PI unknown-input observer (:mod:`roadtruth.observers.pi_observer`), shared by step() and run().

:func:`pi_run` is the observer's whole per-sample update (latching the inputs, the start at the first
``v_x`` sample, the trapezoidal integral of the gyro and its re-centring to (-pi, pi], the
first-order-held input of the step, the choice between the corrected and the prediction ODE by the
freshness of ``v_x`` and ``r``, the sub-stepped RK4 step of :func:`roadtruth.observers.uio_nguyen.affine_rk4`,
the derived ``beta``) on arrays carried between calls. ``PIObserverNguyen.step()`` calls it with one
sample and ``PIObserverNguyen.run()`` with the whole log, so both execute the same compiled code on
the same state and agree bit for bit (``tests/test_observers_pi_algebraic.py``).

Carried state: ``u``/``tl`` (4,) held inputs ``(v_x, r, a_x, delta)`` and their arrival times [s];
``z`` (6,) ``(v_x, v_y, psi_hat, r, f_yf, f_yr)`` (forces in kN); ``s`` = ``(t_cur [s], started,
psi_m [rad], r_prev [rad/s], t_r_prev [s], have_w_prev)``; ``w_prev`` (5,) the ODE input
``(v_x, psi_m, r, a_x, delta)`` at the end of the previous step. ``Fs, Gs`` / ``Fp, Gp`` (3, 6, 6) /
(3, 6, 5): the corrected and the prediction ODE, affine in ``rho = (v_x, 1/v_x)``. ``par`` = ``(v_lo,
v_hi, hold_s, ||M||_corrected, ||M||_prediction)`` (:data:`N_PAR` floats; the norms bound the ODE's
rate on the design domain and set the RK4 sub-steps).

numba caches each kernel per source file: after editing this file delete
``observers/__pycache__/pi_observer_loop*.nbi, *.nbc``.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit
from roadtruth.observers.uio_nguyen import SUBSTEP_RATE, TWO_PI, affine_rk4

N_PAR = 5
#: Size of the carried scalar state ``s``.
N_STATE = 6


@jit
def pi_run(t: np.ndarray, Y: np.ndarray, u: np.ndarray, tl: np.ndarray, z: np.ndarray, s: np.ndarray,
           w_prev: np.ndarray, Fs: np.ndarray, Gs: np.ndarray, Fp: np.ndarray, Gp: np.ndarray, par: np.ndarray,
           x: np.ndarray) -> None:
    """The PI observer over ``t`` (n,) [s], ``Y`` (n, 4) ``(v_x, r, a_x, delta)``, NaN = no new sample;
    writes ``(v_y, r, beta)`` to ``x`` (n, 3) (state arrays: module docstring). A repeated time stamp
    latches its samples without a step."""
    vlo, vhi, hold = par[0], par[1], par[2]
    w0 = np.empty(5)
    w1 = np.empty(5)
    for i in range(t.shape[0]):
        ts = t[i]
        fresh_r = False
        for j in range(4):
            val = Y[i, j]
            if val == val:
                u[j] = val
                tl[j] = ts
                if j == 1:
                    fresh_r = True
        h = ts - s[0]
        if h > 0.0:
            s[0] = ts
        else:
            h = 0.0
        vx, r, ax, delta = u[0], u[1], u[2], u[3]
        go = True
        if s[1] == 0.0:
            if vx != vx:
                go = False      # nothing happens before the first v_x sample
            else:
                z[0] = vx
                s[1] = 1.0
        if go:
            if fresh_r:
                if s[3] == s[3]:
                    s[2] += 0.5 * (ts - s[4]) * (s[3] + r)   # trapezoidal integral of the gyro
                s[3] = r
                s[4] = ts
            psi = s[2]
            if psi > math.pi or psi < -math.pi:
                # psi enters only through the residual psi_m - psi_hat and nowhere in A: shift both
                c = TWO_PI * np.rint(psi / TWO_PI)   # Python's round(): half to even
                s[2] = psi - c
                z[2] -= c
                if s[5] != 0.0:
                    w_prev[1] -= c
            v = vx if vx == vx else z[0]
            v = vlo if v < vlo else (vhi if v > vhi else v)
            w1[0] = vx if vx == vx else z[0]
            w1[1] = s[2]
            w1[2] = r if r == r else z[3]
            w1[3] = ax if ax == ax else 0.0
            w1[4] = delta if delta == delta else 0.0
            for j in range(5):
                w0[j] = w_prev[j] if s[5] != 0.0 else w1[j]
                w_prev[j] = w1[j]
            s[5] = 1.0
            if h > 0.0:
                live = r == r and vx == vx and ts - min(tl[0], tl[1]) <= hold
                # one call site of the RK4 (corrected ODE when live, prediction otherwise): compiled once
                if live:
                    F, G, b = Fs, Gs, par[3]
                else:
                    F, G, b = Fp, Gp, par[4]
                affine_rk4(z, F, G, w0, w1, v, 1.0 / v, h, max(1, math.ceil(h * b / SUBSTEP_RATE)))
        vy = z[1]
        vb = u[0] if u[0] == u[0] else z[0]
        x[i, 0] = vy
        x[i, 1] = z[3]
        x[i, 2] = math.atan2(vy, vb) if vb > 0.0 else 0.0
