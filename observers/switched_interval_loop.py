"""The compiled kernel of the switched interval observer (:mod:`roadtruth.observers.switched_interval`).

:func:`switched_run` is the whole per-sample update of ``SwitchedIntervalIfqir``: latching the inputs
(zero-order hold; NaN = no new sample), the step ``h`` since the last advance (0 for a repeated time
stamp), the mode selection with hysteresis and the re-initialisation of ``z^±`` on a switch, the
sampled-data hulls of ``r``, ``delta``, ``v_x``, the exact ZOH step of the Metzler ``N_0`` block, the
intersection with the gyro interval, the lane bounds and the reported bounds/midpoints. ``step()``
calls it with one sample and ``run()`` with the whole log, so both execute the same compiled code on
the same carried state and agree bit for bit (``tests/test_observers_switched_interval.py``).

The 2x2 exponential ``expm2_zoh(N_0, h)`` depends only on the mode and ``h``: it is recomputed only
when either changes (the same function on the same arguments: the same bits).
``min``/``max`` follow Python's semantics (first argument kept on ties), as the original.

numba caches each kernel per source file: after editing this file delete
``observers/__pycache__/switched_interval_loop*.nbi, *.nbc``.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit
from roadtruth.observers.bicycle import expm2_zoh

_expm2 = jit(expm2_zoh)

#: Layout of the kernel's scalar state ``state``.
(T_CUR, MODE, DPREV, VPREV, FW1, FW2, T_SWITCH, DWELL_VIOLATIONS, OUT_OF_BAND, INCONSISTENT, SWITCHES,
 E_MODE, E_H) = range(13)
N_STATE = 13
#: Layout of ``par``.
(P_VR, P_VPSI, P_VYL, P_VV, P_LAT, P_RHO, P_LS, P_VMIN, P_ZETA, P_DWELL) = range(10)
N_PAR = 10


@jit
def _pmin(a: float, b: float) -> float:
    """Python's ``min(a, b)``."""
    return b if b < a else a


@jit
def _pmax(a: float, b: float) -> float:
    """Python's ``max(a, b)``."""
    return b if b > a else a


@jit
def _mul(a: float, lo: float, hi: float) -> tuple[float, float]:
    """Bounds of ``a x`` for ``x`` in ``[lo, hi]`` (Lemma 3(1), scalar)."""
    return (a * lo, a * hi) if a >= 0.0 else (a * hi, a * lo)


@jit
def _mul_ii(al: float, ah: float, bl: float, bh: float) -> tuple[float, float]:
    """Bounds of ``a b`` for ``a`` in ``[al, ah]`` and ``b`` in ``[bl, bh]``."""
    p0, p1, p2, p3 = al * bl, al * bh, ah * bl, ah * bh
    return _pmin(_pmin(_pmin(p0, p1), p2), p3), _pmax(_pmax(_pmax(p0, p1), p2), p3)


@jit
def _select_mode(v: float, t_s: float, rl: float, rh: float, modes: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 zl: np.ndarray, zh: np.ndarray, state: np.ndarray, dwell_s: float) -> None:
    """Keep the mode while ``v`` is in its band, else the band holding ``v`` with the nearest centre."""
    cur = int(state[MODE])
    if cur >= 0 and modes[cur, 1] <= v <= modes[cur, 2]:
        return
    nm = modes.shape[0]
    any_inside = False
    for i in range(nm):
        if modes[i, 1] <= v <= modes[i, 2]:
            any_inside = True
    new = -1
    best = 0.0
    for i in range(nm):
        if any_inside and not modes[i, 1] <= v <= modes[i, 2]:
            continue
        d = abs(modes[i, 0] - v)
        if new < 0 or d < best:
            new, best = i, d
    if not any_inside:
        state[OUT_OF_BAND] += 1.0
    if new == cur:
        return
    if cur >= 0:
        state[SWITCHES] += 1.0
        if t_s - state[T_SWITCH] < dwell_s:
            state[DWELL_VIOLATIONS] += 1.0
    state[T_SWITCH] = t_s
    state[MODE] = float(new)
    # z = x + H y with y = r in [rl, rh] (Lemma 3(1)); x^± is kept across the switch
    a, bb = _mul(modes[new, 11], rl, rh)
    zl[0], zh[0] = lo[0] + a, hi[0] + bb
    a, bb = _mul(modes[new, 12], rl, rh)
    zl[1], zh[1] = lo[1] + a, hi[1] + bb


