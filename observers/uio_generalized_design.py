r"""Generalized (output-derivative) UIO of Nguyen, ch. 1, Section 4: model, rank tests, certified design.

Generalized model (1.27)-(1.30) on the vehicle (1.55)-(1.56) (:func:`roadtruth.observers.uio_nguyen_design.vehicle_model`),
``chi_1 = y``, ``chi_2 = y'``, ``zeta = (chi_1, chi_2, x, mu)``, ``n_zeta = 2 n_y + n_x + n_mu``:

.. math::

    \mathbb E\dot\zeta = J(\rho)\zeta + G(\rho, \dot\rho)(u, \dot u),\qquad
    \mathbb E = \begin{bmatrix}I&0&0&0\\0&I&0&\delta_1E - CB_\mu\\0&0&I&0\end{bmatrix},

``J`` rows: ``chi_1: [0, I, 0, 0]``, ``chi_2: [0, 0, C A^2 + C A', C A B_mu]``, ``x: [0, 0, A, B_mu]``; input
terms ``chi_2: C A B_u u + C B_u u'``, ``x: B_u u``. **Corrections**: (1.27) omits the input-rate term
``C B_u u'`` (the steering rate; not negligible) and, for the LPV model, ``C A'(rho) x`` with
``A' = a (A_1 - A_2 / v_x^2)`` (``v_x' = a`` in (1.55)); both are added. (1.30a) prints ``-CB`` in the
(2, 4) block of ``E_bb``; (1.28) says ``delta_1 E - CB``. The output (1.27) **sums**
``y_chi = chi_1 + C_chi chi_2 + C x`` (two copies of ``y`` plus ``C_chi y'``); for the vehicle that
sum leaves modes no gain can move (the summed variant is kept for the certification table,
``output_form="summed"``); the implemented form **stacks** them:

.. math::

    y_\chi = \begin{bmatrix}\chi_1\\ C_\chi\chi_2\\ C x + \delta_2 D\mu\end{bmatrix} - \bar D\omega,\quad
    H = \begin{bmatrix}I&0&0&0\\0&C_\chi&0&0\\0&0&C&\delta_2 D\end{bmatrix},\quad \bar D = [0; 0; D],
    \ \omega = \delta_2\mu

(``delta_1 = 0``, as in the chapter's vehicle: state-side regularisation alone is infeasible). The
observer (1.32) and Theorem 1 apply unchanged: ``[P_zeta Q_zeta] = pinv([E_bb; H])``,
``E_j = -P_zeta J_j Q_zeta D_bar``, ``D_cal = (I - H Q_zeta) D_bar``, LMI (1.26) with ``+I``. ``A^2`` is
quadratic in ``rho``, so there is no 4-vertex polytope: the LMI is imposed on a ``v_x`` grid
(``lmi_points``) and certified on a denser one (``grid_points``), a gridded (not polytopic) guarantee.

Table 1.1 (sec. 4.4): with ``rank C B = rank B`` and ``C_chi`` invertible, ``delta_2 = 0`` is allowed:
``omega = 0``, the LMI loses its ``lambda`` block and the error decays exponentially,
``|xi(t)| <= sqrt(cond P) exp(-t / (2 lambda_max(P))) |xi(0)|``; the design then minimises
``lambda_max(P)``. With ``C_chi = 0`` the derivative is not used and the observer is the Section-3
UIO with redundant ``chi`` states (not a distinct observer).
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
    certify_design,
    solve_lmi,
    sym,
)
from roadtruth.observers.uio_nguyen_design import D_REG, MU_SCALE_N, N_X, VehicleModel, unmovable_modes

#: Basis of the scheduling: J = sum_k c_k J_k with c = (1, v, 1/v, v^2, 1/v^2, a, a/v^2).
N_BASIS = 7


def basis(v: float, a: float) -> np.ndarray:
    """Coefficients ``(1, v, 1/v, v^2, 1/v^2, a, a/v^2)`` at speed ``v`` [m/s], acceleration ``a`` [m/s^2]."""
    return np.array([1.0, v, 1.0 / v, v * v, 1.0 / (v * v), a, a / (v * v)])


@dataclass(frozen=True)
class GeneralizedModel:
    """Matrices of (1.27)-(1.30) for one choice of unknown input, ``C_chi``, ``D``, ``delta_2`` and output form.

    ``Bmu`` (4, n_mu) [per kN]; ``Js`` (7, 2 n_y + 4, n_zeta) basis of ``J``; ``Gs`` (7, 2 n_y + 4, 4) basis
    of the input map on ``(u, u')``; ``E_bb`` (2 n_y + 4, n_zeta); ``H`` (n_out, n_zeta); ``D_bar`` (n_out,
    n_mu); ``P_zeta``, ``Q_zeta`` from (1.31).
    """

    n_y: int
    n_mu: int
    Bmu: np.ndarray
    C_chi: np.ndarray
    Js: np.ndarray
    Gs: np.ndarray
    E_bb: np.ndarray
    H: np.ndarray
    D_bar: np.ndarray
    P_zeta: np.ndarray
    Q_zeta: np.ndarray
    delta2: float
    summed: bool

    @property
    def n_zeta(self) -> int:
        return 2 * self.n_y + N_X + self.n_mu

    def J(self, v: float, a: float = 0.0) -> np.ndarray:
        """Jacobian of ``phi_zeta`` at ``(v_x, a)``: (2 n_y + 4, n_zeta)."""
        return np.tensordot(basis(v, a), self.Js, axes=1)

    def E_cal(self, J: np.ndarray) -> np.ndarray:
        """(1.13) corrected, ``delta_1 = 0``: ``-P_zeta J Q_zeta D_bar``: (n_zeta, n_mu)."""
        return -self.P_zeta @ J @ self.Q_zeta @ self.D_bar

    @property
    def D_cal(self) -> np.ndarray:
        """(1.13) corrected: ``(I - H Q_zeta) D_bar``."""
        return (np.eye(self.H.shape[0]) - self.H @ self.Q_zeta) @ self.D_bar

    def output(self, y: np.ndarray, ydot: np.ndarray) -> np.ndarray:
        """Measured ``y_chi`` from ``y`` and ``y'``: stacked ``(y, C_chi y', y)`` or summed ``2 y + C_chi y'``."""
        cy = self.C_chi @ ydot
        return 2.0 * y + cy if self.summed else np.concatenate([y, cy, y])


