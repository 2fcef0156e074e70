r"""LMI design of the GNSS kinematic high-gain observers of Bessafa (2024) (see :mod:`roadtruth.observers.gnss_kinematic`).

Model M8 (sec. 5.3.2, (5.6)-(5.16)): ``z = (X, X', X'', Y, Y', Y'')``, two 3-integrator chains,
``z' = A z + B f(z)``, ``y = C z + w = (X, Y) + w``, ``f(z) = -gamma(z)^2 (z2, z5)``,
``gamma = (z2 z6 - z5 z3) / (z2^2 + z5^2)`` (the yaw rate). Extra outputs ``h(z)``: speed
``h1 = hypot(z2, z5)``, the orthogonality pseudo-measurement ``h2 = z2 z3 + z5 z6 = 0`` and, for the
IMU fusion of sec. 5.3.5, ``h3 = gamma``.

Generalized HGO, Thm 4.3.4 with the multi-output form: ``eps = T(theta)^-1 e``,
``T = blkdiag(diag(theta, theta^2, theta^3) x 2)``, chain order ``n = 3``. The mean-value (Lemma 4.3.1)
parameters ``psi_ij`` of ``h_i`` w.r.t. ``z_j`` (``j`` = index inside its chain) become
``xi_ij = theta^(j-n-1) psi_ij``; for ``theta >= sigma`` they lie in the box with vertices
``{gamma_ij_lo, gamma_ij_hi} sigma^(j-n-1)`` (0 kept inside). LMI (4.57) at every vertex:

``[[He{P A - Y^T C + Z^T Acal(xi)} + lambda I_6, Y^T], [Y, -X]] < 0``,
``Acal(xi) = -sum_ij xi_ij e_i e_j^T``, ``K = P^-1 Y^T``, ``N = P^-1 Z^T``,
``theta > max(sigma, 2 k_f lambda_max(P) / lambda)`` (4.58); decay rate of ``V = eps^T P eps``:
``kappa = (theta lambda - 2 k_f lambda_max(P)) / lambda_max(P)`` (4.60).

Non-constant partials over the design box (speed ``v in [v_min, v_max]``, ``|z3|, |z6| <= a_max``,
``|gamma| <= r_max``): ``dh1/dz2 = z2/v``, ``dh1/dz5 = z5/v`` in [-1, 1]; ``dh2/dz2 = z3``,
``dh2/dz5 = z6`` in ``[-a_max, a_max]``, ``dh2/dz3 = z2``, ``dh2/dz6 = z5`` in ``[-v_max, v_max]``;
``dh3/dz3 = -z5/v^2``, ``dh3/dz6 = z2/v^2`` in ``[-1/v_min, 1/v_min]``, ``dh3/dz2 = (z6 - 2 z2 gamma)/v^2``,
``dh3/dz5 = -(z3 + 2 z5 gamma)/v^2`` in ``+-(a_max/v_min^2 + 2 r_max/v_min)``. That is 6 partials
(64 vertices) without and 10 (1024 vertices) with the yaw rate, as the thesis counts.

``k_f`` = max of ``||df/dz||_2`` on a grid of the box (App. A.2; the observer evaluates ``f`` with
``gamma`` clipped to ``r_max`` and ``v >= v_min``). The thesis's ``k_f = 0.1005`` comes from an
undisclosed box.

"As printed" (sec. 5.3.3, 5.3.5): the printed ``K``, ``N`` and ``theta`` with no printed ``P``; the
certificate then searches a ``P`` for the printed gains (LMI (4.57) with ``Y = K^T P``,
``Z = N^T P``: linear in ``P``, ``X``) and applies the same checks.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

import roadtruth.harness as harness
from roadtruth.observers import lmi
from roadtruth.observers.lmi import DesignResult, DesignStatus, SolverSettings, certify_design, solve_lmi, sym

N_CHAIN = 3
A1 = np.diag([1.0, 1.0], k=1)
A6 = np.kron(np.eye(2), A1)
B6 = np.kron(np.eye(2), np.array([[0.0], [0.0], [1.0]]))
C6 = np.kron(np.eye(2), np.array([[1.0, 0.0, 0.0]]))
#: index of each state inside its chain (1..3): z1..z3 -> 1..3, z4..z6 -> 1..3
CHAIN_INDEX = np.array([1, 2, 3, 1, 2, 3])
P_FLOOR = 1.0

#: sec. 5.3.3 (speed + orthogonality, lambda = 1e7, sigma = 5): K (6 x 2), N (6 x 2), theta = 5.2.
PRINTED_BASE: dict[str, Any] = {
    "K": [[392.8, 0.0], [680.9, 0.0], [392.7, 0.0], [0.0, 392.8], [0.0, 680.9], [0.0, 392.7]],
    "N": [[4.72, 9.72], [8.14, 1.14], [4.71, 0.71], [4.72, 9.72], [8.14, 1.14], [4.71, 0.71]],
    "theta": 5.2, "sigma": 5.0, "theta0": 1.36, "k_f": 0.1005, "lambda": 1e7,
}
#: sec. 5.3.5 (speed + orthogonality + yaw rate): K (6 x 2), N (6 x 3), theta = 3.
PRINTED_FUSED: dict[str, Any] = {
    "K": [[0.2247, 0.0], [0.4704, 0.0], [0.1832, 0.0], [0.0, 0.2247], [0.0, 0.4704], [0.0, 0.1832]],
    "N": [[0.4858, 0.8858, 0.4858], [0.7402, 0.3402, 0.7402], [0.4603, 0.1603, 0.4603],
          [0.4858, 0.8858, 0.4858], [0.7402, 0.3402, 0.7402], [0.4603, 0.1603, 0.4603]],
    "theta": 3.0, "sigma": 3.0,
}


def partial_boxes(box: dict[str, float], fused: bool) -> list[tuple[int, int, float, float]]:
    """Non-constant partials ``(output i, state j (0-based), lo, hi)`` of ``h`` over the design box."""
    vmin, vmax, amax, rmax = box["v_min_mps"], box["v_max_mps"], box["a_max_mps2"], box["r_max_radps"]
    out = [(0, 1, -1.0, 1.0), (0, 4, -1.0, 1.0),
           (1, 1, -amax, amax), (1, 2, -vmax, vmax), (1, 4, -amax, amax), (1, 5, -vmax, vmax)]
    if fused:
        g = amax / vmin ** 2 + 2.0 * rmax / vmin
        out += [(2, 1, -g, g), (2, 2, -1.0 / vmin, 1.0 / vmin), (2, 4, -g, g), (2, 5, -1.0 / vmin, 1.0 / vmin)]
    return out


def vertex_matrices(partials: list[tuple[int, int, float, float]], sigma: float, p_z: int) -> list[np.ndarray]:
    """``Acal(xi)`` (p_z, 6) at every vertex of ``V^sigma`` (4.55)-(4.56)."""
    mats = []
    for corner in itertools.product(*[(lo, hi) for _, _, lo, hi in partials]):
        A = np.zeros((p_z, 6))
        for (i, j, _, _), g in zip(partials, corner, strict=True):
            A[i, j] -= g * sigma ** (CHAIN_INDEX[j] - N_CHAIN - 1)
        mats.append(A)
    return mats


def f_chain(z: np.ndarray, box: dict[str, float]) -> np.ndarray:
    """``f(z) = -gamma^2 (z2, z5)`` [m/s^3] with the observer's clipping (v >= v_min, |gamma| <= r_max)."""
    v2 = max(z[1] ** 2 + z[4] ** 2, box["v_min_mps"] ** 2)
    g = min(max((z[1] * z[5] - z[4] * z[2]) / v2, -box["r_max_radps"]), box["r_max_radps"])
    return -g * g * np.array([z[1], z[4]])


