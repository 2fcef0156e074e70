r"""Theorem 2 SDP of the switched unknown-input interval observer of Ifqir et al. (ACC 2018).

Plant per mode ``i`` (eqs. (12)-(16)), ``x = [v_y, r, psi_L, y_L]``, ``y = C x = [r, psi_L, y_L]``,
``u = delta_f``, unknown input ``d = rho``:

.. math::

    \dot x = A(c_f, c_r, v_x) x + B(c_f) u + E(v_x) \rho,\quad
    A = \begin{bmatrix} -\frac{c_f+c_r}{m v} & \frac{c_r l_r - c_f l_f}{m v} - v & 0 & 0\\
    \frac{c_r l_r - c_f l_f}{I_z v} & -\frac{c_r l_r^2 + c_f l_f^2}{I_z v} & 0 & 0\\ 0&1&0&0\\ 1&l_s&v&0\end{bmatrix}.

Interval matrices ``A_i^- <= A <= A_i^+`` (the paper's interval matrices, computed soundly): elementwise
min/max of the *stiffness* entries over the 4 corners of the ``±unc`` stiffness box and the speed band
``[v_i - dV, v_i + dV]`` (every entry is multi-affine in ``(c_f, c_r, 1/v)``, so corners suffice). The
kinematic entries (``-v`` in ``a_12``, ``v`` in ``a_43``) are frozen at ``v_i`` here: ``v_x`` and ``r`` are
both measured, so the observer adds ``P (A_kin(v_x) - A_kin(v_i)) x`` exactly at run time (ours; it
avoids a ``dV``-sized uncertainty on ``a_12``).

SDP (Theorem 2, eqs. (26)-(28), linearised with ``Z_i = Q_i Y_i``, ``alpha = 1``):

.. math::

    \min\gamma\ \text{s.t.}\ I \preceq Q_i = \mathrm{diag}(q_i) \preceq \beta I,\quad
    \begin{bmatrix}\mathrm{He}(Q_iP_iA_i^+ - W_iC)+\varepsilon Q_i & Q_i\\ Q_i & -\gamma I\end{bmatrix}\prec 0,\quad
    Q_iP_iA_i^- - W_iC + \eta Q_i \ge 0,\quad Q_iP_i \ge 0,

``Q_iP_i = Q_i(I + H_0C) - Z_i\Pi C`` (so ``P_iE_i = 0`` by construction, eq. (24)-(25) with the
pseudo-inverse transpose restored), ``K_i = Q_i^{-1}W_i``, ``H_i = H_0 - Q_i^{-1}Z_i\Pi``, ``P_i = I + H_iC``.

Two structural constraints (ours, documented in :mod:`roadtruth.observers.switched_interval`): rows 3-4 of
``Q_iP_i`` are zero (``h_3 = h_4 = 0``; with ``P >= 0`` the columns 3-4 already vanish) and
``W_i`` has zero camera columns in rows 1-2. Then the ``(v_y, r)`` bounds never use the camera (they
could not be tightened by it anyway, §2.8), ``z_3 = z_4 = 0`` exactly, and a camera dropout does not
touch the ``(v_y, r)`` bounds.

Certification (NumPy, independent of the solver) per mode: ``P >= 0``, ``P E = 0``, ``Q`` diagonal and
``>= alpha``, ``N(c, v) = P A(c, v) - K C`` Metzler and Hurwitz and the LMI (27) negative definite at every
stiffness corner x speed-band end and on a 5x5x9 grid, (27) at ``N^+`` itself, ``N^+`` Hurwitz and
``N_0 + P (A^+ - A^-)`` Hurwitz (width ISS of the sound form). Dwell time
``tau_a = ln(mu)/epsilon`` with ``mu = max_{i,j,k} q_i[k]/q_j[k]`` (``= 1`` with a common ``Q``) and the
paper's ``ln(beta/alpha)/epsilon``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

import roadtruth.harness as harness
from roadtruth.observers import bicycle, lmi
from roadtruth.observers.lmi import (
    DesignRequest,
    DesignResult,
    DesignStatus,
    SolverSettings,
    certify_design,
    solve_lmi,
    sym,
)

N_X, N_Y = 4, 3
C = np.array([[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class LateralModel:
    """Parameters of the linear bicycle + lane model: SI units, stiffness [N/rad], ``ls`` [m]."""

    m: float
    iz: float
    lf: float
    lr: float
    cf0: float
    cr0: float
    ls: float

    def A(self, cf: float, cr: float, v: float, v_kin: float | None = None) -> np.ndarray:
        """(4, 4) state matrix (13) [1/s]; kinematic entries use ``v_kin`` (default ``v``)."""
        vk = v if v_kin is None else v_kin
        m, iz, lf, lr = self.m, self.iz, self.lf, self.lr
        return np.array([
            [-(cf + cr) / (m * v), (cr * lr - cf * lf) / (m * v) - vk, 0.0, 0.0],
            [(cr * lr - cf * lf) / (iz * v), -(cr * lr * lr + cf * lf * lf) / (iz * v), 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [1.0, self.ls, vk, 0.0]])

    def B(self, cf: float) -> np.ndarray:
        """(4,) input vector [1/s^2 per rad]."""
        return np.array([cf / self.m, cf * self.lf / self.iz, 0.0, 0.0])

    def E(self, v: float) -> np.ndarray:
        """(4,) unknown-input (curvature) vector [m/s per 1/m]."""
        return np.array([0.0, 0.0, -v, -self.ls * v])


def lateral_model(req: DesignRequest) -> LateralModel:
    v = req.vehicle
    cf, cr = bicycle.axle_stiffness(v)
    return LateralModel(v.mass_kg, v.yaw_inertia_kgm2, v.lf_m, v.lr_m, float(cf), float(cr),
                        float(req.options["lookahead_m"]))


def mode_boxes(model: LateralModel, unc: float, v_c: float, v_lo: float, v_hi: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Interval matrices of one mode: ``(A^-, A^+, A_0, D)``, each (4, 4) [1/s]; ``A_0`` the centre."""
    mats = [model.A(cf, cr, v, v_kin=v_c)
            for cf in (model.cf0 * (1 - unc), model.cf0 * (1 + unc))
            for cr in (model.cr0 * (1 - unc), model.cr0 * (1 + unc)) for v in (v_lo, v_hi)]
    am, ap = np.min(mats, axis=0), np.max(mats, axis=0)
    return am, ap, 0.5 * (am + ap), 0.5 * (ap - am)


