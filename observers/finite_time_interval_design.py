r"""LMI designs of the discrete LPV finite-time and interval estimators of Bessafa (2024), ch. 2.

Model (thesis eqs. (2.32)–(2.37)): forward-Euler bicycle in ``x = (beta, r)`` with step ``T_s``,
scheduled on ``rho = (1/v_x, 1/v_x^2)`` (treated as independent, box ``[rho1_lo, rho1_hi] x
[rho2_lo, rho2_hi]``), ``y = r``:

.. math::

    A_N(\rho) = I + T_s \begin{bmatrix} -(c_f + c_r)\rho_1/m & (c_r l_r - c_f l_f)\rho_2/m - 1 \\
    (c_r l_r - c_f l_f)/I_z & -(c_r l_r^2 + c_f l_f^2)\rho_1/I_z \end{bmatrix},\quad
    B_u(\rho) = T_s \begin{bmatrix} c_f \rho_1/m \\ c_f l_f/I_z \end{bmatrix}.

``A_N`` is affine in each ``rho_i``; the bilinear weights ``xi`` of (2.37) interpolate it exactly
over the 4 box corners, in the thesis's order ``(lo, lo), (lo, hi), (hi, lo), (hi, hi)``.

*Fresh design* (Algorithm 1, Theorem 2.3.2). Gains are designed on the true corner matrices
``A_N(v_i)`` with the poly-quadratic LMIs over all corner pairs ``(i, j)``:

* (2.12) ``[[P_j - X - X^T, (X A_i - Z_i C)/alpha], [*, -P_i]] < 0``, ``L_i = X^-1 Z_i``,
* (2.13) ``[[P_j - Y - Y^T, 2 (Y A_i - S_i C)], [*, -P_i]] < 0``, ``K_i = Y^-1 S_i``,
  with (2.14) ``2 beta Y - He(Y A_i - S_i C) < 0`` (else (2.15) with the sign reversed) added when
  feasible.

One deliberate change: the slack matrix ``X`` (resp. ``Y``) is *common* to the corners instead of
``X_i``. With a common slack the weighted sum ``sum xi_i(rho) xi_j(rho+) LMI(i, j)`` is exactly the
LMI of the closed loop ``A_N(rho) - L(rho) C`` with ``L(rho) = sum xi_i L_i`` and the Lyapunov
matrices ``P(rho) = sum xi_i P_i`` at ``rho``, ``rho+``: the vertex conditions then certify the
parameter-varying error dynamics for *any* measured ``rho`` trajectory in the box, which per-corner
slacks only do for switching between the corners. ``alpha`` starts at ``alpha_start`` and grows by
``alpha_step`` until (2.12) is feasible (Algorithm 1, steps 1–2).

Algorithm 1, step 4 (``m``): ``E_m = Phi_L^-1 - Phi_K^-1`` must be invertible for every schedule.
``L(rho) C`` and ``K(rho) C`` differ by a rank-1 matrix, so ``E_1`` is singular and ``m = 2`` is the
smallest horizon (the thesis's value). The check evaluates ``cond(E_2)`` on every pair of points of
a grid of the box.

*As printed* (thesis §2.4.2): the printed ``L_i, K_i`` (``i = 0..4``, increment form
``L(rho) = L_0 + sum xi_i L_i``) are evaluated, not solved: the vertex gains are ``L_0 + L_i``.

Certification (:func:`roadtruth.observers.lmi.certify_design` plus the discrete-time checks below): the
poly-quadratic LMIs at the 16 corner pairs and on pairs of grid points, ``P(rho) > 0``; the frozen
closed loops' spectral radius ``< 1`` with no zero eigenvalue (Theorem 2.3.1 needs invertible
``A - L C``); ``cond(E_2) <= cond_max`` on all grid pairs. The Efimov et al. observer (thesis §2.2)
is certified by ``A_N(rho) - L C >= 0`` elementwise (cooperativity, needed for inclusion) and the
boundedness LMI (2.7) with a diagonal ``P`` at the corners and on the grid.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

import roadtruth.harness as harness
from roadtruth.observers import lmi
from roadtruth.observers.lmi import (
    DesignResult,
    DesignStatus,
    SolverSettings,
    box_corners,
    certify_design,
    solve_lmi,
    sym,
)

C = np.array([[0.0, 1.0]])
I2 = np.eye(2)
#: Printed gains of thesis §2.4.2 (increment form, i = 0..4): L_i, K_i as (2,) columns.
PRINTED_L = ((-0.2603, 0.2670), (-0.0271, 0.4457), (-0.0660, -0.0011), (0.0642, 0.5662), (-0.1776, 0.2238))
PRINTED_K = ((0.0124, 0.0856), (0.0782, -0.0111), (0.6228, -0.5721), (0.0899, -0.0111), (0.6345, -0.5721))
P_FLOOR = 1.0        # P_i >= I: normalisation of the homogeneous LMIs
EIG_FLOOR = 1e-6     # |eig(A - L C)| above this: Phi invertible (Theorem 2.3.1)


@dataclass(frozen=True)
class BicycleLPV:
    """Discrete bicycle LPV model (2.32)–(2.34). Masses [kg], inertia [kg m^2], lengths [m],
    axle stiffness [N/rad], step [s], scheduling box ``rho1 = 1/v_x`` [s/m], ``rho2 = 1/v_x^2`` [s^2/m^2]."""

    mass_kg: float
    yaw_inertia_kgm2: float
    lf_m: float
    lr_m: float
    cf_Npr: float
    cr_Npr: float
    ts_s: float
    rho1_range: tuple[float, float]
    rho2_range: tuple[float, float]

    @classmethod
    def from_speed_range(cls, mass_kg: float, yaw_inertia_kgm2: float, lf_m: float, lr_m: float, cf_Npr: float,
                         cr_Npr: float, ts_s: float, vx_range_mps: tuple[float, float]) -> BicycleLPV:
        vlo, vhi = vx_range_mps
        return cls(mass_kg, yaw_inertia_kgm2, lf_m, lr_m, cf_Npr, cr_Npr, ts_s,
                   (1.0 / vhi, 1.0 / vlo), (1.0 / vhi**2, 1.0 / vlo**2))

    def a(self, rho1: float, rho2: float, dcf: float = 0.0, dcr: float = 0.0) -> np.ndarray:
        """``A(rho)`` (2.33) with stiffness ``c_N + dc`` (``dc = 0``: nominal ``A_N``): (2, 2) [1]."""
        m, iz, lf, lr, ts = self.mass_kg, self.yaw_inertia_kgm2, self.lf_m, self.lr_m, self.ts_s
        cf, cr = self.cf_Npr + dcf, self.cr_Npr + dcr
        return I2 + ts * np.array([[-(cf + cr) / m * rho1, (cr * lr - cf * lf) / m * rho2 - 1.0],
                                   [(cr * lr - cf * lf) / iz, -(cr * lr**2 + cf * lf**2) / iz * rho1]])

    def b(self, rho1: float, dcf: float = 0.0) -> np.ndarray:
        """``B_u(rho)`` (2.34) with front stiffness ``c_fN + dcf``: (2,) [1/s, rad/s per rad]."""
        cf = self.cf_Npr + dcf
        return self.ts_s * np.array([cf / self.mass_kg * rho1, cf * self.lf_m / self.yaw_inertia_kgm2])

    def corners(self) -> np.ndarray:
        """The 4 corners of the scheduling box in the order of (2.37): (4, 2)."""
        return box_corners([self.rho1_range, self.rho2_range])

    def weights(self, rho1: float, rho2: float) -> np.ndarray:
        """Polytopic weights ``xi`` (2.37): (4,), nonnegative inside the box, summing to 1."""
        (l1, h1), (l2, h2) = self.rho1_range, self.rho2_range
        a1, a2 = (h1 - rho1) / (h1 - l1), (h2 - rho2) / (h2 - l2)
        return np.array([a1 * a2, a1 * (1 - a2), (1 - a1) * a2, (1 - a1) * (1 - a2)])

    def grid(self, n: int) -> np.ndarray:
        """``n x n`` points of the box: (n*n, 2)."""
        return np.array(list(itertools.product(np.linspace(*self.rho1_range, n), np.linspace(*self.rho2_range, n))))


def scheduled(gains: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """``sum xi_i G_i`` for vertex gains (4, 2): (2,)."""
    return xi @ gains


def closed_loop(model: BicycleLPV, gains: np.ndarray, rho: Sequence[float]) -> np.ndarray:
    """Frozen error matrix ``A_N(rho) - G(rho) C``: (2, 2)."""
    g = scheduled(gains, model.weights(rho[0], rho[1]))
    return model.a(rho[0], rho[1]) - np.outer(g, C[0])


def e2_condition(model: BicycleLPV, L: np.ndarray, K: np.ndarray, pts: np.ndarray) -> float:
    """Largest ``cond(E_2)`` over all ordered pairs of ``pts`` (rho at k-1, rho at k-2)."""
    ML = [closed_loop(model, L, p) for p in pts]
    MK = [closed_loop(model, K, p) for p in pts]
    worst = 0.0
    for i in range(len(pts)):
        for j in range(len(pts)):
            E = np.linalg.inv(ML[i] @ ML[j]) - np.linalg.inv(MK[i] @ MK[j])
            worst = max(worst, float(np.linalg.cond(E)))
    return worst


# ---- poly-quadratic SDPs ---------------------------------------------------------------------------

def _pq_problem(As: list[np.ndarray], scale: float, region: tuple[str, float] | None,
                settings: SolverSettings) -> tuple[Any, dict[str, Any]]:
    """(2.12)/(2.13) with a common slack ``X``; ``scale`` = 1/alpha (2.12) or 2 (2.13)."""
    import cvxpy as cp

    n = len(As)
    P = [cp.Variable((2, 2), symmetric=True) for _ in range(n)]
    X = cp.Variable((2, 2))
    Z = [cp.Variable((2, 1)) for _ in range(n)]
    eps = settings.strictness
    cons = [Pi >> P_FLOOR * I2 for Pi in P]
    for i in range(n):
        M = X @ As[i] - Z[i] @ C
        for j in range(n):
            cons.append(sym(cp.bmat([[P[j] - X - X.T, scale * M], [scale * M.T, -P[i]]])) << -eps * np.eye(4))
        if region is not None:
            sign = 1.0 if region[0] == "above" else -1.0   # (2.14) or (2.15)
            cons.append(sym(sign * (2 * region[1] * X - M - M.T)) << -eps * I2)
    exprs = {"X": X} | {f"P{i}": P[i] for i in range(n)} | {f"Z{i}": Z[i] for i in range(n)}
    return cp.Problem(cp.Minimize(0), cons), exprs


def _pq_lmi(model: BicycleLPV, X: np.ndarray, P: np.ndarray, G: np.ndarray, scale: float
            ) -> Callable[[np.ndarray], np.ndarray]:
    """The (2.12)/(2.13) matrix at ``(rho, rho+)`` = ``pt[:2], pt[2:]`` (weighted sum of corner pairs)."""
    def fn(pt: np.ndarray) -> np.ndarray:
        xi, xn = model.weights(pt[0], pt[1]), model.weights(pt[2], pt[3])
        Pk, Pn = np.tensordot(xi, P, 1), np.tensordot(xn, P, 1)
        M = X @ closed_loop(model, G, pt[:2])
        return np.block([[Pn - X - X.T, scale * M], [scale * M.T, -Pk]])
    return fn


def _solve_pq(model: BicycleLPV, scale: float, region: tuple[str, float] | None, settings: SolverSettings
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    As = [model.a(*v) for v in model.corners()]
    out = solve_lmi(lambda: _pq_problem(As, scale, region, settings), settings)
    if out.status != "optimal":
        return None
    X = out.values["X"].reshape(2, 2)
    P = np.array([out.values[f"P{i}"].reshape(2, 2) for i in range(4)])
    G = np.array([np.linalg.solve(X, out.values[f"Z{i}"].reshape(2, 1))[:, 0] for i in range(4)])
    return X, P, G


@dataclass(frozen=True)
class FlpvOptions:
    """Design options: ``alpha_start``, ``alpha_step`` (Algorithm 1), ``beta`` of (2.14)/(2.15),
    ``cond_max`` (largest accepted ``cond(E_2)``), ``grid_n`` (certification grid per axis)."""

    alpha_start: float = 0.05
    alpha_step: float = 0.05
    beta: float = 0.0
    cond_max: float = 1e8
    grid_n: int = 6


def _discrete_checks(model: BicycleLPV, L: np.ndarray, K: np.ndarray, pts: np.ndarray, cond_max: float
                     ) -> tuple[list[str], dict[str, float]]:
    margins: dict[str, float] = {}
    failures: list[str] = []
    for name, G in (("L", L), ("K", K)):
        eig = [np.abs(np.linalg.eigvals(closed_loop(model, G, p))) for p in pts]
        rad, low = max(float(e.max()) for e in eig), min(float(e.min()) for e in eig)
        margins[f"{name}_spectral_radius_max"] = rad
        margins[f"{name}_eig_modulus_min"] = low
        if not rad < 1.0:
            worst = pts[int(np.argmax([e.max() for e in eig]))]
            failures.append(f"{name} observer unstable: |eig| = {rad:.4g} at rho = ({worst[0]:.4g}, {worst[1]:.4g})")
        if not low > EIG_FLOOR:
            failures.append(f"{name} observer has a zero eigenvalue (|eig| = {low:.3g}): Phi not invertible")
    for i, v in enumerate(model.corners()):
        for name, G in (("L", L), ("K", K)):
            margins[f"{name}_radius_vertex{i + 1}"] = float(np.abs(np.linalg.eigvals(closed_loop(model, G, v))).max())
    ce = e2_condition(model, L, K, pts)
    margins["cond_E2_max"] = ce
    if not ce <= cond_max:
        failures.append(f"E_2 ill-conditioned: cond = {ce:.3g} > {cond_max:.3g}")
    return failures, margins


def _pair_points(model: BicycleLPV, n: int) -> tuple[np.ndarray, np.ndarray]:
    c, g = model.corners(), model.grid(n)
    verts = np.array([np.r_[a, b] for a in c for b in c])
    grid = np.array([np.r_[a, b] for a in g for b in g])
    return verts, grid


def design_flpv(model: BicycleLPV, variant: str, opts: FlpvOptions, settings: SolverSettings) -> DesignResult:
    """Algorithm 1 (``fresh``) or the printed gains (``printed``), certified. Gains ``L``, ``K``:
    vertex gains (4, 2) in the corner order of (2.37); margins include ``alpha``, ``beta``, ``m``."""
    pts = np.vstack([model.corners(), model.grid(opts.grid_n)])
    if variant == "printed":
        L = np.array([np.add(PRINTED_L[0], PRINTED_L[i]) for i in range(1, 5)])
        K = np.array([np.add(PRINTED_K[0], PRINTED_K[i]) for i in range(1, 5)])
        failures, margins = _discrete_checks(model, L, K, pts, opts.cond_max)
        ok = not failures
        head = "printed gains (thesis §2.4.2), vertex gains L_0 + L_i: "
        reason = head + ("all discrete-time checks passed" if ok else "certification failed: " + "; ".join(failures))
        return DesignResult(DesignStatus.CERTIFIED if ok else DesignStatus.REJECTED, ok, reason,
                            {"L": L.tolist(), "K": K.tolist()}, None, {**margins, "m": 2.0}, None, {}, variant)
    if variant != "fresh":
        raise ValueError(f"unknown FLPV variant {variant!r}")
    alpha, solL = opts.alpha_start, None
    while alpha < 1.0 and solL is None:
        solL = _solve_pq(model, 1.0 / alpha, None, settings)
        if solL is None:
            alpha = round(alpha + opts.alpha_step, 10)
    if solL is None:
        return DesignResult(DesignStatus.INFEASIBLE, False, "LMI (2.12) infeasible for every alpha < 1", variant=variant)
    region: tuple[str, float] | None = ("above", opts.beta)
    solK = _solve_pq(model, 2.0, region, settings)
    if solK is None:
        region = ("below", opts.beta)
        solK = _solve_pq(model, 2.0, region, settings)
    if solK is None:
        region = None
        solK = _solve_pq(model, 2.0, None, settings)
    if solK is None:
        return DesignResult(DesignStatus.INFEASIBLE, False, "LMI (2.13) infeasible", variant=variant)
    (XL, PL, L), (XK, PK, K) = solL, solK
    verts, grid = _pair_points(model, opts.grid_n)
    lmis = {"lmi_2_12": _pq_lmi(model, XL, PL, L, 1.0 / alpha), "lmi_2_13": _pq_lmi(model, XK, PK, K, 2.0),
            "P_L_positive": lambda p: -np.tensordot(model.weights(p[0], p[1]), PL, 1),
            "P_K_positive": lambda p: -np.tensordot(model.weights(p[0], p[1]), PK, 1)}
    cert = certify_design(P=None, lmis=lmis, vertices=verts, grid=grid, margin=settings.certify_margin)
    failures, margins = _discrete_checks(model, L, K, pts, opts.cond_max)
    ok = cert.certified and not failures
    region_txt = "none" if region is None else ("(2.14)" if region[0] == "above" else "(2.15)")
    head = f"alpha = {alpha:.3g}, K region {region_txt}, m = 2: "
    reason = head + ("all checks passed at every corner pair and grid pair" if ok else
                     "certification failed: " + "; ".join(([] if cert.certified else [cert.reason]) + failures))
    margins = {**cert.margins, **margins, "alpha": alpha, "beta": opts.beta, "m": 2.0,
               "k_region": 0.0 if region is None else (1.0 if region[0] == "above" else -1.0)}
    return DesignResult(DesignStatus.CERTIFIED if ok else DesignStatus.REJECTED, ok, reason,
                        {"L": L.tolist(), "K": K.tolist()}, None, margins, None, {}, variant)


# ---- Efimov et al. interval observer (thesis §2.2) ---------------------------------------------------

def delta_a_bounds(model: BicycleLPV, rho1: float, rho2: float, dcf: float, dcr: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Elementwise bounds of ``Delta A(rho)`` (2.35, times ``T_s``) for ``|dc_f| <= dcf``, ``|dc_r| <= dcr``."""
    m, iz, lf, lr, ts = model.mass_kg, model.yaw_inertia_kgm2, model.lf_m, model.lr_m, model.ts_s
    h = ts * np.array([[(dcf + dcr) / m * rho1, (dcr * lr + dcf * lf) / m * rho2],
                       [(dcr * lr + dcf * lf) / iz, (dcr * lr**2 + dcf * lf**2) / iz * rho1]])
    return -h, h


