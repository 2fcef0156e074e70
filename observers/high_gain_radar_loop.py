"""Compiled whole-run loops of the radar high-gain observers (:mod:`roadtruth.observers.high_gain_radar`,
:mod:`roadtruth.observers.high_gain_methods`).

Each kernel is the ``_advance`` of its class written on arrays, operation for operation, so a
compiled ``run()`` equals stepping ``step()`` one sample at a time (tested in
``tests/test_observers_conformance.py``); ``step()`` stays the plain-Python reference. The exact
discretisations ``(Phi, Gamma0, Gamma1)`` come from scipy's ``expm`` (not available in numba): a first
kernel (:func:`step_keys`) replays the time and sample bookkeeping, which depends on the data only,
to find every ``(h, range used, range rate used)`` a run needs; each distinct one is discretised once
by the class (its own cache) and the main kernel looks its row up.

numba caches each kernel per source file: after editing this file delete
``observers/__pycache__/*.nbi, *.nbc``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from roadtruth.harness.truth.tire import jit

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

    from roadtruth.observers.base import EstimateTrack
    from roadtruth.observers.high_gain_radar import HighGainRadarStandard


@jit
def step_keys(t: np.ndarray, Y: np.ndarray, t_cur: float, t_last: np.ndarray, started: bool,
              hold_s: float, uses_rate: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per row: step ``h`` [s], range used, range rate used, and whether the row integrates.

    Replays ``ScalarLoopObserver._tick`` (latched arrival times, step since the last advance) and the
    start on the first range sample; a row integrates when the observer had started before it and
    ``h > 0``. ``t_last`` (4,) [s] is copied, not changed.
    """
    n = t.shape[0]
    hs = np.zeros(n)
    use_y = np.zeros(n, dtype=np.bool_)
    use_z = np.zeros(n, dtype=np.bool_)
    need = np.zeros(n, dtype=np.bool_)
    tl = t_last.copy()
    have_range = False
    for i in range(n):
        ts = t[i]
        for j in range(Y.shape[1]):
            v = Y[i, j]
            if v == v:
                tl[j] = ts
                if j == 0:
                    have_range = True
        h = ts - t_cur
        if h > 0.0:
            t_cur = ts
        else:
            h = 0.0
        if not started:
            if have_range:
                started = True
            continue
        if h <= 0.0:
            continue
        hs[i] = h
        use_y[i] = ts - tl[0] <= hold_s
        use_z[i] = uses_rate and ts - tl[1] <= hold_s
        need[i] = True
    return hs, use_y, use_z, need


