r"""LMI designs of Wang's (2014, ch. 5) nonlinear observers (see :mod:`roadtruth.observers.nonlinear_wang`).

Plant (5.1)/(5.28)/(5.37): ``x' = A x + B_f f(x) + Psi(y, u) + B_w w``, ``y = C x``, ``z = C_p e``. The
nonlinearity enters through ``q`` scalar channels, channel ``j`` depending on the single scalar
``(S x)_j``; its slope lies in ``[k1_j, k2_j]``, i.e. ``K1 = diag(k1) S``, ``K2 = diag(k2) S`` (q x n).
Writing the nonlinearity per channel is what makes the Jacobian-box sector condition of Lemma 15
valid: with multi-argument ``f_i`` (the Van der Pol term) the element-wise bounds of (5.6)-(5.12) do
not give ``K1 e <= phi <= K2 e`` for errors of mixed sign, so the Van der Pol term is split into its
two column terms ``df/dx_j e_j`` (mean-value theorem on a scalar function), each a scalar sector.

LMIs (strict ``< 0`` imposed as ``<< -strictness I``; all linear after ``Y = P L1``, ``Lb = tau L2``):

* ``lemma17`` (5.19), extended Luenberger, ``L2 = 0``, sector matrix ``M`` of (5.12)::

    [[He(P A) - He(Y C) + 2 sigma P - tau (K1^T K2 + K2^T K1)/2,  P B_f + tau (K1 + K2)^T / 2],
     [ *,                                                            -tau I                    ]] < 0

* ``thm7`` (5.22)-(5.23), Arcak two-DOF after the ``K1`` shift (``Kb = K2 - K1``)::

    [[He(P (A + B_f K1)) - He(Y C) + 2 sigma P,  P B_f + (tau I - C^T Lb^T) Kb^T / 2],
     [ *,                                          -tau I                           ]] < 0

* ``thm8`` (5.30): the ``thm7`` block plus ``C_p^T C_p`` in (1,1) and the column ``[P B_w; 0; -g I]``,
  minimise ``g = gamma^2``; gain-norm limits (5.33)-(5.36): ``P >= alpha I``, ``tau >= beta``,
  ``[[eps1 I, Y^T], [Y, alpha^2 I]] >= 0``, ``[[eps2 I, Lb^T], [Lb, beta^2 I]] >= 0``, which give
  ``||L1|| <= sqrt(eps1)`` and ``||L2|| <= sqrt(eps2)``.

Gain scheduling (Theorems 9, 10): ``L(lambda) = sum_i b_i(lambda) L_i`` with the basis values
``b(lambda)`` given per point (``(1,)`` for constant gains, ``(1, lambda1, lambda2)`` for the PVNL
observer). With ``C`` and ``C_p`` constant every block is affine in lambda and the vertex checks are
exact (Lemma 19, (5.44)-(5.45)); the multipliers of sec. 5.3.3 are needed only when ``C`` depends on
lambda (quadratic terms) and are implemented in :func:`quadratic_in_lambda_certificate`.

The term ``2 sigma P`` (not in the dissertation) certifies the decay rate: inside the slip domain
``V = e^T P e`` falls at least as ``exp(-2 sigma t)`` (for ``w = 0``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from roadtruth.observers.lmi import (
    Certificate,
    DesignResult,
    DesignStatus,
    SolverSettings,
    box_corners,
    certify_design,
    solve_lmi,
    sym,
)

#: Van der Pol example (5.57)-(5.62): mu, the design box and the printed gains.
VDP_MU = 1.0
VDP_BOX = 5.0
VDP_PRINTED = {"L1": [[17.5846], [63.8993]], "L2": [[0.3639], [0.6864]]}

#: Slip-angle observer gains printed in (5.73), speeds in m/s.
PRINTED_5_73 = {
    "L1_0": [[9.6103], [10.1651]], "L1_1": [[-72.1241], [-84.5006]], "L1_2": [[-0.4527], [-0.5227]],
    "L2_0": [[0.5307], [0.4693]], "L2_1": [[0.5170], [-0.5154]], "L2_2": [[-0.018], [0.0187]],
}


# ---- tire (5.63) ---------------------------------------------------------------------------------

def brush_theta(c1_Npr: float, mu_fz_N: float) -> float:
    """Shape parameter ``theta_t = c1 / (3 mu F_z)`` [1/rad] of (5.63) for a given linear stiffness."""
    return c1_Npr / (3.0 * mu_fz_N)


def brush_force(alpha: np.ndarray | float, c1_Npr: float, theta_t: float) -> np.ndarray:
    """Lateral force (5.63) [N], with the saturation branch beyond ``|alpha| = 1/theta_t``."""
    a = np.asarray(alpha, dtype=float)
    s = np.minimum(theta_t * np.abs(a), 1.0)
    mu_fz = c1_Npr / (3.0 * theta_t)
    return np.sign(a) * mu_fz * (3.0 * s - 3.0 * s * s + s ** 3)


def sector_lower_slope(c1_Npr: float, theta_t: float, alpha_max_rad: float) -> float:
    """Smallest slope of ``f = F_y - c1 alpha`` on ``|alpha| <= alpha_max``: ``-c1 (2 s - s^2)``,
    ``s = min(1, theta_t alpha_max)`` (the largest slope is 0)."""
    s = min(1.0, theta_t * alpha_max_rad)
    return -c1_Npr * (2.0 * s - s * s)


# ---- problem data --------------------------------------------------------------------------------

#: ``(A, B_f, B_w or None, basis of L1, basis of L2, rho)`` at one point.
Matrices = tuple[np.ndarray, np.ndarray, "np.ndarray | None", np.ndarray, np.ndarray, float]


@dataclass(frozen=True)
class SectorProblem:
    """Data of one design: ``matrices(point)`` (see :data:`Matrices`), the polytope vertices, a dense
    check grid (same coordinates), ``C`` (p, n), ``C_p`` (r, n), ``K1``, ``K2`` (q, n).

    Gains: ``L1(lambda) = sum_i b1_i L1_i``, ``L2(lambda) = sum_i b2_i L2_i``. The S-procedure
    multiplier is ``T(lambda) = rho(lambda) diag(t)`` (one per channel) when ``K2 - K1`` is square
    diagonal (``per_channel``), else a scalar ``tau`` (dissertation form, needed for the element-wise
    Van der Pol sector). ``rho * b2_i`` and ``b1_i`` must be affine in the point coordinates.
    """

    matrices: Callable[[np.ndarray], Matrices]
    vertices: np.ndarray
    grid: np.ndarray | None
    C: np.ndarray
    Cp: np.ndarray
    K1: np.ndarray
    K2: np.ndarray

    @property
    def n(self) -> int:
        return self.C.shape[1]

    @property
    def q(self) -> int:
        return self.K1.shape[0]

    @property
    def nb(self) -> tuple[int, int]:
        m = self.matrices(self.vertices[0])
        return len(m[3]), len(m[4])

    @property
    def per_channel(self) -> bool:
        kb = self.K2 - self.K1
        return kb.shape[0] == kb.shape[1] and np.allclose(kb, np.diag(np.diag(kb))) and bool(np.all(np.diag(kb) > 0))


@dataclass(frozen=True)
class GainLimits:
    """(5.33)-(5.36): ``||L1|| <= sqrt(eps1)``, ``||L2|| <= sqrt(eps2)`` at every vertex (hence on the
    box), via ``P >= alpha I``, multiplier ``>= beta``: ``[[eps1 I, Y^T], [Y, alpha^2 I]] >= 0`` and the
    same on the multiplier-weighted ``L2``."""

    eps1: float
    eps2: float
    alpha: float
    beta: float


def vehicle_problem(Bf0: np.ndarray, c1: Sequence[float], k1: Sequence[float], v_range: tuple[float, float],
                    a_range: tuple[float, float], *, scheduled: bool, force_scale_N: float,
                    lf_m: float, lr_m: float, iz: float, m: float, grid_n: tuple[int, int] = (19, 9)
                    ) -> SectorProblem:
    """Slip-angle model (5.64)-(5.72) on the box of (5.70), forces in units of ``force_scale_N``.

    ``lambda = (1/v_x, a_x/v_x)``; by Lemma 9 the 4 trapezoid corners span the box's image. ``B_w`` is
    the corrected (5.66) (row 2 ``(-1/m, +l_r/I_z)``), disturbances ``(W_F, W_T)`` in the same units.
    The multiplier is proportional to ``lambda1`` like ``B_f``: a constant one cannot serve both ends of
    the speed range (the LMI is then infeasible at any useful slip domain). Scheduled (Thm 10):
    ``L1`` affine in lambda, ``L2`` affine in ``(v_x, a_x) = (1/lambda1, lambda2/lambda1)`` (then the
    multiplier-weighted ``L2`` is affine in lambda); constant gains otherwise (Lemma 17, Thms 7, 8).
    """
    S = float(force_scale_N)
    A1 = Bf0 @ np.diag(c1)
    Bw0 = np.array([[-1.0 / m, -lf_m / iz], [-1.0 / m, lr_m / iz]])

    def mats(pt: np.ndarray) -> Matrices:
        th1, th2 = float(pt[0]), float(pt[1])
        b1 = np.array([1.0, th1, th2]) if scheduled else np.array([1.0])
        b2 = np.array([1.0, 1.0 / th1, th2 / th1]) if scheduled else np.array([1.0])
        return th1 * A1 - th2 * np.eye(2), th1 * Bf0 * S, th1 * Bw0 * S, b1, b2, th1

    c = box_corners([v_range, a_range])
    verts = np.column_stack([1.0 / c[:, 0], c[:, 1] / c[:, 0]])
    vg = np.linspace(v_range[0], v_range[1], grid_n[0])
    ag = np.linspace(a_range[0], a_range[1], grid_n[1])
    g = np.array([(1.0 / v, a / v) for v in vg for a in ag])
    return SectorProblem(mats, verts, g, np.array([[1.0, -1.0]]), np.eye(2),
                         np.diag(np.asarray(k1, dtype=float) / S), np.zeros((2, 2)))


def van_der_pol_problem(*, per_column: bool, mu: float = VDP_MU, box: float = VDP_BOX) -> SectorProblem:
    """Van der Pol (5.57)-(5.61): ``x1' = x2``, ``x2' = -x1 + mu (1 - x1^2) x2``, ``y = x1``.

    Jacobian of ``f = (1 - x1^2) x2`` on ``[-box, box]^2``: ``df/dx1 = -2 x1 x2 in [-2 box^2, 2 box^2]``,
    ``df/dx2 = 1 - x1^2 in [1 - box^2, 1]`` (5.61): ``K1 = (-50, -24)``, ``K2 = (50, 1)`` for box 5.
    ``per_column=False`` is the dissertation's (element-wise, q = 1) sector, ``True`` the valid one
    (q = 2 channels ``df/dx_j e_j``, ``B_f = mu (0, 1)^T [1, 1]``).
    """
    A = np.array([[0.0, 1.0], [-1.0, 0.0]])
    lo, hi = np.array([-2 * box * box, 1 - box * box]), np.array([2 * box * box, 1.0])
    if per_column:
        Bf, K1, K2 = mu * np.array([[0.0, 0.0], [1.0, 1.0]]), np.diag(lo), np.diag(hi)
    else:
        Bf, K1, K2 = mu * np.array([[0.0], [1.0]]), lo.reshape(1, 2), hi.reshape(1, 2)
    one = np.array([1.0])
    return SectorProblem(lambda pt: (A, Bf, None, one, one, 1.0), np.zeros((1, 1)), None,
                         np.array([[1.0, 0.0]]), np.eye(2), K1, K2)


# ---- the LMI blocks (shared by the solver and the NumPy check) -----------------------------------

def lmi_block(kind: str, pb: SectorProblem, A: Any, Bf: np.ndarray, Bw: np.ndarray | None, P: Any, Y: Any,
              T: Any, W: Any, sigma: float, g: Any, bmat: Callable[[list[list[Any]]], Any]) -> Any:
    """The matrix that must be negative definite at one point (``bmat`` from cvxpy or NumPy).

    ``T``: multiplier (q x q); ``W``: ``T (K2 - K1) L2`` (q x p) per channel, or ``tau L2`` (n x p)
    in the scalar form (then ``T = tau I``).
    """
    C, K1, K2 = pb.C, pb.K1, pb.K2
    n, q = A.shape[0], K1.shape[0]
    YC = Y @ C
    if kind == "lemma17":
        m11 = P @ A + A.T @ P - YC - YC.T + 2 * sigma * P - (K1.T @ T @ K2 + K2.T @ T @ K1) / 2
        m12 = P @ Bf + (K1 + K2).T @ T / 2
    else:
        As = A + Bf @ K1
        Kb = K2 - K1
        m11 = P @ As + As.T @ P - YC - YC.T + 2 * sigma * P
        if pb.per_channel:
            m12 = P @ Bf + (Kb.T @ T - C.T @ W.T) / 2
        else:
            m12 = P @ Bf + (T[0, 0] * np.eye(n) - C.T @ W.T) @ Kb.T / 2
    if kind != "thm8":
        return bmat([[m11, m12], [m12.T, -T]])
    assert Bw is not None
    d = Bw.shape[1]
    m13 = P @ Bw
    return bmat([[m11 + pb.Cp.T @ pb.Cp, m12, m13], [m12.T, -T, np.zeros((q, d))],
                 [m13.T, np.zeros((d, q)), -g * np.eye(d)]])


def _combine(mats: Sequence[Any], basis: np.ndarray) -> Any:
    out = basis[0] * mats[0]
    for b, Mi in zip(basis[1:], mats[1:], strict=True):
        out = out + b * Mi
    return out


# ---- solving -------------------------------------------------------------------------------------

Fixed = tuple[list[np.ndarray], list[np.ndarray]]


def _problem(pb: SectorProblem, kind: str, sigma: float, settings: SolverSettings, *,
             fixed: Fixed | None, limits: GainLimits | None, objective: str) -> tuple[Any, dict[str, Any]]:
    import cvxpy as cp

    n, q, p = pb.n, pb.q, pb.C.shape[0]
    nb1, nb2 = pb.nb
    pc = pb.per_channel
    eps = settings.strictness
    P = cp.Variable((n, n), symmetric=True)
    t = cp.Variable(q) if pc else cp.Variable(1)
    Tt = cp.diag(t) if pc else t[0] * np.eye(q)
    Kb = pb.K2 - pb.K1
    g = cp.Variable()
    two_dof = kind != "lemma17"
    wshape = (q, p) if pc else (n, p)
    Ys = [cp.Variable((n, p)) for _ in range(nb1)] if fixed is None else [P @ Li for Li in fixed[0]]
    Ws = [cp.Variable(wshape) for _ in range(nb2)] if (fixed is None and two_dof) else None
    alpha = limits.alpha if limits is not None else 1.0
    beta = limits.beta if limits is not None else 1e-3
    cons = [P >> alpha * np.eye(n), t >= beta]
    if limits is None:
        cons.append(P << 1e6 * np.eye(n))  # conditioning: a bounded P keeps the gains finite
    kmin = float(np.min(np.diag(Kb))) if pc else 1.0
    for pt in pb.vertices:
        A, Bf, Bw, b1, b2, rho = pb.matrices(pt)
        Y = _combine(Ys, b1)
        T = rho * Tt
        if not two_dof:
            W = np.zeros(wshape)
        elif Ws is not None:
            W = rho * _combine(Ws, b2)
        else:
            L2 = _combine(fixed[1], b2)  # type: ignore[index]
            W = (T @ Kb @ L2) if pc else (rho * t[0]) * L2
        blk = lmi_block(kind, pb, A, Bf, Bw, P, Y, T, W, sigma, g, cp.bmat)
        cons.append(sym(blk) << -eps * np.eye(blk.shape[0]))
        if limits is not None and fixed is None:
            cons.append(sym(cp.bmat([[limits.eps1 * np.eye(p), Y.T], [Y, alpha ** 2 * np.eye(n)]])) >> 0)
            if Ws is not None:
                Wt = _combine(Ws, b2)  # = diag(t) Kb L2: ||L2|| <= ||Wt|| / (beta kmin)
                r = Wt.shape[0]
                cons.append(sym(cp.bmat([[limits.eps2 * np.eye(p), Wt.T],
                                         [Wt, (beta * kmin) ** 2 * np.eye(r)]])) >> 0)
    if objective == "gamma":
        obj = cp.Minimize(g)
    elif objective == "min_norm" and fixed is None:
        obj = cp.Minimize(sum(cp.norm(Yi, "fro") for Yi in Ys) + (sum(cp.norm(W, "fro") for W in Ws) if Ws else 0))
    else:
        obj = cp.Minimize(0)
    exprs: dict[str, Any] = {"P": P, "t": t}
    if kind == "thm8":
        exprs["g"] = g
    if fixed is None:
        exprs |= {f"Y{i}": Yi for i, Yi in enumerate(Ys)}
        if Ws is not None:
            exprs |= {f"W{i}": Wi for i, Wi in enumerate(Ws)}
    return cp.Problem(obj, cons), exprs


def solve(pb: SectorProblem, kind: str, sigma: float, settings: SolverSettings, *,
          fixed: Fixed | None = None, limits: GainLimits | None = None,
          objective: str = "min_norm") -> tuple[str, dict[str, np.ndarray], dict[str, Any]]:
    """Solve one LMI problem; returns ``(status, values, stats)`` with the gains ``L1_i``, ``L2_i``."""
    out = solve_lmi(lambda: _problem(pb, kind, sigma, settings, fixed=fixed, limits=limits,
                                     objective=objective), settings)
    if out.status != "optimal":
        return out.status, {}, out.stats
    v = dict(out.values)
    P, t = v["P"], v["t"]
    nb1, nb2 = pb.nb
    if fixed is not None:
        for i in range(nb1):
            v[f"L1_{i}"] = fixed[0][i]
        for i in range(nb2):
            v[f"L2_{i}"] = fixed[1][i]
        return "optimal", v, out.stats
    for i in range(nb1):
        v[f"L1_{i}"] = np.linalg.solve(P, v[f"Y{i}"])
    for i in range(nb2):
        if kind == "lemma17":
            v[f"L2_{i}"] = np.zeros((pb.n, pb.C.shape[0]))
        elif pb.per_channel:
            v[f"L2_{i}"] = np.linalg.solve(np.diag(t) @ (pb.K2 - pb.K1), v[f"W{i}"])
        else:
            v[f"L2_{i}"] = v[f"W{i}"] / float(t[0])
    return "optimal", v, out.stats


def max_decay_rate(pb: SectorProblem, kind: str, settings: SolverSettings, *, fixed: Fixed | None = None,
                   limits: GainLimits | None = None, cap: float = 32.0, rel_tol: float = 3e-2) -> float | None:
    """Largest sigma [1/s] for which the (thm7 / lemma17) LMI is feasible, by bisection; None if not at 0."""
    k = "thm7" if kind == "thm8" else kind

    def ok(s: float) -> bool:
        return solve(pb, k, s, settings, fixed=fixed, limits=limits, objective="none")[0] == "optimal"

    if not ok(0.0):
        return None
    lo, hi = 0.0, 0.5
    while hi <= cap and ok(hi):
        lo, hi = hi, 2 * hi
    hi = min(hi, cap)
    while hi - lo > rel_tol * max(hi, 1e-3):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


# ---- certification -------------------------------------------------------------------------------

def gains_at(pb: SectorProblem, L1: list[np.ndarray], L2: list[np.ndarray], pt: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """``L1(lambda)``, ``L2(lambda)`` at one point."""
    m = pb.matrices(pt)
    return _combine(L1, m[3]), _combine(L2, m[4])


def certify(pb: SectorProblem, kind: str, L1: list[np.ndarray], L2: list[np.ndarray], P: np.ndarray,
            t: np.ndarray, sigma: float, gamma2: float | None, settings: SolverSettings) -> Certificate:
    """NumPy re-check of the LMI with the final gains at every vertex and grid point, and frozen
    stability of the error dynamics at both sector ends (slope ``K1`` and ``K2``) at rate sigma."""
    n, pc = pb.n, pb.per_channel
    Kb = pb.K2 - pb.K1
    Tt = np.diag(t) if pc else float(t[0]) * np.eye(pb.q)

    def lmi(pt: np.ndarray) -> np.ndarray:
        A, Bf, Bw, _, _, rho = pb.matrices(pt)
        L1t, L2t = gains_at(pb, L1, L2, pt)
        T = rho * Tt
        W = (T @ Kb @ L2t) if pc else rho * float(t[0]) * L2t
        return lmi_block(kind, pb, A, Bf, Bw, P, P @ L1t, T, W, sigma,
                         gamma2 if gamma2 is not None else 0.0, np.block)

    def closed(pt: np.ndarray) -> np.ndarray:
        A, Bf, _, _, _, _ = pb.matrices(pt[:-1])
        L1t, L2t = gains_at(pb, L1, L2, pt[:-1])
        D = pb.K1 if pt[-1] < 0.5 else pb.K2
        # e' = (A + B_f K1 - L1 C) e + B_f (D - K1)(I - L2 C) e  (two-DOF form (5.21))
        return A + Bf @ pb.K1 - L1t @ pb.C + Bf @ (D - pb.K1) @ (np.eye(n) - L2t @ pb.C)

    def with_ends(pts: np.ndarray | None) -> np.ndarray | None:
        if pts is None:
            return None
        return np.vstack([np.column_stack([pts, np.full(len(pts), e)]) for e in (0.0, 1.0)])

    return certify_design(P=P, lmis={kind: lambda pt: lmi(pt[:-1])}, vertices=with_ends(pb.vertices),
                          grid=with_ends(pb.grid), closed_loop=closed, stability_rate=sigma,
                          margin=settings.certify_margin)


def quadratic_in_lambda_certificate(F0: np.ndarray, F1: Sequence[np.ndarray], F2: Sequence[Sequence[np.ndarray]],
                                    bounds: Sequence[tuple[float, float]], settings: SolverSettings,
                                    multiplier: str = "V2") -> tuple[bool, dict[str, Any]]:
    r"""Sec. 5.3.3 (b): is ``F(lambda) = F0 + sum lambda_i F_i + sum_ij lambda_i lambda_j F_ij < 0`` on the box?

    ``F(lambda) = (I; lambda (x) I)^T G (I; lambda (x) I)`` (5.46)-(5.47), with ``G`` built with the
    symmetrised cross terms ``(F_ij + F_ji)/2`` (each pair counted once per ordered index). Sufficient
    conditions: ``V1`` (unstructured, (5.49)-(5.50)): some symmetric ``V1`` with ``G - V1 < 0`` and
    ``(I; Lambda^k (x) I)^T V1 (I; Lambda^k (x) I) <= 0`` at every vertex ``k`` and ``V1``'s lower-right
    block ``>= 0`` (then the form is convex in lambda, so the vertex inequalities hold on the box); ``V2``
    (structured, (5.51)-(5.56)): ``G - V2 < 0`` with ``V2 = T^T blkdiag(U_i) T`` built from full blocks
    ``Gamma_i > 0``, ``U_i = [[lo_i hi_i Gamma_i, -(lo_i + hi_i)/2 Gamma_i], [., Gamma_i]]``, which is
    ``<= 0`` on the box since ``(lambda_i - lo_i)(lambda_i - hi_i) <= 0``.
    Returns ``(certified, info)``.
    """
    import cvxpy as cp

    m, p = F0.shape[0], len(F1)
    G = np.zeros(((p + 1) * m, (p + 1) * m))
    G[:m, :m] = F0
    for i in range(p):
        G[:m, (i + 1) * m:(i + 2) * m] += F1[i] / 2
        G[(i + 1) * m:(i + 2) * m, :m] += F1[i].T / 2
        for j in range(p):
            G[(i + 1) * m:(i + 2) * m, (j + 1) * m:(j + 2) * m] += (F2[i][j] + F2[j][i].T) / 2
    G = 0.5 * (G + G.T)
    eps = settings.strictness
    cons: list[Any] = []
    if multiplier == "V1":
        V = cp.Variable(G.shape, symmetric=True)
        for lam in box_corners(bounds):
            E = np.vstack([np.eye(m)] + [li * np.eye(m) for li in lam])
            cons.append(sym(E.T @ V @ E) << 0)
        cons.append(V[m:, m:] >> 0)
    elif multiplier == "V2":
        V = 0
        for i, (lo, hi) in enumerate(bounds):
            Gam = cp.Variable((m, m), symmetric=True)
            cons.append(Gam >> eps * np.eye(m))
            T = np.zeros((2 * m, G.shape[0]))
            T[:m, :m] = np.eye(m)
            T[m:, (i + 1) * m:(i + 2) * m] = np.eye(m)
            U = cp.bmat([[lo * hi * Gam, -(lo + hi) / 2 * Gam], [-(lo + hi) / 2 * Gam, Gam]])
            V = V + T.T @ U @ T
    else:
        raise ValueError(f"unknown multiplier {multiplier!r}")
    cons.append(sym(G - V) << -eps * np.eye(G.shape[0]))
    prob = cp.Problem(cp.Minimize(0), cons)
    try:
        prob.solve(solver=cp.CLARABEL)
    except cp.error.SolverError:
        return False, {"status": "solver error"}
    return prob.status == cp.OPTIMAL, {"status": str(prob.status)}


# ---- results -------------------------------------------------------------------------------------

def gains_dict(L1: list[np.ndarray], L2: list[np.ndarray]) -> dict[str, list[Any]]:
    """Gains as nested lists, ``L1_i``/``L2_i`` per basis function."""
    out: dict[str, list[Any]] = {}
    for i, a in enumerate(L1):
        out[f"L1_{i}"] = np.asarray(a, dtype=float).tolist()
    for i, b in enumerate(L2):
        out[f"L2_{i}"] = np.asarray(b, dtype=float).tolist()
    return out


def result(variant: str, cert: Certificate, L1: list[np.ndarray], L2: list[np.ndarray], P: np.ndarray,
           extra: dict[str, float], stats: dict[str, Any], gamma: float | None, prefix: str) -> DesignResult:
    """A :class:`DesignResult` from a certificate (CERTIFIED or REJECTED, gains always kept)."""
    status = DesignStatus.CERTIFIED if cert.certified else DesignStatus.REJECTED
    reason = prefix + (cert.reason if cert.certified else "certification failed: " + cert.reason)
    return DesignResult(status, cert.certified, reason, gains_dict(L1, L2), np.asarray(P).tolist(),
                        {**cert.margins, **extra}, gamma, stats, variant)


def design_problem(pb: SectorProblem, variant: str, kind: str, settings: SolverSettings, *,
                   limits: GainLimits | None, decay_fraction: float,
                   fixed: tuple[list[np.ndarray], list[np.ndarray]] | None = None,
                   extra: dict[str, float] | None = None) -> DesignResult:
    """Full design of one variant on a problem: the largest decay rate, then (``kind``) the gains at
    ``decay_fraction`` of it (thm8: minimum gamma there), then the NumPy certificate.

    ``fixed`` (printed gains): evaluated, not solved: the largest certified rate, then (thm8) the
    smallest gamma at half of it.
    """
    extra = dict(extra or {})
    lim = None if fixed is not None else limits
    smax = max_decay_rate(pb, kind, settings, fixed=fixed, limits=lim)
    if smax is None:
        status = DesignStatus.REJECTED if fixed is not None else DesignStatus.INFEASIBLE
        why = "the given gains admit no common quadratic Lyapunov function on the slip domain" if fixed \
            else f"{kind} LMI infeasible even at decay rate 0"
        L1, L2 = (fixed if fixed is not None else ([], []))
        return DesignResult(status, False, why, gains_dict(L1, L2) if fixed else {}, None, extra, None, {}, variant)
    sigma = decay_fraction * smax
    extra |= {"max_decay_rate_radps": smax, "decay_rate_radps": sigma}
    st, vals, stats = solve(pb, kind, sigma, settings, fixed=fixed, limits=lim,
                            objective="gamma" if kind == "thm8" else "min_norm")
    if st != "optimal":
        return DesignResult(DesignStatus.SOLVER_FAILED, False, f"{kind} at sigma {sigma:.4g}: {st}", margins=extra,
                            solver_stats=stats, variant=variant)
    nb1, nb2 = pb.nb
    L1 = [vals[f"L1_{i}"] for i in range(nb1)]
    L2 = [vals[f"L2_{i}"] for i in range(nb2)]
    P, t = vals["P"], vals["t"]
    g2 = float(vals["g"][0]) * 1.0001 if kind == "thm8" else None
    cert = certify(pb, kind, L1, L2, P, t, sigma, g2, settings)
    gamma = None if g2 is None else float(np.sqrt(g2))
    if gamma is not None:
        extra["gamma"] = gamma
    extra |= {f"multiplier_{i}": float(x) for i, x in enumerate(t)}
    pre = "printed gains, " if fixed is not None else ""
    pre += f"decay rate {sigma:.4g} 1/s" + (f", gamma {gamma:.4g}" if gamma is not None else "") + ": "
    return result(variant, cert, L1, L2, P, extra, stats, gamma, pre)


# ---- the vehicle observers -----------------------------------------------------------------------

#: Options that change how the observer runs, not its design (left out of the design cache key).
RUN_ONLY_OPTIONS = ("hold_s", "vx_min_output_mps", "use_cache")
#: variant -> (LMI kind, scheduled gains)
VARIANTS = {"luenberger": ("lemma17", False), "arcak": ("thm7", False), "l2": ("thm8", False),
            "scheduled": ("thm8", True), "scheduled_printed": ("thm8", True)}


def tire_data(vehicle: Any, mu: float, alpha_max_rad: float) -> tuple[list[float], list[float], list[float]]:
    """Per axle ``c1`` [N/rad], ``theta_t`` [1/rad] of (5.63) and the slope bound ``k1`` [N/rad] on
    ``|alpha| <= alpha_max``; ``mu F_z`` = tire grip x ``mu`` x static axle load."""
    from roadtruth.harness.errors import InputError
    if not (isinstance(mu, int | float) and 0.05 <= mu <= 2.0):
        raise InputError(f"road friction mu must be a number in [0.05, 2] (got {mu!r})", field="observer option mu")
    c1 = [float(vehicle.cornering_stiffness_f_Npr), float(vehicle.cornering_stiffness_r_Npr)]
    k = float(vehicle.tires.grip) * float(mu)
    theta = [brush_theta(c1[0], k * vehicle.fz_front_static_N), brush_theta(c1[1], k * vehicle.fz_rear_static_N)]
    k1 = [sector_lower_slope(c, t, alpha_max_rad) for c, t in zip(c1, theta, strict=True)]
    return c1, theta, k1


def vehicle_design_problem(vehicle: Any, opts: dict[str, Any], *, scheduled: bool, l2_in_lambda: bool = False
                           ) -> SectorProblem:
    """The design problem of a vehicle and the observer options (see :func:`vehicle_problem`)."""
    from roadtruth.observers.bicycle import slip_model_terms
    c1, _, k1 = tire_data(vehicle, float(opts["mu"]), float(opts["slip_domain_rad"]))
    _, Bf0 = slip_model_terms(vehicle)
    pb = vehicle_problem(Bf0, c1, k1, tuple(opts["vx_range_mps"]), tuple(opts["ax_range_mps2"]),
                         scheduled=scheduled, force_scale_N=max(c1), lf_m=vehicle.lf_m, lr_m=vehicle.lr_m,
                         iz=vehicle.yaw_inertia_kgm2, m=vehicle.mass_kg)
    if not l2_in_lambda:
        return pb
    base = pb.matrices

    def mats(pt: np.ndarray) -> Matrices:  # the printed (5.73) L2 is affine in lambda
        A, Bf, Bw, b1, _, rho = base(pt)
        return A, Bf, Bw, b1, b1, rho

    return SectorProblem(mats, pb.vertices, pb.grid, pb.C, pb.Cp, pb.K1, pb.K2)


def design_vehicle(vehicle: Any, variant: str, opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    """Solve (or evaluate, printed gains) and certify one variant on a vehicle."""
    kind, scheduled = VARIANTS[variant]
    printed = variant == "scheduled_printed"
    pb = vehicle_design_problem(vehicle, opts, scheduled=scheduled, l2_in_lambda=printed)
    S = max(vehicle.cornering_stiffness_f_Npr, vehicle.cornering_stiffness_r_Npr)
    extra = {"slip_domain_rad": float(opts["slip_domain_rad"]), "force_scale_N": float(S)}
    fixed = None
    if printed:
        fixed = ([np.asarray(PRINTED_5_73[f"L1_{i}"], dtype=float) for i in range(3)],
                 [np.asarray(PRINTED_5_73[f"L2_{i}"], dtype=float) for i in range(3)])
    limits = GainLimits(eps1=float(opts["max_gain_L1_per_s"]) ** 2, eps2=float(opts["max_gain_L2"]) ** 2,
                        alpha=1.0, beta=1e-2)
    return design_problem(pb, variant, kind, settings, limits=limits, decay_fraction=float(opts["decay_fraction"]),
                          fixed=fixed, extra=extra)


def design_for(obs: Any) -> DesignResult:
    """Cached design for an observer's request (its vehicle, variant and options)."""
    import roadtruth.harness as harness
    from roadtruth.observers import lmi
    v = obs.vehicle
    opts = {k: val for k, val in obs.options.items() if k not in RUN_ONLY_OPTIONS}
    settings = SolverSettings()
    payload = {
        "family": "nonlinear_wang", "variant": obs.variant, "options": opts, "solver": settings.to_dict(),
        "vehicle": {"mass_kg": v.mass_kg, "yaw_inertia_kgm2": v.yaw_inertia_kgm2, "lf_m": v.lf_m, "lr_m": v.lr_m,
                    "cf_Npr": v.cornering_stiffness_f_Npr, "cr_Npr": v.cornering_stiffness_r_Npr,
                    "fzf_N": v.fz_front_static_N, "fzr_N": v.fz_rear_static_N, "grip": v.tires.grip},
        "code": [harness.__version__, lmi.source_fingerprint(lmi, design_for)],
    }
    return lmi.cached_design(payload, lambda: design_vehicle(v, obs.variant, opts, settings),
                             use_cache=bool(obs.options["use_cache"]))
