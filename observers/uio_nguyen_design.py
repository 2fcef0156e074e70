r"""Model, regularisation and certified LMI design of Nguyen's UIO (see :mod:`roadtruth.observers.uio_nguyen`).

Vehicle model (1.52)-(1.56), small angles, ``x = (v_x, v_y, psi, r)``, ``u = (a, delta)``,
``y = (v_x, psi, r)``, ``mu = (f_yf, f_yr)`` in **kN** (in N, ``B_mu ~ 1e-3`` and the LMIs are ill-conditioned):

.. math::

    \dot x = A(\rho) x + B_u u + B_\mu \mu,\qquad y = C x,\qquad
    A(\rho) = A_0 + \rho_1 A_1 + \rho_2 A_2,\ \rho_1 = v_x,\ \rho_2 = 1/v_x,

the chapter's ``E`` renamed ``B_mu``. Regularised model (1.5)-(1.7), corrected sign of the
``omega`` term: ``E_bb = [I, delta1 E_reg]``, ``H = [C, delta2 D_reg]``,
``E_bar = [E_reg, 0]``, ``D_bar = [0, -D_reg]``, ``omega = (delta1 mu', delta2 mu)``; ``D_reg`` is
(1.58) (``f_yf`` into the psi channel, ``f_yr`` into the r channel). ``[P_zeta Q_zeta] = pinv([E_bb; H])``
solves (1.9). Error dynamics (1.13), corrected:
``E_j = P_zeta E_bar - P_zeta A_j Q_zeta D_bar`` and ``D_cal = (I - H Q_zeta) D_bar``; the vertices
``A_j = [A(rho_j), B_mu]`` are ``n_x x n_zeta`` (1.60 corrected).

Theorem 1 LMI (1.26) **with the +I the printed LMI omits** (without it the LMI is homogeneous and lambda -> 0):

.. math::

    \begin{bmatrix}\mathrm{He}(\mathcal P P_\zeta A_j - \mathcal Q^T H) + I & \mathcal P E_j - \mathcal Q^T D_{cal}
    & (P_\zeta A_j)^T\mathcal P - H^T\mathcal Q\\ \star & -\lambda I & E_j^T\mathcal P - D_{cal}^T\mathcal Q\\
    \star & \star & -\mathcal P/\epsilon\end{bmatrix} \prec 0,\quad j = 1..4,

minimise lambda, ``K = P^-1 Q^T``. The certificate re-checks (1.26) at the 4 vertices of the
``(rho_1, rho_2)`` box and on a dense grid of the physical curve ``(v, 1/v)``, ``P > 0`` and the frozen
closed loop ``P_zeta A(rho) - K H``. Bound constants (1.16a)-(1.16b): ``lambda_delta``, ``beta``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

import roadtruth.harness as harness
from roadtruth.harness.truth.vehicle import VehicleParams
from roadtruth.observers import lmi
from roadtruth.observers.lmi import (
    DesignRequest,
    DesignResult,
    DesignStatus,
    SolverSettings,
    box_corners,
    certify_design,
    solve_lmi,
    sym,
)

N_X, N_Y, N_MU = 4, 3, 2
N_ZETA = N_X + N_MU
C_OUT = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
#: (1.58): f_yf regularised into the psi channel, f_yr into the r channel.
D_REG = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
#: State-side regularisation matrix of (1.5), used only when delta1 > 0: mu' into the v_y and r rows
#: (the rows the unknown input enters).
E_REG = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
MU_SCALE_N = 1000.0  # unknown input in kN


@dataclass(frozen=True)
class VehicleModel:
    """LPV matrices of (1.55)-(1.56). ``A(rho) = A0 + rho1 A1 + rho2 A2``: (4, 4) [1/s];
    ``Bu`` (4, 2); ``Bmu`` (4, 2) [per kN]; ``C`` (3, 4)."""

    A0: np.ndarray
    A1: np.ndarray
    A2: np.ndarray
    Bu: np.ndarray
    Bmu: np.ndarray
    C: np.ndarray

    def A(self, vx: float) -> np.ndarray:
        """State matrix at ``v_x`` [m/s]: (4, 4)."""
        return self.A0 + vx * self.A1 + self.A2 / vx

    def A_zeta(self, rho1: float, rho2: float) -> np.ndarray:
        """Jacobian vertex ``[A(rho), B_mu]`` of the polytope (1.19): (4, 6), corrected dimension."""
        return np.hstack([self.A0 + rho1 * self.A1 + rho2 * self.A2, self.Bmu])


def vehicle_model(v: VehicleParams) -> VehicleModel:
    """(1.55)-(1.56) for a vehicle set (axle stiffness ``By Cy Fz_static``)."""
    m, iz, lf, lr = v.mass_kg, v.yaw_inertia_kgm2, v.lf_m, v.lr_m
    cf, cr = v.cornering_stiffness_f_Npr, v.cornering_stiffness_r_Npr
    A1 = np.zeros((4, 4))
    A1[1, 3] = -1.0
    A2 = np.zeros((4, 4))
    A2[1, 1] = -(cf + cr) / m
    A2[1, 3] = (lr * cr - lf * cf) / m
    A2[3, 1] = (lr * cr - lf * cf) / iz
    A2[3, 3] = -(lf * lf * cf + lr * lr * cr) / iz
    A0 = np.zeros((4, 4))
    A0[2, 3] = 1.0
    Bu = np.array([[1.0, 0.0], [0.0, cf / m], [0.0, 0.0], [0.0, lf * cf / iz]])
    Bmu = MU_SCALE_N * np.array([[0.0, 0.0], [1.0 / m, 1.0 / m], [0.0, 0.0], [lf / iz, -lr / iz]])
    return VehicleModel(A0, A1, A2, Bu, Bmu, C_OUT.copy())


@dataclass(frozen=True)
class Regularized:
    """Matrices of (1.6)-(1.13) for given ``delta1, delta2``; shapes in the module docstring."""

    E_bb: np.ndarray     # (4, 6)
    H: np.ndarray        # (3, 6)
    E_bar: np.ndarray    # (4, 4)
    D_bar: np.ndarray    # (3, 4)
    P_zeta: np.ndarray   # (6, 4)
    Q_zeta: np.ndarray   # (6, 3)
    D_cal: np.ndarray    # (3, 4)

    def E_cal(self, A_zeta: np.ndarray) -> np.ndarray:
        """(1.13) corrected: ``P_zeta E_bar - P_zeta A_j Q_zeta D_bar``: (6, 4)."""
        return self.P_zeta @ self.E_bar - self.P_zeta @ A_zeta @ self.Q_zeta @ self.D_bar


def d_bar(*, printed: bool = False) -> np.ndarray:
    """``D_bar`` of (1.7): ``[0, -D]`` (corrected) or ``[0, +D]`` as printed (then ``y != C x``)."""
    return np.hstack([np.zeros((N_Y, N_MU)), D_REG if printed else -D_REG])


def d_cal(H: np.ndarray, Q_zeta: np.ndarray, D_bar: np.ndarray, *, printed: bool = False) -> np.ndarray:
    """``D_cal`` of (1.13): ``(I - H Q) D_bar`` (corrected) or ``(I + H Q) D_bar`` as printed."""
    return (np.eye(N_Y) + (1.0 if printed else -1.0) * H @ Q_zeta) @ D_bar


def rank_condition(delta1: float, delta2: float) -> int:
    """``rank [E_bb; H] - n_x = rank(delta2 D - delta1 C E_reg)``; (1.4) needs 2."""
    return int(np.linalg.matrix_rank(delta2 * D_REG - delta1 * C_OUT @ E_REG))


def regularize(model: VehicleModel, delta1: float, delta2: float) -> Regularized:
    """(1.7) and (1.9) with the Moore-Penrose left inverse. Raises ValueError if (1.4) fails."""
    E_bb = np.hstack([np.eye(N_X), delta1 * E_REG])
    H = np.hstack([model.C, delta2 * D_REG])
    theta = np.vstack([E_bb, H])
    if np.linalg.matrix_rank(theta) != N_ZETA:
        raise ValueError(f"rank condition (1.4) fails for delta1={delta1}, delta2={delta2}")
    PQ = np.linalg.pinv(theta)
    P_zeta, Q_zeta = PQ[:, :N_X], PQ[:, N_X:]
    E_bar = np.hstack([E_REG, np.zeros((N_X, N_MU))])
    D_bar = d_bar()
    return Regularized(E_bb, H, E_bar, D_bar, P_zeta, Q_zeta, d_cal(H, Q_zeta, D_bar))


def unmovable_modes(F: np.ndarray, H: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    """Eigenvalues ``s`` of ``F`` with ``rank [s I - F; H] < n`` (PBH): modes no gain K can move."""
    out = []
    for s in np.linalg.eigvals(F):
        M = np.vstack([s * np.eye(F.shape[0]) - F, H.astype(complex)])
        sv = np.linalg.svd(M, compute_uv=False)
        if sv[-1] <= tol * max(1.0, sv[0]):
            out.append(s)
    return np.array(out, dtype=complex)


def structure(model: VehicleModel, vx: float) -> dict[str, float]:
    """Identifiability facts at ``v_x``: ``rank C B_mu`` (1: (1.2) fails), the normal rank
    of ``G(s) = C (sI - A)^-1 B_mu`` (1: only one combination of f_yf, f_yr is identifiable) and the
    observability rank of ``(A, C)`` with and without the psi row (psi only sees itself)."""
    A, C, B = model.A(vx), model.C, model.Bmu
    s = 0.7 + 1.3j  # a generic point: the rank there is the normal rank
    G = C @ np.linalg.solve(s * np.eye(N_X) - A, B)

    def obs_rank(Cm: np.ndarray) -> int:
        return int(np.linalg.matrix_rank(np.vstack([Cm @ np.linalg.matrix_power(A, k) for k in range(N_X)])))

    return {"rank_c_bmu": float(np.linalg.matrix_rank(C @ B)), "normal_rank_g": float(np.linalg.matrix_rank(G)),
            "observability_rank": float(obs_rank(C)), "observability_rank_without_psi": float(obs_rank(C[[0, 2]]))}


def lmi_126(P: np.ndarray, Q: np.ndarray, lam: float, PA: np.ndarray, E_j: np.ndarray, H: np.ndarray,
            D_cal: np.ndarray, eps: float, *, plus_identity: bool = True) -> np.ndarray:
    """Numerical (1.26) at one vertex: (2 n_zeta + 2 n_mu) square; ``plus_identity=False`` = as printed."""
    n = P.shape[0]
    X = P @ PA - Q.T @ H
    Y = P @ E_j - Q.T @ D_cal
    w = E_j.shape[1]
    M = np.block([[X + X.T + (np.eye(n) if plus_identity else 0.0), Y, X.T],
                  [Y.T, -lam * np.eye(w), Y.T],
                  [X, Y, -P / eps]])
    return 0.5 * (M + M.T)


def scheduling_points(v_range: tuple[float, float], n_grid: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (4, 2) of the ``(v, 1/v)`` box and (n_grid, 2) points of the physical curve."""
    lo, hi = v_range
    verts = box_corners([(lo, hi), (1.0 / hi, 1.0 / lo)])
    v = np.linspace(lo, hi, n_grid)
    return verts, np.column_stack([v, 1.0 / v])