def decoupling(model: LateralModel) -> tuple[np.ndarray, np.ndarray]:
    """``H_0 = -E (CE)^+`` (4, 3) and ``Pi = I - (CE)(CE)^+`` (3, 3); both independent of ``v_x``."""
    e = model.E(1.0).reshape(N_X, 1)
    ce = C @ e
    pinv = np.linalg.solve(ce.T @ ce, ce.T)  # eq. (25) with the transpose restored
    return -e @ pinv, np.eye(N_Y) - ce @ pinv


def modes_from_options(opts: dict[str, Any]) -> list[tuple[float, float, float]]:
    """``(v_c, v_lo, v_hi)`` [m/s] of every mode from ``mode_speeds_mps`` and ``mode_halfwidth_mps``."""
    dv = float(opts["mode_halfwidth_mps"])
    return [(float(v), float(v) - dv, float(v) + dv) for v in opts["mode_speeds_mps"]]


def design_for(req: DesignRequest) -> DesignResult:
    """Cached, certified design for an observer instance (its vehicle and design options)."""
    model = lateral_model(req)
    keys = ("mode_speeds_mps", "mode_halfwidth_mps", "stiffness_uncertainty", "lookahead_m", "epsilon",
            "eta", "common_Q")
    opts = {k: req.options[k] for k in keys}
    settings = SolverSettings()
    payload = {"family": "switched_interval_ifqir", "variant": req.variant, "options": opts,
               "solver": settings.to_dict(), "model": model.__dict__,
               "code": [harness.__version__, lmi.source_fingerprint(lmi, bicycle, design_for)]}
    return lmi.cached_design(payload, lambda: design(model, opts, settings),
                             use_cache=bool(req.options["use_cache"]))


