r"""LMI designs of the radar high-gain observers of Bessafa (2024) (see :mod:`roadtruth.observers.high_gain_radar`).

Error coordinates ``eps = T(theta)^-1 (x - x_hat)``, ``T(theta) = diag(theta, theta^2, theta^3)``.

* SHGO, Thm 4.3.1: ``He{P A - Y^T C} + lambda I < 0`` (4.20), lambda fixed, minimise
  ``lambda_max(P)``; ``K = P^-1 Y^T``; ``theta > theta_0 = 2 k_f lambda_max(P) / lambda`` (4.21).
* Generalized multi-output HGO, Thm 4.3.4 (4.57): ``[[He{P A - Y^T C + Z^T Acal(xi)} + lambda I, Y^T],
  [Y, -X]] < 0`` at every vertex ``xi`` of ``V^sigma`` (4.55)-(4.56); ``K = P^-1 Y^T``, ``N = P^-1 Z^T``,
  ``theta > max(sigma, 2 k_f lambda_max(P) / lambda)`` (4.58). Here ``z = h(x) = x_2`` (range rate), so
  the mean-value (DMVT) parameters of Lemma 4.3.1 are ``psi = (0, 1, 0)`` exactly; with
  ``gamma_lo = 0 <= gamma_hi = 1`` (0 kept in the set) the vertex set is
  ``xi_2 in {0, sigma^-2}``, ``xi_1 = xi_3 = 0`` (``psi_j^theta = theta^(j-n-1) psi_j``). Remark 4.3.1:
  ``Z_2 >= z_min`` keeps ``N`` from collapsing to zero.
* "as printed" SHGO (sec. 5.2.2(a)): the printed ``P``, ``Y`` and ``theta = 39.3974`` are evaluated,
  not solved, through the same certification.

Certification (NumPy, independent of the solver): P > 0; the theorem LMI at every vertex and on a
grid of ``xi_2``; and the **decay LMI** ``He{P M} + kappa P <= 0`` with the *exact* mean-value error
matrix ``M = theta (A - K C - xi_2 N e_2^T) + B [0, f_v / theta, f_a]`` at every corner of the
(lead speed, lead acceleration) box, where ``grad f = (0, f_v, f_a)`` is affine in (v, a), so its
convex hull is spanned by the 4 corners. ``kappa = (theta lambda - 2 k_f lambda_max(P)) / lambda_max(P)``
(4.60) is the rate the theorem promises for ``V = eps^T P eps``: ``V(t) <= V(0) exp(-kappa t)``.
"""

from __future__ import annotations

import itertools
import math
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

N_STATES = 3
A_CHAIN = np.diag([1.0, 1.0], k=1)
B_CHAIN = np.array([[0.0], [0.0], [1.0]])
C_RANGE = np.array([[1.0, 0.0, 0.0]])
E2 = np.array([[0.0, 1.0, 0.0]])
P_FLOOR = 1.0  # P >= I: normalisation; with lambda_max(P) minimised it bounds cond(P) and the gains

#: SHGO design printed in sec. 5.2.2(a) of the thesis (lambda = 1).
PRINTED_SHGO: dict[str, Any] = {
    "P": [[6.5068, -1.5796, -2.3284], [-1.5796, 3.0199, -1.5796], [-2.3284, -1.5796, 6.5068]],
    "Y": [2.3626, 6.5068, -1.5796], "K": [1.7255, 3.7263, 1.2793], "theta": 39.3974, "lambda": 1.0,
}


