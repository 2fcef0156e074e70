"""The compiled kernel of the algebraic camera ``v_y`` (:mod:`roadtruth.observers.algebraic_vy`), shared by step() and run().

:func:`algebraic_run` is the estimator's whole per-sample update (latching the inputs as the
zero-order hold of ``ScalarLoopObserver._tick``, the two Levant differentiators stepped at the
camera's own rate, their re-arming after a camera gap, the settle and timeout rules, the algebraic
``v_y`` and ``beta``) on arrays carried between calls. ``step()`` calls it with one sample and
``run()`` with the whole log, so both execute the same compiled code and agree bit for bit
(``tests/test_observers_pi_algebraic.py``).

:func:`levant_reset` / :func:`levant_update` are the compiled twin of
:class:`roadtruth.observers.levant_differentiator.LevantDifferentiator` (same operations in the same
order, tested equal); the Takagi-Sugeno kernel uses them too. A differentiator's state is one array
``d`` = ``(initialized, f_prev, z_0, ..., z_k)``; its constants a row of gains ``g`` (k+1,) and the
rows ``ex`` = ``((k-i)/(k+1))_i`` and ``fa`` = ``(1/s!)_s`` (:func:`levant_table`).

Carried state of :func:`algebraic_run`: ``u`` (4,) held ``(r, v_x, y_L, psi_L)``; ``s`` =
``(t_cur, t_cam, t_start, v_y)`` (time of the latest camera sample, when the differentiators were
(re)started, the latest estimate); ``dy``, ``dp`` the differentiators of ``y_L`` and ``psi_L``.
``lev`` (4, k+1) = rows ``(g_y, g_psi, ex, fa)``; ``par`` = ``(l_s, camera_timeout_s,
differentiator_settle_s, heading_at_cg)`` (:data:`N_PAR` floats).

numba caches each kernel per source file: after editing this file delete
``observers/__pycache__/algebraic_vy_loop*.nbi, *.nbc`` (and ``takagi_sugeno_loop*``, which calls it).
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit
from roadtruth.observers.levant_differentiator import levant_gains

N_PAR = 4


def levant_table(order: int, lipschitz_a: float, lipschitz_b: float) -> np.ndarray:
    """Constants of two order-``order`` differentiators: rows ``(g_a, g_b, ex, fa)``, shape (4, k+1)."""
    k = int(order)
    return np.array([levant_gains(k, float(lipschitz_a)), levant_gains(k, float(lipschitz_b)),
                     [(k - i) / (k + 1) for i in range(k + 1)], [1.0 / math.factorial(s) for s in range(k + 1)]])


@jit
def levant_reset(d: np.ndarray, f0: float) -> None:
    """Start the differentiator ``d`` at ``z = (f0, 0, ..., 0)`` (``LevantDifferentiator.reset(f0)``)."""
    d[:] = 0.0
    d[0] = 1.0
    d[1] = f0
    d[2] = f0


@jit
def levant_update(d: np.ndarray, f: float, tau: float, g: np.ndarray, ex: np.ndarray, fa: np.ndarray) -> None:
    """Feed sample ``f`` taken ``tau`` [s] after the previous one (``LevantDifferentiator.update``, the
    Livne-Levant explicit step); in place. ``z_i`` only needs ``z_j, j >= i``, so ascending i is exact."""
    if d[0] == 0.0:
        levant_reset(d, f)
        return
    f_prev = d[1]
    d[1] = f
    if tau <= 0.0:
        return
    k = g.shape[0] - 1
    e = d[2] - f_prev
    ae = abs(e)
    sg = 1.0 if e > 0.0 else (-1.0 if e < 0.0 else 0.0)
    for i in range(k + 1):
        if i < k:
            dz = -g[i] * (ae ** ex[i]) * sg
            dz += d[3 + i]
        else:
            dz = -g[k] * sg
        zi = d[2 + i] + tau * dz
        ts = tau
        for s in range(2, k - i + 1):
            ts *= tau
            zi += d[2 + i + s] * ts * fa[s]
        d[2 + i] = zi


@jit
def algebraic_run(t: np.ndarray, Y: np.ndarray, u: np.ndarray, s: np.ndarray, dy: np.ndarray, dp: np.ndarray,
                  lev: np.ndarray, p: np.ndarray, x: np.ndarray) -> None:
    """The algebraic ``v_y`` over ``t`` (n,) [s], ``Y`` (n, 4); writes ``(v_y, beta)`` to ``x`` (n, 2),
    NaN where there is no estimate (state arrays: module docstring)."""
    ls, timeout, settle, cg = p[0], p[1], p[2], p[3] != 0.0
    for i in range(t.shape[0]):
        ts = t[i]
        camera = True
        for j in range(4):
            v = Y[i, j]
            if v == v:
                u[j] = v
            elif j >= 2:
                camera = False   # both lane channels must be fresh
        if ts - s[0] > 0.0:
            s[0] = ts
        r, vx, yl, pl = u[0], u[1], u[2], u[3]
        if camera:
            tau = ts - s[1]
            if tau > timeout or dy[0] == 0.0:
                # camera silent too long (or first sample): re-arm the differentiators
                levant_reset(dy, yl)
                levant_reset(dp, pl)
                s[2] = ts
            else:
                levant_update(dy, yl, tau, lev[0], lev[2], lev[3])
                levant_update(dp, pl, tau, lev[1], lev[2], lev[3])
            s[1] = ts
        if not (ts - s[2] >= settle and ts - s[1] <= timeout and vx == vx):
            vy = math.nan
        elif cg:
            vy = dy[3] - vx * pl - ls * dp[3]                            # (26) as printed
        elif r == r:
            vy = (dy[3] - vx * math.sin(pl)) / math.cos(pl) - ls * r    # exact, look-ahead heading
        else:
            vy = math.nan
        s[3] = vy
        x[i, 0] = vy
        x[i, 1] = math.atan2(vy, vx) if vy == vy and vx == vx and vx > 0.1 else math.nan