def discretisation_table(hs: np.ndarray, use_y: np.ndarray, use_z: np.ndarray, need: np.ndarray,
                         discrete: Callable[[float, bool, bool], tuple[tuple[float, ...], ...]],
                         size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(row, Phi, Gamma0, Gamma1)``: per run row the table row of its discretisation (-1: none),
    and the tables, ``(k, size)`` each, one row per distinct key, from ``discrete(h, use_y, use_z)``."""
    row = np.full(hs.shape[0], -1, dtype=np.int64)
    idx = np.flatnonzero(need)
    if idx.size == 0:
        empty = np.zeros((0, size))
        return row, empty, empty, empty
    flags = use_y[idx].astype(np.int64) * 2 + use_z[idx].astype(np.int64)
    h_unique, h_inv = np.unique(hs[idx], return_inverse=True)
    keys, key_inv = np.unique(h_inv * 4 + flags, return_inverse=True)
    row[idx] = key_inv
    tabs = [np.empty((keys.size, size)) for _ in range(3)]
    for r, key in enumerate(keys.tolist()):
        parts = discrete(float(h_unique[key // 4]), bool(key & 2), bool(key & 1))
        for tab, part in zip(tabs, parts, strict=True):
            tab[r] = part
    return row, tabs[0], tabs[1], tabs[2]


@jit
def _latch(ts: float, Y: np.ndarray, i: int, u: np.ndarray, fresh: np.ndarray, tl: np.ndarray,
           t_cur: float) -> tuple[float, float]:
    """``ScalarLoopObserver._tick`` on arrays: returns ``(h, t_cur)``."""
    for j in range(Y.shape[1]):
        v = Y[i, j]
        if v == v:
            u[j] = v
            fresh[j] = True
            tl[j] = ts
        else:
            fresh[j] = False
    h = ts - t_cur
    if h > 0.0:
        return h, ts
    return 0.0, t_cur


@jit
def radar_run(t: np.ndarray, Y: np.ndarray, row: np.ndarray, Phi_t: np.ndarray, Gam_t: np.ndarray,
              Gam1_t: np.ndarray, z: np.ndarray, u: np.ndarray, fresh: np.ndarray, tl: np.ndarray,
              state: np.ndarray, par: np.ndarray, fohs: bool, uses_rate: bool) -> np.ndarray:
    """``HighGainRadarStandard._advance`` over a run; returns the (n, 3) estimates.

    ``z`` (3,), ``u``/``fresh``/``tl`` (4,) and ``state`` = ``(t_cur, slope_y, slope_z, slope_e,
    started)`` are updated in place (the observer's state after the run). ``par`` = ``(hold_s, l1,
    l2, l3, m1, m2, m3, lo_v, hi_v, lo_a, hi_a, km, dm, itau)``.
    """
    n = t.shape[0]
    out = np.empty((n, 3))
    t_cur, slope_y, slope_z, slope_e = state[0], state[1], state[2], state[3]
    started = state[4] != 0.0
    hold = par[0]
    l1, l2, l3, m1, m2, m3 = par[1], par[2], par[3], par[4], par[5], par[6]
    lo_v, hi_v, lo_a, hi_a = par[7], par[8], par[9], par[10]
    km, dm, itau = par[11], par[12], par[13]
    for i in range(n):
        ts = t[i]
        prev_y, prev_z, prev_e = u[0], u[1], u[3]
        t_y, t_z, t_e = tl[0], tl[1], tl[3]
        h, t_cur = _latch(ts, Y, i, u, fresh, tl, t_cur)
        if fresh[0]:
            dt = ts - t_y
            slope_y = (u[0] - prev_y) / dt if 0.0 < dt <= hold else 0.0
        if fresh[1]:
            dt = ts - t_z
            slope_z = (u[1] - prev_z) / dt if 0.0 < dt <= hold else 0.0
        if fresh[3]:
            dt = ts - t_e
            slope_e = (u[3] - prev_e) / dt if 0.0 < dt <= hold else 0.0
        rng, rate, ve, ae = u[0], u[1], u[2], u[3]
        if not started:
            if rng == rng:
                z[0] = rng
                z[1] = rate if rate == rate else 0.0
                z[2] = ae if ae == ae else 0.0
                started = True
        elif h > 0.0:
            age_y = ts - tl[0]
            age_z = ts - tl[1]
            use_z = uses_rate and age_z <= hold
            use_y = age_y <= hold
            x1, x2, x3 = z[0], z[1], z[2]
            ae = ae if ae == ae else 0.0
            sy = slope_y if fohs else 0.0
            sz = slope_z if fohs else 0.0
            y0 = rng - sy * (age_y + h)
            z0 = rate - sz * (age_z + h)
            se = 0.0
            if fohs and ts - tl[3] <= hold:
                se = slope_e
                ae = ae - se * (ts - tl[3] + h)
            k = row[i]
            Phi, Gam, Gam1 = Phi_t[k], Gam_t[k], Gam1_t[k]
            v = x2 + (ve if ve == ve else 0.0)
            v = lo_v if v < lo_v else (hi_v if v > hi_v else v)
            a = lo_a if x3 < lo_a else (hi_a if x3 > hi_a else x3)
            g1, g2, g3 = 0.0, -ae, -2.0 * km * v * a - (a + km * v * v + dm) * itau
            r1, r2, r3 = 0.0, -se, 0.0
            if use_y:
                g1 += l1 * y0
                g2 += l2 * y0
                g3 += l3 * y0
                r1 += l1 * sy
                r2 += l2 * sy
                r3 += l3 * sy
            if use_z:
                g1 += m1 * z0
                g2 += m2 * z0
                g3 += m3 * z0
                r1 += m1 * sz
                r2 += m2 * sz
                r3 += m3 * sz
            n1 = (Phi[0] * x1 + Phi[1] * x2 + Phi[2] * x3 + Gam[0] * g1 + Gam[1] * g2 + Gam[2] * g3
                  + Gam1[0] * r1 + Gam1[1] * r2 + Gam1[2] * r3)
            n2 = (Phi[3] * x1 + Phi[4] * x2 + Phi[5] * x3 + Gam[3] * g1 + Gam[4] * g2 + Gam[5] * g3
                  + Gam1[3] * r1 + Gam1[4] * r2 + Gam1[5] * r3)
            n3 = (Phi[6] * x1 + Phi[7] * x2 + Phi[8] * x3 + Gam[6] * g1 + Gam[7] * g2 + Gam[8] * g3
                  + Gam1[6] * r1 + Gam1[7] * r2 + Gam1[8] * r3)
            if n1 - n1 == 0.0 and n2 - n2 == 0.0 and n3 - n3 == 0.0:
                z[0], z[1], z[2] = n1, n2, n3
            else:
                z[0], z[1], z[2] = (rng if rng - rng == 0.0 else 0.0), 0.0, 0.0
        out[i, 0], out[i, 1], out[i, 2] = z[0], z[1], z[2]
    state[0], state[1], state[2], state[3] = t_cur, slope_y, slope_z, slope_e
    state[4] = 1.0 if started else 0.0
    return out


@jit
def extension_run(t: np.ndarray, Y: np.ndarray, row: np.ndarray, Phi_t: np.ndarray, Gam_t: np.ndarray,
                  Gam1_t: np.ndarray, z: np.ndarray, u: np.ndarray, fresh: np.ndarray, tl: np.ndarray,
                  state: np.ndarray, par: np.ndarray, fohs: bool) -> np.ndarray:
    """``HighGainRadarExtension._advance`` over a run; returns the (n, 3) estimates ``(d, d', a_L)``.

    ``z`` = ``(nu, d, d', a_L)``; in-place state as :func:`radar_run`; ``par`` = ``(hold_s, alpha,
    beta^2, lo_v, hi_v, lo_a, hi_a, km, dm, itau)``.
    """
    n = t.shape[0]
    out = np.empty((n, 3))
    t_cur, slope_y, slope_z, slope_e = state[0], state[1], state[2], state[3]
    started = state[4] != 0.0
    hold, alpha, b2 = par[0], par[1], par[2]
    lo_v, hi_v, lo_a, hi_a = par[3], par[4], par[5], par[6]
    km, dm, itau = par[7], par[8], par[9]
    new = np.empty(4)
    for i in range(n):
        ts = t[i]
        prev_y, prev_z, prev_e = u[0], u[1], u[3]
        t_y, t_z, t_e = tl[0], tl[1], tl[3]
        h, t_cur = _latch(ts, Y, i, u, fresh, tl, t_cur)
        if fresh[0]:
            dt = ts - t_y
            slope_y = (u[0] - prev_y) / dt if 0.0 < dt <= hold else 0.0
        if fresh[1]:
            dt = ts - t_z
            slope_z = (u[1] - prev_z) / dt if 0.0 < dt <= hold else 0.0
        if fresh[3]:
            dt = ts - t_e
            slope_e = (u[3] - prev_e) / dt if 0.0 < dt <= hold else 0.0
        rng, rate, ve, ae = u[0], u[1], u[2], u[3]
        if not started:
            if rng == rng:
                z[0] = 0.0
                z[1] = rng
                z[2] = rate if rate == rate else 0.0
                z[3] = ae if ae == ae else 0.0
                started = True
        elif h > 0.0:
            use_y = ts - tl[0] <= hold
            use_z = ts - tl[1] <= hold
            nu, x1, x2, x3 = z[0], z[1], z[2], z[3]
            ae = ae if ae == ae else 0.0
            sy = slope_y if fohs else 0.0
            sz = slope_z if fohs else 0.0
            y0 = rng - sy * (ts - tl[0] + h)
            z0 = rate - sz * (ts - tl[1] + h)
            se = 0.0
            if fohs and ts - tl[3] <= hold:
                se = slope_e
                ae = ae - se * (ts - tl[3] + h)
            k = row[i]
            Phi, Gam, Gam1 = Phi_t[k], Gam_t[k], Gam1_t[k]
            v = x2 + (ve if ve == ve else 0.0)
            v = lo_v if v < lo_v else (hi_v if v > hi_v else v)
            a = lo_a if x3 < lo_a else (hi_a if x3 > hi_a else x3)
            g0, g2, g3 = 0.0, -ae, -2.0 * km * v * a - (a + km * v * v + dm) * itau
            r0, r2 = 0.0, -se
            if use_y:
                g0 += alpha * y0
                r0 += alpha * sy
            if use_z:
                g0 += b2 * z0
                r0 += b2 * sz
            finite = True
            for m in range(4):
                k4 = 4 * m
                q = (Phi[k4] * nu + Phi[k4 + 1] * x1 + Phi[k4 + 2] * x2 + Phi[k4 + 3] * x3
                     + Gam[k4] * g0 + Gam[k4 + 2] * g2 + Gam[k4 + 3] * g3 + Gam1[k4] * r0 + Gam1[k4 + 2] * r2)
                new[m] = q
                finite = finite and q - q == 0.0
            if finite:
                z[0], z[1], z[2], z[3] = new[0], new[1], new[2], new[3]
            else:
                z[0], z[1], z[2], z[3] = 0.0, (rng if rng - rng == 0.0 else 0.0), 0.0, 0.0
        out[i, 0], out[i, 1], out[i, 2] = z[1], z[2], z[3]
    state[0], state[1], state[2], state[3] = t_cur, slope_y, slope_z, slope_e
    state[4] = 1.0 if started else 0.0
    return out


def run_compiled(obs: HighGainRadarStandard, t: np.ndarray, Y: np.ndarray,
                 x0: Mapping[str, float] | None) -> EstimateTrack:
    """``obs.run`` through the kernels above; leaves ``obs`` in the state stepping would leave it in."""
    from roadtruth.observers.base import EstimateTrack
    from roadtruth.observers.high_gain_methods import HighGainRadarExtension

    t = np.ascontiguousarray(t, dtype=float)
    Y = np.ascontiguousarray(np.asarray(Y, dtype=float).reshape(len(t), len(obs.inputs)))
    if len(t) == 0:
        return EstimateTrack(obs.name, tuple(obs.states), t, np.zeros((0, len(obs.states))))
    obs.reset(float(t[0]), x0)
    ext = isinstance(obs, HighGainRadarExtension)
    tl = np.array(obs._t_last, dtype=float)
    hs, use_y, use_z, need = step_keys(t, Y, obs._t, tl, obs._started, obs._hold, ext or obs.uses_rate)
    size = 16 if ext else 9
    discrete = obs._discrete4 if ext else obs._discrete
    row, Phi, Gam, Gam1 = discretisation_table(hs, use_y, use_z, need, discrete, size)
    z = np.array(obs._z, dtype=float)
    u = np.array(obs._u, dtype=float)
    fresh = np.array(obs._fresh, dtype=np.bool_)
    state = np.array([obs._t, obs._slope_y, obs._slope_z, obs._slope_e, 1.0 if obs._started else 0.0])
    lo_v, hi_v, lo_a, hi_a = obs._box
    km, dm, itau = obs._fpar
    if ext:
        # the gains are needed (and a failed design raises) only if some row integrates, as in step()
        _, _, _, _, alpha, b2 = obs._params() if need.any() else (0.0,) * 6
        par = np.array([obs._hold, alpha, b2, lo_v, hi_v, lo_a, hi_a, km, dm, itau])
        X = extension_run(t, Y, row, Phi, Gam, Gam1, z, u, fresh, tl, state, par, obs._fohs)
    else:
        lm = obs._float_gains() if need.any() else (0.0,) * 6
        par = np.array([obs._hold, *lm, lo_v, hi_v, lo_a, hi_a, km, dm, itau])
        X = radar_run(t, Y, row, Phi, Gam, Gam1, z, u, fresh, tl, state, par, obs._fohs, obs.uses_rate)
    obs._z = z.tolist()
    obs._u = u.tolist()
    obs._fresh = fresh.tolist()
    obs._t_last = tl.tolist()
    obs._t, obs._slope_y, obs._slope_z, obs._slope_e = (float(x) for x in state[:4])
    obs._started = bool(state[4])
    return EstimateTrack(obs.name, tuple(obs.states), t, X)
