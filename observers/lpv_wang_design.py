r"""LMI designs of Wang's (2014) LPV slip-angle observer (see :mod:`roadtruth.observers.lpv_wang`).

Nominal (3.27) with a decay rate ``sigma``: find ``P = P^T >= I`` and ``Q0, Q1, Q2`` with, at the 4
vertices of Lemma 9, ``He(P A(theta) - Q(theta) C) + 2 sigma P < 0``, ``L_i = P^-1 Q_i``. Then
``V = e^T P e`` decays at least as ``exp(-2 sigma t)`` for any variation of theta inside the polytope.
Since ``L = 0`` already satisfies the LMI with sigma = 0 (the plant is stable), sigma is chosen as
``decay_fraction`` x the largest rate achievable with gains bounded by ``||L(theta_k)|| <= max_gain``
(bisection on sigma; the problem is quasi-convex). For an exactly neutral-steer car that largest rate
is the open-loop rate of the unobservable common-slip mode, ``min ((C_f + C_r)/m + a_x)/v_x``.

H-infinity (3.43) on the 16 vertices of Lemma 10: minimise gamma subject to
``[[He(P A_L), P B_L, I], [B_L^T P, -gamma I5, 0], [I, 0, -gamma I2]] < 0`` with
``P A_L = P A(theta) - Q(theta_m) C`` (observer scheduled on the measured ``theta_m = theta - dtheta``)
and ``B_L = [dtheta1 A1 + dtheta2 A2, dtheta2 B2]``; then, at ``gamma <= gamma_slack * gamma*``, the
smallest ``sum ||Q_i||_F`` (the optimum is flat; this makes the gains reproducible and moderate).

Printed gains are evaluated, not solved: the largest certified decay rate (nominal) or the smallest
certified gamma (H-infinity) for the given L, then the same NumPy certification.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

import roadtruth.harness as harness
from roadtruth.observers import bicycle, lmi
from roadtruth.observers.lmi import (
    DesignRequest,
    DesignResult,
    DesignStatus,
    SolverSettings,
    certify_design,
    physical_grid,
    robust_vertices,
    solve_lmi,
    sym,
    trapezoid_vertices,
)

C = np.array([[1.0, -1.0]])
B2 = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
I2 = np.eye(2)
P_MAX = 1e4  # conditioning bound on P in the decay-rate problems
#: Options that change how the observer runs, not its design (left out of the design cache key).
RUN_ONLY_OPTIONS = ("hold_s", "vx_min_output_mps", "use_cache", "scheduling_error")

#: Gains printed in sec. 3.3 of the dissertation (for its 800 kg car, speeds in m/s).
PRINTED_GAINS: dict[str, dict[str, list[list[float]]]] = {
    "nominal_printed": {"L0": [[0.0477], [0.0477]], "L1": [[-65.7731], [-63.7411]], "L2": [[-0.4363], [-0.4363]]},
    "hinf_printed": {"L0": [[390.3628], [376.0443]], "L1": [[941.1064], [908.2782]],
                     "L2": [[104.0730], [100.1726]]},
}


def design_for(req: DesignRequest) -> DesignResult:
    """Cached design for an observer's request (its vehicle, variant and options)."""
    v = req.vehicle
    cf, cr = bicycle.axle_stiffness(v)
    opts = {k: val for k, val in req.options.items() if k not in RUN_ONLY_OPTIONS}
    settings = SolverSettings()
    payload = {
        "family": "lpv_wang", "variant": req.variant, "options": opts, "solver": settings.to_dict(),
        "vehicle": {"mass_kg": v.mass_kg, "yaw_inertia_kgm2": v.yaw_inertia_kgm2, "lf_m": v.lf_m, "lr_m": v.lr_m,
                    "cf_Npr": cf, "cr_Npr": cr},
        "code": [harness.__version__, lmi.source_fingerprint(lmi, bicycle, design_for)],
    }
    A1, _ = bicycle.slip_model_terms(v)
    return lmi.cached_design(payload, lambda: design(req.variant, A1, opts, settings),
                             use_cache=bool(req.options["use_cache"]))