@jit
def _lane(h: float, vl: float, vh: float, psi_m: float, yl_m: float, new_psi: bool, new_y: bool, rl: float,
          rh: float, vyl: float, vyh: float, lo: np.ndarray, hi: np.ndarray, par: np.ndarray) -> None:
    """Lane bounds: camera sample ± noise (± drift over its age), else open-loop propagation."""
    ls, rho = par[P_LS], par[P_RHO]
    vpos = _pmax(vh, 0.0)
    # psi_L' = r - v rho ; worst case over the step
    dpl, dph = rl - vpos * rho, rh + vpos * rho
    pl, ph = lo[2] + h * dpl, hi[2] + h * dph
    psi_max, psi_min = _pmax(hi[2], ph), _pmin(lo[2], pl)
    # y_L' = v_y + l_s r + v psi_L - l_s v rho, v in [vl, vh]
    vpl, vph = _mul_ii(vl, vh, psi_min, psi_max)
    dyl = vyl + ls * rl + vpl - ls * vpos * rho
    dyh = vyh + ls * rh + vph + ls * vpos * rho
    yl, yh = lo[3] + h * dyl, hi[3] + h * dyh
    lat = par[P_LAT]
    # a sample taken `lat` ago: the state has since moved by the integral of its rate bounds
    if new_psi:
        pl, ph = psi_m - par[P_VPSI] + lat * dpl, psi_m + par[P_VPSI] + lat * dph
    if new_y:
        yl, yh = yl_m - par[P_VYL] + lat * dyl, yl_m + par[P_VYL] + lat * dyh
    lo[2], hi[2], lo[3], hi[3] = pl, ph, yl, yh


@jit
def _advance(ts: float, h: float, u: np.ndarray, fresh: np.ndarray, lo: np.ndarray, hi: np.ndarray,
             zl: np.ndarray, zh: np.ndarray, state: np.ndarray, modes: np.ndarray, par: np.ndarray,
             eg: np.ndarray) -> None:
    """One sample of ``SwitchedIntervalIfqir`` after the latch, in place; ``eg`` (8,) = the cached
    ``(E, G)`` of the current mode and step (valid for ``state[E_MODE], state[E_H]``)."""
    r_m, delta, v, psi_m, yl_m = u[0], u[1], u[2], u[3], u[4]
    mode = int(state[MODE])
    if delta != delta or v != v or (r_m != r_m and mode < 0):
        return  # not started: the initial box is reported
    vr = par[P_VR]
    if mode < 0:
        state[DPREV], state[VPREV] = delta, v
        lo[1], hi[1] = r_m - vr, r_m + vr  # the latest gyro sample
    # Sampled data: over the step a signal is taken within the hull of its two end samples.
    # lo[1], hi[1] still hold the bounds of r at the previous step.
    if fresh[0]:
        r0l, r0h = r_m - vr, r_m + vr        # r now
        rl, rh = _pmin(lo[1], r0l), _pmax(hi[1], r0h)        # r over the step
    else:
        r0l, r0h = lo[1], hi[1]
        rl, rh = r0l, r0h
    _select_mode(v, ts, lo[1], hi[1], modes, lo, hi, zl, zh, state, par[P_DWELL])
    dprev, vprev = state[DPREV], state[VPREV]
    state[DPREV], state[VPREV] = delta, v
    if h <= 0.0:
        return
    mode = int(state[MODE])
    m = modes[mode]
    v_c, n11, n12, n21, n22, m1, m2, g1, g2, h1, h2 = m[0], m[3], m[4], m[5], m[6], m[7], m[8], m[9], m[10], m[11], m[12]
    d11, d12, d21, d22, pb1, pb2, p1, p2 = m[13], m[14], m[15], m[16], m[17], m[18], m[19], m[20]
    vv = par[P_VV]
    vl, vh = _pmin(v, vprev) - vv, _pmax(v, vprev) + vv
    zeta = par[P_ZETA]
    ul, uh = _pmin(delta, dprev) - zeta, _pmax(delta, dprev) + zeta
    xb1 = _pmax(abs(lo[0]), abs(hi[0]))
    xb2 = _pmax(abs(rl), abs(rh))
    au = _pmax(abs(ul), abs(uh))
    w1 = d11 * xb1 + d12 * xb2 + pb1 * au
    w2 = d21 * xb1 + d22 * xb2 + pb2 * au
    kl, kh = _mul_ii(v_c - vh, v_c - vl, rl, rh)      # (v_i - v_x) r, kinematic term of A
    a1l, a1h = _mul(m1, rl, rh)
    a2l, a2h = _mul(m2, rl, rh)
    k1l, k1h = _mul(p1, kl, kh)
    k2l, k2h = _mul(p2, kl, kh)
    f1l = a1l + g1 * ul + k1l - w1      # g >= 0: P >= 0 and B0 >= 0
    f1h = a1h + g1 * uh + k1h + w1
    f2l = a2l + g2 * ul + k2l - w2
    f2h = a2h + g2 * uh + k2h + w2
    state[FW1], state[FW2] = f1h - f1l, f2h - f2l
    if state[E_MODE] != float(mode) or state[E_H] != h:
        # the exact ZOH of N_0 depends on (mode, h) only: recomputed when either changes
        E, Gm = _expm2(n11, n12, n21, n22, h)
        eg[0], eg[1], eg[2], eg[3] = E[0], E[1], E[2], E[3]
        eg[4], eg[5], eg[6], eg[7] = Gm[0], Gm[1], Gm[2], Gm[3]
        state[E_MODE], state[E_H] = float(mode), h
    zl0 = eg[0] * zl[0] + eg[1] * zl[1] + eg[4] * f1l + eg[5] * f2l
    zl1 = eg[2] * zl[0] + eg[3] * zl[1] + eg[6] * f1l + eg[7] * f2l
    zh0 = eg[0] * zh[0] + eg[1] * zh[1] + eg[4] * f1h + eg[5] * f2h
    zh1 = eg[2] * zh[0] + eg[3] * zh[1] + eg[6] * f1h + eg[7] * f2h
    zl[0], zl[1], zh[0], zh[1] = zl0, zl1, zh0, zh1
    old_vyh, old_vyl = hi[0], lo[0]
    a, bb = _mul(h1, r0l, r0h)
    lo[0], hi[0] = zl0 - bb, zh0 - a
    a, bb = _mul(h2, r0l, r0h)
    x2l, x2h = zl1 - bb, zh1 - a
    if fresh[0]:
        x2l, x2h = _pmax(x2l, r0l), _pmin(x2h, r0h)   # both are valid enclosures of r
        if x2l > x2h:
            # Empty: the plant left the model (e.g. tire saturation). Keep the measurement, count it.
            state[INCONSISTENT] += 1.0
            x2l, x2h = r0l, r0h
    lo[1], hi[1] = x2l, x2h
    _lane(h, vl, vh, psi_m, yl_m, fresh[3], fresh[4], _pmin(rl, x2l), _pmax(rh, x2h),
          _pmin(old_vyl, lo[0]), _pmax(old_vyh, hi[0]), lo, hi, par)


