r"""Certified LMI design of the proportional-integral (PI) unknown-input observer (see :mod:`roadtruth.observers.pi_observer`).

Augmented model on Nguyen's vehicle (1.55)-(1.56) (:func:`roadtruth.observers.uio_nguyen_design.vehicle_model`,
``mu = (f_yf, f_yr)`` in kN), the unknown input given **leaky** null dynamics ``mu' = -kappa mu``:

.. math::

    z = (x, \mu),\quad A_a(\rho) = \begin{bmatrix}A(\rho) & B_\mu\\ 0 & -\kappa I\end{bmatrix},\quad
    C_a = [C\ \ 0],

observer ``z_hat' = A_a z_hat + [B_u; 0] u + L (y - C_a z_hat)``, ``L = [L_P; L_I] = P^-1 Q^T``.
Why the leakage: with ``y = (v_x, psi, r)`` the pair ``([A B_mu; 0 0], [C 0])`` fails the PBH test at
``s = 0`` (``rank C B_mu = 1``, normal rank of ``C (sI-A)^-1 B_mu`` = 1): one combination of the two
forces is never seen and a pure integrator on it would drift. With ``-kappa`` that mode sits at
``s = -kappa`` (PBH rank deficient there too, but stable): detectable, and the design asks for
decay rate ``alpha < kappa`` only.

LMIs at the 4 vertices of the ``(v_x, 1/v_x)`` box, ``A_cl = A_a - L C_a``:

* decay: ``He(P A_a - Q^T C_a) + 2 alpha P < 0`` (every frozen pole has ``Re s <= -alpha``);
* disk: ``[[-R P, P A_a - Q^T C_a], [*, -R P]] < 0`` (every pole within ``|s| < R``: the gains stay
  of the order of the model's bandwidth, so noise is not amplified without bound).

* L2 gain (bounded real lemma): the error ``e' = A_cl e + (B_w - L D_w) w`` driven by
  ``w = (nu, n)`` (``nu = mu' + kappa mu`` the generator input of the unknown input, weight
  ``W_nu``; ``n`` the output noise, weights ``W_n``) with performance output ``z = C_z e``
  (``v_y`` and ``r`` errors, weights ``W_z``):
  ``[[He(P A_a - Q^T C_a) + C_z^T C_z, P B_w - Q^T D_w], [*, -gamma^2 I]] < 0``.

Objective: minimise ``gamma^2`` (without it the smallest gains satisfy the region, the integral
channel is never used and the "PI" observer is the open-loop model). The certificate re-checks the
three LMIs at the vertices and on a dense grid of the physical curve ``(v, 1/v)`` and the frozen
closed loops; ``gamma`` is the certified bound.
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

N_A = N_X + N_MU


def augmented(model: VehicleModel, rho1: float, rho2: float, kappa: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A_a, C_a)`` of the leaky PI model at ``rho = (v_x, 1/v_x)``: (6, 6) [1/s], (3, 6)."""
    Aa = np.zeros((N_A, N_A))
    Aa[:N_X, :N_X] = model.A0 + rho1 * model.A1 + rho2 * model.A2
    Aa[:N_X, N_X:] = model.Bmu
    Aa[N_X:, N_X:] = -kappa * np.eye(N_MU)
    return Aa, np.hstack([model.C, np.zeros((N_Y, N_MU))])


def lmi_decay(P: np.ndarray, Q: np.ndarray, Aa: np.ndarray, Ca: np.ndarray, alpha: float) -> np.ndarray:
    """``He(P A_a - Q^T C_a) + 2 alpha P`` (must be < 0)."""
    X = P @ Aa - Q.T @ Ca
    return X + X.T + 2.0 * alpha * P


def lmi_disk(P: np.ndarray, Q: np.ndarray, Aa: np.ndarray, Ca: np.ndarray, radius: float) -> np.ndarray:
    """``[[-R P, X], [X^T, -R P]]``, ``X = P A_a - Q^T C_a`` (must be < 0: poles in ``|s| < R``)."""
    X = P @ Aa - Q.T @ Ca
    return np.block([[-radius * P, X], [X.T, -radius * P]])


#: Weights of the L2-gain design: unknown-input generator [kN/s], output noise (v_x [m/s], psi [rad],
#: r [rad/s]), performance (v_y error per m/s, r error per rad/s).
W_NU = 2.0
W_N = (0.05, 0.005, 0.002)
W_Z = (1.0, 10.0)


