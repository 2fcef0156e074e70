"""The compiled kernel of the generalized UIO (:mod:`roadtruth.observers.uio_generalized`), shared by step() and run().

:func:`generalized_run` is the whole per-sample update (latching, causal differentiators, integrated
gyro and its re-centring, prediction while ``v_x`` / ``r`` are stale, re-seeding, the UIO step) on
arrays carried in a :class:`UIOKernelState`. ``GeneralizedUIO.step()`` calls it with one sample and
``GeneralizedUIO.run()`` with the whole log, so the two execute the same compiled code on the same
state and agree bit for bit (``tests/test_observers_uio_compiled.py``); a 550 s log at 100 Hz is one
call.

Each frozen affine step ``eta' = F eta + G w(t)`` (first-order-held input) is integrated exactly
(:func:`affine_step_pade`): the exponential of the (n + 2)-square augmented matrix, whose 1-norm
reaches ~600 at 100 Hz (``|K|`` ~ 3e4), evaluated as Higham's scaling and squaring with the [13/13]
Padé approximant (N. J. Higham, "The scaling and squaring method for the matrix exponential
revisited", SIAM J. Matrix Anal. Appl. 26(4), 2005, Table 2.3 / Algorithm 2.3) after a fixed diagonal
similarity in powers of two (LAPACK balancing of the gain-dominated ``F``, which changes no bit of
the result's scaling); only its action on ``(eta, 1, 0)`` is formed: the Padé factor is applied
``2^s`` times to the vector instead of squaring the matrix. Accurate to rounding against scipy's
``expm`` (asserted at 1e-13 of the state).

numba caches each kernel per source file: after editing this file delete
``observers/__pycache__/uio_generalized_loop*.nbi, *.nbc``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadtruth.harness.truth.tire import jit
from roadtruth.observers.uio_nguyen import SUBSTEP_RATE, TWO_PI, affine_rk4

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


#: Layout of the kernel's scalar state vector ``state`` (see :class:`UIOKernelState`).
T_CUR, HAVE_ZETA, HAVE_ETA, HAVE_W, TRACKING, PSI_M, R_PREV, T_R_PREV, T_PREV, V_PREV, A_PREV, Z0, Z1 = range(13)
N_STATE = 13


@jit
def uio_update(h: float, yv: np.ndarray, yd: np.ndarray, a: float, d: float, ad: float, dd: float, vx: float,
               Fb: np.ndarray, Gb: np.ndarray, dbal: np.ndarray, Q: np.ndarray, cchi: np.ndarray,
               zeta: np.ndarray, eta: np.ndarray, w_prev: np.ndarray, state: np.ndarray, par: np.ndarray,
               summed: bool, work: np.ndarray, piv: np.ndarray) -> None:
    """One UIO step of ``h`` [s] to ``y = yv``, ``y' = yd``, ``u = (a, d)``, ``u' = (ad, dd)`` at speed ``vx``.

    The first call (or the first after a prediction spell) seeds ``eta = zeta - Q y_chi``; later calls
    integrate the frozen affine ODE exactly (:func:`affine_step_pade`) scheduled at the step's midpoint
    (second order in ``h``; the end point would leave ``O(h v')``) and set ``zeta = eta + Q y_chi``.
    """
    nz = zeta.shape[0]
    no = Q.shape[1]
    nw = w_prev.shape[0]
    ychi = np.empty(no)
    w1 = np.empty(nw)
    _output(yv, yd, cchi, summed, ychi)
    for j in range(no):
        w1[j] = ychi[j]
    w1[no], w1[no + 1], w1[no + 2], w1[no + 3] = a, d, ad, dd
    vc = _clamp(vx, par[0], par[1])
    if state[HAVE_ETA] == 0.0 or state[HAVE_W] == 0.0 or state[TRACKING] == 0.0:
        if state[HAVE_ZETA] == 0.0:
            for j in range(nz):
                zeta[j] = 0.0
            for j in range(3):
                zeta[j] = yv[j]
                zeta[3 + j] = yd[j]
            zeta[6], zeta[7], zeta[8], zeta[9] = yv[0], state[Z0], yv[1], state[Z1]
            state[HAVE_ZETA] = 1.0
        for p in range(nz):
            s = 0.0
            for q in range(no):
                s += Q[p, q] * ychi[q]
            eta[p] = zeta[p] - s
        state[HAVE_ETA] = 1.0
        for j in range(nw):
            w_prev[j] = w1[j]
        state[HAVE_W] = 1.0
        state[V_PREV], state[A_PREV] = vc, a
        state[TRACKING] = 1.0
        return
    if h > 0.0:
        vm, am = 0.5 * (vc + state[V_PREV]), 0.5 * (a + state[A_PREV])
        cb = np.array([1.0, vm, 1.0 / vm, vm * vm, 1.0 / (vm * vm), am, am / (vm * vm)])
        affine_step_pade(eta, Fb, Gb, cb, w_prev, w1, h, dbal, work, piv)
    for j in range(nw):
        w_prev[j] = w1[j]
    state[V_PREV], state[A_PREV] = vc, a
    for p in range(nz):
        s = 0.0
        for q in range(no):
            s += Q[p, q] * ychi[q]
        zeta[p] = eta[p] + s


@jit
def generalized_run(t: np.ndarray, Y: np.ndarray, Fb: np.ndarray, Gb: np.ndarray, dbal: np.ndarray,
                    Q: np.ndarray, Mp: np.ndarray, Gp: np.ndarray, cchi: np.ndarray, dpsi: np.ndarray,
                    u: np.ndarray, fresh: np.ndarray, tl: np.ndarray, zeta: np.ndarray, eta: np.ndarray,
                    w_prev: np.ndarray, dst: np.ndarray, state: np.ndarray, par: np.ndarray, summed: bool,
                    levant: bool, out: np.ndarray) -> None:
    """The generalized UIO over samples ``t`` (n,) [s], ``Y`` (n, 4); writes ``(v_y, r, beta)`` to ``out`` (n, 3).

    ``step()`` calls it with one sample and ``run()`` with the whole log, so both execute the same
    compiled code on the same carried state: ``u``/``fresh``/``tl`` (4,) held inputs, whether each is
    new and its arrival time; ``zeta``/``eta`` (n_zeta,); ``w_prev`` (n_out + 4,) the previous step's
    input; ``dst`` (3, 6) the differentiators of ``r``, ``a``, ``delta``; ``state`` (``N_STATE``,) the
    scalars named ``T_CUR`` ... ``Z1`` above. ``par`` = ``(v_lo, v_hi, hold_s, T, g0, g1, delta2)``;
    ``dpsi`` (n_mu,) = ``D_bar[k0 + 1]`` (zero for the summed output).
    """
    n = t.shape[0]
    nz = zeta.shape[0]
    no = Q.shape[1]
    k0 = 6
    vlo, vhi, hold = par[0], par[1], par[2]
    dpar = par[3:6]
    N = nz + 2
    work = np.zeros((9, N, N))
    piv = np.zeros(N, dtype=np.int64)
    yv = np.empty(3)
    yd = np.empty(3)
    uu = np.empty(2)
    nxm = Mp.shape[1]
    xm = np.empty(nxm)
    for i in range(n):
        ts = t[i]
        # ScalarLoopObserver._tick: latch new samples (NaN = none), step since the last advance
        for j in range(4):
            v = Y[i, j]
            if v == v:
                u[j] = v
                fresh[j] = True
                tl[j] = ts
            else:
                fresh[j] = False
        h = ts - state[T_CUR]
        if h > 0.0:
            state[T_CUR] = ts
        else:
            h = 0.0
        vx, r, ax, delta = u[0], u[1], u[2], u[3]
        if vx == vx:
            a = ax if ax == ax else 0.0
            d = delta if delta == delta else 0.0
            tau = ts - state[T_PREV] if state[T_PREV] == state[T_PREV] else 0.0
            state[T_PREV] = ts
            if fresh[1]:
                # psi_m: the integrated gyro (trapezoid between gyro samples) while tracking
                if state[R_PREV] == state[R_PREV] and state[TRACKING] != 0.0:
                    state[PSI_M] += 0.5 * (ts - state[T_R_PREV]) * (state[R_PREV] + r)
                state[R_PREV], state[T_R_PREV] = r, ts
            rd = _derivative(r, tau, 0, dst, dpar, levant) if r == r and tau > 0.0 else dst[0, 0]
            ad = _derivative(a, tau, 1, dst, dpar, levant) if tau > 0.0 else 0.0
            dd = _derivative(d, tau, 2, dst, dpar, levant) if tau > 0.0 else 0.0
            live = r == r and ts - min(tl[0], tl[1]) <= hold
            if not live:
                # v_x or r stale: the model x' = A x + B_u u + B_mu mu_hat predicts with mu_hat held
                if state[HAVE_ZETA] != 0.0 and h > 0.0:
                    for j in range(nxm):
                        xm[j] = zeta[k0 + j]
                    vc = min(max(vx, vlo), vhi)
                    uu[0], uu[1] = a, d
                    affine_rk4(xm, Mp, Gp, uu, uu, vc, 1.0 / vc, h, max(1, math.ceil(h * 200.0 / SUBSTEP_RATE)))
                    for j in range(nxm):
                        zeta[k0 + j] = xm[j]
                state[TRACKING] = 0.0
            else:
                if state[TRACKING] == 0.0 and state[HAVE_ZETA] != 0.0:
                    # restart where the model's psi is (the psi output carries delta2 D mu, see uio_nguyen)
                    s = 0.0
                    for j in range(dpsi.shape[0]):
                        s += dpsi[j] * zeta[k0 + 4 + j]
                    state[PSI_M] = zeta[k0 + 2] + par[6] * s
                psi_m = state[PSI_M]
                if psi_m > math.pi or psi_m < -math.pi:
                    c = TWO_PI * round(psi_m / TWO_PI)
                    state[PSI_M] = psi_m - c
                    if state[HAVE_ETA] != 0.0 and state[HAVE_W] != 0.0 and state[HAVE_ZETA] != 0.0:
                        # psi has a zero column in J: shift every psi slot and the measured psi together
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
                yv[0], yv[1], yv[2] = vx, state[PSI_M], r
                yd[0], yd[1], yd[2] = a, r, rd
                uio_update(h, yv, yd, a, d, ad, dd, vx, Fb, Gb, dbal, Q, cchi, zeta, eta, w_prev, state, par,
                           summed, work, piv)
        # the estimate (v_y, r, beta); before the first seed the initial state
        if state[HAVE_ZETA] == 0.0:
            out[i, 0], out[i, 1], out[i, 2] = state[Z0], state[Z1], 0.0
        else:
            vy, rr = zeta[k0 + 1], zeta[k0 + 3]
            v = u[0] if u[0] == u[0] else zeta[k0]
            out[i, 0], out[i, 1] = vy, rr
            out[i, 2] = math.atan2(vy, v) if v > 0.0 else 0.0


def balanced_constants(Fs: np.ndarray, Gws: np.ndarray, v_mid: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Fb, Gb, d)``: the basis under the power-of-two balancing ``D = diag(d)`` of ``F(v_mid, 0)``."""
    from scipy.linalg import matrix_balance

    from roadtruth.observers.uio_generalized_design import basis

    _, (scale, _) = matrix_balance(np.tensordot(basis(v_mid, 0.0), Fs, axes=1), permute=False, separate=True)
    d = np.asarray(scale, dtype=float)
    Fb = np.ascontiguousarray(Fs / d[None, :, None] * d[None, None, :])
    Gb = np.ascontiguousarray(Gws / d[None, :, None])
    return Fb, Gb, d


@dataclass
class UIOKernelState:
    """The state :func:`generalized_run` carries between calls (arrays updated in place).

    ``u``/``tl`` (4,) held inputs and their arrival times [s], ``fresh`` (4,) bool; ``zeta``/``eta``
    (n_zeta,); ``w_prev`` (n_out + 4,); ``dst`` (3, 6) differentiator states ``(value, prev, z0, z1,
    initialized, f_prev)``; ``state`` (``N_STATE``,) scalars, flags as 0.0 / 1.0.
    """

    u: np.ndarray
    fresh: np.ndarray
    tl: np.ndarray
    zeta: np.ndarray
    eta: np.ndarray
    w_prev: np.ndarray
    dst: np.ndarray
    state: np.ndarray

    @classmethod
    def initial(cls, t0_s: float, n_zeta: int, n_out: int, z0: float, z1: float) -> UIOKernelState:
        """State after ``reset(t0_s)`` with initial ``(v_y, r) = (z0, z1)``: nothing latched, nothing seeded."""
        state = np.zeros(N_STATE)
        state[T_CUR] = t0_s
        state[R_PREV] = state[T_R_PREV] = state[T_PREV] = math.nan
        state[Z0], state[Z1] = z0, z1
        dst = np.zeros((3, 6))
        dst[:, 1] = math.nan
        return cls(np.full(4, math.nan), np.zeros(4, dtype=np.bool_), np.full(4, -math.inf), np.zeros(n_zeta),
                   np.zeros(n_zeta), np.zeros(n_out + 4), dst, state)