def lipschitz_kf(box: dict[str, float], n: int = 7) -> float:
    """``k_f = max ||df/dz||_2`` [1/s] on a grid of the box (central differences; App. A.2)."""
    vmin, vmax, amax, rmax = box["v_min_mps"], box["v_max_mps"], box["a_max_mps2"], box["r_max_radps"]
    best = 0.0
    for v, psi, a_t, r in itertools.product(np.linspace(vmin, vmax, n), np.linspace(0, 2 * math.pi, 8, endpoint=False),
                                            np.linspace(-amax, amax, n), np.linspace(-rmax, rmax, n)):
        c, s = math.cos(psi), math.sin(psi)
        a_n = r * v  # normal acceleration of a turn at rate r
        if a_t * a_t + a_n * a_n > amax * amax:
            continue
        z = np.array([0.0, v * c, a_t * c - a_n * s, 0.0, v * s, a_t * s + a_n * c])
        J = np.zeros((2, 6))
        for j in (1, 2, 4, 5):
            d = np.zeros(6)
            d[j] = 1e-6 * max(1.0, abs(z[j]))
            J[:, j] = (f_chain(z + d, box) - f_chain(z - d, box)) / (2 * d[j])
        best = max(best, float(np.linalg.norm(J, 2)))
    return best


def design_for(name: str, variant: str, opts: dict[str, Any], use_cache: bool = True) -> DesignResult:
    """Cached design of ``variant`` in {'base', 'fused', 'base_printed', 'fused_printed'}."""
    settings = SolverSettings()
    payload = {"family": "gnss_kinematic", "variant": variant, "options": opts, "solver": settings.to_dict(),
               "code": [harness.__version__, lmi.source_fingerprint(lmi, design_for)]}
    return lmi.cached_design(payload, lambda: design(variant, opts, settings), use_cache=use_cache)


