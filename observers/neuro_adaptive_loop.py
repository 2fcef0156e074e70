"""The compiled kernel of the neuro-adaptive radar observers (:mod:`roadtruth.observers.neuro_adaptive`), shared by step() and run().

:func:`learning_run` is the whole per-sample update of the family: latching the samples (value,
arrival time and slope from the two latest samples of each channel), the start at the first
position sample, and then either

- mode 0, (3.11) / (3.7) (``neuro_adaptive_cl``, ``neuro_adaptive_cl_printed``, ``cl_aeo_ran_xie``):
  the exact discretisation of ``A~ - L~ C~`` (closed loop) or of the open chain (no position sample
  within ``hold_s``) with first-order-held inputs, the backward-Euler step of the weight ODE and
  the history stack of Algorithm 2 (its minimum singular value never decreases), or
- mode 1, (3.4) (``neuro_adaptive_chakrabarty``): RK4 sub-steps of the bilinear observer and the
  output-error weight integrator,

on arrays carried between calls. ``step()`` calls it with one sample and ``run()`` with the whole
log, so both execute the same compiled code on the same state and agree bit for bit
(``tests/test_observers_neuro_adaptive.py``). One kernel for the four observers: every extra kernel
costs numba compilation time on a fresh install.

Carried state: ``z`` (4,) = ``(x_1, x_2, x_3, x_4)`` (mode 1: ``x_4`` unused), ``W`` (N,) weights,
``Z`` (N, p) and ``Lam`` (p,) the history stack, ``last``/``tl``/``slope`` (4,) the latest sample of
each input channel, its time [s] and slope; ``st`` = ``(started, t_prev, t_rec, k, smin)``.
``par`` = ``(mode, regressor, eta1, eta2, record_interval_s, hold_s, rk4_max_step_s)``.

The matrix products (``@``, ``np.linalg.solve``, ``eigvalsh``) are kept as they were in the earlier
per-family loops: numba sends them to BLAS / LAPACK, whose results a hand-written sum would not
reproduce to the bit.

numba caches each kernel per source file: after editing this file delete
``observers/__pycache__/neuro_adaptive_loop*.nbi, *.nbc``.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit

REG_SIGMOID = 0   # sigma(x) of (3.29): three sigmoids
REG_M7C = 1       # known regressor of (3.27): (v a, a, v^2, 1)
IOTA = 0.01       # saturation overshoot of rho (Ran & Xie: rho(inf) = 1 + iota)
MODE_CL = 0       # (3.11) / (3.7): exact discretisation + backward-Euler weights + history stack
MODE_CHAKRABARTY = 1   # (3.4): RK4 sub-steps, weights integrate the output error
N_PAR = 7
N_ST = 5


@jit
def regressor(kind: int, x1: float, x2: float, x3: float, out: np.ndarray) -> None:
    """``sigma(x)`` (3,) of (3.29) or the known regressor (4,) of (3.27) into ``out``."""
    if kind == REG_SIGMOID:
        out[0] = 1.0 / (1.0 + math.exp(-x1))
        out[1] = 1.0 / (1.0 + math.exp(-x2))
        out[2] = 1.0 / (1.0 + math.exp(-x3))
    else:
        out[0] = x2 * x3
        out[1] = x3
        out[2] = x2 * x2
        out[3] = 1.0


@jit
def rho(v: float, m: float) -> float:
    """``M rho(v / M)``: identity inside ``|v| <= M``, smooth saturation to ``(1 + iota) M`` outside."""
    if not m < math.inf:
        return v
    q = v / m
    if abs(q) <= 1.0:
        return v
    s = 1.0 if q > 0 else -1.0
    return m * s * (1.0 + IOTA * math.tanh((abs(q) - 1.0) / IOTA))


@jit
def smin(Z: np.ndarray) -> float:
    """Minimum singular value of the history stack ``Z`` (N, p)."""
    ev = np.linalg.eigvalsh(Z @ Z.T)
    return math.sqrt(max(ev[0], 0.0))


@jit
def _cl_update(ti: float, h: float, hi: int, PHI: np.ndarray, G0: np.ndarray, G1: np.ndarray, Lt: np.ndarray,
               par: np.ndarray, sat: np.ndarray, z: np.ndarray, W: np.ndarray, Z: np.ndarray, Lam: np.ndarray,
               last: np.ndarray, tl: np.ndarray, slope: np.ndarray, st: np.ndarray, s: np.ndarray,
               rhs0: np.ndarray, rhs1: np.ndarray) -> None:
    """One step ``h`` > 0 [s] of (3.11) / (3.7) ending at ``ti`` [s], discretisation ``hi`` of ``PHI``."""
    kind, eta1, eta2, rec_dt, hold = int(par[1]), par[2], par[3], par[4], par[5]
    N = W.shape[0]
    p = Lam.shape[0]
    use_y = (ti - tl[0]) <= hold
    j = 0 if use_y else 1
    # input lines over [t - h, t]: value at t - h and slope (extrapolated while held)
    for r in range(4):
        rhs0[r] = 0.0
        rhs1[r] = 0.0
    for c in (1, 2):
        if last[c] == last[c]:
            sc = slope[c] if ti - tl[c] <= hold else 0.0
            rhs0[c] += last[c] + sc * (ti - h - tl[c])
            rhs1[c] += sc
    if use_y:
        y0 = last[0] + slope[0] * (ti - h - tl[0])
        for r in range(4):
            rhs0[r] += Lt[r] * y0
            rhs1[r] += Lt[r] * slope[0]
    zn = PHI[hi, j] @ z + G0[hi, j] @ rhs0 + G1[hi, j] @ rhs1
    ok = True
    for r in range(4):
        if not (zn[r] - zn[r] == 0.0):
            ok = False
    if ok:
        z[:] = zn
    # weights: backward Euler of W' = -(eta1 s s^T + eta2 Z Z^T) W + eta1 s x4 + eta2 Z Lam
    voff = last[3] if last[3] == last[3] else 0.0
    regressor(kind, rho(z[0], sat[0]), rho(z[1] + voff, sat[1]), rho(z[2], sat[2]), s)
    x4 = rho(z[3], sat[3])
    M = np.eye(N) + h * (eta1 * np.outer(s, s) + eta2 * (Z @ Z.T))
    b = W + h * (eta1 * s * x4 + eta2 * (Z @ Lam))
    W[:] = np.linalg.solve(M, b)
    if ti - st[2] >= rec_dt - 1e-12:
        st[2] = ti
        k = int(st[3])
        if k < p:
            Z[:, k] = s
            Lam[k] = x4
            st[3] = k + 1
            st[4] = smin(Z)
        else:
            best = -1.0
            jbest = -1
            for jj in range(p):
                old = Z[:, jj].copy()
                Z[:, jj] = s
                sj = smin(Z)
                Z[:, jj] = old
                if sj > best:
                    best = sj
                    jbest = jj
            if best > st[4]:
                Z[:, jbest] = s
                Lam[jbest] = x4
                st[4] = best


@jit
def _chak_rhs(x: np.ndarray, W: np.ndarray, y: float, b2: float, b3: float, voff: float, L0: np.ndarray,
              lw: np.ndarray, use_y: bool, s: np.ndarray, dx: np.ndarray, dW: np.ndarray) -> None:
    """Right side of (3.4): ``dx`` (3,), ``dW`` (N,) at ``(x, W)`` with position ``y`` and inputs ``b2, b3``."""
    regressor(REG_SIGMOID, x[0], x[1] + voff, x[2], s)
    e = (y - x[0]) if use_y else 0.0
    dx[0] = x[1] + L0[0] * e
    dx[1] = x[2] + b2 + L0[1] * e
    dx[2] = W @ s + b3 + L0[2] * e
    for r in range(W.shape[0]):
        dW[r] = lw[r] * e


@jit
def _chak_update(ti: float, h: float, Lt: np.ndarray, lw: np.ndarray, par: np.ndarray, z: np.ndarray,
                 W: np.ndarray, last: np.ndarray, tl: np.ndarray, slope: np.ndarray, s: np.ndarray,
                 kx: np.ndarray, kw: np.ndarray) -> None:
    """One step ``h`` > 0 [s] of (3.4) ending at ``ti`` [s], RK4 sub-steps of at most ``par[6]`` [s];
    ``kx`` (4, 3), ``kw`` (4, N): scratch for the RK4 stages."""
    hold, hmax = par[5], par[6]
    L0 = Lt[:3]
    x = z[:3].copy()
    k1x, k2x, k3x, k4x = kx[0], kx[1], kx[2], kx[3]
    k1w, k2w, k3w, k4w = kw[0], kw[1], kw[2], kw[3]
    use_y = (ti - tl[0]) <= hold
    m = int(math.ceil(h / hmax))
    hs = h / m
    voff = last[3] if last[3] == last[3] else 0.0
    for q in range(m):
        ta = ti - h + q * hs
        vals = np.zeros(3)
        sl = np.zeros(3)
        for c in range(3):
            if last[c] == last[c]:
                sc = slope[c] if (c == 0 or ti - tl[c] <= hold) else 0.0
                vals[c] = last[c] + sc * (ta - tl[c])
                sl[c] = sc
        _chak_rhs(x, W, vals[0], vals[1], vals[2], voff, L0, lw, use_y, s, k1x, k1w)
        hh = 0.5 * hs
        _chak_rhs(x + hh * k1x, W + hh * k1w, vals[0] + hh * sl[0], vals[1] + hh * sl[1],
                  vals[2] + hh * sl[2], voff, L0, lw, use_y, s, k2x, k2w)
        _chak_rhs(x + hh * k2x, W + hh * k2w, vals[0] + hh * sl[0], vals[1] + hh * sl[1],
                  vals[2] + hh * sl[2], voff, L0, lw, use_y, s, k3x, k3w)
        _chak_rhs(x + hs * k3x, W + hs * k3w, vals[0] + hs * sl[0], vals[1] + hs * sl[1],
                  vals[2] + hs * sl[2], voff, L0, lw, use_y, s, k4x, k4w)
        xn = x + (hs / 6.0) * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
        Wn = W + (hs / 6.0) * (k1w + 2.0 * k2w + 2.0 * k3w + k4w)
        if np.all(np.isfinite(xn)) and np.all(np.isfinite(Wn)):
            x[:] = xn
            W[:] = Wn
    z[0], z[1], z[2] = x[0], x[1], x[2]


@jit
def learning_run(t: np.ndarray, Y: np.ndarray, hidx: np.ndarray, PHI: np.ndarray, G0: np.ndarray,
                 G1: np.ndarray, Lt: np.ndarray, lw: np.ndarray, par: np.ndarray, sat: np.ndarray, z: np.ndarray,
                 W: np.ndarray, Z: np.ndarray, Lam: np.ndarray, last: np.ndarray, tl: np.ndarray, slope: np.ndarray,
                 st: np.ndarray, out_z: np.ndarray, out_W: np.ndarray, out_smin: np.ndarray,
                 out_fnn: np.ndarray) -> None:
    """The observer over ``t`` (n,) [s], ``Y`` (n, 4) = (y, b_2, b_3, v_offset), NaN = no sample.

    ``b_2``, ``b_3``: known inputs of rows 2, 3; ``v_offset`` is added to ``x_2`` in the regressor.
    ``PHI, G0, G1`` (nh, 2, 4, 4): exact discretisation of the step of row ``i`` at ``hidx[i]``
    ([0] the closed loop ``A~ - L~ C~``, [1] the open chain; mode 0 only). ``Lt`` (4,) = ``L~``;
    ``lw`` (N,) weight gains of mode 1. Writes ``out_z`` (n, 4) (mode 1: ``x_4`` = ``W^T s``),
    ``out_W`` (n, N), ``out_smin`` (n,), ``out_fnn`` (n,) = ``W^T s``; state arrays: module docstring.
    """
    mode, kind = int(par[0]), int(par[1])
    hold = par[5]
    N = W.shape[0]
    s = np.zeros(N)
    rhs0 = np.zeros(4)
    rhs1 = np.zeros(4)
    kx = np.zeros((4, 3))
    kw = np.zeros((4, N))
    for i in range(t.shape[0]):
        ti = t[i]
        for c in range(4):
            v = Y[i, c]
            if v == v:
                dt = ti - tl[c]
                slope[c] = (v - last[c]) / dt if (dt > 0.0 and dt <= hold and last[c] == last[c]) else 0.0
                last[c] = v
                tl[c] = ti
        h = ti - st[1]   # NaN at the first sample after a reset: nothing to integrate
        st[1] = ti
        if st[0] == 0.0:
            if last[0] == last[0]:
                z[0] = last[0]
                z[1] = 0.0
                z[2] = 0.0 if last[1] != last[1] else -last[1]  # a_L = a_E (b_2 = -a_E)
                z[3] = 0.0
                st[0] = 1.0
        elif h > 0.0:
            if mode == MODE_CL:
                _cl_update(ti, h, hidx[i], PHI, G0, G1, Lt, par, sat, z, W, Z, Lam, last, tl, slope, st, s,
                           rhs0, rhs1)
            else:
                _chak_update(ti, h, Lt, lw, par, z, W, last, tl, slope, s, kx, kw)
        voff = last[3] if last[3] == last[3] else 0.0
        if mode == MODE_CL:
            regressor(kind, rho(z[0], sat[0]), rho(z[1] + voff, sat[1]), rho(z[2], sat[2]), s)
            f = W @ s
            for r in range(4):
                out_z[i, r] = z[r]
        else:
            regressor(REG_SIGMOID, z[0], z[1] + voff, z[2], s)
            f = W @ s
            out_z[i, 0], out_z[i, 1], out_z[i, 2], out_z[i, 3] = z[0], z[1], z[2], f
        out_fnn[i] = f
        for r in range(N):
            out_W[i, r] = W[r]
        out_smin[i] = st[4]