def efimov_gain(model: BicycleLPV) -> np.ndarray:
    """Constant ``L`` that makes ``A_N(rho) - L C`` nonnegative on the whole box with the largest
    injection on the measured column (its entries are affine in rho: the corners decide): (2,)."""
    As = [model.a(*v) for v in model.corners()]
    return np.array([min(A[0, 1] for A in As), min(A[1, 1] for A in As)])


def _efimov_G(model: BicycleLPV, L: np.ndarray, rho: np.ndarray, dc: tuple[float, float]
              ) -> tuple[np.ndarray, float]:
    A0 = model.a(rho[0], rho[1]) - np.outer(L, C[0])
    lo, hi = delta_a_bounds(model, rho[0], rho[1], *dc)
    pos = lambda M: np.maximum(M, 0.0)  # noqa: E731
    neg = lambda M: pos(M) - M  # noqa: E731
    eta = 2.0 * (np.linalg.norm(pos(lo) - pos(hi), 2) + np.linalg.norm(neg(lo), 2) + np.linalg.norm(neg(hi), 2))
    G = np.block([[A0 + pos(lo), np.zeros((2, 2))], [np.zeros((2, 2)), A0 + pos(hi)]])
    return G, float(eta)


def _efimov_lmi(G: np.ndarray, eta: float, P: Any, Q: Any, g: Any, e1: float, e2: float) -> Any:
    import cvxpy as cp
    psi = (1 + e1) * G.T @ P @ G - P + Q + g * eta**2 * np.eye(4)
    return cp.bmat([[psi, G.T @ P], [P @ G, (1 + e2) * P - g * np.eye(4)]])