def unknown_input_matrix(model: VehicleModel, kind: str, yaw_inertia_kgm2: float) -> np.ndarray:
    """``B_mu`` of the unknown input: ``"axle_forces"`` (f_yf, f_yr) [kN] or ``"yaw_moment"`` M_z [kN m]."""
    if kind == "axle_forces":
        return model.Bmu
    if kind == "yaw_moment":
        b = np.zeros((N_X, 1))
        b[3, 0] = MU_SCALE_N / yaw_inertia_kgm2
        return b
    raise ValueError(f"unknown input kind {kind!r} (known: axle_forces, yaw_moment)")


def generalized_model(model: VehicleModel, Bmu: np.ndarray, C_chi: np.ndarray, delta2: float,
                      *, summed: bool = False, D: np.ndarray | None = None) -> GeneralizedModel:
    """(1.27)-(1.31) for the vehicle; ``D`` defaults to (1.58) (2 inputs) or the r channel (1 input).

    Raises ValueError when the rank condition (Assumption 5) fails.
    """
    C, ny, nmu = model.C, model.C.shape[0], Bmu.shape[1]
    if D is None:
        D = D_REG if nmu == 2 else np.array([[0.0], [0.0], [1.0]])
    nz, nr = 2 * ny + N_X + nmu, 2 * ny + N_X
    c1, c2, cx, cm = slice(0, ny), slice(ny, 2 * ny), slice(2 * ny, 2 * ny + N_X), slice(2 * ny + N_X, nz)
    E_bb = np.zeros((nr, nz))
    E_bb[c1, c1] = np.eye(ny)
    E_bb[c2, c2] = np.eye(ny)
    E_bb[c2, cm] = -C @ Bmu                       # delta_1 E - C B with delta_1 = 0 ((1.28); (1.30a) drops delta_1 E)
    E_bb[ny * 2:, cx] = np.eye(N_X)
    A0, A1, A2, Bu = model.A0, model.A1, model.A2, model.Bu
    # A = A0 + v A1 + A2 / v; A^2 on the basis (1, v, 1/v, v^2, 1/v^2); A' = a A1 - (a / v^2) A2.
    Asq = [A0 @ A0 + A1 @ A2 + A2 @ A1, A0 @ A1 + A1 @ A0, A0 @ A2 + A2 @ A0, A1 @ A1, A2 @ A2, A1, -A2]
    Alin = [A0, A1, A2, 0 * A0, 0 * A0, 0 * A0, 0 * A0]
    Js = np.zeros((N_BASIS, nr, nz))
    Gs = np.zeros((N_BASIS, nr, 4))
    for k in range(N_BASIS):
        if k == 0:
            Js[k, c1, c2] = np.eye(ny)
        Js[k, c2, cx] = C @ Asq[k]
        Js[k, cx, cx] = Alin[k]
        if k < 3:
            Js[k, c2, cm] = C @ Alin[k] @ Bmu
            Gs[k, c2, 0:2] = C @ Alin[k] @ Bu
    Js[0, cx, cm] = Bmu
    Gs[0, cx, 0:2] = Bu
    Gs[0, c2, 2:4] = C @ Bu                        # the input-rate term (1.27) omits
    if summed:
        H = np.hstack([np.eye(ny), C_chi, C, delta2 * D])
        D_bar = D.copy()
    else:
        H = np.zeros((3 * ny, nz))
        H[c1, c1] = np.eye(ny)
        H[ny:2 * ny, c2] = C_chi
        H[2 * ny:, cx] = C
        H[2 * ny:, cm] = delta2 * D
        D_bar = np.vstack([np.zeros((2 * ny, nmu)), D])
    theta = np.vstack([E_bb, H])
    if np.linalg.matrix_rank(theta) != nz:
        raise ValueError(f"rank condition (Assumption 5) fails: rank(delta2 D - C_chi C B_mu) < {nmu}")
    PQ = np.linalg.pinv(theta)
    return GeneralizedModel(ny, nmu, Bmu, C_chi, Js, Gs, E_bb, H, D_bar, PQ[:, :nr], PQ[:, nr:], delta2, summed)


