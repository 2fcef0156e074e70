"""The compiled kernel of the neural adaptive observers of Nguyen (:mod:`roadtruth.observers.neural_adaptive_nguyen`).

:func:`nao_run` is the observers' whole per-sample update, teacher UIO included (the regularised
UIO's own compiled per-sample update, :mod:`roadtruth.observers.uio_nguyen_loop`): latching the
inputs, the integrated gyro and its re-centring, the Euler sub-steps of the state, the loss
gradient and forward sensitivity, Adam and the ensemble queue, on arrays carried between calls.
``NeuralAdaptiveNguyen.step()`` calls it with one sample and ``run()`` with the whole log, so both
execute the same compiled code on the same state and agree bit for bit
(``tests/test_observers_nao_compiled.py``). What makes it fast is the layout:

- one fused loop over the 1282 parameters updates the loss gradient (1.45)-(1.47) and the forward
  sensitivity ``S`` (1.48)-(1.50) together, with the 4x4 closed-loop matrix and ``B_mu`` held in
  scalars, so LLVM vectorises it across parameters;
- the backward pass of the network runs its inner loops over one contiguous index (row views),
  which LLVM vectorises;
- the newest queue snapshot of the ensemble (1.51) is the network being trained (a snapshot is
  taken right after each Adam step), so its output is the one the training step computes.

The matrix-vector products of the ensemble correction and the teacher's ``Q y`` go through
``np.dot`` (BLAS ``gemv``), whose fused multiply-adds a hand-written sum would not reproduce; they
are kept so that the estimates stay those of the earlier numpy implementation to the bit.

numba caches each kernel per source file: after editing this file (or the kernels it calls in
``observers/uio_nguyen_loop.py``) delete ``observers/__pycache__/*.nbi, *.nbc``.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit
from roadtruth.observers.uio_nguyen_loop import TWO_PI
from roadtruth.observers.uio_nguyen_loop import _advance as teacher_advance  # the teacher's own update

H = 32                  # hidden width of mu_theta (4-32-32-2)
O1 = 0                  # offsets of W1 (32x4), b1, W2 (32x32), b2, W3 (2x32), b3 in theta
O2 = O1 + H * 4
O3 = O2 + H
O4 = O3 + H * H
O5 = O4 + H
O6 = O5 + 2 * H
N_STATE = 9          # length of nao_run's ``state``
N_PAR = 10           # length of nao_run's ``par``


@jit
def adam_step(theta: np.ndarray, g: np.ndarray, m: np.ndarray, v: np.ndarray, t: int, lr: float, clip: float,
              scale: float) -> None:
    """Adam (beta = 0.9, 0.999) on ``g * scale`` clipped to norm ``clip``; ``t`` is the 1-based step."""
    n = theta.shape[0]
    nrm = 0.0
    for k in range(n):
        nrm += (g[k] * scale) ** 2
    nrm = math.sqrt(nrm)
    c = scale * (clip / nrm if nrm > clip else 1.0)
    b1, b2 = 0.9, 0.999
    for k in range(n):
        gk = g[k] * c
        m[k] = b1 * m[k] + (1 - b1) * gk
        v[k] = b2 * v[k] + (1 - b2) * gk * gk
        mh = m[k] / (1 - b1 ** t)
        vh = v[k] / (1 - b2 ** t)
        theta[k] -= lr * mh / (math.sqrt(vh) + 1e-8)


@jit
def forward(theta: np.ndarray, x: np.ndarray, delta: float, s: np.ndarray, h1: np.ndarray, h2: np.ndarray,
            mu: np.ndarray) -> None:
    """``mu = mu_theta(x, delta)`` (2,) [kN]; leaves the features ``s`` (4,) and the hidden layers
    ``h1``, ``h2`` (32,) for :func:`backward`. Same operations as ``mlp``'s forward pass."""
    s[0] = (x[0] - 15.0) * 0.1
    s[1] = x[1]
    s[2] = x[3] * 2.0
    s[3] = delta * 10.0
    for i in range(H):
        z = theta[O2 + i]
        for j in range(4):
            z += theta[O1 + i * 4 + j] * s[j]
        h1[i] = math.tanh(z)
    for i in range(H):
        z = theta[O4 + i]
        for j in range(H):
            z += theta[O3 + i * H + j] * h1[j]
        h2[i] = math.tanh(z)
    for o in range(2):
        z = theta[O6 + o]
        for j in range(H):
            z += theta[O5 + o * H + j] * h2[j]
        mu[o] = z