#: Method 2 design printed in sec. 5.2.2(b) (no lambda printed for it; the same P, Y, Z are printed with
#: lambda = 1 for the CARLA case, sec. 5.2.3). ``Z > 1e4`` is printed as a constraint but Z is ~2.
PRINTED_METHOD2: dict[str, Any] = {
    "P": [[294.6169, -85.2035, -111.2819], [-85.2035, 105.2495, -49.4222], [-111.2819, -49.4222, 211.9653]],
    "Y": [104.6494, 350.2155, -29.3206], "Z": [2.9269, 1.6601, 2.0146], "K": [4.7563, 9.3042, 4.5281],
    "theta": 30.3704, "M_norm": 1.5338,
}
#: Design options read by :func:`design` (the cache key holds those an observer has).
DESIGN_OPTIONS = ("lambda_", "sigma", "z_min", "theta_factor", "lead_speed_range_mps", "lead_accel_range_mps2",
                  "m1_alpha", "m1_norm_fraction", "m1_direction", "m2_sigma", "m2_lambda", "ext_alpha", "ext_varpi")


def gradient_corners(lead: dict[str, float], v_range: tuple[float, float],
                     a_range: tuple[float, float]) -> np.ndarray:
    """Corners of a rectangle holding every mean-value ``(f_v, f_a)``: (4, 2) [1/s, 1/s].

    ``f(v, a) = -(2 K_d/m) v a - (1/tau)(a + (K_d/m) v^2 + d_m/m)`` (1.35); its gradient is affine in
    (v, a), so these corners span the convex hull of the gradient over the box.
    """
    m, tau, kd = lead["mass_kg"], lead["tau_s"], lead["kd_Ns2pm2"]
    g = np.array([(-(2.0 * kd / m) * a - (2.0 * kd / (m * tau)) * v, -(2.0 * kd / m) * v - 1.0 / tau)
                  for v, a in itertools.product(v_range, a_range)])
    # The observer evaluates f at (v, a) clipped to the box, which scales each component of the
    # mean-value gradient by some s in [0, 1]: 0 is added to each component's range.
    fv = (min(g[:, 0].min(), 0.0), max(g[:, 0].max(), 0.0))
    fa = (min(g[:, 1].min(), 0.0), max(g[:, 1].max(), 0.0))
    return np.array(list(itertools.product(fv, fa)))


def lipschitz_kf(corners: np.ndarray) -> float:
    """``k_f = max ||grad f||_2`` over the box (a convex function of an affine map: max at a corner).

    For ``theta >= 1``: ``||T^-1 B (f(x) - f(x_hat))|| = theta^-3 |grad f . T eps| <= k_f ||eps||``.
    """
    return float(np.max(np.hypot(corners[:, 0], corners[:, 1])))


def design_for(req: DesignRequest) -> DesignResult:
    """Cached design for an observer instance (its lead model, variant and options)."""
    opts = {k: req.options[k] for k in DESIGN_OPTIONS if k in req.options}
    lead = req.model
    settings = SolverSettings()
    payload = {"family": "high_gain_radar", "variant": req.variant, "options": opts, "lead": lead,
               "solver": settings.to_dict(),
               "code": [harness.__version__, lmi.source_fingerprint(lmi, design_for)]}
    return lmi.cached_design(payload, lambda: design(req.variant, lead, opts, settings),
                             use_cache=bool(req.options["use_cache"]))