@jit
def switched_run(t: np.ndarray, Y: np.ndarray, u: np.ndarray, fresh: np.ndarray, tl: np.ndarray, lo: np.ndarray,
                 hi: np.ndarray, zl: np.ndarray, zh: np.ndarray, state: np.ndarray, eg: np.ndarray,
                 modes: np.ndarray, par: np.ndarray, x: np.ndarray, xlo: np.ndarray, xhi: np.ndarray) -> None:
    """The observer over ``t`` (n,) [s], ``Y`` (n, 5) = ``(r, delta, v_x, psi_L, y_L)``.

    Writes the midpoints, lower and upper bounds of ``(v_y, r, psi_L, y_L, beta)`` to ``x``, ``xlo``,
    ``xhi`` (n, 5). Carried in place: ``u``/``fresh``/``tl`` (5,) held inputs, whether each is new and
    its arrival time; ``lo``/``hi`` (4,) bounds of ``x``; ``zl``/``zh`` (2,) bounds of ``z_1, z_2``;
    ``state`` (``N_STATE``,) the scalars ``T_CUR`` ... ``E_H``; ``eg`` (8,) the cached ZOH.
    ``modes`` (n_modes, 21) rows of ``SwitchedIntervalIfqir.mode_constants()``; ``par`` (``N_PAR``,).
    """
    n = t.shape[0]
    for i in range(n):
        ts = t[i]
        # ScalarLoopObserver._tick: latch new samples, step since the last advance
        for j in range(5):
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
        _advance(ts, h, u, fresh, lo, hi, zl, zh, state, modes, par, eg)
        bounds(u[2], lo, hi, par, xlo[i], xhi[i])
        for k in range(5):
            x[i, k] = 0.5 * (xlo[i, k] + xhi[i, k])


@jit
def bounds(v: float, lo: np.ndarray, hi: np.ndarray, par: np.ndarray, blo: np.ndarray, bhi: np.ndarray) -> None:
    """The reported bounds of ``(v_y, r, psi_L, y_L, beta)`` into ``blo``, ``bhi`` (5,) at held speed ``v``."""
    for k in range(4):
        blo[k], bhi[k] = lo[k], hi[k]
    if v != v:
        blo[4], bhi[4] = -0.5 * math.pi, 0.5 * math.pi
        return
    vv, vmin = par[P_VV], par[P_VMIN]
    vl, vh = _pmax(v - vv, vmin), _pmax(v + vv, vmin)
    bhi[4] = math.atan(hi[0] / (vl if hi[0] >= 0.0 else vh))
    blo[4] = math.atan(lo[0] / (vh if lo[0] >= 0.0 else vl))