@jit
def scaled(out: np.ndarray, a: np.ndarray, c: float) -> None:
    """``out = c a`` elementwise (a loop over one index: LLVM vectorises it)."""
    for j in range(a.shape[0]):
        out[j] = c * a[j]


@jit
def axpy(acc: np.ndarray, w: np.ndarray, c: float) -> None:
    """``acc += w c`` elementwise (a loop over one index: LLVM vectorises it)."""
    for j in range(acc.shape[0]):
        acc[j] += w[j] * c


@jit
def backward(theta: np.ndarray, s: np.ndarray, h1: np.ndarray, h2: np.ndarray, Jth: np.ndarray, Jx: np.ndarray,
             g1: np.ndarray, g2: np.ndarray, acc: np.ndarray) -> None:
    """``Jth = d mu / d theta`` (2, 1282) and ``Jx = d mu / d x`` (2, 4) after :func:`forward`
    (``g1``, ``g2``, ``acc``: (32,) scratch). Same values as ``mlp(..., grads=True)``."""
    for o in range(2):
        q = 1 - o
        Jo = Jth[o]
        for j in range(H):
            Jo[O5 + o * H + j] = h2[j]
            Jo[O5 + q * H + j] = 0.0  # the other output's last-layer weights
        Jo[O6 + o] = 1.0
        Jo[O6 + q] = 0.0
        for i in range(H):
            g2[i] = theta[O5 + o * H + i] * (1.0 - h2[i] * h2[i])
            Jo[O4 + i] = g2[i]
        for i in range(H):
            scaled(Jo[O3 + i * H:O3 + i * H + H], h1, g2[i])
        for j in range(H):
            acc[j] = 0.0
        for i in range(H):
            # acc[j] = sum_i W2[i, j] g2[i] with i ascending for every j (mlp's order), row by row
            axpy(acc, theta[O3 + i * H:O3 + i * H + H], g2[i])
        s0, s1, s2, s3 = s[0], s[1], s[2], s[3]
        d0 = 0.0
        d1 = 0.0
        d2 = 0.0
        for j in range(H):
            gj = acc[j] * (1.0 - h1[j] * h1[j])
            g1[j] = gj
            Jo[O2 + j] = gj
            r = O1 + j * 4
            Jo[r] = gj * s0
            Jo[r + 1] = gj * s1
            Jo[r + 2] = gj * s2
            Jo[r + 3] = gj * s3
            d0 += theta[r] * gj
            d1 += theta[r + 1] * gj
            d2 += theta[r + 2] * gj
        Jx[o, 0] = d0 * 0.1
        Jx[o, 1] = d1
        Jx[o, 2] = 0.0
        Jx[o, 3] = d2 * 2.0


@jit
def sensitivity_and_gradient(S: np.ndarray, g: np.ndarray, Jth: np.ndarray, Acl: np.ndarray, Bmu: np.ndarray,
                             ex: np.ndarray, m0: float, m1: float, dt: float) -> None:
    """``g += dL/dmu Jth + ex S`` and ``S += dt (Acl S + Bmu Jth)`` in one pass over the parameters.

    ``S`` (4, n), ``g`` (n,), ``Jth`` (2, n), ``Acl`` (4, 4), ``Bmu`` (4, 2), ``ex`` (4,) = d L / d x
    including the network's x-dependence, ``(m0, m1)`` = d L / d mu. The gradient uses ``S`` before
    the update, as ``nao_step`` does; the constants sit in scalars so the loop has no loads that a
    store could alias and vectorises across parameters.
    """
    a00, a01, a02, a03 = Acl[0, 0], Acl[0, 1], Acl[0, 2], Acl[0, 3]
    a10, a11, a12, a13 = Acl[1, 0], Acl[1, 1], Acl[1, 2], Acl[1, 3]
    a20, a21, a22, a23 = Acl[2, 0], Acl[2, 1], Acl[2, 2], Acl[2, 3]
    a30, a31, a32, a33 = Acl[3, 0], Acl[3, 1], Acl[3, 2], Acl[3, 3]
    b00, b01, b10, b11 = Bmu[0, 0], Bmu[0, 1], Bmu[1, 0], Bmu[1, 1]
    b20, b21, b30, b31 = Bmu[2, 0], Bmu[2, 1], Bmu[3, 0], Bmu[3, 1]
    e0, e1, e2, e3 = ex[0], ex[1], ex[2], ex[3]
    S0, S1, S2, S3 = S[0], S[1], S[2], S[3]
    J0, J1 = Jth[0], Jth[1]
    for k in range(g.shape[0]):
        j0 = J0[k]
        j1 = J1[k]
        s0 = S0[k]
        s1 = S1[k]
        s2 = S2[k]
        s3 = S3[k]
        # each sum left to right, in nao_step's order
        g[k] += m0 * j0 + m1 * j1 + e0 * s0 + e1 * s1 + e2 * s2 + e3 * s3
        c0 = b00 * j0 + b01 * j1 + a00 * s0 + a01 * s1 + a02 * s2 + a03 * s3
        c1 = b10 * j0 + b11 * j1 + a10 * s0 + a11 * s1 + a12 * s2 + a13 * s3
        c2 = b20 * j0 + b21 * j1 + a20 * s0 + a21 * s1 + a22 * s2 + a23 * s3
        c3 = b30 * j0 + b31 * j1 + a30 * s0 + a31 * s1 + a32 * s2 + a33 * s3
        S0[k] = s0 + dt * c0
        S1[k] = s1 + dt * c1
        S2[k] = s2 + dt * c2
        S3[k] = s3 + dt * c3