def design(variant: str, opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    """Solve (or, for the printed variants, find P for the printed gains) and certify."""
    fused = variant.startswith("fused")
    box = {k: float(opts[k]) for k in ("v_min_mps", "v_max_mps", "a_max_mps2", "r_max_radps")}
    p_z = 3 if fused else 2
    kf = lipschitz_kf(box)
    lam = float(opts["lambda_"])
    printed = PRINTED_FUSED if fused else PRINTED_BASE
    if variant.endswith("_printed"):
        sigma = float(printed["sigma"])
        K, N = np.array(printed["K"]), np.array(printed["N"])
        verts = vertex_matrices(partial_boxes(box, fused), sigma, p_z)
        out = solve_lmi(lambda: _problem_fixed_gains(K, N, verts, lam, settings), settings)
        stats = {**out.stats, "printed_theta0": printed.get("theta0"), "printed_k_f": printed.get("k_f")}
        if out.status != "optimal":
            # No P makes (4.57) hold for the printed gains: they still run, uncertified.
            return DesignResult(DesignStatus.REJECTED, False,
                                f"no P satisfies (4.57) for the printed K, N at the {len(verts)} vertices "
                                f"(sigma = {sigma:g}): {out.status}",
                                {"K": K.tolist(), "N": N.tolist(), "theta": [float(printed["theta"])]},
                                None, {"k_f": kf, "lambda": lam, "sigma": sigma}, None, stats, variant)
        P = sym(out.values["P"])
        X = sym(out.values["X"].reshape(2, 2))
        return certify_gains(variant, P, K.T @ P, N.T @ P, X, lam, sigma, kf, box, fused,
                             float(printed["theta"]), stats)
    sigma = float(opts["sigma"])
    verts = vertex_matrices(partial_boxes(box, fused), sigma, p_z)
    out = solve_lmi(lambda: _problem(verts, lam, float(opts["z_min"]), p_z, settings), settings)
    if out.status != "optimal":
        status = DesignStatus.INFEASIBLE if out.status == "infeasible" else DesignStatus.SOLVER_FAILED
        return DesignResult(status, False, f"LMI (4.57) {out.status}", solver_stats=out.stats, variant=variant)
    P = sym(out.values["P"])
    Y = out.values["Y"].reshape(2, 6)
    Z = out.values["Z"].reshape(p_z, 6)
    X = sym(out.values["X"].reshape(2, 2))
    theta0 = 2.0 * kf * float(np.linalg.eigvalsh(P).max()) / lam
    theta = max(sigma, 1.0, float(opts["theta_factor"]) * theta0)
    return certify_gains(variant, P, Y, Z, X, lam, sigma, kf, box, fused, theta, out.stats)


def _lmi_block(P: Any, Y: Any, Z: Any, X: Any, acal: np.ndarray, lam: float) -> Any:
    import cvxpy as cp

    top = 2 * sym(P @ A6 - Y.T @ C6 + Z.T @ acal) + lam * np.eye(6)
    return sym(cp.bmat([[top, Y.T], [Y, -X]]))


def _problem(verts: list[np.ndarray], lam: float, z_min: float, p_z: int, settings: SolverSettings) -> tuple[Any, dict]:
    import cvxpy as cp

    P = cp.Variable((6, 6), symmetric=True)
    Y = cp.Variable((2, 6))
    Z = cp.Variable((p_z, 6))
    X = cp.Variable((2, 2), symmetric=True)
    t = cp.Variable()
    eps = settings.strictness
    # Remark 4.3.1: without a floor on Z the speed injection collapses to ~0 (N = P^-1 Z^T); the floor
    # is on the speed output's velocity entries, the ones a speed measurement informs.
    cons = [P >> P_FLOOR * np.eye(6), P << t * np.eye(6), X >> eps * np.eye(2), Z[0, 1] >= z_min, Z[0, 4] >= z_min]
    cons += [_lmi_block(P, Y, Z, X, a, lam) << -eps * np.eye(8) for a in verts]
    # lambda_max(P) sets theta_0; trace X the noise gain of the ISS bound (4.59): weight X lightly.
    return cp.Problem(cp.Minimize(t + 1e-3 * cp.trace(X)), cons), {"P": P, "Y": Y, "Z": Z, "X": X}


def _problem_fixed_gains(K: np.ndarray, N: np.ndarray, verts: list[np.ndarray], lam: float,
                         settings: SolverSettings) -> tuple[Any, dict]:
    import cvxpy as cp

    P = cp.Variable((6, 6), symmetric=True)
    X = cp.Variable((2, 2), symmetric=True)
    t = cp.Variable()
    eps = settings.strictness
    cons = [P >> P_FLOOR * np.eye(6), P << t * np.eye(6), X >> eps * np.eye(2)]
    cons += [_lmi_block(P, K.T @ P, N.T @ P, X, a, lam) << -eps * np.eye(8) for a in verts]
    return cp.Problem(cp.Minimize(t + 1e-3 * cp.trace(X)), cons), {"P": P, "X": X}


def error_matrix(K: np.ndarray, N: np.ndarray, theta: float, acal: np.ndarray) -> np.ndarray:
    """Frozen error matrix ``theta (A - K C + N Acal(xi))`` of ``eps`` (6, 6) [1/s] ((4.53) without f)."""
    return theta * (A6 - K @ C6 + N @ acal)


def certify_gains(variant: str, P: np.ndarray, Y: np.ndarray, Z: np.ndarray, X: np.ndarray, lam: float,
                  sigma: float, kf: float, box: dict[str, float], fused: bool, theta: float,
                  stats: dict[str, Any]) -> DesignResult:
    """Certify ``P`` (6, 6), ``Y`` (2, 6), ``Z`` (p_z, 6), ``X`` (2, 2) at ``theta``.

    Checks LMI (4.57) at every vertex of ``V^sigma`` and on a grid of the xi-box, condition (4.58)
    ``theta > max(sigma, theta_0)``, and the frozen decay ``He{P M} + kappa_lin P <= 0`` of the linear
    part at the vertices (``kappa_lin = theta lambda / lambda_max(P)``, the rate (4.60) before the
    ``k_f`` term, which (4.58) covers).
    """
    p_z = Z.shape[0]
    K = np.linalg.solve(P, Y.T)
    N = np.linalg.solve(P, Z.T)
    pmax = float(np.linalg.eigvalsh(P).max())
    pmin = float(np.linalg.eigvalsh(P).min())
    theta0 = 2.0 * kf * pmax / lam
    kappa = (theta * lam - 2.0 * kf * pmax) / pmax
    partials = partial_boxes(box, fused)
    scale = np.array([sigma ** (CHAIN_INDEX[j] - N_CHAIN - 1) for _, j, _, _ in partials])
    lo = np.array([p[2] for p in partials]) * scale
    hi = np.array([p[3] for p in partials]) * scale

    def acal(p: np.ndarray) -> np.ndarray:
        A = np.zeros((p_z, 6))
        for (i, j, _, _), g in zip(partials, p, strict=True):
            A[i, j] -= g
        return A

    def thm_lmi(p: np.ndarray) -> np.ndarray:
        top = 2 * (P @ A6 - Y.T @ C6 + Z.T @ acal(p))
        top = 0.5 * (top + top.T) + lam * np.eye(6)
        return np.block([[top, Y.T], [Y, -X]])

    vertices = np.array(list(itertools.product(*zip(lo, hi, strict=True))))
    rng = np.random.default_rng(0)
    grid = lo + (hi - lo) * rng.random((200, len(lo)))
    cert = certify_design(P=P, lmis={"thm_lmi": thm_lmi}, vertices=vertices, grid=grid)
    Li = np.linalg.inv(np.linalg.cholesky(P))
    kappa_lin = min(-float(np.linalg.eigvalsh(Li @ (P @ M + M.T @ P) @ Li.T).max())
                    for M in (error_matrix(K, N, theta, acal(p)) for p in vertices))
    failures = [] if cert.certified else [cert.reason]
    if not theta > max(theta0, sigma):
        failures.append(f"theta {theta:.4g} <= max(sigma, theta_0) = {max(theta0, sigma):.4g} (4.58)")
    ok = not failures
    margins = {**cert.margins, "theta": theta, "theta0": theta0, "kappa_per_s": kappa,
               "kappa_vertex_linear_per_s": kappa_lin, "k_f": kf, "lambda": lam, "sigma": sigma,
               "p_max_eig": pmax, "p_min_eig": pmin, "x_max_eig": float(np.linalg.eigvalsh(X).max()),
               "n_vertices": float(len(vertices))}
    reason = cert.reason if ok else "certification failed: " + "; ".join(failures)
    gains = {"K": K.tolist(), "N": N.tolist(), "theta": [theta]}
    return DesignResult(DesignStatus.CERTIFIED if ok else DesignStatus.REJECTED, ok, reason, gains, P.tolist(),
                        margins, None, stats, variant)


def iss_bound(design: DesignResult, e0_norm: float, w_sup: float, t_s: np.ndarray) -> np.ndarray:
    """ISS bound (4.59) on ``||z - z_hat||`` [SI mix] at times ``t_s`` (s) for ``||e(0)||`` and ``sup ||w||``."""
    m = design.margins
    th, pmax, pmin, xmax, kappa = m["theta"], m["p_max_eig"], m["p_min_eig"], m["x_max_eig"], m["kappa_per_s"]
    n = N_CHAIN
    return (th ** (n - 1) * math.sqrt(pmax / pmin) * e0_norm * np.exp(-kappa * t_s / 2.0)
            + th ** (n - 0.5) / math.sqrt(kappa) * math.sqrt(xmax / pmin) * w_sup)