def width_matrix(model: BicycleLPV, L: np.ndarray, rho: Sequence[float], dc: tuple[float, float]) -> np.ndarray:
    """Nonnegative matrix of the width recursion ``w+ <= (A_N(rho) - L C + 2 h(rho)) w + ...`` (2, 2),
    where ``[-h, h]`` bounds ``Delta A(rho)`` (from (2.5): the upper minus the lower bracket term is
    ``2 h (x_hi^+ + x_lo^-) <= 2 h (w + |x|)``)."""
    return model.a(rho[0], rho[1]) - np.outer(L, C[0]) + 2.0 * delta_a_bounds(model, rho[0], rho[1], *dc)[1]


def design_efimov(model: BicycleLPV, dc: tuple[float, float], settings: SolverSettings, grid_n: int = 6
                  ) -> DesignResult:
    """Cooperative gain ``L``; the boundedness LMI (2.7) as printed (diagonal ``P``, corners + grid),
    and the certificate actually used: a linear copositive Lyapunov function ``p`` of the width
    recursion, ``W(rho)^T p <= decay p`` at the corners (``W`` is affine in rho, so the corners
    cover the box and any time variation; ``V = p^T w`` then contracts)."""
    import cvxpy as cp

    L = efimov_gain(model)
    pts = np.vstack([model.corners(), model.grid(grid_n)])
    coop = min(float((model.a(*p) - np.outer(L, C[0])).min()) for p in pts)
    margins: dict[str, float] = {"nonnegativity_min_entry": coop}
    if coop < 0.0:
        return DesignResult(DesignStatus.INFEASIBLE, False,
                            f"A_N(rho) - L C cannot be made nonnegative (entry {coop:.3g} < 0: a11 = 1 - T_s (c_f + c_r)"
                            " rho1 / m is negative at this step); the interval observer does not apply",
                            {"L": L.tolist()}, None, margins, variant="efimov")
    Gs = [_efimov_G(model, L, p, dc) for p in pts]
    e1 = e2 = 0.01

    def build() -> tuple[Any, dict[str, Any]]:
        p = cp.Variable(4)
        P, Q, g = cp.diag(p), cp.Variable((4, 4), symmetric=True), cp.Variable()
        cons = [p >= 1.0, Q >> settings.strictness * np.eye(4), g >= 0]
        cons += [sym(_efimov_lmi(G, eta, P, Q, g, e1, e2)) << -settings.strictness * np.eye(8) for G, eta in Gs]
        return cp.Problem(cp.Minimize(g), cons), {"p": p}

    printed = solve_lmi(build, settings)
    margins["lmi_2_7_feasible"] = 1.0 if printed.status == "optimal" else 0.0
    margins["eta_max"] = max(eta for _, eta in Gs)
    Ws = [width_matrix(model, L, v, dc) for v in model.corners()]
    best = None
    lo, hi = 0.0, 1.0
    for _ in range(14):   # bisection on the contraction factor (the LP is quasi-convex in it)
        mid = 0.5 * (lo + hi)
        out = solve_lmi(lambda mid=mid: _copositive_lp(Ws, mid), settings)
        if out.status == "optimal":
            best, hi = (out.values["p"], mid), mid
        else:
            lo = mid
    text_27 = "feasible" if printed.status == "optimal" else f"infeasible (eta up to {margins['eta_max']:.3g})"
    if best is None:
        # Inclusion still holds (cooperative error dynamics); boundedness of the width is not certified.
        return DesignResult(DesignStatus.REJECTED, False,
                            f"cooperative gain (inclusion holds); boundedness LMI (2.7) as printed {text_27}; no "
                            "copositive certificate of the width recursion: the bounds may grow",
                            {"L": L.tolist()}, None, margins, variant="efimov")
    p, rate = best
    fine = np.vstack([model.corners(), model.grid(2 * grid_n + 1)])
    # diag(W^T p - p) is negative definite iff every entry of W^T p is below p
    chk = {"width_copositive": lambda r: np.diag(width_matrix(model, L, r, dc).T @ p - p)}
    cert = certify_design(P=np.diag(p), lmis=chk, vertices=model.corners(), grid=fine, margin=settings.certify_margin)
    margins.update(cert.margins)
    margins["width_contraction"] = rate
    st = DesignStatus.CERTIFIED if cert.certified else DesignStatus.REJECTED
    reason = (f"cooperative gain; boundedness LMI (2.7) as printed {text_27}; width recursion contracts by "
              f"{rate:.4g} per step (copositive p): {cert.reason}")
    return DesignResult(st, cert.certified, reason, {"L": L.tolist(), "p": p.tolist()}, np.diag(p).tolist(), margins,
                        None, printed.stats, "efimov")


