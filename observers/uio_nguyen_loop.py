"""The compiled kernel of the regularised UIO (:mod:`roadtruth.observers.uio_nguyen`), shared by step() and run().

:func:`nguyen_run` is the whole per-sample update of ``NguyenUIO``: latching the inputs (zero-order
hold, arrival times; NaN = no new sample), the step ``h`` since the last advance (0 for a repeated
time stamp), the integrated gyro ``psi_m`` and its re-centring, the model prediction while ``v_x`` /
``r`` are stale, the re-seeding of ``eta`` on resumption, the sub-stepped RK4 step of the UIO
(:func:`affine_rk4`) and the estimate ``(v_y, r, beta)``. ``NguyenUIO.step()`` calls it with one
sample and ``NguyenUIO.run()`` with the whole log, so both execute the same compiled code on the same
carried state and agree bit for bit (``tests/test_observers_uio_nguyen.py``).

numba caches each kernel per source file: after editing this file delete
``observers/__pycache__/uio_nguyen_loop*.nbi, *.nbc`` (and those of the kernels that call
:func:`affine_rk4`: ``uio_generalized_loop``, ``pi_observer_loop``, ``neural_adaptive_nguyen_loop``).
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit

TWO_PI = 2.0 * math.pi
SUBSTEP_RATE = 0.5  # largest ||M|| h_sub of one RK4 sub-step


@jit
def affine_rk4(z: np.ndarray, Ms: np.ndarray, Gs: np.ndarray, w0: np.ndarray, w1: np.ndarray, rho1: float,
               rho2: float, h: float, nsub: int) -> None:
    """Advance ``z' = M z + G w(t)`` by ``h`` [s] in place with ``nsub`` RK4 sub-steps.

    ``M = Ms[0] + rho1 Ms[1] + rho2 Ms[2]``: Ms (3, n, n); ``G`` likewise from Gs (3, n, m); the input
    is first-order held, ``w(t)`` linear from w0 (m,) at the start to w1 (m,) at the end of the step.
    """
    n = z.shape[0]
    m = w0.shape[0]
    M = np.empty((n, n))
    b0 = np.empty(n)
    db = np.empty(n)
    for i in range(n):
        s0 = 0.0
        s1 = 0.0
        for j in range(m):
            g = Gs[0, i, j] + rho1 * Gs[1, i, j] + rho2 * Gs[2, i, j]
            s0 += g * w0[j]
            s1 += g * w1[j]
        b0[i] = s0
        db[i] = s1 - s0
        for j in range(n):
            M[i, j] = Ms[0, i, j] + rho1 * Ms[1, i, j] + rho2 * Ms[2, i, j]
    k = np.empty((4, n))
    zt = np.empty(n)
    for sub in range(nsub):
        for stage in range(4):
            # stage times 0, 1/2, 1/2, 1 of the sub-step, as a fraction of the whole step
            frac = (sub + (0.0 if stage == 0 else (1.0 if stage == 3 else 0.5))) / nsub
            for i in range(n):
                if stage == 0:
                    zt[i] = z[i]
                elif stage == 3:
                    zt[i] = z[i] + (h / nsub) * k[2, i]
                else:
                    zt[i] = z[i] + 0.5 * (h / nsub) * k[stage - 1, i]
            for i in range(n):
                s = b0[i] + frac * db[i]
                for j in range(n):
                    s += M[i, j] * zt[j]
                k[stage, i] = s
        for i in range(n):
            z[i] += (h / nsub) / 6.0 * (k[0, i] + 2.0 * k[1, i] + 2.0 * k[2, i] + k[3, i])


#: Layout of the kernel's scalar state ``state`` (flags as 0.0 / 1.0).
T_CUR, PSI_M, R_PREV, T_R_PREV, TRACKING, STARTED, HAVE_U_PREV = range(7)
N_STATE = 7


@jit
def nguyen_run(t: np.ndarray, Y: np.ndarray, u: np.ndarray, fresh: np.ndarray, tl: np.ndarray, eta: np.ndarray,
               zeta: np.ndarray, w_prev: np.ndarray, u_prev: np.ndarray, state: np.ndarray, Fs: np.ndarray,
               Gs: np.ndarray, Qz: np.ndarray, Ms: np.ndarray, Gp: np.ndarray, bounds: np.ndarray,
               par: np.ndarray, out: np.ndarray) -> None:
    """The UIO over samples ``t`` (n,) [s], ``Y`` (n, 4) = ``(v_x, r, a_x, delta)``; ``(v_y, r, beta)`` into ``out`` (n, 3).

    Carried in place: ``u``/``fresh``/``tl`` (4,) held inputs, whether each is new, arrival times [s];
    ``eta``/``zeta`` (6,) (forces in kN); ``w_prev`` (5,) the previous ``(y, u)``; ``u_prev`` (2,)
    the previous ``u``; ``state`` (``N_STATE``,) the scalars ``T_CUR`` ... ``HAVE_U_PREV``.
    Constants: ``Fs``, ``Gs``, ``Qz``, ``Ms``, ``Gp``, ``bounds`` of ``NguyenUIO.constants()``;
    ``par`` = ``(v_lo, v_hi, hold_s, delta2)``.
    """
    n = t.shape[0]
    nz = eta.shape[0]
    u0, u1, ym, w1, q = np.empty(2), np.empty(2), np.empty(3), np.empty(5), np.empty(nz)
    for i in range(n):
        ts = t[i]
        # ScalarLoopObserver._tick: latch new samples, step since the last advance
        for j in range(4):
            y = Y[i, j]
            if y == y:
                u[j] = y
                fresh[j] = True
                tl[j] = ts
            else:
                fresh[j] = False
        h = ts - state[T_CUR]
        if h > 0.0:
            state[T_CUR] = ts
        else:
            h = 0.0
        _advance(ts, h, u, fresh, tl, eta, zeta, w_prev, u_prev, state, Fs, Gs, Qz, Ms, Gp, bounds, par,
                 u0, u1, ym, w1, q)
        vx = u[0]
        v = vx if vx == vx else zeta[0]
        out[i, 0], out[i, 1] = zeta[1], zeta[3]
        out[i, 2] = math.atan2(zeta[1], v) if v > 0.0 else 0.0


@jit
def _advance(ts: float, h: float, u: np.ndarray, fresh: np.ndarray, tl: np.ndarray, eta: np.ndarray,
             zeta: np.ndarray, w_prev: np.ndarray, u_prev: np.ndarray, state: np.ndarray, Fs: np.ndarray,
             Gs: np.ndarray, Qz: np.ndarray, Ms: np.ndarray, Gp: np.ndarray, bounds: np.ndarray, par: np.ndarray,
             u0: np.ndarray, u1: np.ndarray, ym: np.ndarray, w1: np.ndarray, q: np.ndarray) -> None:
    """One sample of ``NguyenUIO`` after the latch, in place; ``u0``, ``u1`` (2,), ``ym`` (3,), ``w1`` (5,),
    ``q`` (6,) are scratch."""
    vx, r, ax, delta = u[0], u[1], u[2], u[3]
    if state[STARTED] == 0.0:
        if vx != vx:
            return
        zeta[0] = vx
        state[STARTED] = 1.0
    tracking = state[TRACKING] != 0.0
    if fresh[1]:
        # heading pseudo-measurement: trapezoidal integral of the gyro between its samples
        if state[R_PREV] == state[R_PREV] and tracking:
            state[PSI_M] += 0.5 * (ts - state[T_R_PREV]) * (state[R_PREV] + r)
        state[R_PREV], state[T_R_PREV] = r, ts
    v = vx if vx == vx else zeta[0]
    v = par[0] if v < par[0] else (par[1] if v > par[1] else v)
    u1[0] = ax if ax == ax else 0.0
    u1[1] = delta if delta == delta else 0.0
    if state[HAVE_U_PREV] != 0.0:
        u0[0], u0[1] = u_prev[0], u_prev[1]
    else:
        u0[0], u0[1] = u1[0], u1[1]
    u_prev[0], u_prev[1] = u1[0], u1[1]
    state[HAVE_U_PREV] = 1.0
    live = r == r and vx == vx and ts - min(tl[0], tl[1]) <= par[2]
    if live and not tracking:
        # (re)start: the integrated gyro restarts where the model's psi is, eta = zeta - Q y
        psi = zeta[2] + par[3] * zeta[4]
        state[PSI_M] = psi
        state[TRACKING] = 1.0
        w_prev[0], w_prev[1], w_prev[2], w_prev[3], w_prev[4] = vx, psi, r, u1[0], u1[1]
        ym[0], ym[1], ym[2] = vx, psi, r
        np.dot(Qz, ym, q)   # the BLAS product numpy's ``Qz @ y`` uses: same bits as the Python original
        for k in range(eta.shape[0]):
            eta[k] = zeta[k] - q[k]
        return
    if live:
        psi = state[PSI_M]
        if psi > math.pi or psi < -math.pi:
            # re-centre psi_m, psi_hat and eta together (the psi column of A is 0)
            c = TWO_PI * np.rint(psi / TWO_PI)  # Python's round(): half to even
            psi -= c
            state[PSI_M] = psi
            eta[2] -= c
            for k in range(eta.shape[0]):
                eta[k] += c * Qz[k, 1]
            w_prev[1] -= c
        ym[0], ym[1], ym[2] = vx, psi, r
        w1[0], w1[1], w1[2], w1[3], w1[4] = vx, psi, r, u1[0], u1[1]
    else:
        state[TRACKING] = 0.0
    if h > 0.0:
        # one call site (the UIO's eta ODE when live, the model prediction of zeta otherwise): the RK4
        # kernel is inlined once (compile time)
        if live:
            z, M, G, w_a, w_b, rate = eta, Fs, Gs, w_prev, w1, bounds[0]
        else:
            z, M, G, w_a, w_b, rate = zeta, Ms, Gp, u0, u1, bounds[1]
        affine_rk4(z, M, G, w_a, w_b, v, 1.0 / v, h, max(1, math.ceil(h * rate / SUBSTEP_RATE)))
    if not live:
        return
    for k in range(5):
        w_prev[k] = w1[k]
    np.dot(Qz, ym, q)
    for k in range(eta.shape[0]):
        zeta[k] = eta[k] + q[k]