def design(model: LateralModel, opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    """Solve the Theorem 2 SDP for all modes jointly and certify each mode."""
    import cvxpy as cp

    modes = modes_from_options(opts)
    unc, eps, eta = float(opts["stiffness_uncertainty"]), float(opts["epsilon"]), float(opts["eta"])
    common = bool(opts["common_Q"])
    boxes = [mode_boxes(model, unc, *md) for md in modes]
    H0, Pi = decoupling(model)
    strict = settings.strictness

    def build() -> tuple[Any, dict[str, Any]]:
        gam, beta = cp.Variable(), cp.Variable()
        cons = [gam >= 0]
        exprs: dict[str, Any] = {"gamma": gam, "beta": beta}
        qc = cp.Variable(N_X)
        for i, (am, ap, _, _) in enumerate(boxes):
            q = qc if common else cp.Variable(N_X)
            Q = cp.diag(q)
            W, Z = cp.Variable((N_X, N_Y)), cp.Variable((N_X, N_Y))
            QP = Q @ (np.eye(N_X) + H0 @ C) - Z @ Pi @ C
            M = QP @ ap - W @ C
            blk = cp.bmat([[M + M.T + eps * Q, Q], [Q, -gam * np.eye(N_X)]])
            cons += [q >= 1.0, q <= beta,                               # (26), alpha = 1
                     sym(blk) << -strict * np.eye(2 * N_X),              # (27)
                     QP >= 0,                                            # P_i >= 0 (24)
                     QP @ am - W @ C + eta * Q >= 0,                     # (28)
                     QP[2:, :] == 0, W[:2, 1:] == 0]                     # structure (module doc)
            exprs |= {f"q{i}": q, f"W{i}": W, f"Z{i}": Z}
        # gamma first; a tiny weight on beta picks the best-conditioned Q among the optima
        return cp.Problem(cp.Minimize(gam + 1e-6 * beta), cons), exprs

    out = solve_lmi(build, settings)
    if out.status != "optimal":
        st = DesignStatus.INFEASIBLE if out.status == "infeasible" else DesignStatus.SOLVER_FAILED
        return DesignResult(st, False, f"Theorem 2 SDP: {out.status}", solver_stats=out.stats,
                            variant="sound")
    gamma = float(out.values["gamma"][0]) * (1.0 + 1e-6)
    gains: dict[str, list[Any]] = {"B0": model.B(model.cf0).tolist(),
                                   "b": (model.B(model.cf0) * unc).tolist(), "C": C.tolist()}
    margins: dict[str, float] = {}
    failures: list[str] = []
    qs = []
    for i, ((v_c, v_lo, v_hi), (am, ap, a0, dm)) in enumerate(zip(modes, boxes, strict=True)):
        q = out.values[f"q{i}"].reshape(N_X)
        Q = np.diag(q)
        K = np.linalg.solve(Q, out.values[f"W{i}"].reshape(N_X, N_Y))
        Y = np.linalg.solve(Q, out.values[f"Z{i}"].reshape(N_X, N_Y))
        H = H0 - Y @ Pi
        H[np.abs(H) < 1e-9] = 0.0
        P = np.eye(N_X) + H @ C
        P[np.abs(P) < 1e-9] = 0.0
        K = _metzler_cleanup(P, K, am)
        qs.append(q)
        cert, extra = certify_mode(model, unc, (v_c, v_lo, v_hi), am, ap, a0, P, K, Q, gamma, eps,
                                   settings.certify_margin)
        margins |= {f"mode{i}_{k}": val for k, val in {**cert.margins, **extra}.items()}
        if not cert.certified:
            failures.append(f"mode {i} ({v_c:g} m/s): {cert.reason}")
        gains |= {f"K{i}": K.tolist(), f"H{i}": H.tolist(), f"P{i}": P.tolist(), f"q{i}": q.tolist(),
                  f"Am{i}": am.tolist(), f"Ap{i}": ap.tolist(), f"A0{i}": a0.tolist(), f"D{i}": dm.tolist(),
                  f"mode{i}": [v_c, v_lo, v_hi]}
    qa = np.array(qs)
    alpha, beta = float(qa.min()), float(qa.max())
    mu = float(max((qa[i] / qa[j]).max() for i in range(len(qs)) for j in range(len(qs))))
    margins |= {"gamma": gamma, "alpha": alpha, "beta": beta, "epsilon": eps, "mu": mu,
                "dwell_time_s": math.log(mu) / eps, "dwell_time_paper_s": math.log(beta / alpha) / eps,
                "iss_gain": math.sqrt(gamma / (alpha * eps))}
    if failures:
        return DesignResult(DesignStatus.REJECTED, False, "certification failed: " + "; ".join(failures), gains,
                            None, margins, gamma, out.stats, "sound")
    return DesignResult(DesignStatus.CERTIFIED, True,
                        f"gamma = {gamma:.4g}, ISS gain {margins['iss_gain']:.3g}, dwell {margins['dwell_time_s']:.3g} s:"
                        " all checks passed at every vertex and grid point", gains, None, margins, gamma,
                        out.stats, "sound")


def _metzler_cleanup(P: np.ndarray, K: np.ndarray, am: np.ndarray, tol: float = 1e-8) -> np.ndarray:
    """Move the solver's round-off off the Metzler boundary: an off-diagonal ``N^-_{ij}`` (``j >= 1``, the
    columns ``K`` reaches through ``C``) in ``[-tol, 0)`` is lifted to ``+1e-12`` by changing
    ``K_{i, j-1}`` by the same tiny amount; anything more negative is left for the certificate to reject."""
    K = K.copy()
    n_minus = P @ am - K @ C
    for i in range(N_X):
        for j in range(1, N_X):
            if i != j and -tol <= n_minus[i, j] < 0.0:
                K[i, j - 1] += n_minus[i, j] - 1e-12
    return K


def lmi27(Q: np.ndarray, N: np.ndarray, gamma: float, eps: float) -> np.ndarray:
    """(8, 8) matrix of eq. (27) for a closed-loop ``N``; negative definite when the LMI holds."""
    return np.block([[Q @ N + N.T @ Q + eps * Q, Q], [Q, -gamma * np.eye(N_X)]])


def certify_mode(model: LateralModel, unc: float, band: tuple[float, float, float], am: np.ndarray,
                 ap: np.ndarray, a0: np.ndarray, P: np.ndarray, K: np.ndarray, Q: np.ndarray, gamma: float,
                 eps: float, margin: float) -> tuple[lmi.Certificate, dict[str, float]]:
    """Re-check one mode in NumPy (see module docstring); returns the certificate and extra margins."""
    v_c, v_lo, v_hi = band
    cf = (model.cf0 * (1 - unc), model.cf0 * (1 + unc))
    cr = (model.cr0 * (1 - unc), model.cr0 * (1 + unc))
    verts = lmi.box_corners([cf, cr, (v_lo, v_hi)])
    grid = lmi.physical_grid([cf, cr, (v_lo, v_hi)], (5, 5, 9))

    def closed(p: np.ndarray) -> np.ndarray:
        return P @ model.A(p[0], p[1], p[2], v_kin=v_c) - K @ C

    lmis: dict[str, Callable[[np.ndarray], np.ndarray]] = {
        "lmi27": lambda p: lmi27(Q, closed(p), gamma, eps),
        "lmi27_Nplus": lambda p: lmi27(Q, P @ ap - K @ C, gamma, eps)}
    cert = certify_design(P=Q, lmis=lmis, vertices=verts, grid=grid, closed_loop=closed, metzler=closed,
                          margin=margin)
    n_plus, n_minus, n0 = P @ ap - K @ C, P @ am - K @ C, P @ a0 - K @ C
    extra = {"P_min_entry": float(P.min()), "PE_residual": float(np.abs(P @ model.E(1.0)).max()),
             "Q_offdiag_max": float(np.abs(Q - np.diag(np.diag(Q))).max()),
             "Nminus_metzler_min_offdiag": lmi.metzler_margin(n_minus),
             "Nplus_max_real_eig": float(np.linalg.eigvals(n_plus).real.max()),
             "width_matrix_max_real_eig": float(np.linalg.eigvals(n0 + P @ (ap - am)).real.max())}
    fails = [cert.reason] if not cert.certified else []
    if extra["P_min_entry"] < 0:
        fails.append("P has a negative entry")
    if extra["PE_residual"] > 1e-8:
        fails.append("P E != 0")
    if extra["Nminus_metzler_min_offdiag"] < 0:
        fails.append("N^- not Metzler")
    if extra["Nplus_max_real_eig"] >= 0:
        fails.append("N^+ not Hurwitz")
    if extra["width_matrix_max_real_eig"] >= 0:
        fails.append("N_0 + P(A^+ - A^-) not Hurwitz")
    if fails:
        return lmi.Certificate(False, "; ".join(fails), cert.margins), extra
    return cert, extra
