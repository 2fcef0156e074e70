r"""Gain ``L_NN`` of Nguyen's neural adaptive observer: Theorem 2 (1.39)-(1.41) with a disk constraint.

LMI (1.41) **with the +I the printed LMI omits** (without it the LMI is homogeneous and sigma -> 0),
at the 4 vertices ``A_j`` of the ``(v_x, 1/v_x)`` box of the vehicle (1.55) (unknown input ``B_mu``):

.. math::

    \begin{bmatrix}A_j^T\mathcal P + \mathcal P A_j - C^T\mathcal Q - \mathcal Q^T C + I & \mathcal P B_\mu\\
    B_\mu^T\mathcal P & -\sigma I\end{bmatrix}\prec 0,

``L_NN = P^-1 Q^T``, ``lambda_nn = sqrt(sigma)`` (1.39). Minimising sigma alone gives poles near
-1300 1/s, for which the forward-Euler model (1.43) of the chapter diverges at 10 ms; so the disk
(D-stability) LMI of the Euler step ``(I + dt A_cl)^T P (I + dt A_cl) < s^2 P`` is added
(``[[-s P, (P + dt (P A_j - Q^T C))^T], [*, -s P]] < 0``, ``s = disk_radius``; the digest's 0.8 is infeasible on the sedan at 10 ms, 0.95 is the default). Certified at the
vertices and on a dense grid of the physical curve ``(v, 1/v)``, with the Euler spectral radius.
"""

from __future__ import annotations

import math
from collections.abc import Callable
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
    certify_design,
    solve_lmi,
    sym,
)
from roadtruth.observers.uio_nguyen_design import (
    N_MU,
    N_X,
    N_Y,
    VehicleModel,
    scheduling_points,
    vehicle_model,
)


def lmi_141(P: np.ndarray, Q: np.ndarray, sigma: float, A: np.ndarray, Bmu: np.ndarray, C: np.ndarray,
            *, plus_identity: bool = True) -> np.ndarray:
    """(1.41) at one point (``plus_identity=False``: as printed)."""
    X = A.T @ P + P @ A - C.T @ Q - Q.T @ C + (np.eye(N_X) if plus_identity else 0.0)
    return np.block([[X, P @ Bmu], [Bmu.T @ P, -sigma * np.eye(N_MU)]])


def lmi_disk(P: np.ndarray, Q: np.ndarray, A: np.ndarray, C: np.ndarray, dt: float, s: float) -> np.ndarray:
    """Disk LMI of the Euler step: negative definite iff ``(I + dt A_cl)^T P (I + dt A_cl) < s^2 P``."""
    Y = P + dt * (P @ A - Q.T @ C)
    return np.block([[-s * P, Y.T], [Y, -s * P]])


def design(model: VehicleModel, opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    """Minimise sigma s.t. (1.41) + disk at the 4 vertices; certify on the v_x grid."""
    dt, s = float(opts["dt_s"]), float(opts["disk_radius"])
    verts, grid = scheduling_points((float(opts["vx_range_mps"][0]), float(opts["vx_range_mps"][1])),
                                    int(opts["grid_points"]))
    A_of = lambda p: model.A0 + p[0] * model.A1 + p[1] * model.A2  # noqa: E731
    C, B = model.C, model.Bmu

    def build() -> tuple[Any, dict[str, Any]]:
        import cvxpy as cp

        P = cp.Variable((N_X, N_X), symmetric=True)
        Q = cp.Variable((N_Y, N_X))
        sig = cp.Variable()
        eps = settings.strictness
        cons = [P >> eps * np.eye(N_X)]
        for p in verts:
            A = A_of(p)
            X = A.T @ P + P @ A - C.T @ Q - Q.T @ C + np.eye(N_X)
            cons.append(sym(cp.bmat([[X, P @ B], [B.T @ P, -sig * np.eye(N_MU)]])) << -eps * np.eye(N_X + N_MU))
            Y = P + dt * (P @ A - Q.T @ C)
            cons.append(sym(cp.bmat([[-s * P, Y.T], [Y, -s * P]])) << -eps * np.eye(2 * N_X))
        return cp.Problem(cp.Minimize(sig), cons), {"P": P, "Q": Q, "sigma": sig}

    out = solve_lmi(build, settings)
    if out.status != "optimal":
        st = DesignStatus.INFEASIBLE if out.status == "infeasible" else DesignStatus.SOLVER_FAILED
        return DesignResult(st, False, f"LMI (1.41) + disk: {out.status}", solver_stats=out.stats, variant="lmi_disk")
    P = 0.5 * (out.values["P"] + out.values["P"].T)
    L = np.linalg.solve(P, out.values["Q"].reshape(N_Y, N_X).T)
    Qk = L.T @ P
    sigma = float(out.values["sigma"][0]) * 1.01
    cert = certify_design(P=P, lmis={"lmi_141": lambda p: lmi_141(P, Qk, sigma, A_of(p), B, C),
                                     "disk": lambda p: lmi_disk(P, Qk, A_of(p), C, dt, s)},
                          vertices=verts, grid=grid, closed_loop=lambda p: A_of(p) - L @ C,
                          margin=settings.certify_margin)
    rho = max(float(np.abs(np.linalg.eigvals(np.eye(N_X) + dt * (A_of(p) - L @ C))).max()) for p in grid)
    poles = np.concatenate([np.linalg.eigvals(A_of(p) - L @ C) for p in grid])
    margins = {**cert.margins, "sigma": sigma, "lambda_nn": math.sqrt(sigma), "euler_spectral_radius": rho,
               "l_norm": float(np.linalg.norm(L, 2)), "fastest_pole_abs": float(np.abs(poles).max()),
               "slowest_pole_real": float(poles.real.max())}
    status = DesignStatus.CERTIFIED if cert.certified and rho < 1.0 else DesignStatus.REJECTED
    reason = (f"sigma={sigma:.4g} (lambda_nn={math.sqrt(sigma):.4g}), Euler radius {rho:.4f} at dt={dt}: "
              + (cert.reason if cert.certified else "certification failed: " + cert.reason))
    return DesignResult(status, status is DesignStatus.CERTIFIED, reason, {"L": L.tolist()}, P.tolist(), margins,
                        math.sqrt(sigma), out.stats, "lmi_disk")


def design_for(req: DesignRequest) -> DesignResult:
    """Cached design for an observer instance."""
    v: VehicleParams = req.vehicle
    opts = {k: req.options[k] for k in ("dt_s", "disk_radius", "vx_range_mps", "grid_points")}
    settings = SolverSettings()
    payload = {
        "family": "neural_adaptive_nguyen", "options": opts, "solver": settings.to_dict(),
        "vehicle": {"mass_kg": v.mass_kg, "yaw_inertia_kgm2": v.yaw_inertia_kgm2, "lf_m": v.lf_m, "lr_m": v.lr_m,
                    "cf_Npr": v.cornering_stiffness_f_Npr, "cr_Npr": v.cornering_stiffness_r_Npr},
        "code": [harness.__version__, lmi.source_fingerprint(lmi, design_for, design)],
    }
    model = vehicle_model(v)
    compute: Callable[[], DesignResult] = lambda: design(model, opts, settings)  # noqa: E731
    return lmi.cached_design(payload, compute, use_cache=bool(req.options["use_cache"]))