def l2_blocks(model: VehicleModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(B_w, D_w, C_z)`` of the L2-gain LMI: (6, 5), (3, 5), (2, 6)."""
    Bw = np.zeros((N_A, N_MU + N_Y))
    Bw[N_X:, :N_MU] = W_NU * np.eye(N_MU)
    Dw = np.hstack([np.zeros((N_Y, N_MU)), np.diag(W_N)])
    Cz = np.zeros((2, N_A))
    Cz[0, 1], Cz[1, 3] = W_Z
    return Bw, Dw, Cz


def lmi_l2(P: np.ndarray, Q: np.ndarray, Aa: np.ndarray, Ca: np.ndarray, gamma2: float,
           blocks: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """Bounded-real LMI of the error dynamics (must be < 0 for an L2 gain below ``sqrt(gamma2)``)."""
    Bw, Dw, Cz = blocks
    X = P @ Aa - Q.T @ Ca
    Y = P @ Bw - Q.T @ Dw
    return np.block([[X + X.T + Cz.T @ Cz, Y], [Y.T, -gamma2 * np.eye(Bw.shape[1])]])


def design(model: VehicleModel, opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    """Solve the decay + disk LMIs at the 4 vertices (smallest gains), then certify on the grid."""
    kappa, alpha, radius = float(opts["kappa"]), float(opts["decay_rate"]), float(opts["pole_radius"])
    v_range = (float(opts["vx_range_mps"][0]), float(opts["vx_range_mps"][1]))
    variant = "leaky_pi"
    if not (0.0 < alpha < kappa):
        return DesignResult(DesignStatus.INFEASIBLE, False,
                            f"decay rate {alpha} must lie in (0, kappa = {kappa}): the mode at -kappa cannot move",
                            variant=variant)
    verts, grid = scheduling_points(v_range, int(opts["grid_points"]))
    pairs = [augmented(model, *p, kappa) for p in verts]
    blocks = l2_blocks(model)
    Bw, Dw, Cz = blocks
    nw = Bw.shape[1]

    def build() -> tuple[Any, dict[str, Any]]:
        import cvxpy as cp

        P = cp.Variable((N_A, N_A), symmetric=True)
        Q = cp.Variable((N_Y, N_A))
        g2 = cp.Variable()
        s = settings.strictness
        cons = [P >> s * np.eye(N_A)]
        for Aa, Ca in pairs:
            X = P @ Aa - Q.T @ Ca
            Y = P @ Bw - Q.T @ Dw
            cons.append(sym(X + X.T + 2.0 * alpha * P) << -s * np.eye(N_A))
            cons.append(sym(cp.bmat([[-radius * P, X], [X.T, -radius * P]])) << -s * np.eye(2 * N_A))
            cons.append(sym(cp.bmat([[X + X.T + Cz.T @ Cz, Y], [Y.T, -g2 * np.eye(nw)]])) << -s * np.eye(N_A + nw))
        return cp.Problem(cp.Minimize(g2), cons), {"P": P, "Q": Q, "gamma2": g2}

    out = solve_lmi(build, settings)
    if out.status != "optimal":
        st = DesignStatus.INFEASIBLE if out.status == "infeasible" else DesignStatus.SOLVER_FAILED
        return DesignResult(st, False, f"PI LMIs (kappa={kappa}, alpha={alpha}, R={radius}): {out.status}",
                            solver_stats=out.stats, variant=variant)
    P = 0.5 * (out.values["P"] + out.values["P"].T)
    Q = out.values["Q"].reshape(N_Y, N_A)
    g2 = float(out.values["gamma2"][0]) * 1.01  # certified slightly above the solver's optimum
    L = np.linalg.solve(P, Q.T)
    Qk = L.T @ P
    cert = certify_design(
        P=P,
        lmis={"decay": lambda p: lmi_decay(P, Qk, *augmented(model, *p, kappa), alpha),
              "disk": lambda p: lmi_disk(P, Qk, *augmented(model, *p, kappa), radius),
              "l2": lambda p: lmi_l2(P, Qk, *augmented(model, *p, kappa), g2, blocks)},
        vertices=verts, grid=grid,
        closed_loop=lambda p: (lambda Aa, Ca: Aa - L @ Ca)(*augmented(model, *p, kappa)),
        stability_rate=alpha, margin=settings.certify_margin)
    poles = np.concatenate([np.linalg.eigvals((lambda Aa, Ca: Aa - L @ Ca)(*augmented(model, *p, kappa)))
                            for p in grid])
    margins = {**cert.margins, "l_norm": float(np.linalg.norm(L, 2)),
               "slowest_pole_real": float(poles.real.max()), "fastest_pole_abs": float(np.abs(poles).max())}
    status = DesignStatus.CERTIFIED if cert.certified else DesignStatus.REJECTED
    reason = (f"kappa={kappa}, alpha={alpha}, R={radius}, gamma={math.sqrt(g2):.4g}: "
              + (cert.reason if cert.certified else "certification failed: " + cert.reason))
    return DesignResult(status, cert.certified, reason, {"L": L.tolist()}, P.tolist(), margins, math.sqrt(g2),
                        out.stats, variant)


def design_for(req: DesignRequest) -> DesignResult:
    """Cached design for an observer instance (its vehicle and design options)."""
    v: VehicleParams = req.vehicle
    keys = ("kappa", "decay_rate", "pole_radius", "vx_range_mps", "grid_points")
    opts = {k: req.options[k] for k in keys}
    settings = SolverSettings()
    payload = {
        "family": "pi_observer_nguyen", "variant": req.variant, "options": opts, "solver": settings.to_dict(),
        "vehicle": {"mass_kg": v.mass_kg, "yaw_inertia_kgm2": v.yaw_inertia_kgm2, "lf_m": v.lf_m, "lr_m": v.lr_m,
                    "cf_Npr": v.cornering_stiffness_f_Npr, "cr_Npr": v.cornering_stiffness_r_Npr},
        "code": [harness.__version__, lmi.source_fingerprint(lmi, design_for, design)],
    }
    model = vehicle_model(v)
    compute: Callable[[], DesignResult] = lambda: design(model, opts, settings)  # noqa: E731
    return lmi.cached_design(payload, compute, use_cache=bool(req.options["use_cache"]))