def design(variant: str, A1: np.ndarray, opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    """Solve (or evaluate) and certify one variant for the slip model ``A1`` (2, 2) [1/m]."""
    v_rng, a_rng = tuple(opts["vx_range_mps"]), tuple(opts["ax_range_mps2"])
    if variant in ("nominal", "nominal_printed"):
        return _nominal(variant, A1, v_rng, a_rng, opts, settings)
    if variant in ("hinf", "hinf_printed"):
        return _hinf(variant, A1, v_rng, a_rng, opts, settings)
    raise ValueError(f"unknown lpv_wang variant {variant!r}")


def _gain_at(L: list[np.ndarray], th1: float, th2: float) -> np.ndarray:
    return L[0] + th1 * L[1] + th2 * L[2]


def _to_gains(L: list[np.ndarray]) -> dict[str, list[Any]]:
    return {f"L{i}": np.asarray(Li, dtype=float).reshape(2, 1).tolist() for i, Li in enumerate(L)}


def _finish(variant: str, cert: lmi.Certificate, L: list[np.ndarray], P: np.ndarray | None,
            extra: dict[str, float], stats: dict[str, Any], gamma: float | None = None,
            prefix: str = "") -> DesignResult:
    status = DesignStatus.CERTIFIED if cert.certified else DesignStatus.REJECTED
    reason = (prefix + cert.reason) if cert.certified else (prefix + "certification failed: " + cert.reason)
    return DesignResult(status, cert.certified, reason, _to_gains(L), None if P is None else P.tolist(),
                        {**cert.margins, **extra}, gamma, stats, variant)


# ---- nominal: decay rate -------------------------------------------------------------------------

def _decay_problem(A1: np.ndarray, verts: np.ndarray, settings: SolverSettings, *, fixed_L: list[np.ndarray] | None,
                   max_gain: float | None, min_norm: bool) -> tuple[Any, Any, dict[str, Any]]:
    import cvxpy as cp

    sigma = cp.Parameter(nonneg=True)
    P = cp.Variable((2, 2), symmetric=True)
    Q = None if fixed_L is not None else [cp.Variable((2, 1)) for _ in range(3)]
    eps = settings.strictness
    cons = [P >> I2, P << P_MAX * I2]
    for th1, th2 in verts:
        A = th1 * A1 - th2 * I2
        if Q is None:
            M = P @ (A - _gain_at(fixed_L, th1, th2) @ C)  # type: ignore[arg-type]
        else:
            Qt = Q[0] + th1 * Q[1] + th2 * Q[2]
            M = P @ A - Qt @ C
            if max_gain is not None:
                cons.append(cp.norm(cp.vec(Qt, order="F"), 2) <= max_gain)
        cons.append(sym(M + M.T + 2 * sigma * P) << -eps * I2)
    objective = cp.Minimize(sum(cp.norm(Qi, "fro") for Qi in Q)) if (Q is not None and min_norm) else cp.Minimize(0)
    exprs = {"P": P} | ({} if Q is None else {f"Q{i}": Qi for i, Qi in enumerate(Q)})
    return cp.Problem(objective, cons), sigma, exprs


def max_decay_rate(A1: np.ndarray, verts: np.ndarray, settings: SolverSettings, *,
                   fixed_L: list[np.ndarray] | None = None, max_gain: float | None = None,
                   rel_tol: float = 2e-3, cap: float = 256.0) -> tuple[float | None, dict[str, np.ndarray]]:
    """Largest sigma [1/s] for which the decay LMI is feasible (bisection), and the values there.

    Returns ``(None, {})`` when even sigma = 0 is infeasible.
    """
    import cvxpy as cp

    problem, sigma, exprs = _decay_problem(A1, verts, settings, fixed_L=fixed_L, max_gain=max_gain, min_norm=False)

    def feasible(s: float) -> dict[str, np.ndarray] | None:
        sigma.value = s
        try:
            problem.solve(solver=cp.CLARABEL, tol_gap_abs=settings.tol, tol_gap_rel=settings.tol,
                          tol_feas=settings.tol)
        except cp.error.SolverError:
            return None
        if problem.status != cp.OPTIMAL:
            return None
        return {k: np.asarray(e.value, dtype=float) for k, e in exprs.items()}

    best = feasible(0.0)
    if best is None:
        return None, {}
    lo, hi = 0.0, 1.0
    while hi <= cap:
        vals = feasible(hi)
        if vals is None:
            break
        lo, best, hi = hi, vals, 2.0 * hi
    hi = min(hi, cap)
    while hi - lo > rel_tol * hi:
        mid = 0.5 * (lo + hi)
        vals = feasible(mid)
        if vals is None:
            hi = mid
        else:
            lo, best = mid, vals
    return lo, best


def _decay_checks(A1: np.ndarray, L: list[np.ndarray], P: np.ndarray, sigma: float
                  ) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray]]:
    def closed(th: np.ndarray) -> np.ndarray:
        return th[0] * A1 - th[1] * I2 - _gain_at(L, th[0], th[1]) @ C

    def lyap(th: np.ndarray) -> np.ndarray:
        AL = closed(th)
        return AL.T @ P + P @ AL + 2.0 * sigma * P

    return lyap, closed