@jit
def substep(x: np.ndarray, S: np.ndarray, g: np.ndarray, theta: np.ndarray, A: np.ndarray, Bu: np.ndarray,
            Bmu: np.ndarray, L: np.ndarray, y: np.ndarray, u: np.ndarray, x_t: np.ndarray, mu_t: np.ndarray,
            Ty: np.ndarray, Tu: np.ndarray, lam: float, dt: float, learn: bool, mu: np.ndarray, Jth: np.ndarray,
            Jx: np.ndarray, work: np.ndarray, Acl: np.ndarray, ex: np.ndarray) -> float:
    """``nao_step`` (one Euler step (1.63), gradient of (1.42), sensitivity) with the fast layout.

    Same arguments and results as ``nao_step``; ``work`` (6, 32) (features, hidden layers, backward
    terms), ``Acl`` (4, 4) and ``ex`` (4,) are scratch. Returns the loss at the step start.
    """
    s, h1, h2, g1, g2, acc = work[0], work[1], work[2], work[3], work[4], work[5]
    forward(theta, x, u[1], s, h1, h2, mu)
    ey0 = y[0] - x[0]
    ey1 = y[1] - x[2]
    ey2 = y[2] - x[3]
    loss = 0.0
    loss += Ty[0] * ey0 * ey0
    loss += Ty[1] * ey1 * ey1
    loss += Ty[2] * ey2 * ey2
    for i in range(4):
        d = x[i] - x_t[i]
        loss += Tu[i] * d * d
    for o in range(2):
        d = mu[o] - mu_t[o]
        loss += lam * d * d
    if learn:
        backward(theta, s, h1, h2, Jth, Jx, g1, g2, acc)
        for i in range(4):
            ex[i] = 2.0 * Tu[i] * (x[i] - x_t[i])
        ex[0] -= 2.0 * Ty[0] * ey0
        ex[2] -= 2.0 * Ty[1] * ey1
        ex[3] -= 2.0 * Ty[2] * ey2
        m0 = 2.0 * lam * (mu[0] - mu_t[0])
        m1 = 2.0 * lam * (mu[1] - mu_t[1])
        for i in range(4):
            ex[i] = ex[i] + m0 * Jx[0, i] + m1 * Jx[1, i]
        for i in range(4):
            for j in range(4):
                Acl[i, j] = A[i, j] + (Bmu[i, 0] * Jx[0, j] + Bmu[i, 1] * Jx[1, j])
            Acl[i, 0] -= L[i, 0]
            Acl[i, 2] -= L[i, 1]
            Acl[i, 3] -= L[i, 2]
        sensitivity_and_gradient(S, g, Jth, Acl, Bmu, ex, m0, m1, dt)
    dx = ex  # free again: the state derivative of all four rows before x changes
    for i in range(4):
        d = Bu[i, 0] * u[0] + Bu[i, 1] * u[1] + Bmu[i, 0] * mu[0] + Bmu[i, 1] * mu[1]
        for j in range(4):
            d += A[i, j] * x[j]
        d += L[i, 0] * ey0 + L[i, 1] * ey1 + L[i, 2] * ey2
        dx[i] = d
    for i in range(4):
        x[i] += dt * dx[i]
    return loss


