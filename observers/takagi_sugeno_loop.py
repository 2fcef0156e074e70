"""The compiled kernel of the Takagi-Sugeno observers (:mod:`roadtruth.observers.takagi_sugeno`), shared by step() and run().

:func:`ts_run` is the observers' whole per-sample update (latching the inputs as the zero-order hold
of ``ScalarLoopObserver._tick``, the Levant differentiators of the camera at its own rate, the
algebraic premise ``v_y`` (26) and curvature (11), the premise choice, the rule memberships from the
Magic Formula secants, the exact ZOH step :func:`ts_step` and the derived outputs (46)) on arrays
carried between calls. ``step()`` calls it with one sample and ``run()`` with the whole log, so both
execute the same compiled code and agree bit for bit (``tests/test_observers_takagi_sugeno.py``).

Carried state: ``u`` (5,) held ``(r, delta, v_x, y_L, psi_L)``; ``x`` (4,) the TS state; ``s`` =
``(t_cur, t_cam, t_cam_start, v_y_alg, rho, premise_is_camera, t_gyro)`` (latest camera sample, when
the differentiators were (re)started, the algebraic premise (NaN until trusted), the curvature, the
premise of the latest step, arrival of the latest gyro sample); ``dy``, ``dp`` the differentiators of
``y_L``, ``psi_L`` and ``lev`` their constants (:mod:`roadtruth.observers.algebraic_vy_loop`).
``par`` = ``(v_lo, v_hi, a_f, a_r, M_f1, M_f2, M_r1, M_r2, m, I_z, l_s, camera_timeout_s,
differentiator_settle_s, hold_s, heading_at_cg, as_printed, premise_from_camera)`` (:data:`N_PAR`
floats); ``curves`` (8,) the Magic Formula ``(B, C, E, D)`` of the front and rear axle; ``Av`` (8, 4,
4), ``Bv`` (8, 4), ``Lv`` (8, 4) the vertices and gains; ``w`` (8,) scratch.

numba caches each kernel per source file: after editing this file (or ``algebraic_vy_loop.py``)
delete ``observers/__pycache__/takagi_sugeno_loop*.nbi, *.nbc``.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit
from roadtruth.observers.algebraic_vy_loop import levant_reset, levant_update
from roadtruth.observers.takagi_sugeno_design import secant_slope

N_PAR = 17
_secant = jit(secant_slope)


@jit
def expm_taylor(M: np.ndarray) -> np.ndarray:
    """``exp(M)`` of a small square matrix: scaling and squaring with an order-12 Taylor series."""
    n = M.shape[0]
    norm = 0.0
    for j in range(n):
        s = 0.0
        for i in range(n):
            s += abs(M[i, j])
        norm = max(norm, s)
    sq = 0
    while norm > 0.25:
        norm *= 0.5
        sq += 1
    A = M * (0.5 ** sq)
    E = np.eye(n)
    T = np.eye(n)
    for k in range(1, 13):
        T = T @ A / k
        E = E + T
    for _ in range(sq):
        E = E @ E
    return E


@jit
def rule_weights(mv1: float, mf1: float, mr1: float, as_printed: bool, w: np.ndarray) -> None:
    """Fill ``w`` (8,) with ``h_i = mu_vl mu_fj mu_rk`` in the order of ``RULES`` (memberships of the
    first vertices given, clipped to [0, 1]); ``as_printed`` swaps rules (1,2)<->(2,1) as eq. (22)."""
    mv1 = min(max(mv1, 0.0), 1.0)
    mf1 = min(max(mf1, 0.0), 1.0)
    mr1 = min(max(mr1, 0.0), 1.0)
    i = 0
    for l in range(2):
        mv = mv1 if l == 0 else 1.0 - mv1
        for j in range(2):
            mf = mf1 if j == 0 else 1.0 - mf1
            for k in range(2):
                mr = mr1 if k == 0 else 1.0 - mr1
                w[i] = mv * mf * mr
                i += 1
    if as_printed:
        for base in (0, 4):
            a = w[base + 1]
            w[base + 1] = w[base + 2]
            w[base + 2] = a


@jit
def ts_step(x: np.ndarray, h: float, mv1: float, mf1: float, mr1: float, as_printed: bool, delta: float,
            r_meas: float, correct: bool, Av: np.ndarray, Bv: np.ndarray, Lv: np.ndarray, w: np.ndarray) -> None:
    """Advance ``x`` (4,) in place by ``h`` [s]: exact ZOH of ``x' = Phi x + g``.

    Weights ``w`` (8,, scratch, filled by :func:`rule_weights` from the memberships), then
    ``Phi = sum w_i (A_i - L_i C)``, ``g = sum w_i (B_i delta + L_i r_meas)`` (``L = 0`` unless
    ``correct``); ``Av`` (8, 4, 4), ``Bv`` (8, 4), ``Lv`` (8, 4). Uses the augmented exponential
    ``exp([[Phi, g], [0, 0]] h)``.
    """
    rule_weights(mv1, mf1, mr1, as_printed, w)
    M = np.zeros((5, 5))
    for i in range(w.shape[0]):
        wi = w[i]
        if wi == 0.0:
            continue
        for a in range(4):
            for b in range(4):
                M[a, b] += wi * Av[i, a, b]
            M[a, 4] += wi * Bv[i, a] * delta
            if correct:
                M[a, 1] -= wi * Lv[i, a]
                M[a, 4] += wi * Lv[i, a] * r_meas
    E = expm_taylor(M * h)
    x0, x1, x2, x3 = x[0], x[1], x[2], x[3]
    for a in range(4):
        x[a] = E[a, 0] * x0 + E[a, 1] * x1 + E[a, 2] * x2 + E[a, 3] * x3 + E[a, 4]


@jit
def _camera(ts: float, yl: float, pl: float, r: float, vx: float, s: np.ndarray, dy: np.ndarray, dp: np.ndarray,
            lev: np.ndarray, p: np.ndarray) -> None:
    """A camera sample: step (or re-arm) the differentiators, then the algebraic ``v_y`` (26) and ``rho`` (11)."""
    vlo, ls, timeout, settle, cg = p[0], p[10], p[11], p[12], p[14] != 0.0
    tau = ts - s[1]
    if tau > timeout or dy[0] == 0.0:
        levant_reset(dy, yl)
        levant_reset(dp, pl)
        s[2] = ts
    else:
        levant_update(dy, yl, tau, lev[0], lev[2], lev[3])
        levant_update(dp, pl, tau, lev[1], lev[2], lev[3])
    s[1] = ts
    if ts - s[2] < settle or vx != vx:
        return
    dyl, dpsi = dy[3], dp[3]
    if cg:
        s[3] = dyl - vx * pl - ls * dpsi          # (26) as printed
    elif r == r:
        s[3] = dyl - vx * pl - ls * r             # (26), camera convention
    if r == r and vx >= vlo:
        s[4] = (r - dpsi) / vx                    # (11)


@jit
def ts_run(t: np.ndarray, Y: np.ndarray, u: np.ndarray, x: np.ndarray, s: np.ndarray, dy: np.ndarray,
           dp: np.ndarray, lev: np.ndarray, p: np.ndarray, curves: np.ndarray, Av: np.ndarray, Bv: np.ndarray,
           Lv: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """The TS observer over ``t`` (n,) [s], ``Y`` (n, 5); writes ``(v_y, r, beta, F_f, F_r, rho)`` to
    ``out`` (n, 6) (state arrays: module docstring)."""
    vlo, vhi, af_m, ar_m = p[0], p[1], p[2], p[3]
    mf1, mf2, mr1, mr2, m, iz = p[4], p[5], p[6], p[7], p[8], p[9]
    timeout, settle, hold = p[11], p[12], p[13]
    printed, from_camera = p[15] != 0.0, p[16] != 0.0
    for i in range(t.shape[0]):
        ts = t[i]
        for j in range(5):
            v = Y[i, j]
            if v == v:
                u[j] = v
        if Y[i, 0] == Y[i, 0]:
            s[6] = ts
        h = ts - s[0]
        if h > 0.0:
            s[0] = ts
        else:
            h = 0.0
        r, delta, vx, yl, pl = u[0], u[1], u[2], u[3], u[4]
        if Y[i, 3] == Y[i, 3] and Y[i, 4] == Y[i, 4]:
            _camera(ts, yl, pl, r, vx, s, dy, dp, lev, p)
        if h > 0.0 and delta == delta and vx == vx:
            vc = vlo if vx < vlo else (vhi if vx > vhi else vx)
            correct = r == r and ts - s[6] <= hold
            rp = r if r == r else x[1]
            if from_camera and ts - s[2] >= settle and ts - s[1] <= timeout and s[3] == s[3]:
                vy_p = s[3]
                s[5] = 1.0
            else:
                vy_p = x[0]   # unmeasured premise h_i(x_hat)
                s[5] = 0.0
            af = delta - (vy_p + af_m * rp) / vc   # (4)
            ar = -(vy_p - ar_m * rp) / vc
            ff = _secant(af, curves[0], curves[1], curves[2], curves[3])
            fr = _secant(ar, curves[4], curves[5], curves[6], curves[7])
            ts_step(x, h, (vc - vlo) / (vhi - vlo), (ff - mf2) / (mf1 - mf2), (fr - mr2) / (mr1 - mr2),
                    printed, delta, r if correct else 0.0, correct, Av, Bv, Lv, w)
        out[i, 0], out[i, 1] = x[0], x[1]
        out[i, 2] = math.atan2(x[0], vx) if vx == vx and vx > 0.1 else 0.0
        out[i, 3] = (m * ar_m * x[2] + iz * x[3]) / (af_m + ar_m)   # (46)
        out[i, 4] = (m * af_m * x[2] - iz * x[3]) / (af_m + ar_m)
        out[i, 5] = s[4]
