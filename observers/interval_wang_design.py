r"""LMI design of Wang's (2014) LPV interval observer (see :mod:`roadtruth.observers.interval_wang`).

Theorem 5 of the dissertation (4.32)-(4.35), over the ``4 eta x 4 xi = 16`` vertex pairs of
Lemma 14 (``A(eta, xi) = eta1 Bf0 diag(xi) - eta2 I`` is bilinear in ``eta = (1/v_x, a_x/v_x)`` and
``xi = (C_f, C_r)``, so every condition below is affine in each argument for the other fixed and the
vertex pairs suffice):

.. math::

    \min \gamma \ \text{s.t.}\ P = \mathrm{diag}(p_1, p_2) \succ 0,\quad
    \begin{bmatrix} \mathrm{He}(P A - Q(\eta) C) & P & I \\ P & -\gamma I & 0 \\ I & 0 & -\gamma I
    \end{bmatrix} \prec 0,\quad P A - Q(\eta) C\ \text{Metzler},

``Q(eta) = Q0 + eta1 Q1 + eta2 Q2``, ``L_i = P^-1 Q_i`` (Lemma 11: with diagonal P, ``P A_L`` is
Metzler iff ``A_L`` is). Metzler is imposed with a small positive margin so that the certificate's
exact ``>= 0`` check is not decided by round-off. The optimum is flat (the common-slip mode of a
neutral-steer car is unobservable), so a second solve takes the smallest ``sum ||Q_i||_F`` with
``gamma <= gamma_slack * gamma*``; the certified gamma of the final gains is then re-derived with the
gains fixed (linear in ``P`` and ``gamma``).

The printed gain (4.47) is evaluated, not solved: Metzler check at every vertex pair (it fails at all
16), plus, for information, the smallest gamma a diagonal P certifies for it ignoring
the Metzler condition.

Certification (:func:`roadtruth.observers.lmi.certify_design`): the bounded-real LMI at the 16 vertex pairs and
on a (v_x, a_x, C_f, C_r) grid, ``A_L`` Metzler at the same points, frozen closed loop Hurwitz.
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
    box_corners,
    certify_design,
    metzler_margin,
    physical_grid,
    solve_lmi,
    sym,
    trapezoid_vertices,
)

C = np.array([[1.0, -1.0]])
I2 = np.eye(2)
Z2 = np.zeros((2, 2))
P_MIN = 1e-3      # lower bound on the diagonal of P (scale; the LMI is homogeneous in (P, Q))
METZLER_MARGIN = 1e-6  # off-diagonal entries of P A_L imposed >= this in the SDP

#: Gain printed in (4.47) of the dissertation (its 800 kg car, speeds in m/s): L0, L1, L2 (2x1).
PRINTED_GAIN: dict[str, list[list[float]]] = {
    "L0": [[1.7127], [1.3431]], "L1": [[-58.5902], [-42.9510]], "L2": [[-0.5579], [-0.4398]],
}


def design_for(req: DesignRequest) -> DesignResult:
    """Cached design for an observer's request (its vehicle, variant and options)."""
    v = req.vehicle
    cf, cr = bicycle.axle_stiffness(v)
    opts = {"vx_range_mps": list(req.options["vx_range_mps"]), "ax_range_mps2": list(req.options["ax_range_mps2"]),
            "cf_range_Npr": list(req.model["cf_range"]), "cr_range_Npr": list(req.model["cr_range"]),
            "gamma_slack": float(req.options.get("gamma_slack", 1.0))}
    settings = SolverSettings()
    payload = {
        "family": "interval_wang", "variant": req.variant, "options": opts, "solver": settings.to_dict(),
        "vehicle": {"mass_kg": v.mass_kg, "yaw_inertia_kgm2": v.yaw_inertia_kgm2, "lf_m": v.lf_m, "lr_m": v.lr_m,
                    "cf_Npr": cf, "cr_Npr": cr},
        "code": [harness.__version__, lmi.source_fingerprint(lmi, bicycle, design_for)],
    }
    _, bf0 = bicycle.slip_model_terms(v)
    return lmi.cached_design(payload, lambda: design(req.variant, bf0, opts, settings),
                             use_cache=bool(req.options["use_cache"]))


# ---- model at a point ------------------------------------------------------------------------------

def vertex_pairs(v_rng: tuple[float, float], a_rng: tuple[float, float], cf_rng: tuple[float, float],
                 cr_rng: tuple[float, float]) -> np.ndarray:
    """The 16 pairs ``(eta1, eta2, C_f, C_r)``: 4 trapezoid vertices (Lemma 9) x 4 stiffness corners.

    Returns (16, 4) array [s/m, 1/s, N/rad, N/rad].
    """
    eta = trapezoid_vertices(v_rng, a_rng)
    xi = box_corners([cf_rng, cr_rng])
    return np.array([[e[0], e[1], x[0], x[1]] for e in eta for x in xi], dtype=float)