@jit
def nao_run(t: np.ndarray, Y: np.ndarray, latch: np.ndarray, u: np.ndarray, fresh: np.ndarray, tl: np.ndarray,
            x: np.ndarray, theta: np.ndarray, S: np.ndarray, g: np.ndarray, m: np.ndarray, v: np.ndarray,
            mu: np.ndarray, queue: np.ndarray, state: np.ndarray, model: np.ndarray, Bu: np.ndarray,
            Bmu: np.ndarray, L: np.ndarray, Ty: np.ndarray, Tu: np.ndarray, weights: np.ndarray, par: np.ndarray,
            eta: np.ndarray, zeta: np.ndarray, w_prev: np.ndarray, u_prev: np.ndarray, ts_state: np.ndarray,
            Fs: np.ndarray, Gs: np.ndarray, Qz: np.ndarray, Ms: np.ndarray, Gp: np.ndarray, bounds: np.ndarray,
            tpar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The observer over ``t`` (n,) [s], ``Y`` (n, 4): the (n, 3) estimates (``vy, r, beta``) and the loss trace.

    In place: ``latch`` = ``(t_cur,)``, ``u``/``fresh``/``tl`` (4,) (the latch, shared with the
    teacher: both see the same samples), the network and learning arrays, ``queue`` (p, n_theta)
    ring of snapshots, ``state`` = ``(psi_m, r_prev, t_r_prev, started, adam_t, k, q_count,
    q_head, needs_gain)`` and the teacher's own state arrays (``eta`` ... ``ts_state``, advanced by
    the UIO's compiled per-sample update :func:`roadtruth.observers.uio_nguyen_loop._advance`). ``model`` (3, 4, 4) = ``A0, A1, A2``;
    ``weights`` (p,) = ``exp(-age)``; ``par`` = ``(dt_s, accumulate, learning_rate, clip,
    queue_size, teacher_weight, v_lo, v_hi, hold_s, has_gain)``.

    Without a usable gain (``has_gain = 0``, a failed design) the kernel stops at the first step
    that needs it, sets ``needs_gain = 1`` and returns; the rows from there on are not written.
    """
    n = t.shape[0]
    out = np.empty((n, 3))
    dt_s, K, lr, clip = par[0], int(par[1]), par[2], par[3]
    p, lam, vlo, vhi, hold = int(par[4]), par[5], par[6], par[7], par[8]
    has_gain = par[9] != 0.0
    A0, A1, A2 = model[0], model[1], model[2]
    Lzero = np.zeros((4, 3))
    Jth = np.zeros((2, theta.shape[0]))
    Jx = np.zeros((2, 4))
    work = np.zeros((6, H))
    Acl = np.empty((4, 4))
    ex = np.empty(4)
    x_start = np.empty(4)
    A = np.empty((4, 4))
    yv = np.empty(3)
    uu = np.empty(2)
    mu_e = np.empty(2)
    d_mu = np.empty(2)
    corr = np.empty(4)
    dtBmu = np.empty((4, 2))
    tu0, tu1, tym, tw1, tq = np.empty(2), np.empty(2), np.empty(3), np.empty(5), np.empty(6)
    mu_q = np.empty(2)
    feat = np.empty((3, H))
    loss_trace = np.empty(max(16, 2 * n))
    n_loss = 0
    cap = queue.shape[0]
    psi_m, r_prev, t_r_prev = state[0], state[1], state[2]
    started = state[3] != 0.0
    adam_t, k_acc, q_count, q_head = int(state[4]), int(state[5]), int(state[6]), int(state[7])
    t_cur = latch[0]
    for row in range(n):
        ts = t[row]
        for j in range(4):
            val = Y[row, j]
            if val == val:
                u[j] = val
                fresh[j] = True
                tl[j] = ts
            else:
                fresh[j] = False
        h = ts - t_cur
        if h > 0.0:
            t_cur = ts
        else:
            h = 0.0
        teacher_advance(ts, h, u, fresh, tl, eta, zeta, w_prev, u_prev, ts_state, Fs, Gs, Qz, Ms, Gp, bounds, tpar,
                        tu0, tu1, tym, tw1, tq)
        vx, r, ax, delta = u[0], u[1], u[2], u[3]
        go = True
        if not started:
            if vx != vx:
                go = False
            else:
                x[0] = vx
                started = True
        if go:
            if fresh[1]:
                if r_prev == r_prev:
                    psi_m += 0.5 * (ts - t_r_prev) * (r_prev + r)
                r_prev, t_r_prev = r, ts
            if psi_m > math.pi or psi_m < -math.pi:
                c = TWO_PI * np.rint(psi_m / TWO_PI)
                psi_m -= c
                x[2] -= c
        if go and h > 0.0:
            live = r == r and vx == vx and ts - min(tl[0], tl[1]) <= hold
            if live and not has_gain:
                state[8] = 1.0
                break
            vv = vx if vx == vx else x[0]
            vv = vlo if vlo > vv else vv
            vv = vhi if vhi < vv else vv
            for i in range(4):
                for j in range(4):
                    A[i, j] = A0[i, j] + vv * A1[i, j] + A2[i, j] / vv
            Lk = L if live else Lzero
            yv[0] = vx if vx == vx else x[0]
            yv[1] = psi_m
            yv[2] = r if r == r else x[3]
            uu[0] = ax if ax == ax else 0.0
            uu[1] = delta if delta == delta else 0.0
            nsub = max(1, math.ceil(h / dt_s - 1e-9))
            dt = h / nsub
            x_t = zeta[:4]
            mu_t = zeta[4:]
            for _ in range(nsub):
                ensemble = p > 0 and q_count > 0
                x_start[:] = x
                loss = substep(x, S, g, theta, A, Bu, Bmu, Lk, yv, uu, x_t, mu_t, Ty, Tu, lam, dt, live, mu, Jth, Jx,
                               work, Acl, ex)
                if ensemble:
                    # the loss, gradient and S used the newest network (snapshot q_head - 1, equal to theta)
                    # and so did the state update; move x to the recency-weighted mean of the queue,
                    # evaluated at the step start, as the Python path does
                    mu_e[0] = 0.0
                    mu_e[1] = 0.0
                    wsum = 0.0
                    for age in range(q_count):
                        if age == 0:
                            mu_q[0], mu_q[1] = mu[0], mu[1]
                        else:
                            forward(queue[(q_head - 1 - age) % cap], x_start, uu[1], feat[0], feat[1], feat[2], mu_q)
                        w = weights[age]
                        mu_e[0] += w * mu_q[0]
                        mu_e[1] += w * mu_q[1]
                        wsum += w
                    mu_e[0] = mu_e[0] / wsum
                    mu_e[1] = mu_e[1] / wsum
                    d_mu[0] = mu_e[0] - mu[0]
                    d_mu[1] = mu_e[1] - mu[1]
                    for i in range(4):
                        dtBmu[i, 0] = dt * Bmu[i, 0]
                        dtBmu[i, 1] = dt * Bmu[i, 1]
                    np.dot(dtBmu, d_mu, corr)
                    for i in range(4):
                        x[i] += corr[i]
                    mu[0], mu[1] = mu_e[0], mu_e[1]
                if not live:
                    continue
                if n_loss == loss_trace.shape[0]:
                    grown = np.empty(2 * n_loss)
                    grown[:n_loss] = loss_trace
                    loss_trace = grown
                loss_trace[n_loss] = loss
                n_loss += 1
                k_acc += 1
                if k_acc >= K:
                    adam_t += 1
                    adam_step(theta, g, m, v, adam_t, lr, clip, 1.0 / k_acc)
                    g[:] = 0.0
                    k_acc = 0
                    if K > 1:
                        S[:] = 0.0  # truncated forward sensitivity per window
                    if p > 0:
                        queue[q_head] = theta
                        q_head = (q_head + 1) % cap
                        q_count = min(q_count + 1, cap)
        vr = vx if vx == vx else x[0]
        out[row, 0] = x[1]
        out[row, 1] = x[3]
        out[row, 2] = math.atan2(x[1], vr) if vr > 0.0 else 0.0
    latch[0] = t_cur
    state[0], state[1], state[2] = psi_m, r_prev, t_r_prev
    state[3] = 1.0 if started else 0.0
    state[4], state[5], state[6], state[7] = adam_t, k_acc, q_count, q_head
    return out, loss_trace[:n_loss].copy()
