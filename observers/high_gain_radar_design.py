r"""LMI designs of the radar high-gain observers of Bessafa (2024) (see :mod:`observers.high_gain_radar`).

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
from typing import TYPE_CHECKING, Any

import numpy as np

import harness
from observers import lmi
from observers.lmi import DesignResult, DesignStatus, SolverSettings, certify_design, solve_lmi, sym

if TYPE_CHECKING:
    from observers.high_gain_radar import HighGainRadarStandard

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


def design_for(obs: HighGainRadarStandard) -> DesignResult:
    """Cached design for an observer instance (its lead model, variant and options)."""
    opts = {k: obs.options[k] for k in ("lambda_", "sigma", "z_min", "theta_factor", "lead_speed_range_mps",
                                         "lead_accel_range_mps2")}
    lead = obs.lead_model()
    settings = SolverSettings()
    payload = {"family": "high_gain_radar", "variant": obs.variant, "options": opts, "lead": lead,
               "solver": settings.to_dict(),
               "code": [harness.__version__, lmi.source_fingerprint(lmi, design_for)]}
    return lmi.cached_design(payload, lambda: design(obs.variant, lead, opts, settings),
                             use_cache=bool(obs.options["use_cache"]))


def design(variant: str, lead: dict[str, float], opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    """Solve (or evaluate) and certify ``variant`` in {'standard', 'multi', 'standard_printed'}."""
    lam = float(opts["lambda_"])
    corners = gradient_corners(lead, tuple(opts["lead_speed_range_mps"]), tuple(opts["lead_accel_range_mps2"]))
    kf = lipschitz_kf(corners)
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
                  sigma: float, kf: float, corners: np.ndarray, theta: float, stats: dict[str, Any]) -> DesignResult:
    """Certify given ``P`` (3, 3), ``Y``, ``Z`` (1, 3), ``X`` (1, 1) or None (SHGO) at ``theta``.

    Checks LMI (4.20)/(4.57) at the vertices ``xi_2 in {0, sigma^-2}`` and a grid, condition
    (4.21)/(4.58) ``theta > theta_0``, and the decay LMI ``He{P M} + kappa P <= 0`` at the corners
    ``corners`` (4, 2) of the mean-value gradient of f (see module docstring).
    """
    K = np.linalg.solve(P, Y.T).reshape(3)
    N = np.linalg.solve(P, Z.T).reshape(3)
    pmax = float(np.linalg.eigvalsh(P).max())
    theta0 = 2.0 * kf * pmax / lam
    kappa = (theta * lam - 2.0 * kf * pmax) / pmax
    multi = X is not None
    xi_hi = sigma ** -2 if multi else 0.0

    def thm_lmi(p: np.ndarray) -> np.ndarray:
        top = 2 * (P @ A_CHAIN - C_RANGE.T @ Y - p[0] * Z.T @ E2)
        top = 0.5 * (top + top.T) + lam * np.eye(3)
        if X is None:
            return top
        return np.block([[top, Y.T], [Y, -X]])

    def decay_lmi(p: np.ndarray) -> np.ndarray:
        M = error_matrix(K, N, theta, p[0], p[1], p[2])
        return P @ M + M.T @ P + kappa * P

    xi_v = np.array([[0.0], [xi_hi]]) if multi else np.array([[0.0]])
    xi_g = np.linspace(0.0, xi_hi, 21).reshape(-1, 1) if multi else None
    cert_thm = certify_design(P=P, lmis={"thm_lmi": thm_lmi}, vertices=xi_v, grid=xi_g)
    # xi_2 = theta^-2 is what the observer really runs with; the polytope covers it since theta >= sigma.
    dec_v = np.array([[x, fv, fa] for x in xi_v[:, 0] for fv, fa in corners])
    dec_g = np.array([[x, fv, fa] for x in (np.linspace(0.0, xi_hi, 5) if multi else [0.0])
                      for fv in np.linspace(corners[:, 0].min(), corners[:, 0].max(), 5)
                      for fa in np.linspace(corners[:, 1].min(), corners[:, 1].max(), 5)])
    cert_dec = certify_design(P=P, lmis={"decay_lmi": decay_lmi}, vertices=dec_v, grid=dec_g, margin=0.0)
    # Sharper rate certified by the same vertices: largest k with He{P M} + k P <= 0 at every vertex.
    Li = np.linalg.inv(np.linalg.cholesky(P))
    kappa_v = min(-float(np.linalg.eigvalsh(Li @ (P @ M + M.T @ P) @ Li.T).max())
                  for M in (error_matrix(K, N, theta, *p) for p in dec_v))
    failures = [c.reason for c in (cert_thm, cert_dec) if not c.certified]
    if not theta > max(theta0, sigma if multi else 1.0):
        failures.append(f"theta {theta:.4g} <= theta_0 {theta0:.4g} (4.21)/(4.58)")
    ok = not failures
    margins = {**cert_thm.margins, **cert_dec.margins, "theta": theta, "theta0": theta0, "kappa_per_s": kappa,
               "kappa_vertex_per_s": kappa_v,
               "k_f": kf, "lambda": lam, "sigma": sigma, "p_max_eig": pmax,
               "overshoot": theta ** 2 * math.sqrt(pmax / float(np.linalg.eigvalsh(P).min()))}
    if X is not None:
        margins["x_max_eig"] = float(np.linalg.eigvalsh(X).max())
    reason = cert_thm.reason if ok else "certification failed: " + "; ".join(failures)
    gains = {"K": K.tolist(), "N": N.tolist(), "theta": [theta], "Y": Y.reshape(3).tolist(),
             "Z": Z.reshape(3).tolist()}
    return DesignResult(DesignStatus.CERTIFIED if ok else DesignStatus.REJECTED, ok, reason, gains, P.tolist(),
                        margins, None, stats, variant)