def _nominal(variant: str, A1: np.ndarray, v_rng: tuple[float, float], a_rng: tuple[float, float],
             opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    verts = trapezoid_vertices(v_rng, a_rng)
    g = physical_grid([v_rng, a_rng], (25, 9))
    grid = np.column_stack([1.0 / g[:, 0], g[:, 1] / g[:, 0]])
    zero = [np.zeros((2, 1))] * 3
    sigma_ol, _ = max_decay_rate(A1, verts, settings, fixed_L=zero)
    extra: dict[str, float] = {"open_loop_decay_rate_radps": sigma_ol if sigma_ol is not None else float("nan")}
    if variant == "nominal_printed":
        L = [np.asarray(PRINTED_GAINS[variant][k], dtype=float) for k in ("L0", "L1", "L2")]
        sig, vals = max_decay_rate(A1, verts, settings, fixed_L=L)
        if sig is None:
            lyap, closed = _decay_checks(A1, L, I2, 0.0)
            cert = certify_design(P=None, lmis={}, vertices=verts, grid=grid, closed_loop=closed,
                                  margin=settings.certify_margin)
            return DesignResult(DesignStatus.REJECTED, False,
                                "no common quadratic Lyapunov function for the printed gains (LMI infeasible); "
                                f"frozen check: {cert.reason}", _to_gains(L), None, {**cert.margins, **extra},
                                None, {}, variant)
        P = vals["P"]
        lyap, closed = _decay_checks(A1, L, P, sig)
        cert = certify_design(P=P, lmis={"lyapunov_decay": lyap}, vertices=verts, grid=grid, closed_loop=closed,
                              stability_rate=sig, margin=settings.certify_margin)
        return _finish(variant, cert, L, P, {**extra, "decay_rate_radps": sig}, {"solver": "CLARABEL bisection"},
                       prefix=f"printed gains, certified decay rate {sig:.4g} 1/s: ")
    max_gain = float(opts["max_gain_per_s"])
    sig_max, _ = max_decay_rate(A1, verts, settings, max_gain=max_gain)
    if sig_max is None:
        return DesignResult(DesignStatus.INFEASIBLE, False, "decay LMI infeasible even at sigma = 0",
                            margins=extra, variant=variant)
    extra["max_decay_rate_radps"] = sig_max
    sigma = opts["decay_rate_radps"]
    if sigma is None:
        # A fraction of the way from what L = 0 certifies to the best bounded-gain rate, so that the
        # design always uses the measurement (L = 0 is feasible below the open-loop rate).
        base = min(sigma_ol or 0.0, sig_max)
        sigma = base + float(opts["decay_fraction"]) * (sig_max - base)
    sigma = float(sigma)
    extra["decay_rate_radps"] = sigma

    def build() -> tuple[Any, dict[str, Any]]:
        problem, par, exprs = _decay_problem(A1, verts, settings, fixed_L=None, max_gain=max_gain, min_norm=True)
        par.value = sigma
        return problem, exprs

    out = solve_lmi(build, settings)
    if out.status != "optimal":
        st = DesignStatus.INFEASIBLE if out.status == "infeasible" else DesignStatus.SOLVER_FAILED
        return DesignResult(st, False, f"decay LMI at sigma = {sigma:.4g} 1/s: {out.status}", margins=extra,
                            solver_stats=out.stats, variant=variant)
    P = out.values["P"]
    L = [np.linalg.solve(P, out.values[f"Q{i}"].reshape(2, 1)) for i in range(3)]
    lyap, closed = _decay_checks(A1, L, P, sigma)
    cert = certify_design(P=P, lmis={"lyapunov_decay": lyap}, vertices=verts, grid=grid, closed_loop=closed,
                          stability_rate=sigma, margin=settings.certify_margin)
    return _finish(variant, cert, L, P, extra, out.stats, prefix=f"decay rate {sigma:.4g} 1/s: ")


# ---- robust H-infinity ---------------------------------------------------------------------------

def _hinf_blocks(A1: np.ndarray, pt: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    th1, th2, d1, d2 = pt
    A = th1 * A1 - th2 * I2
    BL = np.hstack([d1 * A1 - d2 * I2, d2 * B2])
    return A, BL, th1 - d1, th2 - d2


def _hinf_problem(A1: np.ndarray, verts: np.ndarray, settings: SolverSettings, *,
                  fixed_L: list[np.ndarray] | None, gamma_cap: float | None) -> tuple[Any, dict[str, Any]]:
    import cvxpy as cp

    P = cp.Variable((2, 2), symmetric=True)
    g = cp.Variable()
    Q = None if fixed_L is not None else [cp.Variable((2, 1)) for _ in range(3)]
    eps = settings.strictness
    cons = [P >> eps * I2]
    for pt in verts:
        A, BL, m1, m2 = _hinf_blocks(A1, pt)
        if Q is None:
            PAL = P @ (A - _gain_at(fixed_L, m1, m2) @ C)  # type: ignore[arg-type]
        else:
            PAL = P @ A - (Q[0] + m1 * Q[1] + m2 * Q[2]) @ C
        PBL = P @ BL
        blk = cp.bmat([[PAL + PAL.T, PBL, I2],
                       [PBL.T, -g * np.eye(5), np.zeros((5, 2))],
                       [I2, np.zeros((2, 5)), -g * I2]])
        cons.append(sym(blk) << -eps * np.eye(9))
    if gamma_cap is not None and Q is not None:
        cons.append(g <= gamma_cap)
        objective = cp.Minimize(sum(cp.norm(Qi, "fro") for Qi in Q))
    else:
        objective = cp.Minimize(g)
    exprs = {"P": P, "gamma": g} | ({} if Q is None else {f"Q{i}": Qi for i, Qi in enumerate(Q)})
    return cp.Problem(objective, cons), exprs


def _hinf_checks(A1: np.ndarray, L: list[np.ndarray], P: np.ndarray, gamma: float
                 ) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray]]:
    def closed(pt: np.ndarray) -> np.ndarray:
        A, _, m1, m2 = _hinf_blocks(A1, pt)
        return A - _gain_at(L, m1, m2) @ C

    def brl(pt: np.ndarray) -> np.ndarray:
        _, BL, _, _ = _hinf_blocks(A1, pt)
        PAL = P @ closed(pt)
        PBL = P @ BL
        return np.block([[PAL + PAL.T, PBL, I2], [PBL.T, -gamma * np.eye(5), np.zeros((5, 2))],
                         [I2, np.zeros((2, 5)), -gamma * I2]])

    return brl, closed


