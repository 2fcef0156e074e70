"""The compiled kernel of the nonlinear slip-angle observers (:mod:`roadtruth.observers.nonlinear_wang`), shared by step() and run().

:func:`nonlinear_run` is the observers' whole per-sample update (latching the inputs, the change of
variable ``z1 = alpha_f - delta`` at the first steering sample, the freshness test of the correction,
the sub-stepped RK4 step of (5.21)/(5.38) on the brush tire (5.63), the derived ``v_y`` / ``beta``)
on arrays carried between calls. ``NonlinearWang.step()`` calls it with one sample and
``NonlinearWang.run()`` with the whole log, so both execute the same compiled code on the same state
and agree bit for bit (``tests/test_observers_nonlinear_wang.py``). All five variants (printed,
Luenberger, Arcak, L2, scheduled) run this one kernel: they differ only in the gains and the basis
of ``L2`` held in the parameter vector.

Carried state: ``u``/``tl`` (4,) held inputs ``(delta, r, v_x, a_x)`` and their arrival times [s];
``z`` (2,) ``(alpha_f, alpha_r)`` until the first ``delta``, then ``(alpha_f - delta, alpha_r)``
[rad]; ``s`` = ``(t_cur [s], have_delta)``. ``p``: the :data:`N_PAR` floats indexed by ``P_*``
(tire data, model terms, design domain, gains; the gains are zero until the design is needed).

numba caches each kernel per source file: after editing this file delete
``observers/__pycache__/nonlinear_wang_loop*.nbi, *.nbc``.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit

#: Index layout of the parameter array: axle stiffness c1 [N/rad] and theta_t [1/rad] of (5.63),
#: slopes k1 [N/rad], A1 = Bf0 diag(c1) and Bf0 (row-major), l_f + l_r [m], the design domain of
#: v_x [m/s] and a_x [m/s^2], the v_x floor of the pseudo-output [m/s], L1 and L2 (6 each: const_f,
#: const_r, b1_f, b1_r, b2_f, b2_r), the L2 basis flag (1 = (v_x, a_x), 0 = lambda), l_f, l_r [m]
#: and the freshness limit hold_s [s] of the correction.
(P_C1F, P_C1R, P_THF, P_THR, P_K1F, P_K1R, P_A11, P_A12, P_A21, P_A22, P_B11, P_B12, P_B21, P_B22,
 P_ELL, P_VLO, P_VHI, P_ALO, P_AHI, P_VMIN, P_L1, P_L2, P_BASIS2, P_LF, P_LR, P_HOLD, N_PAR) = (
    0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 26, 32, 33, 34, 35, 36)
#: Largest RK4 sub-steps per step (bounds the cost at very low speed).
MAX_SUBSTEPS = 64


@jit
def brush_nonlinear_part(alpha: float, c1: float, theta: float) -> float:
    """``F_y(alpha) - c1 alpha`` [N] of (5.63) with saturation beyond ``1/theta``."""
    s = theta * abs(alpha)
    if s > 1.0:
        s = 1.0
    mu_fz = c1 / (3.0 * theta)
    fy = mu_fz * (3.0 * s - 3.0 * s * s + s * s * s)
    return (fy if alpha >= 0.0 else -fy) - c1 * alpha


@jit
def _rhs(z1: float, ar: float, p: np.ndarray, delta: float, r: float, th1: float, th2: float,
         ytil_off: float, l1a: float, l1b: float, l2a: float, l2b: float, correct: bool) -> tuple[float, float]:
    af = z1 + delta
    if correct:
        yt = ytil_off - (z1 - ar)  # y - C x, with y - delta = ytil_off
    else:
        yt = 0.0
    fa = brush_nonlinear_part(af + l2a * yt, p[P_C1F], p[P_THF])
    fb = brush_nonlinear_part(ar + l2b * yt, p[P_C1R], p[P_THR])
    # A x + B_f f + (L1 - B_f K1 L2) y~ + Phi (without delta', absorbed by z1)
    lin_a = th1 * (p[P_A11] * af + p[P_A12] * ar) - th2 * af
    lin_b = th1 * (p[P_A21] * af + p[P_A22] * ar) - th2 * ar
    nf_a = th1 * (p[P_B11] * fa + p[P_B12] * fb)
    nf_b = th1 * (p[P_B21] * fa + p[P_B22] * fb)
    kl_a = p[P_K1F] * l2a * yt
    kl_b = p[P_K1R] * l2b * yt
    bk_a = th1 * (p[P_B11] * kl_a + p[P_B12] * kl_b)
    bk_b = th1 * (p[P_B21] * kl_a + p[P_B22] * kl_b)
    da = lin_a + nf_a + (l1a * yt - bk_a) + th2 * delta + r
    db = lin_b + nf_b + (l1b * yt - bk_b) + r
    return da, db


@jit
def observer_step(z: np.ndarray, p: np.ndarray, delta: float, r: float, vx: float, ax: float, h: float,
                  correct: bool) -> None:
    """Advance ``z = (alpha_f - delta, alpha_r)`` by ``h`` [s] with held inputs (RK4, sub-stepped)."""
    vc = min(max(vx, p[P_VLO]), p[P_VHI])
    ac = min(max(ax, p[P_ALO]), p[P_AHI])
    th1 = 1.0 / vc
    th2 = ac * th1
    l1a = p[P_L1] + th1 * p[P_L1 + 2] + th2 * p[P_L1 + 4]
    l1b = p[P_L1 + 1] + th1 * p[P_L1 + 3] + th2 * p[P_L1 + 5]
    if p[P_BASIS2] > 0.5:      # L2 affine in (v_x, a_x)
        b1, b2 = vc, ac
    else:                      # L2 affine in lambda
        b1, b2 = th1, th2
    l2a = p[P_L2] + b1 * p[P_L2 + 2] + b2 * p[P_L2 + 4]
    l2b = p[P_L2 + 1] + b1 * p[P_L2 + 3] + b2 * p[P_L2 + 5]
    vm = vx if vx > p[P_VMIN] else p[P_VMIN]
    yoff = -p[P_ELL] * r / vm
    # stiffness bound of the right-hand side [1/s], for the sub-step count (h * rate <= 0.5)
    c1m = max(p[P_C1F], p[P_C1R])
    bnorm = max(abs(p[P_B11]) + abs(p[P_B12]), abs(p[P_B21]) + abs(p[P_B22]))
    rate = (th1 * c1m * bnorm * (1.0 + 2.0 * (abs(l2a) + abs(l2b))) + abs(th2)
            + (2.0 * (abs(l1a) + abs(l1b)) if correct else 0.0))
    n = int(math.ceil(h * rate / 0.5))
    n = 1 if n < 1 else (MAX_SUBSTEPS if n > MAX_SUBSTEPS else n)
    dt = h / n
    a, b = z[0], z[1]
    for _ in range(n):
        k1a, k1b = _rhs(a, b, p, delta, r, th1, th2, yoff, l1a, l1b, l2a, l2b, correct)
        k2a, k2b = _rhs(a + 0.5 * dt * k1a, b + 0.5 * dt * k1b, p, delta, r, th1, th2, yoff, l1a, l1b, l2a, l2b,
                        correct)
        k3a, k3b = _rhs(a + 0.5 * dt * k2a, b + 0.5 * dt * k2b, p, delta, r, th1, th2, yoff, l1a, l1b, l2a, l2b,
                        correct)
        k4a, k4b = _rhs(a + dt * k3a, b + dt * k3b, p, delta, r, th1, th2, yoff, l1a, l1b, l2a, l2b, correct)
        a += dt * (k1a + 2.0 * k2a + 2.0 * k3a + k4a) / 6.0
        b += dt * (k1b + 2.0 * k2b + 2.0 * k3b + k4b) / 6.0
    z[0] = a
    z[1] = b


@jit
def nonlinear_run(t: np.ndarray, Y: np.ndarray, u: np.ndarray, tl: np.ndarray, z: np.ndarray, s: np.ndarray,
                  p: np.ndarray, x: np.ndarray) -> None:
    """The nonlinear observer over ``t`` (n,) [s], ``Y`` (n, 4) ``(delta, r, v_x, a_x)``, NaN = no new
    sample; writes the estimates to ``x`` (n, 4) in ``NonlinearWang.states`` order (state arrays:
    module docstring). A repeated time stamp latches its samples without a step."""
    hold = p[P_HOLD]
    for i in range(t.shape[0]):
        ts = t[i]
        for j in range(4):
            v = Y[i, j]
            if v == v:
                u[j] = v
                tl[j] = ts
        h = ts - s[0]
        if h > 0.0:
            s[0] = ts
        else:
            h = 0.0
        delta, r, vx, ax = u[0], u[1], u[2], u[3]
        if delta == delta:
            if s[1] == 0.0:
                z[0] -= delta   # from here on z[0] = alpha_f - delta (no steering rate needed)
                s[1] = 1.0
            if h > 0.0 and r == r and vx == vx and ax == ax:
                # correct only while delta, r and v_x are fresh; otherwise predict on the model
                correct = ts - min(tl[0], tl[1], tl[2]) <= hold
                observer_step(z, p, delta, r, vx, ax, h, correct)
        # estimates; v_y is the mean of the two CONTRACT slip definitions, v_x tan(delta - alpha_f) - l_f r
        # and l_r r - v_x tan(alpha_r) (v_x floored); 0 without delta, r or v_x
        af = z[0] + delta if s[1] != 0.0 else z[0]
        ar = z[1]
        x[i, 0] = af
        x[i, 1] = ar
        if s[1] == 0.0 or r != r or vx != vx:
            x[i, 2] = 0.0
            x[i, 3] = 0.0
        else:
            vm = vx if vx > p[P_VMIN] else p[P_VMIN]
            vy = 0.5 * (vm * math.tan(delta - af) - p[P_LF] * r - vm * math.tan(ar) + p[P_LR] * r)
            x[i, 2] = math.atan2(vy, vm)
            x[i, 3] = vy
