"""Compiled whole-run loops of the finite-time / interval estimators (:mod:`roadtruth.observers.finite_time_interval`).

Each kernel is the class's ``_advance`` (fixed-step clock, validity checks, the discrete step)
written on arrays, operation for operation, so a compiled ``run()`` equals stepping ``step()`` one
sample at a time (tested in ``tests/test_observers_compiled_loops.py``); ``step()`` stays the
plain-Python reference. ``par`` (both kernels): ``(m, iz, lf, lr, cf, cr, ts, rho1_lo, rho1_hi,
rho2_lo, rho2_hi, vlo, vhi, hold_s, beta_bound, nu, dcf, dcr)``. The per-run state is carried in
arrays updated in place: ``u``/``tl`` (3,) held inputs and their times, ``s`` = ``(t_next, count,
lo0, lo1, hi0, hi1, x0, x1)`` and the family's own memory.

numba caches each kernel per source file: after editing this file delete
``observers/__pycache__/*.nbi, *.nbc``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from roadtruth.harness.truth.tire import jit

if TYPE_CHECKING:
    from collections.abc import Mapping

    from roadtruth.observers.base import EstimateTrack
    from roadtruth.observers.finite_time_interval import _BicycleLPVObserver

R_PRIOR = 2.0  # = finite_time_interval.R_PRIOR_RADPS (asserted equal in run_compiled)


@jit
def _prior(s: np.ndarray, r: float, b: float, nu: float) -> None:
    if r != r:
        s[2], s[3], s[4], s[5], s[6], s[7] = -b, -R_PRIOR, b, R_PRIOR, 0.0, 0.0
    else:
        s[2], s[3], s[4], s[5], s[6], s[7] = -b, r - nu, b, r + nu, 0.0, r


@jit
def _clock(ts_now: float, Y: np.ndarray, i: int, u: np.ndarray, tl: np.ndarray, s: np.ndarray,
           par: np.ndarray) -> int:
    """Latch the samples, run the fixed-step clock: 0 = no tick, 1 = invalid tick (restarted), 2 = step."""
    for j in range(3):
        v = Y[i, j]
        if v == v:
            u[j] = v
            tl[j] = ts_now
    ts, vlo, vhi, hold = par[6], par[11], par[12], par[13]
    if ts_now < s[0] - 1e-6 * ts:
        return 0
    s[0] = ts_now + ts if s[0] == -np.inf else s[0] + ts
    if s[0] <= ts_now:
        s[0] = ts_now + ts
    r, delta, vx = u[0], u[1], u[2]
    if (r != r or delta != delta or vx != vx or ts_now - min(tl[0], min(tl[1], tl[2])) > hold
            or not vlo <= vx <= vhi):
        s[1] = 0.0
        _prior(s, r, par[14], par[15])
        return 1
    return 2


@jit
def _a_b(par: np.ndarray, rho1: float, rho2: float) -> tuple[float, float, float, float, float, float]:
    """``A_N(rho)`` (2.33) row-major and ``B_u(rho)`` (2.34), as ``BicycleLPV.a`` / ``.b``."""
    m, iz, lf, lr, cf, cr, ts = par[0], par[1], par[2], par[3], par[4], par[5], par[6]
    a0 = 1.0 + ts * (-(cf + cr) / m * rho1)
    a1 = 0.0 + ts * ((cr * lr - cf * lf) / m * rho2 - 1.0)
    a2 = 0.0 + ts * ((cr * lr - cf * lf) / iz)
    a3 = 1.0 + ts * (-(cr * lr ** 2 + cf * lf ** 2) / iz * rho1)
    return a0, a1, a2, a3, ts * (cf / m * rho1), ts * (cf * lf / iz)


@jit
def _inv(a: np.ndarray) -> np.ndarray:
    d = a[0] * a[3] - a[1] * a[2]
    return np.array([a[3] / d, -a[1] / d, -a[2] / d, a[0] / d])


@jit
def _mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array([a[0] * b[0] + a[1] * b[2], a[0] * b[1] + a[1] * b[3],
                     a[2] * b[0] + a[3] * b[2], a[2] * b[1] + a[3] * b[3]])


@jit
def _mv(a: np.ndarray, x0: float, x1: float) -> tuple[float, float]:
    return a[0] * x0 + a[1] * x1, a[2] * x0 + a[3] * x1


@jit
def _solve(a: np.ndarray, x0: float, x1: float) -> tuple[float, float]:
    d = a[0] * a[3] - a[1] * a[2]
    return (a[3] * x0 - a[1] * x1) / d, (-a[2] * x0 + a[0] * x1) / d


@jit
def _mx(c: float, a: float, blo: float, bhi: float) -> float:
    return max(abs(c + a * blo), abs(c + a * bhi))


@jit
def finite_time_run(t: np.ndarray, Y: np.ndarray, u: np.ndarray, tl: np.ndarray, s: np.ndarray,
                    zeta_eta: np.ndarray, hist: np.ndarray, nh: np.ndarray, par: np.ndarray,
                    Lv: np.ndarray, Kv: np.ndarray, bounded: bool, have_gains: bool) -> tuple[np.ndarray, int]:
    """``_FiniteTime._advance`` over a run: returns ``(out (n, 6) = x, lo, hi, rows done)``.

    ``zeta_eta`` (4,), ``hist`` (3, 18) = per past step ``zeta, eta, M_L, M_K, L, K, vbar`` (oldest
    first, ``nh[0]`` rows used). Without gains the run stops at the first discrete step (the caller
    raises the design failure there, as ``step()`` does).
    """
    n = t.shape[0]
    out = np.empty((n, 6))
    m, iz, lf, lr, ts = par[0], par[1], par[2], par[3], par[6]
    (l1r, h1r), (l2r, h2r) = (par[7], par[8]), (par[9], par[10])
    bmax, nu, dcf, dcr = par[14], par[15], par[16], par[17]
    xi = np.empty(4)
    for i in range(n):
        ts_now = t[i]
        tick = _clock(ts_now, Y, i, u, tl, s, par)
        if tick == 2:
            if not have_gains:
                return out, i
            r, delta, vx = u[0], u[1], u[2]
            rho1, rho2 = 1.0 / vx, 1.0 / (vx * vx)
            a1w, a2w = (h1r - rho1) / (h1r - l1r), (h2r - rho2) / (h2r - l2r)
            xi[0], xi[1], xi[2], xi[3] = a1w * a2w, a1w * (1 - a2w), (1 - a1w) * a2w, (1 - a1w) * (1 - a2w)
            # np.dot (BLAS, as numpy's ``xi @ L`` in step()): the same summation order, the same bits
            lv, kv = np.dot(xi, Lv), np.dot(xi, Kv)
            l1, l2, k1, k2 = lv[0], lv[1], kv[0], kv[1]
            A0, A1, A2, A3, b1, b2 = _a_b(par, rho1, rho2)
            if s[1] == 0.0:
                nh[0] = 0
            if nh[0] == 3:
                hist[0, :] = hist[1, :]
                hist[1, :] = hist[2, :]
                nh[0] = 2
            e = hist[nh[0]]
            e[0], e[1], e[2], e[3] = zeta_eta[0], zeta_eta[1], zeta_eta[2], zeta_eta[3]
            e[4], e[5], e[6], e[7] = A0, A1 - l1, A2, A3 - l2
            e[8], e[9], e[10], e[11] = A0, A1 - k1, A2, A3 - k2
            e[12], e[13], e[14], e[15], e[16], e[17] = l1, l2, k1, k2, 0.0, 0.0
            nh[0] += 1
            if s[1] >= 2.0:
                # (2.11c) and the bounds (2.24)-(2.25) from the steps k-1 (hist[1]), k-2 (hist[0])
                zk0, zk1, ek0, ek1 = hist[2, 0], hist[2, 1], hist[2, 2], hist[2, 3]
                h2, h1 = hist[0], hist[1]
                ML2, MK2, ML1, MK1 = h2[4:8], h2[8:12], h1[4:8], h1[8:12]
                iPL, iPK = _inv(_mul(ML1, ML2)), _inv(_mul(MK1, MK2))
                E = iPL - iPK
                a0, a1 = _mv(iPL, zk0, zk1)
                c0, c1 = _mv(iPK, ek0, ek1)
                xh0, xh1 = _solve(E, a0 - c0 + h2[2] - h2[0], a1 - c1 + h2[3] - h2[1])
                if not bounded:
                    s[6], s[7], s[2], s[3], s[4], s[5] = xh0, xh1, xh0, xh1, xh0, xh1
                else:
                    iE = _inv(E)
                    G2 = _mul(iE, _inv(ML2) - _inv(MK2))
                    w0 = h1[16] + abs(G2[0]) * h2[16] + abs(G2[1]) * h2[17]
                    w1 = h1[17] + abs(G2[2]) * h2[16] + abs(G2[3]) * h2[17]
                    if nu > 0.0:
                        p0, p1 = _mv(iPL, h1[12], h1[13])
                        q0, q1 = _mv(iPK, h1[14], h1[15])
                        g10, g11 = _mv(iE, p0 - q0, p1 - q1)
                        p0, p1 = _solve(ML2, h2[12], h2[13])
                        q0, q1 = _solve(MK2, h2[14], h2[15])
                        g20, g21 = _mv(iE, p0 - q0, p1 - q1)
                        w0 += (abs(g10) + abs(g20)) * nu
                        w1 += (abs(g11) + abs(g21)) * nu
                    lo0, lo1 = max(xh0 - w0, -bmax), max(xh1 - w1, r - nu)
                    hi0, hi1 = min(xh0 + w0, bmax), min(xh1 + w1, r + nu)
                    if lo0 > hi0 or lo1 > hi1:
                        lo0, lo1, hi0, hi1 = xh0 - w0, xh1 - w1, xh0 + w0, xh1 + w1
                    s[6], s[7] = 0.5 * (lo0 + hi0), 0.5 * (lo1 + hi1)
                    s[2], s[3], s[4], s[5] = lo0, lo1, hi0, hi1
            else:
                _prior(s, r, bmax, nu)
            # vbar of this step from the bounds just computed (see _FiniteTime._vbar)
            blo, bhi = max(s[2], -bmax), min(s[4], bmax)
            e[16] = ts / m * (dcf * (_mx(rho1 * delta - lf * rho2 * r, -rho1, blo, bhi) + lf * rho2 * nu)
                              + dcr * (_mx(lr * rho2 * r, -rho1, blo, bhi) + lr * rho2 * nu))
            e[17] = ts / iz * (dcf * (_mx(lf * delta - lf * lf * rho1 * r, -lf, blo, bhi) + lf * lf * rho1 * nu)
                               + dcr * (_mx(-lr * lr * rho1 * r, lr, blo, bhi) + lr * lr * rho1 * nu))
            z1, z2 = _mv(e[4:8], zeta_eta[0], zeta_eta[1])
            e1, e2 = _mv(e[8:12], zeta_eta[2], zeta_eta[3])
            zeta_eta[0], zeta_eta[1] = z1 + b1 * delta + l1 * r, z2 + b2 * delta + l2 * r
            zeta_eta[2], zeta_eta[3] = e1 + b1 * delta + k1 * r, e2 + b2 * delta + k2 * r
            s[1] += 1.0
        out[i, 0], out[i, 1] = s[6], s[7]
        out[i, 2], out[i, 3], out[i, 4], out[i, 5] = s[2], s[3], s[4], s[5]
    return out, n


@jit
def efimov_run(t: np.ndarray, Y: np.ndarray, u: np.ndarray, tl: np.ndarray, s: np.ndarray,
               box: np.ndarray, par: np.ndarray, l1: float, l2: float, have_gains: bool) -> tuple[np.ndarray, int]:
    """``IntervalEfimovLPV._advance`` over a run: ``(out (n, 6) = x, lo, hi, rows done)``.

    ``box`` (5,) = ``(set, beta_lo, r_lo, beta_hi, r_hi)`` (``set = 0``: no box yet)."""
    n = t.shape[0]
    out = np.empty((n, 6))
    m, iz, lf, lr, ts = par[0], par[1], par[2], par[3], par[6]
    bmax, nu, dcf, dcr = par[14], par[15], par[16], par[17]
    for i in range(n):
        ts_now = t[i]
        tick = _clock(ts_now, Y, i, u, tl, s, par)
        if tick == 2:
            if not have_gains:
                return out, i
            r, delta, vx = u[0], u[1], u[2]
            rho1, rho2 = 1.0 / vx, 1.0 / (vx * vx)
            if s[1] == 0.0 or box[0] == 0.0:
                box[0], box[1], box[2], box[3], box[4] = 1.0, -bmax, r - nu, bmax, r + nu
            xl0, xl1, xh0, xh1 = box[1], box[2], box[3], box[4]
            s[2], s[3], s[4], s[5] = xl0, xl1, xh0, xh1
            s[6], s[7] = 0.5 * (xl0 + xh0), 0.5 * (xl1 + xh1)
            A0, A1, A2, A3, b1, b2 = _a_b(par, rho1, rho2)
            M = np.array([A0, A1 - l1, A2, A3 - l2])
            h0 = ts * ((dcf + dcr) / m * rho1)
            h1 = ts * ((dcr * lr + dcf * lf) / m * rho2)
            h2 = ts * ((dcr * lr + dcf * lf) / iz)
            h3 = ts * ((dcr * lr ** 2 + dcf * lf ** 2) / iz * rho1)
            s0 = max(xh0, 0.0) + max(-xl0, 0.0)
            s1 = max(xh1, 0.0) + max(-xl1, 0.0)
            up0, up1 = h0 * s0 + h1 * s1, h2 * s0 + h3 * s1
            dB0 = ts * dcf * abs(delta) * rho1 / m
            dB1 = ts * dcf * abs(delta) * lf / iz
            ml0, ml1 = _mv(M, xl0, xl1)
            mh0, mh1 = _mv(M, xh0, xh1)
            base0, base1 = b1 * delta + l1 * r, b2 * delta + l2 * r
            n1, n2 = abs(l1) * nu, abs(l2) * nu
            box[1], box[2] = ml0 + base0 - up0 - dB0 - n1, ml1 + base1 - up1 - dB1 - n2
            box[3], box[4] = mh0 + base0 + up0 + dB0 + n1, mh1 + base1 + up1 + dB1 + n2
            s[1] += 1.0
        out[i, 0], out[i, 1] = s[6], s[7]
        out[i, 2], out[i, 3], out[i, 4], out[i, 5] = s[2], s[3], s[4], s[5]
    return out, n


def run_compiled(obs: _BicycleLPVObserver, t: np.ndarray, Y: np.ndarray,
                 x0: Mapping[str, float] | None) -> EstimateTrack:
    """``obs.run`` through the kernels above; leaves ``obs`` in the state stepping would leave it in."""
    from roadtruth.observers import finite_time_interval as fti
    from roadtruth.observers.base import EstimateTrack
    from roadtruth.observers.lmi import DesignFailed, usable_gains

    assert fti.R_PRIOR_RADPS == R_PRIOR
    t = np.ascontiguousarray(t, dtype=float)
    Y = np.ascontiguousarray(np.asarray(Y, dtype=float).reshape(len(t), len(obs.inputs)))
    n = len(t)
    if n:
        obs.reset(float(t[0]), x0)
    md = obs.model
    par = np.array([md.mass_kg, md.yaw_inertia_kgm2, md.lf_m, md.lr_m, md.cf_Npr, md.cr_Npr, md.ts_s,
                    *md.rho1_range, *md.rho2_range, obs._vlo, obs._vhi, obs._hold, obs._bmax, obs._nu,
                    obs._dcf, obs._dcr])
    u = np.array(obs._u, dtype=float)
    tl = np.array(obs._t_last, dtype=float)
    s = np.array([obs._next, float(obs._count), *obs._lo, *obs._hi, *obs._x])
    failure: DesignFailed | None = None
    if isinstance(obs, fti._FiniteTime):
        try:
            Lv, Kv = obs.gains()
        except DesignFailed as exc:   # raised at the first discrete step, as step() raises it
            failure, Lv, Kv = exc, np.zeros((4, 2)), np.zeros((4, 2))
        ze = np.array([*obs._zeta, *obs._eta])
        hist = np.zeros((3, 18))
        for j, e in enumerate(obs._hist):
            hist[j] = [x for part in e for x in part]
        nh = np.array([len(obs._hist)], dtype=np.int64)
        out, done = finite_time_run(t, Y, u, tl, s, ze, hist, nh, par, np.ascontiguousarray(Lv, dtype=float),
                                    np.ascontiguousarray(Kv, dtype=float), obs.bounded, failure is None)
        obs._zeta, obs._eta = (float(ze[0]), float(ze[1])), (float(ze[2]), float(ze[3]))
        obs._hist = [tuple(tuple(float(x) for x in row[a:b]) for a, b in
                           ((0, 2), (2, 4), (4, 8), (8, 12), (12, 14), (14, 16), (16, 18)))
                     for row in hist[: int(nh[0])]]
    else:
        try:
            if obs._gains is None:
                obs._gains = usable_gains(obs.name, obs.design(), ("L",))
            l1, l2 = obs._gains
        except DesignFailed as exc:
            failure, l1, l2 = exc, 0.0, 0.0
        box = np.zeros(5) if obs._box is None else np.array([1.0, *obs._box])
        out, done = efimov_run(t, Y, u, tl, s, box, par, float(l1), float(l2), failure is None)
        obs._box = None if box[0] == 0.0 else box[1:].tolist()
    obs._u = u.tolist()
    obs._t_last = tl.tolist()
    obs._fresh = (Y[done - 1] == Y[done - 1]).tolist() if done else obs._fresh
    if done:
        obs._t = max(obs._t, float(np.max(t[:done])))
    obs._next, obs._count = float(s[0]), int(s[1])
    obs._lo, obs._hi, obs._x = s[2:4].tolist(), s[4:6].tolist(), s[6:8].tolist()
    if failure is not None and done < n:
        raise failure
    bounds = obs.has_bounds
    return EstimateTrack(obs.name, tuple(obs.states), t, out[:, 0:2].copy(),
                         out[:, 2:4].copy() if bounds else None, out[:, 4:6].copy() if bounds else None)