def grid_points(v_rng: tuple[float, float], a_rng: tuple[float, float], cf_rng: tuple[float, float],
                cr_rng: tuple[float, float], n: tuple[int, int, int, int] = (9, 5, 3, 3)) -> np.ndarray:
    """Dense physical grid mapped to ``(eta1, eta2, C_f, C_r)``: (prod(n), 4) array."""
    g = physical_grid([v_rng, a_rng, cf_rng, cr_rng], n)
    return np.column_stack([1.0 / g[:, 0], g[:, 1] / g[:, 0], g[:, 2], g[:, 3]])


def plant(bf0: np.ndarray, pt: np.ndarray) -> np.ndarray:
    """``A(eta, xi) = eta1 Bf0 diag(xi) - eta2 I`` (4.36) at ``pt = (eta1, eta2, C_f, C_r)``: (2, 2) [1/s]."""
    return pt[0] * bf0 @ np.diag(pt[2:4]) - pt[1] * I2


def gain_at(L: list[np.ndarray], eta1: float, eta2: float) -> np.ndarray:
    """``L(eta) = L0 + eta1 L1 + eta2 L2`` (4.26): (2, 1) [1/s]."""
    return L[0] + eta1 * L[1] + eta2 * L[2]


def closed_loop(bf0: np.ndarray, L: list[np.ndarray], pt: np.ndarray) -> np.ndarray:
    """Error matrix ``A_L = A(eta, xi) - L(eta) C`` at ``pt``: (2, 2) [1/s]."""
    return plant(bf0, pt) - gain_at(L, pt[0], pt[1]) @ C


def _brl(PAL: Any, P: Any, g: Any) -> Any:
    return [[PAL + PAL.T, P, I2], [P, -g * I2, Z2], [I2, Z2, -g * I2]]


# ---- SDP -----------------------------------------------------------------------------------------

def _problem(bf0: np.ndarray, verts: np.ndarray, settings: SolverSettings, *, fixed_L: list[np.ndarray] | None,
             gamma_cap: float | None, metzler: bool) -> tuple[Any, dict[str, Any]]:
    import cvxpy as cp

    p = cp.Variable(2)
    P = cp.diag(p)
    g = cp.Variable()
    Q = None if fixed_L is not None else [cp.Variable((2, 1)) for _ in range(3)]
    eps = settings.strictness
    cons = [p >= P_MIN]
    for pt in verts:
        A = plant(bf0, pt)
        if Q is None:
            PAL = P @ (A - gain_at(fixed_L, pt[0], pt[1]) @ C)  # type: ignore[arg-type]
        else:
            PAL = P @ A - (Q[0] + pt[0] * Q[1] + pt[1] * Q[2]) @ C
        cons.append(sym(cp.bmat(_brl(PAL, P, g))) << -eps * np.eye(6))
        if metzler and Q is not None:
            cons += [PAL[0, 1] >= METZLER_MARGIN, PAL[1, 0] >= METZLER_MARGIN]
    if gamma_cap is not None and Q is not None:
        cons.append(g <= gamma_cap)
        objective = cp.Minimize(sum(cp.norm(Qi, "fro") for Qi in Q))
    else:
        objective = cp.Minimize(g)
    exprs = {"p": p, "gamma": g} | ({} if Q is None else {f"Q{i}": Qi for i, Qi in enumerate(Q)})
    return cp.Problem(objective, cons), exprs


def _checks(bf0: np.ndarray, L: list[np.ndarray], P: np.ndarray, gamma: float
            ) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray]]:
    def closed(pt: np.ndarray) -> np.ndarray:
        return closed_loop(bf0, L, pt)

    def brl(pt: np.ndarray) -> np.ndarray:
        return np.block(_brl(P @ closed(pt), P, gamma))

    return brl, closed


def _certify(bf0: np.ndarray, L: list[np.ndarray], P: np.ndarray, gamma: float, verts: np.ndarray,
             grid: np.ndarray, settings: SolverSettings) -> tuple[lmi.Certificate, float]:
    """Certify at the solver's gamma, else at gamma inflated by 1 % or 10 % (a larger gamma only
    makes the bounded-real LMI more negative, so certifying a slightly larger bound is sound)."""
    cert = None
    for factor in (1.0, 1.01, 1.1):
        brl, closed = _checks(bf0, L, P, gamma * factor)
        cert = certify_design(P=P, lmis={"bounded_real": brl}, vertices=verts, grid=grid, closed_loop=closed,
                              metzler=closed, margin=settings.certify_margin)
        if cert.certified:
            return cert, gamma * factor
    assert cert is not None
    return cert, gamma