def design(variant: str, lead: dict[str, float], opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    """Solve (or evaluate) and certify ``variant`` in {'standard', 'multi', 'standard_printed', 'method1',
    'method2', 'method2_printed', 'extension'}."""
    lam = float(opts["lambda_"])
    corners = gradient_corners(lead, tuple(opts["lead_speed_range_mps"]), tuple(opts["lead_accel_range_mps2"]))
    kf = lipschitz_kf(corners)
    if variant == "method1":
        return _design_method1(lam, kf, corners, opts, settings)
    if variant in ("method2", "method2_printed"):
        return _design_method2(variant, kf, corners, opts, settings)
    if variant == "extension":
        return design_extension(lam, kf, corners, opts, settings)
    if variant == "standard_printed":
        P = np.array(PRINTED_SHGO["P"])
        Y = np.array(PRINTED_SHGO["Y"]).reshape(1, 3)
        return certify_gains(variant, P, Y, np.zeros((1, 3)), None, lam, 1.0, kf, corners,
                        float(PRINTED_SHGO["theta"]), {"solver": "none (printed gains)"})
    multi = variant == "multi"
    sigma = float(opts["sigma"]) if multi else 1.0
    out = solve_lmi(lambda: _problem(multi, lam, sigma, float(opts["z_min"]), settings), settings)
    if out.status != "optimal":
        status = DesignStatus.INFEASIBLE if out.status == "infeasible" else DesignStatus.SOLVER_FAILED
        return DesignResult(status, False, f"LMI (4.20)/(4.57) {out.status}", solver_stats=out.stats, variant=variant)
    P = sym(out.values["P"])
    Y = out.values["Y"].reshape(1, 3)
    Z = out.values["Z"].reshape(1, 3) if multi else np.zeros((1, 3))
    X = out.values["X"].reshape(1, 1) if multi else None
    theta0 = 2.0 * kf * float(np.linalg.eigvalsh(P).max()) / lam
    theta = max(sigma, 1.0, float(opts["theta_factor"]) * theta0)
    return certify_gains(variant, P, Y, Z, X, lam, sigma, kf, corners, theta, out.stats)


def _problem(multi: bool, lam: float, sigma: float, z_min: float, settings: SolverSettings) -> tuple[Any, dict]:
    import cvxpy as cp

    P = cp.Variable((3, 3), symmetric=True)
    Y = cp.Variable((1, 3))
    t = cp.Variable()
    eps = settings.strictness
    cons = [P >> P_FLOOR * np.eye(3), P << t * np.eye(3)]
    exprs: dict[str, Any] = {"P": P, "Y": Y}
    if not multi:
        cons.append(sym(P @ A_CHAIN - C_RANGE.T @ Y) * 2 + lam * np.eye(3) << -eps * np.eye(3))
        return cp.Problem(cp.Minimize(t), cons), exprs
    Z = cp.Variable((1, 3))
    X = cp.Variable((1, 1), symmetric=True)
    cons += [Z[0, 1] >= z_min, X >> eps]
    for xi2 in (0.0, sigma ** -2):
        acal = -xi2 * E2                       # Acal(xi) = -sum_j xi_j e_n^T(j)
        top = 2 * sym(P @ A_CHAIN - C_RANGE.T @ Y + Z.T @ acal) + lam * np.eye(3)
        cons.append(sym(cp.bmat([[top, Y.T], [Y, -X]])) << -eps * np.eye(4))
    exprs.update({"Z": Z, "X": X})
    # lambda_max(P) sets theta_0; X sets the noise gain of the ISS bound (4.59). Weight X lightly.
    return cp.Problem(cp.Minimize(t + 1e-3 * X[0, 0]), cons), exprs


def error_matrix(K: np.ndarray, N: np.ndarray, theta: float, xi2: float, fv: float, fa: float) -> np.ndarray:
    """Exact mean-value error matrix of ``eps`` (3, 3) [1/s] (4.53 with ``Delta f = grad f . e``)."""
    M = theta * (A_CHAIN - K.reshape(3, 1) @ C_RANGE - xi2 * N.reshape(3, 1) @ E2)
    M[2, 1] += fv / theta
    M[2, 2] += fa
    return M


def certify_gains(variant: str, P: np.ndarray, Y: np.ndarray, Z: np.ndarray, X: np.ndarray | None, lam: float,
                  sigma: float, kf: float, corners: np.ndarray, theta: float, stats: dict[str, Any], *,
                  thm_xi_hi: float | None = None, err_n: np.ndarray | None = None, err_xi_hi: float | None = None,
                  kappa: float | None = None, theta_min: float | None = None,
                  extra_failures: tuple[str, ...] = (), extra_margins: dict[str, float] | None = None,
                  extra_gains: dict[str, list[float]] | None = None) -> DesignResult:
    """Certify given ``P`` (3, 3), ``Y``, ``Z`` (1, 3), ``X`` (1, 1) or None (SHGO) at ``theta``.

    Checks LMI (4.20)/(4.57) at the vertices ``xi_2 in {0, sigma^-2}`` and a grid, condition
    (4.21)/(4.58) ``theta > theta_0``, and the decay LMI ``He{P M} + kappa P <= 0`` at the corners
    ``corners`` (4, 2) of the mean-value gradient of f (see module docstring).

    The keywords serve Methods 1 and 2 (Thm 4.3.2 / 4.3.3): ``thm_xi_hi`` the upper vertex of ``xi_2``
    in the theorem LMI (Method 2: ``sigma``, LMI (4.39)); ``err_n`` (3,) and ``[0, err_xi_hi]`` the
    range-rate term ``xi_2 err_n e_2^T`` of the exact error matrix (default ``N`` and the theorem's
    range); ``kappa`` the theorem's rate [1/s]; ``theta_min`` the lower bound theta must exceed
    (default ``theta_0`` and sigma); ``extra_failures`` further failed conditions (e.g. (4.27b)).
    """
    K = np.linalg.solve(P, Y.T).reshape(3)
    N = np.linalg.solve(P, Z.T).reshape(3)
    pmax = float(np.linalg.eigvalsh(P).max())
    theta0 = 2.0 * kf * pmax / lam
    if kappa is None:
        kappa = (theta * lam - 2.0 * kf * pmax) / pmax
    multi = X is not None or thm_xi_hi is not None
    xi_hi = thm_xi_hi if thm_xi_hi is not None else (sigma ** -2 if X is not None else 0.0)
    n_err = N if err_n is None else np.asarray(err_n, dtype=float).reshape(3)
    exi_hi = xi_hi if err_xi_hi is None else float(err_xi_hi)

    def thm_lmi(p: np.ndarray) -> np.ndarray:
        top = 2 * (P @ A_CHAIN - C_RANGE.T @ Y - p[0] * Z.T @ E2)
        top = 0.5 * (top + top.T) + lam * np.eye(3)
        if X is None:
            return top
        return np.block([[top, Y.T], [Y, -X]])

    def decay_lmi(p: np.ndarray) -> np.ndarray:
        M = error_matrix(K, n_err, theta, p[0], p[1], p[2])
        return P @ M + M.T @ P + kappa * P

    xi_v = np.array([[0.0], [xi_hi]]) if multi else np.array([[0.0]])
    xi_g = np.linspace(0.0, xi_hi, 21).reshape(-1, 1) if multi else None
    cert_thm = certify_design(P=P, lmis={"thm_lmi": thm_lmi}, vertices=xi_v, grid=xi_g)
    # xi_2 = theta^-2 is what the observer really runs with; the polytope covers it since theta >= sigma.
    exi_v = [0.0, exi_hi] if exi_hi > 0.0 else [0.0]
    dec_v = np.array([[x, fv, fa] for x in exi_v for fv, fa in corners])
    dec_g = np.array([[x, fv, fa] for x in (np.linspace(0.0, exi_hi, 5) if exi_hi > 0.0 else [0.0])
                      for fv in np.linspace(corners[:, 0].min(), corners[:, 0].max(), 5)
                      for fa in np.linspace(corners[:, 1].min(), corners[:, 1].max(), 5)])
    cert_dec = certify_design(P=P, lmis={"decay_lmi": decay_lmi}, vertices=dec_v, grid=dec_g, margin=0.0)
    # Sharper rate certified by the same vertices: largest k with He{P M} + k P <= 0 at every vertex.
    Li = np.linalg.inv(np.linalg.cholesky(P))
    kappa_v = min(-float(np.linalg.eigvalsh(Li @ (P @ M + M.T @ P) @ Li.T).max())
                  for M in (error_matrix(K, n_err, theta, *p) for p in dec_v))
    failures = [c.reason for c in (cert_thm, cert_dec) if not c.certified] + list(extra_failures)
    lower = max(theta0, sigma if X is not None else 1.0) if theta_min is None else theta_min
    if not theta > lower:
        failures.append(f"theta {theta:.4g} <= theta_0 {lower:.4g} (4.21)/(4.27a)/(4.40)/(4.58)")
    if not kappa > 0:
        failures.append(f"no decay: kappa {kappa:.4g} <= 0")
    ok = not failures
    margins = {**cert_thm.margins, **cert_dec.margins, "theta": theta, "theta0": theta0, "kappa_per_s": kappa,
               "kappa_vertex_per_s": kappa_v,
               "k_f": kf, "lambda": lam, "sigma": sigma, "p_max_eig": pmax,
               "overshoot": theta ** 2 * math.sqrt(pmax / float(np.linalg.eigvalsh(P).min())),
               **(extra_margins or {})}
    if X is not None:
        margins["x_max_eig"] = float(np.linalg.eigvalsh(X).max())
    reason = cert_thm.reason if ok else "certification failed: " + "; ".join(failures)
    gains = {"K": K.tolist(), "N": N.tolist(), "theta": [theta], "Y": Y.reshape(3).tolist(),
             "Z": Z.reshape(3).tolist(), **(extra_gains or {})}
    return DesignResult(DesignStatus.CERTIFIED if ok else DesignStatus.REJECTED, ok, reason, gains, P.tolist(),
                        margins, None, stats, variant)


K_H = 1.0  # Lipschitz constant of h(x) = x_2 (range rate): exactly 1


def _failed(variant: str, what: str, out: Any) -> DesignResult:
    status = DesignStatus.INFEASIBLE if out.status == "infeasible" else DesignStatus.SOLVER_FAILED
    return DesignResult(status, False, f"LMI {what} {out.status}", solver_stats=out.stats, variant=variant)


def _design_method1(lam: float, kf: float, corners: np.ndarray, opts: dict[str, Any],
                    settings: SolverSettings) -> DesignResult:
    """Method 1 (Thm 4.3.2): LMI (4.26) = (4.20), theta from (4.27a), a range-rate gain bounded by (4.33).

    ``theta = theta_factor * max(1, 2 k_f lambda_max(P) / (alpha lambda))``; ``M = c u`` with ``u`` the
    unit vector ``m1_direction`` and ``c = m1_norm_fraction * (1 - alpha) lambda / (2 k_h lambda_max(P)
    theta^(n-2))`` (4.33). The proof's rate is ``kappa = (theta lambda - 2 k_f lambda_max(P) - 2 theta^(n-1)
    k_h ||M|| lambda_max(P)) / lambda_max(P)``. In error coordinates the injection ``M (z - x_hat_2)`` is
    ``theta xi_2 N' e_2^T eps`` with ``N' = theta T^-1 M`` and ``xi_2 = 1`` (``h = x_2`` exactly).
    """
    alpha, frac = float(opts["m1_alpha"]), float(opts["m1_norm_fraction"])
    u = np.asarray(opts["m1_direction"], dtype=float).reshape(3)
    u = u / np.linalg.norm(u)
    out = solve_lmi(lambda: _problem(False, lam, 1.0, 0.0, settings), settings)
    if out.status != "optimal":
        return _failed("method1", "(4.26)", out)
    P = sym(out.values["P"])
    Y = out.values["Y"].reshape(1, 3)
    pmax = float(np.linalg.eigvalsh(P).max())
    theta_a = max(1.0, 2.0 * kf * pmax / (alpha * lam))          # (4.27a)
    theta = float(opts["theta_factor"]) * theta_a
    m_bound = (1.0 - alpha) * lam / (2.0 * K_H * pmax * theta ** (N_STATES - 2))   # (4.33)
    M = frac * m_bound * u
    m_norm = float(np.linalg.norm(M))
    kappa = (theta * lam - 2.0 * kf * pmax - 2.0 * theta ** (N_STATES - 1) * K_H * m_norm * pmax) / pmax
    theta_b = ((1.0 - alpha) * lam / (2.0 * K_H * m_norm * pmax)) ** (1.0 / (N_STATES - 2)) if m_norm > 0 else math.inf
    extra = () if theta < theta_b else (f"theta {theta:.4g} >= {theta_b:.4g} (4.27b)",)
    Tinv = np.array([theta ** -1, theta ** -2, theta ** -3])
    return certify_gains("method1", P, Y, np.zeros((1, 3)), None, lam, 1.0, kf, corners, theta, out.stats,
                         err_n=theta * Tinv * M, err_xi_hi=1.0, kappa=kappa, theta_min=theta_a,
                         extra_failures=extra, extra_margins={"alpha": alpha, "m_norm": m_norm, "m_bound": m_bound,
                                                              "theta_a": theta_a, "theta_b": theta_b},
                         extra_gains={"M": M.tolist()})


def max_lambda_method2(P: np.ndarray, Y: np.ndarray, Z: np.ndarray, sigma: float) -> float:
    """Largest ``lambda`` for which (4.39) holds with ``P, Y, Z`` at both vertices ``w_2 in {0, 1}``."""
    out = math.inf
    for xi2 in (0.0, sigma):
        G = P @ A_CHAIN - C_RANGE.T @ Y - xi2 * Z.T @ E2
        out = min(out, -float(np.linalg.eigvalsh(G + G.T).max()))
    return out


def _design_method2(variant: str, kf: float, corners: np.ndarray, opts: dict[str, Any],
                    settings: SolverSettings) -> DesignResult:
    """Method 2 (Thm 4.3.3): LMI (4.39) on the DMVT vertices of ``h = x_2``, condition (4.40).

    ``Sigma(sigma, w) = sigma w_2 e_2^T``, ``w_2 in {0, 1}`` (``psi_2 = 1``, 0 kept in the set), so the LMI
    is the multi-output one with ``xi_2 in {0, sigma}``; it covers the running ``xi_2 = theta`` when
    ``theta <= sigma``. ``M = T(theta) P^-1 Z^T`` (corrected; printed ``M = P^-1 Z^T``).
    Fresh design: lambda fixed (``m2_lambda``), minimise ``lambda_max(P)`` with ``Z_2 >= z_min``
    (Remark 4.3.1), ``theta = min(sigma, theta_factor theta_0)``. Printed design: P, Y, Z, theta of
    sec. 5.2.2(b) with ``sigma = theta`` and lambda the largest for which (4.39) holds (or
    ``m2_lambda`` if given as a number other than None).
    """
    if variant == "method2_printed":
        P = np.array(PRINTED_METHOD2["P"])
        Y = np.array(PRINTED_METHOD2["Y"]).reshape(1, 3)
        Z = np.array(PRINTED_METHOD2["Z"]).reshape(1, 3)
        theta = sigma = float(PRINTED_METHOD2["theta"])
        lam_star = max_lambda_method2(P, Y, Z, sigma)
        # a hair inside the largest lambda, so (4.39) holds strictly
        lam = lam_star * (1.0 - 1e-4) if opts.get("m2_lambda") is None else float(opts["m2_lambda"])
        stats: dict[str, Any] = {"solver": "none (printed gains)"}
        extra_m: dict[str, float] = {"lambda_max_feasible": lam_star}
    else:
        sigma = float(opts["m2_sigma"])
        lam = float(opts["m2_lambda"]) if opts.get("m2_lambda") is not None else float(opts["lambda_"])
        out = solve_lmi(lambda: _problem_method2(lam, sigma, float(opts["z_min"]), settings), settings)
        if out.status != "optimal":
            return _failed(variant, "(4.39)", out)
        P = sym(out.values["P"])
        Y, Z = out.values["Y"].reshape(1, 3), out.values["Z"].reshape(1, 3)
        theta0 = 2.0 * kf * float(np.linalg.eigvalsh(P).max()) / lam
        theta = min(sigma, float(opts["theta_factor"]) * theta0)
        stats, extra_m = out.stats, {}
    N = np.linalg.solve(P, Z.T).reshape(3)
    T = np.array([theta, theta ** 2, theta ** 3])
    M = T * N
    extra = () if theta <= sigma else (f"theta {theta:.4g} > sigma {sigma:.4g} (4.40)",)
    return certify_gains(variant, P, Y, Z, None, lam, sigma, kf, corners, theta, stats, thm_xi_hi=sigma,
                         err_xi_hi=theta, extra_failures=extra,
                         extra_margins={**extra_m, "m_norm": float(np.linalg.norm(M)),
                                        "m_norm_as_printed_formula": float(np.linalg.norm(N))},
                         extra_gains={"M": M.tolist()})


def _problem_method2(lam: float, sigma: float, z_min: float, settings: SolverSettings) -> tuple[Any, dict]:
    import cvxpy as cp

    P = cp.Variable((3, 3), symmetric=True)
    Y = cp.Variable((1, 3))
    Z = cp.Variable((1, 3))
    t = cp.Variable()
    eps = settings.strictness
    cons = [P >> P_FLOOR * np.eye(3), P << t * np.eye(3), Z[0, 1] >= z_min]
    for xi2 in (0.0, sigma):   # Sigma(sigma, w)^T Z = sigma w_2 e_2 Z, w_2 in {0, 1}
        cons.append(2 * sym(P @ A_CHAIN - C_RANGE.T @ Y - xi2 * Z.T @ E2) + lam * np.eye(3) << -eps * np.eye(3))
    return cp.Problem(cp.Minimize(t), cons), {"P": P, "Y": Y, "Z": Z}


# ---- output-integrator dynamic extension (Thm 4.4.1) ------------------------------------------------

def extension_matrices(alpha: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``A_xi`` (4, 4), ``C_xi`` (1, 4), ``B_w`` (4, 1) of (4.73) for ``xi = (mu, d, d', a_L)``."""
    A = np.zeros((4, 4))
    A[0, 1] = alpha
    A[1:, 1:] = A_CHAIN
    C = np.array([[1.0, 0.0, 0.0, 0.0]])
    return A, C, C.T.copy()


def extension_error_matrix(K: np.ndarray, alpha: float, beta: float, theta: float, fv: float,
                           fa: float) -> np.ndarray:
    """Exact mean-value error matrix (4, 4) [1/s] of ``eps = T^-1 (xi - xi_hat)`` (4.75).

    ``theta (A_xi - K C_xi)``, plus ``beta^2 theta^2`` (the ``h = x_2`` term, ``(beta^2/theta) Delta h`` with
    ``Delta h = theta^3 eps_3``) in row 1 and ``(f_v / theta, f_a)`` in row 4 (``theta^-4 Delta f``).
    """
    A, C, _ = extension_matrices(alpha)
    M = theta * (A - K.reshape(4, 1) @ C)
    M[0, 2] += beta * beta * theta * theta
    M[3, 2] += fv / theta
    M[3, 3] += fa
    return M


def design_extension(lam: float, kf: float, corners: np.ndarray, opts: dict[str, Any],
                     settings: SolverSettings) -> DesignResult:
    """Thm 4.4.1: LMI (4.84) (alpha, lambda fixed; minimise ``lambda_max(P)``, P >= I), then (4.96)-(4.97).

    ``mu' = alpha y + beta^2 z``; with ``varpi = beta^2 theta^3`` (the substitution of sec. 4.4):
    ``theta = theta_factor * max(1, 2 lambda_max(P) (k_f + k_h varpi) / lambda)``,
    ``beta = sqrt(varpi / theta^3)``, ``kappa = (theta lambda - 2 lambda_max(P)(k_f + k_h varpi)) / lambda_max(P)``.
    Certified: P > 0, (4.84), theta above (4.96), and ``He{P M} + kappa P <= 0`` for the exact error
    matrix at the corners of f's gradient box.
    """
    alpha, varpi = float(opts["ext_alpha"]), float(opts["ext_varpi"])
    A, C, Bw = extension_matrices(alpha)
    out = solve_lmi(lambda: _problem_extension(A, C, Bw, lam, settings), settings)
    if out.status != "optimal":
        return _failed("extension", "(4.84)", out)
    P, Zr, S = sym(out.values["P"]), out.values["Z"].reshape(1, 4), out.values["S"].reshape(1, 1)
    K = np.linalg.solve(P, Zr.T).reshape(4)
    ev = np.linalg.eigvalsh(P)
    pmax, pmin = float(ev.max()), float(ev.min())
    theta0 = max(1.0, 2.0 * pmax * (kf + K_H * varpi) / lam)
    theta = float(opts["theta_factor"]) * theta0
    beta = math.sqrt(varpi / theta ** 3)
    kappa = (theta * lam - 2.0 * pmax * (kf + K_H * varpi)) / pmax

    def lmi_484(_p: np.ndarray) -> np.ndarray:
        top = P @ A + A.T @ P - C.T @ Zr - Zr.T @ C + lam * np.eye(4)
        return np.block([[top, P @ Bw], [(P @ Bw).T, -S]])

    def decay(p: np.ndarray) -> np.ndarray:
        M = extension_error_matrix(K, alpha, beta, theta, p[0], p[1])
        return P @ M + M.T @ P + kappa * P

    cert = certify_design(P=P, lmis={"thm_lmi": lmi_484}, vertices=np.zeros((1, 1)))
    fgrid = np.array([[fv, fa] for fv in np.linspace(corners[:, 0].min(), corners[:, 0].max(), 7)
                      for fa in np.linspace(corners[:, 1].min(), corners[:, 1].max(), 7)])
    cert_dec = certify_design(P=P, lmis={"decay_lmi": decay}, vertices=corners, grid=fgrid, margin=0.0)
    failures = [c.reason for c in (cert, cert_dec) if not c.certified]
    if not theta > theta0:
        failures.append(f"theta {theta:.4g} <= {theta0:.4g} (4.96)")
    if not kappa > 0:
        failures.append(f"no decay: kappa {kappa:.4g} <= 0 (4.97)")
    ok = not failures
    margins = {**cert.margins, **cert_dec.margins, "theta": theta, "theta0": theta0, "kappa_per_s": kappa,
               "k_f": kf, "k_h": K_H, "lambda": lam, "alpha": alpha, "varpi": varpi, "beta": beta,
               "p_max_eig": pmax, "p_min_eig": pmin, "s_max_eig": float(S[0, 0]),
               # (4.87): ||xi~(t)|| <= c0 ||xi~(0)|| e^(-kappa t / 2) + cw sup ||w||
               "iss_c0": theta ** 3 * math.sqrt(pmax / pmin),
               "iss_cw": alpha * theta ** 2.5 / math.sqrt(kappa) * math.sqrt(float(S[0, 0]) / pmin)
               if kappa > 0 else math.inf}
    reason = cert.reason if ok else "certification failed: " + "; ".join(failures)
    gains = {"K": K.tolist(), "theta": [theta], "beta": [beta], "alpha": [alpha], "Z": Zr.reshape(4).tolist()}
    return DesignResult(DesignStatus.CERTIFIED if ok else DesignStatus.REJECTED, ok, reason, gains, P.tolist(),
                        margins, None, out.stats, "extension")


def _problem_extension(A: np.ndarray, C: np.ndarray, Bw: np.ndarray, lam: float,
                       settings: SolverSettings) -> tuple[Any, dict]:
    import cvxpy as cp

    P = cp.Variable((4, 4), symmetric=True)
    Z = cp.Variable((1, 4))
    S = cp.Variable((1, 1), symmetric=True)
    t = cp.Variable()
    eps = settings.strictness
    top = 2 * sym(P @ A - C.T @ Z) + lam * np.eye(4)
    cons = [P >> P_FLOOR * np.eye(4), P << t * np.eye(4), S >> eps,
            sym(cp.bmat([[top, P @ Bw], [(P @ Bw).T, -S]])) << -eps * np.eye(5)]
    # lambda_max(P) sets theta; S the noise gain of the ISS bound (4.87). Weight S lightly.
    return cp.Problem(cp.Minimize(t + 1e-3 * S[0, 0]), cons), {"P": P, "Z": Z, "S": S}
