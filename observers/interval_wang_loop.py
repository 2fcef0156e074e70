"""The compiled kernel of the LPV interval observer (:mod:`roadtruth.observers.interval_wang`), shared by step() and run().

:func:`interval_run` is the observer's whole per-sample update (latching the inputs, the change of
variable at the first steering sample, the guard rails, the inflated exact-ZOH step of both copies,
the derived ``v_y`` / ``beta`` bounds) on arrays carried between calls. ``IntervalWang.step()`` calls
it with one sample and ``IntervalWang.run()`` with the whole log, so both execute the same compiled
code on the same state and agree bit for bit (``tests/test_observers_interval_wang.py``).

Carried state: ``u``/``tl`` (4,) held inputs ``(delta, r, v_x, a_x)`` and their arrival times [s];
``z`` (4,) ``(upper_1, upper_2, lower_1, lower_2)`` (component 1 = ``alpha_f`` until the first
``delta``, then ``alpha_f - delta``); ``s`` = ``(t_cur, have_delta)``.
``par`` = ``(l0a, l0b, l1a, l1b, l2a, l2b, A0..A3, B0..B3, lip0..lip3, vm0, vm1, vp0, vp1, v_lo, v_hi,
a_lo, a_hi, alpha_bound, hold_s, v_min_output, nu_y, nu_r, l_f, l_r)`` (:data:`N_PAR` floats; the
gains are zero until the design is needed).

numba caches each kernel per source file: after editing this file (or ``observers/bicycle.py``)
delete ``observers/__pycache__/interval_wang_loop*.nbi, *.nbc`` and ``bicycle*.nbi, *.nbc``.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit
from roadtruth.observers.bicycle import expm2_zoh

N_PAR = 33
_expm2 = jit(expm2_zoh)


@jit
def _integrate(z: np.ndarray, h: float, delta: float, r: float, vx: float, ax: float, p: np.ndarray) -> None:
    """``IntervalWang`` step of both copies over ``h`` [s] (exact ZOH of ``A_L``, inflated ``w``), in place."""
    l0a, l0b, l1a, l1b, l2a, l2b = p[0], p[1], p[2], p[3], p[4], p[5]
    A0, A1, A2, A3 = p[6], p[7], p[8], p[9]
    B0, B1, B2, B3 = p[10], p[11], p[12], p[13]
    vm0, vm1, vp0, vp1 = p[18], p[19], p[20], p[21]
    alo, ahi = p[24], p[25]
    vmin, ny, nr, lf, lr = p[28], p[29], p[30], p[31], p[32]
    ac = alo if ax < alo else (ahi if ax > ahi else ax)
    e1 = 1.0 / vx
    e2 = ac * e1
    la = l0a + e1 * l1a + e2 * l2a
    lb = l0b + e1 * l1b + e2 * l2b
    # A_L(eta, xi0) = A(eta, xi0) - L(eta) [1, -1]
    a11, a12 = e1 * A0 - e2 - la, e1 * A1 + la
    a21, a22 = e1 * A2 - lb, e1 * A3 - e2 + lb
    yp = -(lf + lr) * r / (vx if vx > vmin else vmin)  # y - delta
    g1 = e1 * A0 * delta + r + la * yp
    g2 = e1 * A2 * delta + r + lb * yp
    k11, k12, k21, k22 = e1 * p[14], e1 * p[15], e1 * p[16], e1 * p[17]
    # bounded input errors enter the error dynamics as (dr) (1, 1) + L(eta) d(y - delta)
    n1 = nr + abs(la) * ny
    n2 = nr + abs(lb) * ny
    n = 1
    while True:
        hs = h / n
        E, G = _expm2(a11, a12, a21, a22, hs)
        q11, q12, q21, q22 = abs(G[0]), abs(G[1]), abs(G[2]), abs(G[3])
        # M = |G| Lambda; (I - M)^-1 >= 0 needs m11 < 1, m22 < 1 and det > 0 (else halve the step)
        m11, m12 = q11 * k11 + q12 * k21, q11 * k12 + q12 * k22
        m21, m22 = q21 * k11 + q22 * k21, q21 * k12 + q22 * k22
        det = (1.0 - m11) * (1.0 - m22) - m12 * m21
        if (m11 < 1.0 and m22 < 1.0 and det > 0.0) or n >= 1024:
            break
        n *= 2
    c11, c12, c21, c22 = (1.0 - m22) / det, m12 / det, m21 / det, (1.0 - m11) / det
    for _ in range(n):
        zn0 = zn1 = zn2 = zn3 = 0.0
        for up in (True, False):
            s1, s2 = (z[0], z[1]) if up else (z[2], z[3])
            af, ar = s1 + delta, s2
            # Lemma 12 with T = eta1 Bf0 diag(alpha): row sums of max / min over v in [v-, v+]
            t11, t12, t21, t22 = e1 * B0 * af, e1 * B1 * ar, e1 * B2 * af, e1 * B3 * ar
            if up:
                w1 = (t11 * vp0 if t11 >= 0.0 else t11 * vm0) + (t12 * vp1 if t12 >= 0.0 else t12 * vm1)
                w2 = (t21 * vp0 if t21 >= 0.0 else t21 * vm0) + (t22 * vp1 if t22 >= 0.0 else t22 * vm1)
            else:
                w1 = (t11 * vm0 if t11 >= 0.0 else t11 * vp0) + (t12 * vm1 if t12 >= 0.0 else t12 * vp1)
                w2 = (t21 * vm0 if t21 >= 0.0 else t21 * vp0) + (t22 * vm1 if t22 >= 0.0 else t22 * vp1)
            f1 = abs(a11 * s1 + a12 * s2 + g1 + w1) + n1
            f2 = abs(a21 * s1 + a22 * s2 + g2 + w2) + n2
            p1, p2 = q11 * f1 + q12 * f2, q21 * f1 + q22 * f2
            d1, d2 = c11 * p1 + c12 * p2, c21 * p1 + c22 * p2   # drift bound D over the step
            i1, i2 = k11 * d1 + k12 * d2, k21 * d1 + k22 * d2
            if up:
                u1, u2 = g1 + w1 + i1 + n1, g2 + w2 + i2 + n2
                zn0 = E[0] * s1 + E[1] * s2 + G[0] * u1 + G[1] * u2
                zn1 = E[2] * s1 + E[3] * s2 + G[2] * u1 + G[3] * u2
            else:
                u1, u2 = g1 + w1 - i1 - n1, g2 + w2 - i2 - n2
                zn2 = E[0] * s1 + E[1] * s2 + G[0] * u1 + G[1] * u2
                zn3 = E[2] * s1 + E[3] * s2 + G[2] * u1 + G[3] * u2
        z[0], z[1], z[2], z[3] = zn0, zn1, zn2, zn3


@jit
def derive_bounds(u: np.ndarray, z: np.ndarray, have_delta: bool, p: np.ndarray, x: np.ndarray, lo: np.ndarray,
            hi: np.ndarray) -> None:
    """Slip bounds in alpha coordinates and the derived ``v_y``, ``beta`` bounds; midpoints as estimates."""
    delta, r, vx = u[0], u[1], u[2]
    vhi, vmin, lf, lr = p[23], p[28], p[31], p[32]
    d = delta if have_delta else 0.0
    afu, afl, aru, arl = z[0] + d, z[2] + d, z[1], z[3]
    if have_delta and r == r and vx == vx:
        v = vx if vx > vmin else vmin
        lim = 1.5
        fl = v * math.tan(max(-lim, min(lim, d - afu))) - lf * r
        fh = v * math.tan(max(-lim, min(lim, d - afl))) - lf * r
        rl = lr * r - v * math.tan(max(-lim, min(lim, aru)))
        rh = lr * r - v * math.tan(max(-lim, min(lim, arl)))
        vyl, vyh = max(fl, rl), min(fh, rh)
        if vyl > vyh:  # disjoint: inclusion already lost somewhere; report the hull
            vyl, vyh = min(fl, rl), max(fh, rh)
        bl, bh = math.atan(vyl / v), math.atan(vyh / v)
    else:
        vyl, vyh, bl, bh = -vhi, vhi, -0.5 * math.pi, 0.5 * math.pi
    lo[0], lo[1], lo[2], lo[3] = afl, arl, bl, vyl
    hi[0], hi[1], hi[2], hi[3] = afu, aru, bh, vyh
    x[0], x[1], x[2], x[3] = 0.5 * (afl + afu), 0.5 * (arl + aru), 0.5 * (bl + bh), 0.5 * (vyl + vyh)


@jit
def interval_run(t: np.ndarray, Y: np.ndarray, u: np.ndarray, tl: np.ndarray, z: np.ndarray, s: np.ndarray,
                 p: np.ndarray, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
    """The interval observer over ``t`` (n,) [s], ``Y`` (n, 4); writes estimates and bounds to ``x``,
    ``lo``, ``hi`` (n, 4) in ``IntervalWang.states`` order (state arrays: module docstring)."""
    vlo, vhi, ab, hold = p[22], p[23], p[26], p[27]
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
                z[2] -= delta
                s[1] = 1.0
            if (r != r or vx != vx or ax != ax or ts - min(tl[0], tl[1], tl[2]) > hold
                    or vx < vlo or vx > vhi):
                # no certified prediction: fall back to the a-priori bracket and restart from it
                z[0], z[1], z[2], z[3] = ab - delta, ab, -ab - delta, -ab
            elif h > 0.0:
                _integrate(z, h, delta, r, vx, ax, p)
        derive_bounds(u, z, s[1] != 0.0, p, x[i], lo[i], hi[i])