def _to_gains(L: list[np.ndarray]) -> dict[str, list[Any]]:
    return {f"L{i}": np.asarray(Li, dtype=float).reshape(2, 1).tolist() for i, Li in enumerate(L)}


def design(variant: str, bf0: np.ndarray, opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    """Solve (``fresh``) or evaluate (``printed``) and certify, for ``Bf0`` (2, 2) [1/kg]."""
    rngs = (tuple(opts["vx_range_mps"]), tuple(opts["ax_range_mps2"]), tuple(opts["cf_range_Npr"]),
            tuple(opts["cr_range_Npr"]))
    verts = vertex_pairs(*rngs)
    grid = grid_points(*rngs)
    if variant == "printed":
        return _printed(bf0, verts, grid, settings)
    if variant != "fresh":
        raise ValueError(f"unknown interval_wang variant {variant!r}")
    first = solve_lmi(lambda: _problem(bf0, verts, settings, fixed_L=None, gamma_cap=None, metzler=True), settings)
    if first.status != "optimal":
        st = DesignStatus.INFEASIBLE if first.status == "infeasible" else DesignStatus.SOLVER_FAILED
        return DesignResult(st, False, f"Theorem 5 SDP (Metzler + bounded real, 16 vertex pairs): {first.status}",
                            solver_stats=first.stats, variant=variant)
    gamma_opt = float(first.values["gamma"][0])
    cap = float(opts["gamma_slack"]) * gamma_opt
    second = solve_lmi(lambda: _problem(bf0, verts, settings, fixed_L=None, gamma_cap=cap, metzler=True), settings)
    out = second if second.status == "optimal" else first
    p = out.values["p"]
    L = [out.values[f"Q{i}"].reshape(2, 1) / p.reshape(2, 1) for i in range(3)]
    ev = solve_lmi(lambda: _problem(bf0, verts, settings, fixed_L=L, gamma_cap=None, metzler=False), settings)
    if ev.status == "optimal":
        p, gamma = ev.values["p"], float(ev.values["gamma"][0])
    else:
        gamma = float(out.values["gamma"][0])
    P = np.diag(p)
    cert, gamma = _certify(bf0, L, P, gamma, verts, grid, settings)
    extra = {"gamma": gamma, "gamma_optimal": gamma_opt,
             "metzler_vertices": float(sum(metzler_margin(closed_loop(bf0, L, pt)) >= 0.0 for pt in verts))}
    status = DesignStatus.CERTIFIED if cert.certified else DesignStatus.REJECTED
    head = f"gamma = {gamma:.4g} (optimum {gamma_opt:.4g}): "
    reason = head + (cert.reason if cert.certified else "certification failed: " + cert.reason)
    stats = {"gamma_min": first.stats, "min_norm": second.stats, "evaluate": ev.stats}
    return DesignResult(status, cert.certified, reason, _to_gains(L), P.tolist(), {**cert.margins, **extra},
                        gamma, stats, variant)


def _printed(bf0: np.ndarray, verts: np.ndarray, grid: np.ndarray, settings: SolverSettings) -> DesignResult:
    L = [np.asarray(PRINTED_GAIN[k], dtype=float) for k in ("L0", "L1", "L2")]
    n_metzler = sum(metzler_margin(closed_loop(bf0, L, pt)) >= 0.0 for pt in verts)
    ev = solve_lmi(lambda: _problem(bf0, verts, settings, fixed_L=L, gamma_cap=None, metzler=False), settings)
    extra: dict[str, float] = {"metzler_vertices": float(n_metzler)}
    if ev.status == "optimal":
        P, gamma = np.diag(ev.values["p"]), float(ev.values["gamma"][0])
        cert, gamma = _certify(bf0, L, P, gamma, verts, grid, settings)
        extra["gamma_without_metzler"] = gamma
    else:
        P, gamma = None, None
        _, closed = _checks(bf0, L, I2, 1.0)
        cert = certify_design(P=None, lmis={}, vertices=verts, grid=grid, closed_loop=closed, metzler=closed,
                              margin=settings.certify_margin)
    reason = (f"printed gain (4.47): A(eta, xi) - L(eta) C is Metzler at {n_metzler} of {len(verts)} vertex pairs, "
              "so the bounds carry no inclusion guarantee")
    if cert.certified:  # cannot happen while a vertex fails Metzler, kept for other vehicles/ranges
        return DesignResult(DesignStatus.CERTIFIED, True, "printed gain (4.47): " + cert.reason, _to_gains(L),
                            None if P is None else P.tolist(), {**cert.margins, **extra}, gamma, ev.stats, "printed")
    return DesignResult(DesignStatus.REJECTED, False, reason + "; certification failed: " + cert.reason,
                        _to_gains(L), None if P is None else P.tolist(), {**cert.margins, **extra}, None,
                        ev.stats, "printed")