def rank_condition(C: np.ndarray, Bmu: np.ndarray, C_chi: np.ndarray, D: np.ndarray, delta2: float) -> int:
    """``rank(delta_2 D - C_chi (delta_1 E - C B))`` with ``delta_1 = 0``; Assumption 5 needs ``n_mu``."""
    return int(np.linalg.matrix_rank(delta2 * D + C_chi @ C @ Bmu))


def lmi_126(P: np.ndarray, Q: np.ndarray, lam: float, PJ: np.ndarray, E_j: np.ndarray, H: np.ndarray,
            D_cal: np.ndarray, eps: float) -> np.ndarray:
    """(1.26) with ``+I`` at one point; without unknown-input channel (``delta_2 = 0``) the 2-block form."""
    n = P.shape[0]
    X = P @ PJ - Q.T @ H
    if lam <= 0.0:
        M = np.block([[X + X.T + np.eye(n), X.T], [X, -P / eps]])
    else:
        Y = P @ E_j - Q.T @ D_cal
        w = E_j.shape[1]
        M = np.block([[X + X.T + np.eye(n), Y, X.T], [Y.T, -lam * np.eye(w), Y.T], [X, Y, -P / eps]])
    return 0.5 * (M + M.T)


def design(gm: GeneralizedModel, opts: dict[str, Any], settings: SolverSettings, variant: str) -> DesignResult:
    """Solve (1.26) on the ``lmi_points`` grid of v_x; certify on ``grid_points`` (a = 0)."""
    eps = float(opts["epsilon"])
    lo, hi = (float(x) for x in opts["vx_range_mps"])
    v_lmi, v_cert = np.linspace(lo, hi, int(opts["lmi_points"])), np.linspace(lo, hi, int(opts["grid_points"]))
    exact = gm.delta2 == 0.0
    nz = gm.n_zeta
    PJs = [gm.P_zeta @ gm.J(v) for v in v_lmi]
    worst = max((float(m.real.max()) for m in (unmovable_modes(PJ, gm.H) for PJ in PJs) if m.size), default=-math.inf)
    extra: dict[str, float] = {"unmovable_mode_max_real": worst, "q_norm": float(np.linalg.norm(gm.Q_zeta, 2))}
    if worst >= 0.0:
        return DesignResult(DesignStatus.INFEASIBLE, False,
                            f"PBH pre-check: a mode no gain can move has Re = {worst:.4g} >= 0", margins=extra,
                            variant=variant)
    Ejs = [gm.E_cal(gm.J(v)) for v in v_lmi]
    Dc, H = gm.D_cal, gm.H

    def build() -> tuple[Any, dict[str, Any]]:
        import cvxpy as cp

        P = cp.Variable((nz, nz), symmetric=True)
        Q = cp.Variable((H.shape[0], nz))
        obj = cp.Variable()
        s = settings.strictness
        cons = [P >> s * np.eye(nz)]
        if exact:
            cons.append(P << obj * np.eye(nz))      # minimise lambda_max(P): the guaranteed decay rate
        for PJ, Ej in zip(PJs, Ejs, strict=True):
            X = P @ PJ - Q.T @ H
            if exact:
                M = cp.bmat([[X + X.T + np.eye(nz), X.T], [X, -(1.0 / eps) * P]])
                cons.append(sym(M) << -s * np.eye(2 * nz))
            else:
                Y = P @ Ej - Q.T @ Dc
                w = Ej.shape[1]
                M = cp.bmat([[X + X.T + np.eye(nz), Y, X.T], [Y.T, -obj * np.eye(w), Y.T], [X, Y, -(1.0 / eps) * P]])
                cons.append(sym(M) << -s * np.eye(2 * nz + w))
        return cp.Problem(cp.Minimize(obj), cons), {"P": P, "Q": Q, "obj": obj}

    out = solve_lmi(build, settings)
    if out.status != "optimal":
        st = DesignStatus.INFEASIBLE if out.status == "infeasible" else DesignStatus.SOLVER_FAILED
        return DesignResult(st, False, f"LMI (1.26) of the generalized UIO: {out.status}", margins=extra,
                            solver_stats=out.stats, variant=variant)
    P = 0.5 * (out.values["P"] + out.values["P"].T)
    K = np.linalg.solve(P, out.values["Q"].reshape(H.shape[0], nz).T)
    Qk = K.T @ P
    cert = None
    lam0 = 0.0 if exact else float(out.values["obj"][0])
    lam = lam0
    for factor in (1.0, 1.01, 1.1):
        # a larger lambda only makes the (2, 2) block more negative: certifying it is sound
        lam_c = lam0 * factor
        lam = lam_c

        def lmi_at(p: np.ndarray, lam_c: float = lam_c) -> np.ndarray:
            J = gm.J(float(p[0]))
            return lmi_126(P, Qk, lam_c, gm.P_zeta @ J, gm.E_cal(J), H, Dc, eps)

        cert = certify_design(P=P, lmis={"lmi_126": lmi_at}, vertices=v_lmi[:, None], grid=v_cert[:, None],
                              closed_loop=lambda p: gm.P_zeta @ gm.J(float(p[0])) - K @ H,
                              margin=settings.certify_margin)
        if cert.certified or exact:
            break
    assert cert is not None
    eigP = np.linalg.eigvalsh(P)
    poles = np.concatenate([np.linalg.eigvals(gm.P_zeta @ gm.J(v) - K @ H) for v in v_cert])
    extra.update({"lambda": lam, "k_norm": float(np.linalg.norm(K, 2)), "p_max_eig": float(eigP.max()),
                  "decay_rate_bound": 1.0 / (2.0 * float(eigP.max())),
                  "slowest_pole_real": float(poles.real.max()), "fastest_pole_abs": float(np.abs(poles).max())})
    status = DesignStatus.CERTIFIED if cert.certified else DesignStatus.REJECTED
    head = (f"exact case (delta2 = 0), rate bound {extra['decay_rate_bound']:.4g} 1/s: " if exact
            else f"delta2={gm.delta2}, epsilon={eps}, lambda={lam:.4g}: ")
    reason = head + (cert.reason if cert.certified else "certification failed: " + cert.reason)
    gains = {"K": K.tolist(), "P_zeta": gm.P_zeta.tolist(), "Q_zeta": gm.Q_zeta.tolist(), "H": gm.H.tolist()}
    return DesignResult(status, cert.certified, reason, gains, P.tolist(), {**cert.margins, **extra},
                        None if exact else lam, out.stats, variant)


def design_for(req: DesignRequest) -> DesignResult:
    """Cached design for an observer instance (its vehicle, unknown input and design options)."""
    v: VehicleParams = req.vehicle
    keys = ("unknown_input", "delta2", "epsilon", "c_chi", "output_form", "vx_range_mps", "lmi_points", "grid_points")
    opts = {k: req.options[k] for k in keys}
    settings = SolverSettings()
    payload = {
        "family": "uio_generalized", "variant": req.variant, "options": opts, "solver": settings.to_dict(),
        "vehicle": {"mass_kg": v.mass_kg, "yaw_inertia_kgm2": v.yaw_inertia_kgm2, "lf_m": v.lf_m, "lr_m": v.lr_m,
                    "cf_Npr": v.cornering_stiffness_f_Npr, "cr_Npr": v.cornering_stiffness_r_Npr},
        "code": [harness.__version__, lmi.source_fingerprint(lmi, design_for, design, generalized_model)],
    }
    compute: Callable[[], DesignResult] = lambda: design(req.model, opts, settings,  # noqa: E731
                                                         req.variant)
    return lmi.cached_design(payload, compute, use_cache=bool(req.options["use_cache"]))
