"""Compiled whole-run loop of the generalized UIO (:mod:`observers.uio_generalized`).

:func:`generalized_run` is ``GeneralizedUIO._advance`` (latching, causal differentiators, integrated
gyro and its re-centring, prediction while ``v_x`` / ``r`` are stale, re-seeding, the UIO step) written
on arrays, so ``GeneralizedUIO.run_compiled()`` follows stepping ``step()`` one sample at a time;
``step()`` (and ``run()``) stay the plain-Python reference (tested in ``tests/test_observers_uio_compiled.py``).

The one deliberate difference is how the frozen affine step is integrated. ``step()`` uses
:func:`observers.uio_generalized.exact_affine_step`: the order-12 Taylor exponential of the
(n + 2)-square augmented matrix, whose 1-norm reaches ~600 at 100 Hz (``|K|`` ~ 3e4), so it squares
12 times. Here (:func:`affine_step_pade`) the same exponential is evaluated as Higham's scaling and
squaring with the [13/13] Padé approximant (N. J. Higham, "The scaling and squaring method for the
matrix exponential revisited", SIAM J. Matrix Anal. Appl. 26(4), 2005, Table 2.3 / Algorithm 2.3)
after a fixed diagonal similarity in powers of two (LAPACK balancing of the gain-dominated ``F``, which
changes no bit of the result's scaling), and only its action on ``(eta, 1, 0)`` is formed: the Padé
factor is applied ``2^s`` times to the vector instead of squaring the matrix. Both are accurate to
rounding; the estimates agree with ``step()`` to ~1e-12 relative (asserted at 1e-9).

numba caches each kernel per source file: after editing this file delete
``observers/__pycache__/uio_generalized_loop*.nbi, *.nbc``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from harness.tire import jit
from observers.uio_nguyen import SUBSTEP_RATE, TWO_PI, affine_rk4

if TYPE_CHECKING:
    from collections.abc import Mapping

    from observers.base import EstimateTrack
    from observers.uio_generalized import GeneralizedUIO

#: Higham (2005) Table 2.3: largest 1-norm for which the [m/m] Padé approximant is accurate to
#: double precision after scaling, m = 9 and 13.
THETA_9 = 2.097847961257068
THETA_13 = 5.371920351148152
PADE_9 = np.array([17643225600.0, 8821612800.0, 2075673600.0, 302702400.0, 30270240.0, 2162160.0,
                   110880.0, 3960.0, 90.0, 1.0])
PADE_13 = np.array([64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
                    129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0,
                    40840800.0, 960960.0, 16380.0, 182.0, 1.0])


@jit
def _mul(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> None:
    """``C = A @ B`` for square matrices (i-k-j order: the inner loop is contiguous)."""
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            C[i, j] = 0.0
        for k in range(n):
            a = A[i, k]
            if a != 0.0:
                for j in range(n):
                    C[i, j] += a * B[k, j]


@jit
def _lu_solve_vec(LU: np.ndarray, piv: np.ndarray, b: np.ndarray) -> None:
    """Solve ``LU x = P b`` in place in ``b`` with the factors of :func:`_lu`."""
    n = LU.shape[0]
    for i in range(n):
        p = piv[i]
        if p != i:
            b[i], b[p] = b[p], b[i]
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= LU[i, k] * b[k]
        b[i] = s
    for i in range(n - 1, -1, -1):
        s = b[i]
        for k in range(i + 1, n):
            s -= LU[i, k] * b[k]
        b[i] = s / LU[i, i]


@jit
def _lu(A: np.ndarray, piv: np.ndarray) -> None:
    """LU factorisation with partial pivoting, in place (row swaps recorded in ``piv``)."""
    n = A.shape[0]
    for c in range(n):
        p = c
        best = abs(A[c, c])
        for i in range(c + 1, n):
            if abs(A[i, c]) > best:
                best = abs(A[i, c])
                p = i
        piv[c] = p
        if p != c:
            for j in range(n):
                A[c, j], A[p, j] = A[p, j], A[c, j]
        d = A[c, c]
        if d == 0.0:
            continue
        for i in range(c + 1, n):
            f = A[i, c] / d
            A[i, c] = f
            if f != 0.0:
                for j in range(c + 1, n):
                    A[i, j] -= f * A[c, j]


@jit
def expm_action(M: np.ndarray, x: np.ndarray, work: np.ndarray, piv: np.ndarray) -> None:
    """``x <- exp(M) x`` in place: [13/13] (or [9/9]) Padé, scaling ``2^-s``, factor applied ``2^s`` times.

    ``M`` (n, n) is overwritten (scaled); ``work`` (>= 8, n, n) scratch (not ``M``); ``piv`` (n,) int64 scratch.
    """
    n = M.shape[0]
    norm = 0.0
    for j in range(n):
        s = 0.0
        for i in range(n):
            s += abs(M[i, j])
        norm = max(norm, s)
    sq = 0
    if norm > THETA_13:
        sq = int(math.ceil(math.log2(norm / THETA_13)))
        f = 0.5 ** sq
        for i in range(n):
            for j in range(n):
                M[i, j] *= f
    A2, A4, A6, U, V, T = work[0], work[1], work[2], work[3], work[4], work[5]
    _mul(M, M, A2)
    if sq == 0 and norm <= THETA_9:
        b = PADE_9
        _mul(A2, A2, A4)
        _mul(A4, A2, A6)
        _mul(A6, A2, V)  # A8 in V
        for i in range(n):
            for j in range(n):
                T[i, j] = b[9] * V[i, j] + b[7] * A6[i, j] + b[5] * A4[i, j] + b[3] * A2[i, j]
                V[i, j] = b[8] * V[i, j] + b[6] * A6[i, j] + b[4] * A4[i, j] + b[2] * A2[i, j]
            T[i, i] += b[1]
            V[i, i] += b[0]
        _mul(M, T, U)
    else:
        b = PADE_13
        _mul(A2, A2, A4)
        _mul(A4, A2, A6)
        for i in range(n):
            for j in range(n):
                T[i, j] = b[13] * A6[i, j] + b[11] * A4[i, j] + b[9] * A2[i, j]
        _mul(A6, T, U)
        for i in range(n):
            for j in range(n):
                U[i, j] += b[7] * A6[i, j] + b[5] * A4[i, j] + b[3] * A2[i, j]
            U[i, i] += b[1]
        _mul(M, U, T)   # T = U of the approximant
        for i in range(n):
            for j in range(n):
                U[i, j] = b[12] * A6[i, j] + b[10] * A4[i, j] + b[8] * A2[i, j]
        _mul(A6, U, V)
        for i in range(n):
            for j in range(n):
                V[i, j] += b[6] * A6[i, j] + b[4] * A4[i, j] + b[2] * A2[i, j]
            V[i, i] += b[0]
        for i in range(n):
            for j in range(n):
                U[i, j] = T[i, j]
    # r = (V - U)^-1 (V + U); x <- r^(2^sq) x
    P, LU = work[6], work[7]
    for i in range(n):
        for j in range(n):
            P[i, j] = V[i, j] + U[i, j]
            LU[i, j] = V[i, j] - U[i, j]
    _lu(LU, piv)
    y = np.empty(n)
    for _ in range(1 << sq):
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += P[i, j] * x[j]
            y[i] = s
        _lu_solve_vec(LU, piv, y)
        for i in range(n):
            x[i] = y[i]


@jit
def affine_step_pade(z: np.ndarray, Fs: np.ndarray, Gs: np.ndarray, c: np.ndarray, w0: np.ndarray,
                     w1: np.ndarray, h: float, d: np.ndarray, work: np.ndarray, piv: np.ndarray) -> None:
    """Advance ``z' = F z + G w(t)`` by ``h`` [s] exactly, in place, as ``exact_affine_step``.

    ``Fs`` (nb, n, n), ``Gs`` (nb, n, m) are the basis *already balanced* by the powers of two ``d``
    (n,): ``Fs = D^-1 Fs_orig D``, ``Gs = D^-1 Gs_orig`` with ``D = diag(d)``; ``z`` is in the original
    coordinates; ``work`` (9, n + 2, n + 2) and ``piv`` (n + 2,) int64 are scratch. The input columns of the augmented matrix are scaled by a power of two ``sigma`` so
    that they do not dominate its norm (an exact similarity ``diag(1, sigma, sigma)``).
    """
    n, m, nb = z.shape[0], w0.shape[0], c.shape[0]
    N = n + 2
    M = work[8]
    for i in range(N):
        for j in range(N):
            M[i, j] = 0.0
    bmax = 0.0
    fnorm = 0.0
    for i in range(n):
        b0 = 0.0
        b1 = 0.0
        for k in range(nb):
            ck = c[k]
            if ck == 0.0:
                continue
            for j in range(n):
                M[i, j] += ck * Fs[k, i, j] * h
            for j in range(m):
                g = ck * Gs[k, i, j]
                b0 += g * w0[j]
                b1 += g * w1[j]
        M[i, n] = b0 * h
        M[i, n + 1] = (b1 - b0) * h
    for j in range(n):
        s = 0.0
        for i in range(n):
            s += abs(M[i, j])
        fnorm = max(fnorm, s)
    for j in range(n, N):
        s = 0.0
        for i in range(n):
            s += abs(M[i, j])
        bmax = max(bmax, s)
    sigma = 1.0
    target = max(fnorm, 1.0)
    while bmax * sigma > target:
        sigma *= 0.5
    for i in range(n):
        M[i, n] *= sigma
        M[i, n + 1] *= sigma
    M[n + 1, n] = 1.0
    x = np.zeros(N)
    for i in range(n):
        x[i] = z[i] / d[i]
    x[n] = 1.0 / sigma
    expm_action(M, x, work, piv)
    for i in range(n):
        z[i] = x[i] * d[i]


@jit
def _clamp(v: float, lo: float, hi: float) -> float:
    return lo if v < lo else (hi if v > hi else v)


@jit
def _derivative(f: float, tau: float, k: int, dst: np.ndarray, par: np.ndarray, levant: bool) -> float:
    """``CausalDerivative.update`` of differentiator ``k`` on ``dst[k] = (value, prev, z0, z1,
    initialized, f_prev)``; ``par`` = ``(T, g0, g1)`` (low-pass time constant [s], Levant gains)."""
    s = dst[k]
    if levant:
        if s[4] == 0.0:          # LevantDifferentiator.reset(f): z = (f, 0)
            s[2], s[3], s[4], s[5] = f, 0.0, 1.0, f
        else:
            f_prev = s[5]
            s[5] = f
            if tau > 0.0:
                z0, z1 = s[2], s[3]
                e = z0 - f_prev
                ae = abs(e)
                sg = 1.0 if e > 0.0 else (-1.0 if e < 0.0 else 0.0)
                dz0 = -par[1] * (ae ** 0.5) * sg + z1
                dz1 = -par[2] * sg
                s[2], s[3] = z0 + tau * dz0, z1 + tau * dz1
        s[0] = s[3]
        return s[0]
    T = par[0]
    if s[1] == s[1] and tau > 0.0:
        raw = (f - s[1]) / tau
        a = math.exp(-tau / T) if T > 0.0 else 0.0
        s[0] = a * s[0] + (1.0 - a) * raw
    s[1] = f
    return s[0]


@jit
def _output(y: np.ndarray, yd: np.ndarray, cchi: np.ndarray, summed: bool, out: np.ndarray) -> None:
    """``GeneralizedModel.output``: stacked ``(y, C_chi y', y)`` or summed ``2 y + C_chi y'``."""
    for i in range(3):
        cy = 0.0
        for j in range(3):
            cy += cchi[i, j] * yd[j]
        if summed:
            out[i] = 2.0 * y[i] + cy
        else:
            out[i], out[3 + i], out[6 + i] = y[i], cy, y[i]


@jit
def generalized_run(t: np.ndarray, Y: np.ndarray, Fb: np.ndarray, Gb: np.ndarray, dbal: np.ndarray,
                    Q: np.ndarray, Mp: np.ndarray, Gp: np.ndarray, cchi: np.ndarray, dpsi: np.ndarray,
                    u: np.ndarray, fresh: np.ndarray, tl: np.ndarray, zeta: np.ndarray, eta: np.ndarray,
                    w_prev: np.ndarray, dst: np.ndarray, state: np.ndarray, par: np.ndarray, summed: bool,
                    levant: bool) -> np.ndarray:
    """``GeneralizedUIO._advance`` over a run; returns the (n, 3) estimates ``(v_y, r, beta)``.

    In-place state: ``u``/``fresh``/``tl`` (4,), ``zeta``/``eta`` (n_zeta,), ``w_prev`` (n_out + 4,),
    ``dst`` (3, 6) differentiators, ``state`` = ``(t_cur, have_zeta, have_eta, have_w, tracking, psi_m,
    r_prev, t_r_prev, t_prev, v_prev, a_prev, z0, z1)``. ``par`` = ``(v_lo, v_hi, hold_s, T, g0, g1)``.
    ``dpsi`` (n_mu,) = ``D_bar[k0 + 1]`` (zero for the summed output), ``par[6]`` = ``delta2``.
    """
    n = t.shape[0]
    nz = zeta.shape[0]
    no = Q.shape[1]
    nw = w_prev.shape[0]
    k0 = 6
    out = np.empty((n, 3))
    t_cur = state[0]
    have_zeta, have_eta, have_w, tracking = state[1] != 0.0, state[2] != 0.0, state[3] != 0.0, state[4] != 0.0
    psi_m, r_prev, t_r_prev, t_prev, v_prev, a_prev = state[5], state[6], state[7], state[8], state[9], state[10]
    vlo, vhi, hold = par[0], par[1], par[2]
    dpar = par[3:6]
    N = nz + 2
    work = np.zeros((9, N, N))
    piv = np.zeros(N, dtype=np.int64)
    yv = np.empty(3)
    yd = np.empty(3)
    ychi = np.empty(no)
    w1 = np.empty(nw)
    uu = np.empty(2)
    nxm = Mp.shape[1]
    xm = np.empty(nxm)
    for i in range(n):
        ts = t[i]
        for j in range(4):
            v = Y[i, j]
            if v == v:
                u[j] = v
                fresh[j] = True
                tl[j] = ts
            else:
                fresh[j] = False
        h = ts - t_cur
        if h > 0.0:
            t_cur = ts
        else:
            h = 0.0
        vx, r, ax, delta = u[0], u[1], u[2], u[3]
        if vx == vx:
            a = ax if ax == ax else 0.0
            d = delta if delta == delta else 0.0
            tau = ts - t_prev if t_prev == t_prev else 0.0
            t_prev = ts
            if fresh[1]:
                if r_prev == r_prev and tracking:
                    psi_m += 0.5 * (ts - t_r_prev) * (r_prev + r)
                r_prev, t_r_prev = r, ts
            rd = _derivative(r, tau, 0, dst, dpar, levant) if r == r and tau > 0.0 else dst[0, 0]
            ad = _derivative(a, tau, 1, dst, dpar, levant) if tau > 0.0 else 0.0
            dd = _derivative(d, tau, 2, dst, dpar, levant) if tau > 0.0 else 0.0
            live = r == r and ts - min(tl[0], tl[1]) <= hold
            if not live:
                if have_zeta and h > 0.0:
                    for j in range(nxm):
                        xm[j] = zeta[k0 + j]
                    vc = min(max(vx, vlo), vhi)
                    uu[0], uu[1] = a, d
                    affine_rk4(xm, Mp, Gp, uu, uu, vc, 1.0 / vc, h, max(1, math.ceil(h * 200.0 / SUBSTEP_RATE)))
                    for j in range(nxm):
                        zeta[k0 + j] = xm[j]
                tracking = False
            else:
                if not tracking and have_zeta:
                    s = 0.0
                    for j in range(dpsi.shape[0]):
                        s += dpsi[j] * zeta[k0 + 4 + j]
                    psi_m = zeta[k0 + 2] + par[6] * s
                if psi_m > math.pi or psi_m < -math.pi:
                    c = TWO_PI * round(psi_m / TWO_PI)
                    psi_m -= c
                    if have_eta and have_w and have_zeta:
                        zeta[1] -= c
                        zeta[k0 + 2] -= c
                        if summed:
                            w_prev[1] -= 2.0 * c
                        else:
                            w_prev[1] -= c
                            w_prev[7] -= c
                        for p in range(nz):
                            s = 0.0
                            for q in range(no):
                                s += Q[p, q] * w_prev[q]
                            eta[p] = zeta[p] - s
                # advance_with_derivatives(h, (vx, psi_m, r), (a, r, rd), (a, d), (ad, dd), vx)
                yv[0], yv[1], yv[2] = vx, psi_m, r
                yd[0], yd[1], yd[2] = a, r, rd
                _output(yv, yd, cchi, summed, ychi)
                for j in range(no):
                    w1[j] = ychi[j]
                w1[no], w1[no + 1], w1[no + 2], w1[no + 3] = a, d, ad, dd
                vc = _clamp(vx, vlo, vhi)
                if not have_eta or not have_w or not tracking:
                    if not have_zeta:
                        for j in range(nz):
                            zeta[j] = 0.0
                        for j in range(3):
                            zeta[j] = yv[j]
                            zeta[3 + j] = yd[j]
                        zeta[6], zeta[7], zeta[8], zeta[9] = yv[0], state[11], yv[1], state[12]
                        have_zeta = True
                    for p in range(nz):
                        s = 0.0
                        for q in range(no):
                            s += Q[p, q] * ychi[q]
                        eta[p] = zeta[p] - s
                    have_eta = True
                    for j in range(nw):
                        w_prev[j] = w1[j]
                    have_w = True
                    v_prev, a_prev = vc, a
                    tracking = True
                else:
                    if h > 0.0:
                        vm, am = 0.5 * (vc + v_prev), 0.5 * (a + a_prev)
                        cb = np.array([1.0, vm, 1.0 / vm, vm * vm, 1.0 / (vm * vm), am, am / (vm * vm)])
                        affine_step_pade(eta, Fb, Gb, cb, w_prev, w1, h, dbal, work, piv)
                    for j in range(nw):
                        w_prev[j] = w1[j]
                    v_prev, a_prev = vc, a
                    for p in range(nz):
                        s = 0.0
                        for q in range(no):
                            s += Q[p, q] * ychi[q]
                        zeta[p] = eta[p] + s
        # _values
        if not have_zeta:
            out[i, 0], out[i, 1], out[i, 2] = state[11], state[12], 0.0
        else:
            vy, rr = zeta[k0 + 1], zeta[k0 + 3]
            v = u[0] if u[0] == u[0] else zeta[k0]
            out[i, 0], out[i, 1] = vy, rr
            out[i, 2] = math.atan2(vy, v) if v > 0.0 else 0.0
    state[0] = t_cur
    state[1] = 1.0 if have_zeta else 0.0
    state[2] = 1.0 if have_eta else 0.0
    state[3] = 1.0 if have_w else 0.0
    state[4] = 1.0 if tracking else 0.0
    state[5], state[6], state[7], state[8], state[9], state[10] = psi_m, r_prev, t_r_prev, t_prev, v_prev, a_prev
    return out


def balanced_constants(Fs: np.ndarray, Gws: np.ndarray, v_mid: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Fb, Gb, d)``: the basis under the power-of-two balancing ``D = diag(d)`` of ``F(v_mid, 0)``."""
    from scipy.linalg import matrix_balance

    from observers.uio_generalized_design import basis

    _, (scale, _) = matrix_balance(np.tensordot(basis(v_mid, 0.0), Fs, axes=1), permute=False, separate=True)
    d = np.asarray(scale, dtype=float)
    Fb = np.ascontiguousarray(Fs / d[None, :, None] * d[None, None, :])
    Gb = np.ascontiguousarray(Gws / d[None, :, None])
    return Fb, Gb, d


def run_compiled(obs: GeneralizedUIO, t: np.ndarray, Y: np.ndarray,
                 x0: Mapping[str, float] | None) -> EstimateTrack:
    """``obs.run`` through :func:`generalized_run`; leaves ``obs`` in the state stepping leaves it in."""
    from observers.base import EstimateTrack
    from observers.levant_differentiator import levant_gains

    t = np.ascontiguousarray(t, dtype=float)
    Y = np.ascontiguousarray(np.asarray(Y, dtype=float).reshape(len(t), len(obs.inputs)))
    if len(t) == 0:
        return EstimateTrack(obs.name, tuple(obs.states), t, np.zeros((0, len(obs.states))))
    obs.reset(float(t[0]), x0)
    Fs, Gws, Q, Mp, Gp = obs.constants()  # a failed design raises here, as on the first step()
    gm = obs.generalized_model()
    bal = obs._balanced
    if bal is None:
        bal = obs._balanced = balanced_constants(Fs, Gws, 0.5 * (obs._vlo + obs._vhi))
    Fb, Gb, dbal = bal
    o = obs.options
    levant = o["differentiator"] == "levant"
    g0, g1 = (levant_gains(1, float(o["levant_lipschitz"])) if levant else (0.0, 0.0))
    par = np.array([obs._vlo, obs._vhi, obs._hold, float(o["lowpass_s"]), g0, g1, gm.delta2])
    k0 = 2 * gm.n_y
    dpsi = np.zeros(gm.n_mu) if gm.summed else np.ascontiguousarray(gm.D_bar[k0 + 1], dtype=float)
    nz, no = gm.n_zeta, Q.shape[1]
    zeta, eta, w_prev = np.zeros(nz), np.zeros(nz), np.zeros(no + 4)
    dst = np.zeros((3, 6))
    dst[:, 1] = math.nan
    u = np.array(obs._u, dtype=float)
    fresh = np.array(obs._fresh, dtype=np.bool_)
    tl = np.array(obs._t_last, dtype=float)
    state = np.array([obs._t, 0.0, 0.0, 0.0, 0.0, obs._psi_m, obs._r_prev, obs._t_r_prev, obs._t_prev,
                      0.0, 0.0, float(obs._z[0]), float(obs._z[1])])
    X = generalized_run(t, Y, Fb, Gb, dbal, np.ascontiguousarray(Q), np.ascontiguousarray(Mp),
                        np.ascontiguousarray(Gp), np.ascontiguousarray(gm.C_chi, dtype=float), dpsi, u, fresh, tl,
                        zeta, eta, w_prev, dst, state, par, gm.summed, levant)
    # leave the observer where stepping would have left it
    obs._u, obs._fresh, obs._t_last = u.tolist(), fresh.tolist(), tl.tolist()
    obs._t = float(state[0])
    obs._zeta = zeta if state[1] else None
    obs._eta = eta if state[2] else None
    obs._w_prev = w_prev if state[3] else None
    obs._tracking = bool(state[4])
    obs._psi_m, obs._r_prev, obs._t_r_prev, obs._t_prev = (float(x) for x in state[5:9])
    if state[2]:
        obs._v_prev, obs._a_prev = float(state[9]), float(state[10])
    for k, diff in enumerate(obs._diff):
        diff.value, diff._prev = float(dst[k, 0]), float(dst[k, 1])
        if diff._lev is not None:
            diff._lev.z = [float(dst[k, 2]), float(dst[k, 3])]
            diff._lev.initialized = bool(dst[k, 4])
            diff._lev._f_prev = float(dst[k, 5])
    return EstimateTrack(obs.name, tuple(obs.states), t, X)