def design(model: VehicleModel, opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    """Solve min lambda s.t. (1.26) at the 4 vertices, then certify (vertices + v_x grid)."""
    d1, d2, eps = float(opts["delta1"]), float(opts["delta2"]), float(opts["epsilon"])
    v_range = (float(opts["vx_range_mps"][0]), float(opts["vx_range_mps"][1]))
    variant = "regularized"
    if rank_condition(d1, d2) != N_MU:
        return DesignResult(DesignStatus.INFEASIBLE, False, f"rank condition (1.4) fails (delta1={d1}, delta2={d2})",
                            variant=variant)
    reg = regularize(model, d1, d2)
    verts, grid = scheduling_points(v_range, int(opts["grid_points"]))
    PAs = [reg.P_zeta @ model.A_zeta(*p) for p in verts]
    Ejs = [reg.E_cal(model.A_zeta(*p)) for p in verts]
    pbh = [unmovable_modes(PA, reg.H) for PA in PAs]
    worst = max((float(m.real.max()) for m in pbh if m.size), default=-math.inf)
    extra: dict[str, float] = {"unmovable_mode_max_real": worst,
                               "q_mu_gain": float(np.linalg.norm(reg.Q_zeta[N_X:], 2)),
                               **structure(model, 0.5 * sum(v_range))}
    if worst >= 0.0:
        return DesignResult(DesignStatus.INFEASIBLE, False,
                            f"PBH pre-check: a mode no gain can move has Re = {worst:.4g} >= 0", margins=extra,
                            variant=variant)
    w = Ejs[0].shape[1]

    def build() -> tuple[Any, dict[str, Any]]:
        import cvxpy as cp

        P = cp.Variable((N_ZETA, N_ZETA), symmetric=True)
        Q = cp.Variable((N_Y, N_ZETA))
        lam = cp.Variable()
        s = settings.strictness
        cons = [P >> s * np.eye(N_ZETA)]
        for PA, Ej in zip(PAs, Ejs, strict=True):
            X = P @ PA - Q.T @ reg.H
            Y = P @ Ej - Q.T @ reg.D_cal
            M = cp.bmat([[X + X.T + np.eye(N_ZETA), Y, X.T], [Y.T, -lam * np.eye(w), Y.T], [X, Y, -(1.0 / eps) * P]])
            cons.append(sym(M) << -s * np.eye(2 * N_ZETA + w))
        return cp.Problem(cp.Minimize(lam), cons), {"P": P, "Q": Q, "lambda": lam}

    out = solve_lmi(build, settings)
    if out.status != "optimal":
        st = DesignStatus.INFEASIBLE if out.status == "infeasible" else DesignStatus.SOLVER_FAILED
        return DesignResult(st, False, f"LMI (1.26) at delta2={d2}, epsilon={eps}: {out.status}", margins=extra,
                            solver_stats=out.stats, variant=variant)
    P, Q, lam = out.values["P"], out.values["Q"].reshape(N_Y, N_ZETA), float(out.values["lambda"][0])
    P = 0.5 * (P + P.T)
    K = np.linalg.solve(P, Q.T)
    cert, lam = _certify(model, reg, P, Q, K, lam, eps, verts, grid, settings)
    pmin = float(np.linalg.eigvalsh(P).min())
    smin = min(1.0, eps * pmin)
    lam_delta = d2 * float(np.linalg.norm(reg.Q_zeta @ D_REG, 2)) + max(d1, d2) * math.sqrt(lam / smin)  # (1.16a)
    beta = math.sqrt(float(np.linalg.eigvalsh(P).max()) / smin)                                        # (1.16b)
    poles = np.concatenate([np.linalg.eigvals(reg.P_zeta @ model.A_zeta(*p) - K @ reg.H) for p in grid])
    extra.update({"lambda": lam, "lambda_delta": lam_delta, "beta": beta, "k_norm": float(np.linalg.norm(K, 2)),
                  "slowest_pole_real": float(poles.real.max()), "fastest_pole_abs": float(np.abs(poles).max())})
    status = DesignStatus.CERTIFIED if cert.certified else DesignStatus.REJECTED
    head = f"delta2={d2}, epsilon={eps}, lambda={lam:.4g}, lambda_delta={lam_delta:.4g}: "
    reason = head + (cert.reason if cert.certified else "certification failed: " + cert.reason)
    gains = {"K": K.tolist(), "P_zeta": reg.P_zeta.tolist(), "Q_zeta": reg.Q_zeta.tolist(), "H": reg.H.tolist()}
    return DesignResult(status, cert.certified, reason, gains, P.tolist(), {**cert.margins, **extra}, lam_delta,
                        out.stats, variant)


def _certify(model: VehicleModel, reg: Regularized, P: np.ndarray, Q: np.ndarray, K: np.ndarray, lam: float,
             eps: float, verts: np.ndarray, grid: np.ndarray, settings: SolverSettings
             ) -> tuple[lmi.Certificate, float]:
    """Re-check (1.26) (with ``Q = K^T P``) at the solver's lambda, else inflated by 1 % or 10 %.

    A larger lambda only makes the (2, 2) block more negative, so certifying it is sound.
    """
    Qk = K.T @ P

    def closed(p: np.ndarray) -> np.ndarray:
        return reg.P_zeta @ model.A_zeta(*p) - K @ reg.H

    cert = None
    for factor in (1.0, 1.01, 1.1):
        lam_c = lam * factor

        def lmi_at(p: np.ndarray, lam_c: float = lam_c) -> np.ndarray:
            Az = model.A_zeta(*p)
            return lmi_126(P, Qk, lam_c, reg.P_zeta @ Az, reg.E_cal(Az), reg.H, reg.D_cal, eps)

        cert = certify_design(P=P, lmis={"lmi_126": lmi_at}, vertices=verts, grid=grid, closed_loop=closed,
                              margin=settings.certify_margin)
        if cert.certified:
            return cert, lam_c
    assert cert is not None
    return cert, lam


def design_for(req: DesignRequest) -> DesignResult:
    """Cached design for an observer instance (its vehicle and design options)."""
    v = req.vehicle
    keys = ("delta1", "delta2", "epsilon", "vx_range_mps", "grid_points")
    opts = {k: req.options[k] for k in keys}
    settings = SolverSettings()
    payload = {
        "family": "uio_nguyen", "variant": req.variant, "options": opts, "solver": settings.to_dict(),
        "vehicle": {"mass_kg": v.mass_kg, "yaw_inertia_kgm2": v.yaw_inertia_kgm2, "lf_m": v.lf_m, "lr_m": v.lr_m,
                    "cf_Npr": v.cornering_stiffness_f_Npr, "cr_Npr": v.cornering_stiffness_r_Npr},
        "code": [harness.__version__, lmi.source_fingerprint(lmi, design_for)],
    }
    model = vehicle_model(v)
    compute: Callable[[], DesignResult] = lambda: design(model, opts, settings)  # noqa: E731
    return lmi.cached_design(payload, compute, use_cache=bool(req.options["use_cache"]))
