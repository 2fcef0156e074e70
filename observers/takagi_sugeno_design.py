r"""TS model and Theorem-1 LMI design of the Yacine et al. (2015) observer (see :mod:`roadtruth.observers.takagi_sugeno`).

Model (seed eqs. (13), (19)-(24)), ``x = (v_y, r, (F_f + F_r)/m, (a_f F_f - a_r F_r)/I_z)``, tire
forces in sector form ``F^S = f(alpha) alpha`` with ``f in [M_2, M_1]`` per axle, speed ``v_x`` in
``[v_min, v_max]``: 8 rules, rule ``i = (l, j, k)`` (``l = 0`` is ``v_max``,
``j``/``k`` = 0 the largest stiffness), weight ``h_i = mu_vl mu_fj mu_rk`` (the CORRECTED ordering;
the paper's eq. (22) swaps ``mu_2`` and ``mu_3``, reproduced by ``rule_order="as_printed"``).

Theorem 1 (eq. (33)): find ``P = P^T > 0``, ``M_i``, ``c > 0`` with, for i = 1..8,

.. math::

    \begin{pmatrix} A_i^T P + P A_i - M_i C - C^T M_i^T + \alpha P & P\Gamma \\
    \Gamma^T P & -c I_2 \end{pmatrix} \prec 0, \qquad L_i = P^{-1} M_i,

``C = (0 1 0 0)``, ``Gamma = (e_3, e_4)``. Solved in state coordinates scaled by
``S = diag(1, 1, s, s)`` (``s`` = ``state_scale``: without it the solvers return
``optimal_inaccurate``) with objective ``min c + 1e-3 tr P`` and ``P >= I``; the
certificate (:func:`roadtruth.observers.lmi.certify_design`) re-checks the block at the 8 vertices and on a
dense grid of ``(v_x, f_f, f_r)`` where ``A`` is rebuilt from the physical formula and ``L`` is the
trilinear blend of the vertex gains (this validates the polytope embedding itself), plus the frozen
closed-loop eigenvalues at rate ``alpha/2``. Any convex premise weights keep the certificate: the
block is affine in ``(A_i, L_i)``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

import roadtruth.harness as harness
from roadtruth.observers import lmi
from roadtruth.observers.lmi import (
    DesignRequest,
    DesignResult,
    DesignStatus,
    SolverSettings,
    certify_design,
    solve_lmi,
    sym,
)

C_OUT = np.array([[0.0, 1.0, 0.0, 0.0]])
GAMMA = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
#: Rule table: rule i -> (l, j, k) = (speed vertex, front stiffness, rear stiffness).
RULES: tuple[tuple[int, int, int], ...] = tuple(itertools.product((0, 1), (0, 1), (0, 1)))

#: Yacine et al. (2015) Table I: sector bounds of its own car (N/rad), ``(M_f1, M_f2, M_r1, M_r2)``.
SEED_STIFFNESS_NPR: tuple[float, float, float, float] = (4.2e4, 3.3e4, 4.9e4, 3.3e4)


@dataclass(frozen=True)
class TSModel:
    """Data of the 8-rule TS model. Masses [kg], inertia [kg m^2], lengths [m], stiffness [N/rad]."""

    mass_kg: float
    yaw_inertia_kgm2: float
    af_m: float
    ar_m: float
    relaxation_length_m: float
    mf_Npr: tuple[float, float]   # (f_f,max, f_f,min) = (M_f1, M_f2)
    mr_Npr: tuple[float, float]   # (M_r1, M_r2)
    vx_range_mps: tuple[float, float]

    def matrices(self, vx: float, ff: float, fr: float) -> tuple[np.ndarray, np.ndarray]:
        """``A`` (4, 4) [1/s ...] and ``B`` (4,) of eq. (21) at speed ``vx`` and secant slopes ``ff, fr``.

        The vertex matrices ``A_jk`` are this at ``(v_l, M_fj, M_rk)``; the model is affine in
        ``ff, fr`` and in ``vx`` except the ``vx * ff`` product in B, which the product weights
        ``h = mu_v mu_f mu_r`` reproduce exactly.
        """
        m, iz, af, ar, r = self.mass_kg, self.yaw_inertia_kgm2, self.af_m, self.ar_m, self.relaxation_length_m
        a1 = -(ff + fr) / (m * r)
        a2 = -(af * ff - ar * fr) / (m * r)
        a3 = -(af * ff - ar * fr) / (iz * r)
        a4 = -(af * af * ff + ar * ar * fr) / (iz * r)
        A = np.array([[0.0, -vx, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0],
                      [a1, a2, -vx / r, 0.0], [a3, a4, 0.0, -vx / r]])
        B = np.array([0.0, 0.0, vx * ff / (m * r), af * vx * ff / (iz * r)])
        return A, B

    def vertex(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """``(A_i, B_i)`` of rule ``i`` (0-based, order of :data:`RULES`)."""
        l, j, k = RULES[i]
        return self.matrices(self.vx_range_mps[1 - l], self.mf_Npr[j], self.mr_Npr[k])

    def weights(self, vx: float, ff: float, fr: float, rule_order: str = "corrected") -> np.ndarray:
        """(8,) rule weights ``h_i`` (eqs. (17), (22)); inputs are clipped into the sector box."""
        mv1 = _unit((vx - self.vx_range_mps[0]) / (self.vx_range_mps[1] - self.vx_range_mps[0]))
        mf1 = _unit((ff - self.mf_Npr[1]) / (self.mf_Npr[0] - self.mf_Npr[1]))
        mr1 = _unit((fr - self.mr_Npr[1]) / (self.mr_Npr[0] - self.mr_Npr[1]))
        mv, mf, mr = (mv1, 1.0 - mv1), (mf1, 1.0 - mf1), (mr1, 1.0 - mr1)
        h = np.array([mv[l] * mf[j] * mr[k] for l, j, k in RULES])
        if rule_order == "as_printed":
            # Eq. (22) as printed: A_12 weighted by mu_f2 mu_r1 and A_21 by mu_f1 mu_r2 (per speed block).
            h = h[[0, 2, 1, 3, 4, 6, 5, 7]]
        return h


def _unit(x: float) -> float:
    return 0.0 if x < 0.0 else (1.0 if x > 1.0 else x)


# ---- sector bounds from a Magic Formula curve ---------------------------------------------------

def secant_slope(alpha: float, B: float, C: float, E: float, D: float) -> float:
    """``f(alpha) = F(alpha)/alpha`` [N/rad] of ``F = D sin(C atan(B a - E(B a - atan B a)))`` (eq. (16)).

    Even in ``alpha``; near 0 the series ``f = BCD (1 - ...)`` avoids 0/0.
    """
    a = abs(alpha)
    if a < 1e-9:
        return B * C * D
    ba = B * a
    return D * math.sin(C * math.atan(ba - E * (ba - math.atan(ba)))) / a


def sector_bounds(B: float, C: float, E: float, D: float, slip_max_rad: float, n: int = 4001) -> tuple[float, float]:
    """``(f_min, f_max)`` of :func:`secant_slope` over ``|alpha| <= slip_max_rad`` on a grid."""
    vals = [secant_slope(a, B, C, E, D) for a in np.linspace(0.0, slip_max_rad, n)]
    return float(min(vals)), float(max(vals))


# ---- the LMI of Theorem 1 -----------------------------------------------------------------------

def _scaled(model: TSModel, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
    S = np.diag([1.0, 1.0, scale, scale])
    Si = np.diag([1.0, 1.0, 1.0 / scale, 1.0 / scale])
    return S, C_OUT @ Si, S @ GAMMA, [S @ model.vertex(i)[0] @ Si for i in range(len(RULES))]


def design_for(req: DesignRequest) -> DesignResult:
    """Cached design for an observer instance (its TS model, alpha and solver settings)."""
    model: TSModel = req.model
    settings = SolverSettings()
    alpha = float(req.options["decay_alpha"])
    scale = float(req.options["state_scale"])
    payload = {"family": "takagi_sugeno", "model": asdict(model), "alpha": alpha, "state_scale": scale,
               "solver": settings.to_dict(),
               "code": [harness.__version__, lmi.source_fingerprint(lmi, design_for)]}
    return lmi.cached_design(payload, lambda: design(model, alpha, scale, settings),
                             use_cache=bool(req.options["use_cache"]))


def blend_gain(model: TSModel, gains: np.ndarray, vx: float, ff: float, fr: float) -> np.ndarray:
    """``L(s) = sum_i h_i L_i``: (4,) from the (8, 4) vertex gains (original coordinates)."""
    return model.weights(vx, ff, fr) @ gains


def design(model: TSModel, alpha: float, scale: float, settings: SolverSettings) -> DesignResult:
    """Solve Theorem 1 for ``model`` and certify it. Gains ``L``: (8, 4) [original coordinates]."""
    import cvxpy as cp

    S, Cs, Gs, As = _scaled(model, scale)
    n_r = len(RULES)

    def build() -> tuple[Any, dict[str, Any]]:
        P = cp.Variable((4, 4), symmetric=True)
        c = cp.Variable()
        Ms = [cp.Variable((4, 1)) for _ in range(n_r)]
        cons = [P >> np.eye(4), c >= 0]
        for A, M in zip(As, Ms, strict=True):
            blk = cp.bmat([[A.T @ P + P @ A - M @ Cs - Cs.T @ M.T + alpha * P, P @ Gs], [Gs.T @ P, -c * np.eye(2)]])
            cons.append(sym(blk) << -settings.strictness * np.eye(6))
        problem = cp.Problem(cp.Minimize(c + 1e-3 * cp.trace(P)), cons)
        return problem, {"P": P, "c": c} | {f"M{i}": M for i, M in enumerate(Ms)}

    out = solve_lmi(build, settings)
    if out.status != "optimal":
        st = DesignStatus.INFEASIBLE if out.status == "infeasible" else DesignStatus.SOLVER_FAILED
        return DesignResult(st, False, f"Theorem 1 LMIs: {out.status}", solver_stats=out.stats, variant="theorem1")
    P = out.values["P"]
    P = 0.5 * (P + P.T)
    c = float(out.values["c"][0])
    Ls_scaled = np.column_stack([np.linalg.solve(P, out.values[f"M{i}"].reshape(4)) for i in range(n_r)]).T
    L = Ls_scaled @ np.linalg.inv(S)  # rows L_i in original coordinates: L_i = S^-1 L_s,i
    return certify(model, L, P, c, alpha, scale, settings, out.stats)


def certify(model: TSModel, L: np.ndarray, P: np.ndarray, c: float, alpha: float, scale: float,
            settings: SolverSettings, stats: dict[str, Any] | None = None, grid_n: int = 7) -> DesignResult:
    """Re-check Theorem 1 for gains ``L`` (8, 4) and ``P`` (scaled coordinates) in NumPy.

    Points are physical ``(v_x, f_f, f_r)``: the 8 box corners and a ``grid_n^3`` grid, where
    ``A`` comes from :meth:`TSModel.matrices` and ``L`` from the weight blend.
    """
    S = np.diag([1.0, 1.0, scale, scale])
    Si = np.diag([1.0, 1.0, 1.0 / scale, 1.0 / scale])
    Gs = S @ GAMMA
    vlo, vhi = model.vx_range_mps
    box = [(vlo, vhi), (model.mf_Npr[1], model.mf_Npr[0]), (model.mr_Npr[1], model.mr_Npr[0])]
    verts = lmi.box_corners(box)
    grid = lmi.physical_grid(box, grid_n)

    def closed_scaled(p: np.ndarray) -> np.ndarray:
        A, _ = model.matrices(*p)
        Lp = blend_gain(model, L, *p)
        return S @ (A - np.outer(Lp, C_OUT[0])) @ Si

    def block(p: np.ndarray) -> np.ndarray:
        Phi = closed_scaled(p)
        return np.block([[Phi.T @ P + P @ Phi + alpha * P, P @ Gs], [Gs.T @ P, -c * np.eye(2)]])

    cert = certify_design(P=P, lmis={"theorem1": block}, vertices=verts, grid=grid, closed_loop=closed_scaled,
                          stability_rate=alpha / 2.0, margin=settings.certify_margin)
    ev = np.linalg.eigvalsh(P)
    slow = max(float(np.linalg.eigvals(closed_scaled(p)).real.max()) for p in verts)
    fast = max(float(np.abs(np.linalg.eigvals(closed_scaled(p))).max()) for p in verts)
    margins = {**cert.margins, "c": c, "alpha": alpha, "p_eig_min": float(ev[0]), "p_eig_max": float(ev[-1]),
               "slowest_vertex_real_eig": slow, "fastest_vertex_abs_eig": fast}
    status = DesignStatus.CERTIFIED if cert.certified else DesignStatus.REJECTED
    reason = f"Theorem 1, alpha = {alpha:g}, c = {c:.4g}: " + (cert.reason if cert.certified
                                                               else "certification failed: " + cert.reason)
    return DesignResult(status, cert.certified, reason, {"L": L.tolist(), "state_scale": [scale]}, P.tolist(),
                        margins, None, stats or {}, "theorem1")