def _copositive_lp(Ws: list[np.ndarray], rate: float) -> tuple[Any, dict[str, Any]]:
    import cvxpy as cp
    p = cp.Variable(2)
    return cp.Problem(cp.Minimize(cp.sum(p)), [p >= 1.0] + [W.T @ p <= rate * p for W in Ws]), {"p": p}


def _efimov_np(model: BicycleLPV, L: np.ndarray, rho: np.ndarray, dc: tuple[float, float], P: np.ndarray,
               Q: np.ndarray, g: float, e1: float, e2: float) -> np.ndarray:
    G, eta = _efimov_G(model, L, rho, dc)
    psi = (1 + e1) * G.T @ P @ G - P + Q + g * eta**2 * np.eye(4)
    return np.block([[psi, G.T @ P], [P @ G, (1 + e2) * P - g * np.eye(4)]])


# ---- cached entry point ------------------------------------------------------------------------------

def cached(family: str, model: BicycleLPV, variant: str, extra: dict[str, Any], use_cache: bool,
           compute: Callable[[], DesignResult]) -> DesignResult:
    """``lmi.cached_design`` keyed by the model, variant, options, solver and this module's source."""
    settings = SolverSettings()
    payload = {"family": family, "variant": variant, "model": asdict(model), "options": extra,
               "solver": settings.to_dict(), "code": [harness.__version__, lmi.source_fingerprint(lmi, cached)]}
    return lmi.cached_design(payload, compute, use_cache=use_cache)