def _certify_hinf(A1: np.ndarray, L: list[np.ndarray], P: np.ndarray, gamma: float, verts: np.ndarray,
                  grid: np.ndarray, settings: SolverSettings) -> tuple[lmi.Certificate, float]:
    """Certify the bounded-real LMI at the solver's gamma, else at gamma inflated by 1 % or 10 %.

    A larger gamma only makes the LMI more negative (Schur complement), so certifying a slightly
    larger bound than the solver reported is sound; the certified value is the one returned.
    """
    cert = None
    for factor in (1.0, 1.01, 1.1):
        brl, closed = _hinf_checks(A1, L, P, gamma * factor)
        cert = certify_design(P=P, lmis={"bounded_real": brl}, vertices=verts, grid=grid, closed_loop=closed,
                              margin=settings.certify_margin)
        if cert.certified:
            return cert, gamma * factor
    assert cert is not None
    return cert, gamma


def _hinf(variant: str, A1: np.ndarray, v_rng: tuple[float, float], a_rng: tuple[float, float],
          opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    e1, e2 = tuple(opts["eps1_range"]), tuple(opts["eps2_range"])
    verts = robust_vertices(v_rng, a_rng, e1, e2)
    g = physical_grid([v_rng, a_rng, e1, e2], (9, 5, 3, 3))
    th1, th2 = 1.0 / g[:, 0], g[:, 1] / g[:, 0]
    grid = np.column_stack([th1, th2, g[:, 2] / (1 + g[:, 2]) * th1, (g[:, 2] - g[:, 3]) / (1 + g[:, 2]) * th2])
    zero = [np.zeros((2, 1))] * 3
    ol = solve_lmi(lambda: _hinf_problem(A1, verts, settings, fixed_L=zero, gamma_cap=None), settings)
    extra = {"gamma_open_loop": float(ol.values["gamma"][0]) if ol.status == "optimal" else float("nan")}
    if variant == "hinf_printed":
        L = [np.asarray(PRINTED_GAINS[variant][k], dtype=float) for k in ("L0", "L1", "L2")]
        out = solve_lmi(lambda: _hinf_problem(A1, verts, settings, fixed_L=L, gamma_cap=None), settings)
        if out.status != "optimal":
            return DesignResult(DesignStatus.REJECTED, False, f"printed gains: bounded-real LMI {out.status}",
                                _to_gains(L), None, extra, None, out.stats, variant)
        P, gamma = out.values["P"], float(out.values["gamma"][0])
        cert, gamma = _certify_hinf(A1, L, P, gamma, verts, grid, settings)
        return _finish(variant, cert, L, P, {**extra, "gamma": gamma}, out.stats, gamma,
                       prefix=f"printed gains, gamma = {gamma:.4g}: ")
    first = solve_lmi(lambda: _hinf_problem(A1, verts, settings, fixed_L=None, gamma_cap=None), settings)
    if first.status != "optimal":
        st = DesignStatus.INFEASIBLE if first.status == "infeasible" else DesignStatus.SOLVER_FAILED
        return DesignResult(st, False, f"H-infinity LMI: {first.status}", margins=extra,
                            solver_stats=first.stats, variant=variant)
    gamma_opt = float(first.values["gamma"][0])
    cap = float(opts["gamma_slack"]) * gamma_opt
    second = solve_lmi(lambda: _hinf_problem(A1, verts, settings, fixed_L=None, gamma_cap=cap), settings)
    out = second if second.status == "optimal" else first
    P = out.values["P"]
    L = [np.linalg.solve(P, out.values[f"Q{i}"].reshape(2, 1)) for i in range(3)]
    # Re-derive the smallest gamma these exact gains certify (the check then uses that gamma).
    ev = solve_lmi(lambda: _hinf_problem(A1, verts, settings, fixed_L=L, gamma_cap=None), settings)
    if ev.status == "optimal":
        P, gamma = ev.values["P"], float(ev.values["gamma"][0])
    else:
        gamma = float(out.values["gamma"][0])
    cert, gamma = _certify_hinf(A1, L, P, gamma, verts, grid, settings)
    stats = {"gamma_min": first.stats, "min_norm": second.stats, "evaluate": ev.stats}
    return _finish(variant, cert, L, P, {**extra, "gamma": gamma, "gamma_optimal": gamma_opt}, stats, gamma,
                   prefix=f"gamma = {gamma:.4g} (optimum {gamma_opt:.4g}): ")
