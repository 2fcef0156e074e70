"""The compiled kernel of the polytopic LPV slip-angle observers (Y. Wang 2014, ch. 3), shared by step() and run().

:func:`lpv_run` is the whole per-sample update of every variant of :mod:`roadtruth.observers.lpv_wang`
and :mod:`roadtruth.observers.lpv_wang_robust`: latching the inputs (zero-order hold, arrival times),
the step ``h = t - t_cur``, the change of variable ``z1 = alpha_f - delta`` at the first steering
sample, the scheduling ``theta_m`` (scheduling error, clamped into the design domain), the exact ZOH
step of the observer and the derived ``v_y`` / ``beta``. ``LPVWang.step()`` calls it with one sample
and ``LPVWang.run()`` with the whole log, so both execute the same compiled code on the same state and
agree bit for bit (``tests/test_observers_lpv.py``). One kernel for the ten variants: the structure
is a parameter, so a fresh install compiles it once.

Two structures (``par[0]``), each with the arithmetic of the Python loop it replaces:

* ``0`` Luenberger (3.22)-(3.23): gains ``(L0, L1, L2)``, 6 floats, ``L(theta) = L0 + theta1 L1 + theta2 L2``;
* ``1`` unstructured (3.47)-(3.48): ``A_o`` (3 x 4), ``B_ou`` (3 x 6), ``B_oy`` (3 x 2), 36 floats,
  each affine in ``theta_m``.

Carried state: ``u``/``tl`` (4,) held inputs ``(delta, r, v_x, a_x)`` and their arrival times [s];
``z`` (2,) ``(alpha_f, alpha_r)`` until the first ``delta``, then ``(alpha_f - delta, alpha_r)``;
``s`` = ``(t_cur, have_delta)``. ``par`` (:data:`N_PAR` floats) = ``(structure, A1 (4), l_f, l_r,
v_lo, v_hi, a_lo, a_hi, hold_s, v_min_output, eps1, eps2, gains (36, zero-padded))``.

numba caches each kernel per source file: after editing this file (or ``observers/bicycle.py``)
delete ``observers/__pycache__/lpv_wang_loop*.nbi, *.nbc`` and ``bicycle*.nbi, *.nbc``.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit
from roadtruth.observers.bicycle import expm2_zoh

LUENBERGER = 0.0
UNSTRUCTURED = 1.0
GAINS_AT = 15          # index of the first gain in ``par``
N_GAINS = 36           # the unstructured form's 36 coefficients (Luenberger uses the first 6)
N_PAR = GAINS_AT + N_GAINS
_expm2 = jit(expm2_zoh)


def parameters(structure: float, A1: tuple[float, ...], lf: float, lr: float, v_range: tuple[float, float],
               a_range: tuple[float, float], hold_s: float, v_min: float, eps: tuple[float, float]) -> np.ndarray:
    """The kernel's parameter vector with zero gains (filled in by :func:`set_gains` when first needed).

    ``A1`` row-major ``Bf0 diag(C_f, C_r)`` [rad/m]; ``v_range`` [m/s], ``a_range`` [m/s^2] the design
    domain; ``hold_s`` [s]; ``v_min`` floor of ``v_x`` in the pseudo-output [m/s]; ``eps`` the
    multiplicative scheduling errors.
    """
    p = np.zeros(N_PAR)
    p[:GAINS_AT] = (structure, *A1, lf, lr, *v_range, *a_range, hold_s, v_min, *eps)
    return p


def set_gains(par: np.ndarray, gains: tuple[float, ...]) -> None:
    """Write the flattened gains (6 Luenberger or 36 unstructured floats) into ``par``, in place."""
    want = 6 if par[0] == LUENBERGER else N_GAINS
    if len(gains) != want:
        raise ValueError(f"expected {want} gains, got {len(gains)}")
    par[GAINS_AT:GAINS_AT + want] = gains


@jit
def _integrate(z: np.ndarray, h: float, fresh: bool, delta: float, r: float, vx: float, ax: float,
               p: np.ndarray) -> None:
    """One exact ZOH step of ``z`` over ``h`` [s] with held inputs, in place; ``fresh``: correct with
    the pseudo-output (else predict with the plant model at ``theta_m``)."""
    A0, A1, A2, A3 = p[1], p[2], p[3], p[4]
    lf, lr, vlo, vhi, alo, ahi, vmin, eps1, eps2 = p[5], p[6], p[7], p[8], p[9], p[10], p[12], p[13], p[14]
    g = p[GAINS_AT:]
    # scheduling (v_m, a_m): the measured values times (1 + eps), clamped into the design domain
    vm = vx * (1.0 + eps1)
    am = ax * (1.0 + eps2)
    vc = vlo if vm < vlo else (vhi if vm > vhi else vm)
    ac = alo if am < alo else (ahi if am > ahi else am)
    m1 = 1.0 / vc
    m2 = ac * m1
    vo = vx if vx > vmin else vmin   # the pseudo-output uses the measured v_x
    if p[0] == LUENBERGER:
        a11, a12, a21, a22 = m1 * A0 - m2, m1 * A1, m1 * A2, m1 * A3 - m2
        g1 = m1 * A0 * delta + r
        g2 = m1 * A2 * delta + r
        if fresh:
            yp = -(lf + lr) * r / vo  # y - delta
            la = g[0] + m1 * g[2] + m2 * g[4]
            lb = g[1] + m1 * g[3] + m2 * g[5]
            a11 -= la
            a12 += la
            a21 -= lb
            a22 += lb
            g1 += la * yp
            g2 += lb * yp
    else:
        if fresh:
            # A_o = Ao0 + m1 Ao1 + m2 Ao2 (g[0:12]); B_ou (g[12:30]); B_oy (g[30:36])
            a11 = g[0] + m1 * g[4] + m2 * g[8]
            a12 = g[1] + m1 * g[5] + m2 * g[9]
            a21 = g[2] + m1 * g[6] + m2 * g[10]
            a22 = g[3] + m1 * g[7] + m2 * g[11]
            bd1 = g[12] + m1 * g[18] + m2 * g[24]
            br1 = g[14] + m1 * g[20] + m2 * g[26]
            bd2 = g[15] + m1 * g[21] + m2 * g[27]
            br2 = g[17] + m1 * g[23] + m2 * g[29]
            by1 = g[30] + m1 * g[32] + m2 * g[34]
            by2 = g[31] + m1 * g[33] + m2 * g[35]
            yv = delta - (lf + lr) * r / vo
        else:  # no measurement: the plant model at theta_m
            a11, a12, a21, a22 = m1 * A0 - m2, m1 * A1, m1 * A2, m1 * A3 - m2
            bd1, br1, bd2, br2, by1, by2, yv = m2, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0
        # x_hat1 = z1 + delta: the delta' terms cancel (B_ou's steering-rate column is (1, 0))
        g1 = (a11 + bd1) * delta + br1 * r + by1 * yv
        g2 = (a21 + bd2) * delta + br2 * r + by2 * yv
    E, G = _expm2(a11, a12, a21, a22, h)
    z0, z1 = z[0], z[1]
    z[0] = E[0] * z0 + E[1] * z1 + G[0] * g1 + G[1] * g2
    z[1] = E[2] * z0 + E[3] * z1 + G[2] * g1 + G[3] * g2


@jit
def derive_outputs(u: np.ndarray, z: np.ndarray, have_delta: bool, p: np.ndarray, x: np.ndarray) -> None:
    """``(alpha_f, alpha_r, beta, v_y)`` into ``x``: ``v_y`` the mean of the front and rear slip
    definitions solved for it, ``beta = atan2(v_y, v_x)``; 0 for both until ``delta, r, v_x`` exist."""
    delta, r, vx = u[0], u[1], u[2]
    lf, lr, vmin = p[5], p[6], p[12]
    af = z[0] + delta if have_delta else z[0]
    ar = z[1]
    x[0], x[1] = af, ar
    if not have_delta or r != r or vx != vx:
        x[2], x[3] = 0.0, 0.0
        return
    v = vx if vx > vmin else vmin
    vy = 0.5 * (v * math.tan(delta - af) - lf * r - v * math.tan(ar) + lr * r)
    x[2], x[3] = math.atan2(vy, v), vy


@jit
def lpv_run(t: np.ndarray, Y: np.ndarray, u: np.ndarray, tl: np.ndarray, z: np.ndarray, s: np.ndarray,
            p: np.ndarray, x: np.ndarray) -> None:
    """The LPV observer over ``t`` (n,) [s], ``Y`` (n, 4) ``(delta, r, v_x, a_x)`` (NaN = no new sample);
    writes ``(alpha_f, alpha_r, beta, v_y)`` to ``x`` (n, 4) (state arrays: module docstring)."""
    hold = p[11]
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
                z[0] -= delta
                s[1] = 1.0
            if h > 0.0 and r == r and vx == vx and ax == ax:
                # correct only while delta, r, v_x are younger than hold_s
                _integrate(z, h, ts - min(tl[0], tl[1], tl[2]) <= hold, delta, r, vx, ax, p)
        derive_outputs(u, z, s[1] != 0.0, p, x[i])
