r"""LMI designs of Wang's (2014) robust H2 and unstructured LPV slip-angle observers.

Observers in :mod:`roadtruth.observers.lpv_wang_robust`. Every variant is written in the unstructured form
(3.47)-(3.48), ``x' = A_o(theta_m) x + B_ou(theta_m) u + B_oy(theta_m) y`` (a Luenberger observer is
``A_o = A - L C``, ``B_ou = B``, ``B_oy = L``), scheduled on the measured ``theta_m = theta - dtheta``.
With ``w = (x_hat, u)`` the estimation error ``e = x - x_hat`` obeys (3.34)/(3.49)-(3.51)

``e' = A_e e + B_e w``, ``A_e = A(theta) - B_oy(theta_m) C``,
``B_e = [A(theta) - B_oy(theta_m) C - A_o(theta_m), B(theta) - B_ou(theta_m)]``,

affine in the 16-vertex coordinates ``(theta1, theta2, dtheta1, dtheta2)`` of Lemma 10 / (3.72).

* H-infinity (3.53): bounded-real LMI (2.51) with output ``e``:
  ``[[He(P A_e), P B_e, I], [B_e^T P, -gamma I5, 0], [I, 0, -gamma I2]] < 0`` at every vertex, so the
  L2 gain from ``w`` to ``e`` is below gamma for any variation inside the polytope.
* H2 (3.41)/(3.52), **corrected** to the standard characterisation (the printed LMI has no output
  term; its derivation is omitted): ``He(P A_e) + I < 0`` and ``[[Z, B_e^T P], [P B_e, P]] > 0`` at
  every vertex, minimise ``trace Z``. Then ``V = e^T P e`` gives ``int |e|^2 <= e(0)^T P e(0)``, so an
  impulse in each ``w`` channel yields total error energy ``sum_j B_ej^T P B_ej <= trace Z`` and white
  noise of unit intensity a stationary ``E|e|^2 <= trace Z``: ``gamma = sqrt(trace Z)`` bounds the H2
  norm. With a noise-free ``y`` the infimum needs unbounded gains, so the design takes the smallest
  ``sum ||Q_i||_F`` at ``trace Z <= gamma_slack^2 x`` the infimum (default 5 % above it).

Linearised with ``Q_i = P L_i`` (Luenberger) or ``Q_o,i = P A_o,i``, ``Q_ou,i = P B_ou,i``,
``Q_oy,i = P B_oy,i`` (unstructured). The steering-rate column of ``B_ou`` is fixed to the plant's
``(1, 0)^T`` (the optimum has it there, and the observer then needs no differentiated steering).

Printed gains and matrices (sec. 3.3) are evaluated, not solved: the smallest certified bound for
them, then the same NumPy certification.
"""

from __future__ import annotations

from collections.abc import Callable
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
    physical_grid,
    robust_vertices,
    solve_lmi,
    sym,
)
from roadtruth.observers.lpv_wang_design import RUN_ONLY_OPTIONS

C = np.array([[1.0, -1.0]])
B0 = np.array([[0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
B2 = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
I2 = np.eye(2)
DDELTA = np.array([1.0, 0.0])  # the plant's steering-rate column of B

#: Printed sec. 3.3 results (800 kg car, speeds in m/s). Luenberger: ``L_i`` (2, 1). Unstructured:
#: ``Ao_i`` (2, 2), ``Bou_i`` (2, 3), ``Boy_i`` (2, 1), coefficient i of ``theta_m(i)`` (i = 0: constant).
PRINTED: dict[str, dict[str, list[list[float]]]] = {
    "h2_printed": {"L0": [[7250.9], [6962.8]], "L1": [[35776.0], [34423.0]], "L2": [[831.9374], [773.2087]]},
    "unstructured_h2_printed": {
        "Ao0": [[-2319.1, -2321.0], [-2531.0, -2532.7]], "Ao1": [[-2982.7, -2818.1], [-1432.1, -1581.4]],
        "Ao2": [[125.4695, 126.4443], [121.1414, 120.1646]],
        "Bou0": [[0.3352, 1.0, 1.0], [0.3364, 0.0, -1.0]], "Bou1": [[-1.5886, 0.0, 0.0], [-1.4224, 0.0, 0.0]],
        "Bou2": [[0.9821, 0.0, 0.0], [0.0147, 0.0, 0.0]],
        "Boy0": [[2320.3], [2532.2]], "Boy1": [[2824.4], [1432.6]], "Boy2": [[-126.4374], [-121.1343]]},
    "unstructured_hinf_printed": {
        "Ao0": [[-324.2065, -324.4028], [-311.0927, -310.6798]], "Ao1": [[-360.3333, -202.7391], [-194.5750, -352.6795]],
        "Ao2": [[-1.0852, -0.1374], [-0.1474, -1.1605]],
        "Bou0": [[-0.9175, 1.0, 1.0], [-0.8422, 0.0, -1.0]], "Bou1": [[2.1202, 0.0, 0.0], [2.0056, 0.0, 0.0]],
        "Bou2": [[1.2391, 0.0, 0.0], [0.2549, 0.0, 0.0]],
        "Boy0": [[324.2891], [310.8739]], "Boy1": [[206.7304], [200.8320]], "Boy2": [[0.1406], [0.1824]]},
}
UNSTRUCTURED_KEYS = tuple(f"{m}{i}" for m in ("Ao", "Bou", "Boy") for i in range(3))
VARIANTS = ("h2", "h2_printed", "unstructured_hinf", "unstructured_hinf_printed", "unstructured_h2",
            "unstructured_h2_printed")


def design_for(req: DesignRequest) -> DesignResult:
    """Cached design for an observer's request (its vehicle, variant and options)."""
    v = req.vehicle
    cf, cr = bicycle.axle_stiffness(v)
    opts = {k: val for k, val in req.options.items() if k not in RUN_ONLY_OPTIONS}
    settings = SolverSettings()
    payload = {
        "family": "lpv_wang_robust", "variant": req.variant, "options": opts, "solver": settings.to_dict(),
        "vehicle": {"mass_kg": v.mass_kg, "yaw_inertia_kgm2": v.yaw_inertia_kgm2, "lf_m": v.lf_m, "lr_m": v.lr_m,
                    "cf_Npr": cf, "cr_Npr": cr},
        "code": [harness.__version__, lmi.source_fingerprint(lmi, bicycle, design_for)],
    }
    A1, _ = bicycle.slip_model_terms(v)
    return lmi.cached_design(payload, lambda: design(req.variant, A1, opts, settings),
                             use_cache=bool(req.options["use_cache"]))


# ---- error system --------------------------------------------------------------------------------

def plant(A1: np.ndarray, th1: float, th2: float) -> tuple[np.ndarray, np.ndarray]:
    """``A(theta) = theta1 A1 - theta2 I`` (3.19) and ``B(theta) = B0 + theta2 B2``."""
    return th1 * A1 - th2 * I2, B0 + th2 * B2


def luenberger_as_unstructured(A1: np.ndarray, L: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Coefficients ``Ao_i, Bou_i, Boy_i`` of the Luenberger observer ``A - L C, B, L`` (all affine in theta)."""
    A_coef = [np.zeros((2, 2)), A1, -I2]
    B_coef = [B0, np.zeros((2, 3)), B2]
    out: dict[str, np.ndarray] = {}
    for i in range(3):
        Li = np.asarray(L[i], dtype=float).reshape(2, 1)
        out[f"Ao{i}"], out[f"Bou{i}"], out[f"Boy{i}"] = A_coef[i] - Li @ C, B_coef[i], Li
    return out


def observer_matrices(g: dict[str, np.ndarray], m1: float, m2: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``A_o, B_ou, B_oy`` at the measured ``theta_m = (m1, m2)``."""
    return tuple(g[f"{k}0"] + m1 * g[f"{k}1"] + m2 * g[f"{k}2"] for k in ("Ao", "Bou", "Boy"))  # type: ignore[return-value]


def error_system(A1: np.ndarray, g: dict[str, np.ndarray], pt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(A_e, B_e)`` of (3.49)-(3.51) at a point ``(theta1, theta2, dtheta1, dtheta2)``."""
    th1, th2, d1, d2 = pt
    A, B = plant(A1, th1, th2)
    Ao, Bou, Boy = observer_matrices(g, th1 - d1, th2 - d2)
    Ae = A - Boy @ C
    return Ae, np.hstack([Ae - Ao, B - Bou])


# ---- problems ------------------------------------------------------------------------------------

def _performance(kind: str, P: Any, PAe: Any, PBe: Any, perf: Any, eps: float) -> list[Any]:
    import cvxpy as cp

    if kind == "hinf":
        blk = cp.bmat([[PAe + PAe.T, PBe, I2], [PBe.T, -perf * np.eye(5), np.zeros((5, 2))],
                       [I2, np.zeros((2, 5)), -perf * I2]])
        return [sym(blk) << -eps * np.eye(9)]
    if kind == "h2_as_printed":  # (3.41)/(3.52) exactly as printed (no output term)
        return [sym(cp.bmat([[PAe + PAe.T, PBe], [PBe.T, -perf * np.eye(5)]])) << -eps * np.eye(7)]
    return [sym(PAe + PAe.T + I2) << -eps * I2, sym(cp.bmat([[perf, PBe.T], [PBe, P]])) >> eps * np.eye(7)]


def _problem(kind: str, structure: str, A1: np.ndarray, verts: np.ndarray, settings: SolverSettings, *,
             fixed: dict[str, np.ndarray] | None, cap: float | None) -> tuple[Any, dict[str, Any]]:
    """min gamma (H-inf) / trace Z (H2) over the vertices; with ``cap``: min gain norm at perf <= cap."""
    import cvxpy as cp

    eps = settings.strictness
    P = cp.Variable((2, 2), symmetric=True)
    scalar = kind in ("hinf", "h2_as_printed")
    perf = cp.Variable() if scalar else cp.Variable((5, 5), symmetric=True)
    size = perf if scalar else cp.trace(perf)
    cons: list[Any] = [P >> eps * I2]
    if kind == "h2_as_printed":  # trace Z < gamma, [[P, I], [I, Z]] > 0
        Z2 = cp.Variable((2, 2), symmetric=True)
        cons += [cp.trace(Z2) <= perf, sym(cp.bmat([[P, I2], [I2, Z2]])) >> eps * np.eye(4)]
    dec: dict[str, Any] = {}
    if fixed is None and structure == "luenberger":
        dec = {f"Q{i}": cp.Variable((2, 1)) for i in range(3)}
    elif fixed is None:
        dec = {f"Qo{i}": cp.Variable((2, 2)) for i in range(3)} | {f"Qoy{i}": cp.Variable((2, 1)) for i in range(3)}
        free = {f"Qou{i}": cp.Variable((2, 2)) for i in range(3)}  # the (delta, r) columns
        dec |= free
    for pt in verts:
        th1, th2, d1, d2 = pt
        m1, m2 = th1 - d1, th2 - d2
        A, B = plant(A1, th1, th2)
        if fixed is not None:
            Ae, Be = error_system(A1, fixed, pt)
            PAe, PBe = P @ Ae, P @ Be
        elif structure == "luenberger":
            PAe = P @ A - (dec["Q0"] + m1 * dec["Q1"] + m2 * dec["Q2"]) @ C
            PBe = P @ np.hstack([d1 * A1 - d2 * I2, d2 * B2])  # B_L of (3.35): independent of L
        else:
            qo = dec["Qo0"] + m1 * dec["Qo1"] + m2 * dec["Qo2"]
            qoy = dec["Qoy0"] + m1 * dec["Qoy1"] + m2 * dec["Qoy2"]
            qf = dec["Qou0"] + m1 * dec["Qou1"] + m2 * dec["Qou2"]
            qou = cp.hstack([qf[:, 0:1], cp.reshape(P @ DDELTA, (2, 1), order="F"), qf[:, 1:2]])
            PAe = P @ A - qoy @ C
            PBe = cp.hstack([PAe - qo, P @ B - qou])
        cons += _performance(kind, P, PAe, PBe, perf, eps)
    if cap is not None and dec:
        cons.append(size <= cap)
        objective = cp.Minimize(sum(cp.norm(q, "fro") for q in dec.values()))
    else:
        objective = cp.Minimize(size)
    return cp.Problem(objective, cons), {"P": P, "perf": perf} | dec


def _gains_from(structure: str, A1: np.ndarray, values: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    P = values["P"]
    if structure == "luenberger":
        return luenberger_as_unstructured(A1, [np.linalg.solve(P, values[f"Q{i}"].reshape(2, 1)) for i in range(3)])
    g: dict[str, np.ndarray] = {}
    for i in range(3):
        g[f"Ao{i}"] = np.linalg.solve(P, values[f"Qo{i}"].reshape(2, 2))
        g[f"Boy{i}"] = np.linalg.solve(P, values[f"Qoy{i}"].reshape(2, 1))
        f = np.linalg.solve(P, values[f"Qou{i}"].reshape(2, 2))
        g[f"Bou{i}"] = np.column_stack([f[:, 0], DDELTA if i == 0 else np.zeros(2), f[:, 1]])
    return g


# ---- certification -------------------------------------------------------------------------------

def _checks(kind: str, A1: np.ndarray, g: dict[str, np.ndarray], P: np.ndarray, perf: np.ndarray | float
            ) -> tuple[dict[str, Callable[[np.ndarray], np.ndarray]], Callable[[np.ndarray], np.ndarray]]:
    def closed(pt: np.ndarray) -> np.ndarray:
        return error_system(A1, g, pt)[0]

    if kind == "hinf":
        gam = float(perf)

        def brl(pt: np.ndarray) -> np.ndarray:
            Ae, Be = error_system(A1, g, pt)
            PA, PB = P @ Ae, P @ Be
            return np.block([[PA + PA.T, PB, I2], [PB.T, -gam * np.eye(5), np.zeros((5, 2))],
                             [I2, np.zeros((2, 5)), -gam * I2]])

        return {"bounded_real": brl}, closed
    Z = np.asarray(perf, dtype=float)

    def lyap(pt: np.ndarray) -> np.ndarray:
        PA = P @ closed(pt)
        return PA + PA.T + I2

    def gramian(pt: np.ndarray) -> np.ndarray:  # must be positive definite: checked as -(.) < 0
        PB = P @ error_system(A1, g, pt)[1]
        return -np.block([[Z, PB.T], [PB, P]])

    return {"h2_lyapunov": lyap, "h2_gramian": gramian}, closed


def _certify(kind: str, A1: np.ndarray, g: dict[str, np.ndarray], P: np.ndarray, perf: np.ndarray,
             verts: np.ndarray, grid: np.ndarray, settings: SolverSettings
             ) -> tuple[lmi.Certificate, np.ndarray | float, np.ndarray]:
    """Certify at the solver's bound, else at a bound inflated by 1 % or 10 % (a larger gamma or Z
    only loosens the LMIs, so certifying it is sound; the certified value is returned)."""
    cert = None
    if kind == "h2":
        # He(P A_e) + I < 0 fixes the scale of P; a solver answer that misses it by lam < 1 is
        # repaired exactly by scaling (P, Z) by s = (1 + margin) / (1 - lam) (the Gramian block
        # scales with s), so the solver's inaccuracy never decides the verdict.
        lyap = _checks(kind, A1, g, P, perf.reshape(5, 5))[0]["h2_lyapunov"]
        lam = max(float(np.linalg.eigvalsh(lyap(pt)).max()) for pt in np.vstack([verts, grid]))
        if -settings.certify_margin < lam < 1.0:
            s = 1.001 * (1.0 + settings.certify_margin) / (1.0 - lam)
            P, perf = s * P, s * perf
    for factor in (1.0, 1.01, 1.1):
        if kind == "hinf":
            p: np.ndarray | float = float(perf.reshape(-1)[0]) * factor
        else:
            Z = perf.reshape(5, 5)
            p = 0.5 * (Z + Z.T) + (factor - 1.0) * np.trace(Z) / 5.0 * np.eye(5)
        lmis, closed = _checks(kind, A1, g, P, p)
        cert = certify_design(P=P, lmis=lmis, vertices=verts, grid=grid, closed_loop=closed,
                              margin=settings.certify_margin)
        if cert.certified:
            return cert, p, P
    assert cert is not None
    return cert, p, P


def _gamma(kind: str, perf: np.ndarray | float) -> float:
    """gamma: the L2-gain bound (H-inf) or the H2-norm bound sqrt(trace Z)."""
    return float(np.asarray(perf).reshape(-1)[0]) if kind == "hinf" else float(np.sqrt(np.trace(np.reshape(perf, (5, 5)))))


def _to_gains(g: dict[str, np.ndarray], structure: str) -> dict[str, list[Any]]:
    if structure == "luenberger":
        return {f"L{i}": np.asarray(g[f"Boy{i}"], dtype=float).reshape(2, 1).tolist() for i in range(3)}
    return {k: np.asarray(g[k], dtype=float).tolist() for k in UNSTRUCTURED_KEYS}


def _printed_gains(variant: str, A1: np.ndarray, structure: str) -> dict[str, np.ndarray]:
    data = {k: np.asarray(val, dtype=float) for k, val in PRINTED[variant].items()}
    if structure == "luenberger":
        return luenberger_as_unstructured(A1, [data["L0"], data["L1"], data["L2"]])
    return data


def design(variant: str, A1: np.ndarray, opts: dict[str, Any], settings: SolverSettings) -> DesignResult:
    """Solve (or evaluate) and certify one variant for the slip model ``A1`` (2, 2) [1/m]."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown robust lpv_wang variant {variant!r}")
    kind = "hinf" if "hinf" in variant else "h2"
    structure = "unstructured" if variant.startswith("unstructured") else "luenberger"
    v_rng, a_rng = tuple(opts["vx_range_mps"]), tuple(opts["ax_range_mps2"])
    e1, e2 = tuple(opts["eps1_range"]), tuple(opts["eps2_range"])
    verts = robust_vertices(v_rng, a_rng, e1, e2)
    gp = physical_grid([v_rng, a_rng, e1, e2], (9, 5, 3, 3))
    th1, th2 = 1.0 / gp[:, 0], gp[:, 1] / gp[:, 0]
    grid = np.column_stack([th1, th2, gp[:, 2] / (1 + gp[:, 2]) * th1, (gp[:, 2] - gp[:, 3]) / (1 + gp[:, 2]) * th2])
    extra: dict[str, float] = {}
    stats: dict[str, Any] = {}
    if variant.endswith("_printed"):
        g = _printed_gains(variant, A1, structure)
        prefix = "printed gains, "
    else:
        first = solve_lmi(lambda: _problem(kind, structure, A1, verts, settings, fixed=None, cap=None), settings)
        if first.status != "optimal":
            st = DesignStatus.INFEASIBLE if first.status == "infeasible" else DesignStatus.SOLVER_FAILED
            return DesignResult(st, False, f"{kind} LMI: {first.status}", solver_stats=first.stats, variant=variant)
        opt = _gamma(kind, first.values["perf"])
        slack = float(opts["gamma_slack"])
        cap = slack * opt if kind == "hinf" else (slack * opt) ** 2
        second = solve_lmi(lambda: _problem(kind, structure, A1, verts, settings, fixed=None, cap=cap), settings)
        out = second if second.status == "optimal" else first
        g = _gains_from(structure, A1, out.values)
        extra["gamma_optimal"] = opt
        stats = {"optimum": first.stats, "min_norm": second.stats}
        prefix = ""
    # The smallest bound these exact gains certify (the NumPy check then uses it).
    ev = solve_lmi(lambda: _problem(kind, structure, A1, verts, settings, fixed=g, cap=None), settings)
    stats["evaluate"] = ev.stats
    shown = _to_gains(g, structure)
    # Stability of the observer's own dynamics x' = A_o x + ... (for a Luenberger observer the same
    # matrix as the error dynamics; for an unstructured one it is not, see the module docstring).
    extra["observer_max_real_eig"] = max(
        float(np.linalg.eigvals(observer_matrices(g, pt[0] - pt[2], pt[1] - pt[3])[0]).real.max())
        for pt in np.vstack([verts, grid]))
    if ev.status != "optimal":
        _, closed = _checks(kind, A1, g, I2, 1.0 if kind == "hinf" else np.eye(5))
        frozen = certify_design(P=None, lmis={}, vertices=verts, grid=grid, closed_loop=closed,
                                margin=settings.certify_margin)
        return DesignResult(DesignStatus.REJECTED, False,
                            f"{prefix}{kind} LMI {ev.status} for these gains (no common Lyapunov matrix); "
                            f"frozen error dynamics A_e: {frozen.reason}; the observer's own A_o has max Re eig "
                            f"{extra['observer_max_real_eig']:.4g}", shown, None, {**frozen.margins, **extra}, None,
                            stats, variant)
    if kind == "h2":
        # The printed (3.41)/(3.52) value, for comparison with the dissertation only (it bounds no
        # defined norm): for these gains and, for a fresh design, its optimum over the gains.
        pr = solve_lmi(lambda: _problem("h2_as_printed", structure, A1, verts, settings, fixed=g, cap=None), settings)
        extra["gamma_as_printed_lmi"] = float(pr.values["perf"][0]) if pr.status == "optimal" else float("nan")
        if not variant.endswith("_printed"):
            po = solve_lmi(lambda: _problem("h2_as_printed", structure, A1, verts, settings, fixed=None, cap=None),
                           settings)
            extra["gamma_as_printed_lmi_optimum"] = float(po.values["perf"][0]) if po.status == "optimal" else float("nan")
    P = ev.values["P"]
    cert, perf, P = _certify(kind, A1, g, P, ev.values["perf"], verts, grid, settings)
    gamma = _gamma(kind, perf)
    extra["gamma"] = gamma
    if kind == "h2":
        extra["h2_norm_squared_bound"] = gamma**2
    opt_txt = f" (optimum {extra['gamma_optimal']:.4g})" if "gamma_optimal" in extra else ""
    label = "L2 gain" if kind == "hinf" else "H2 norm"
    status = DesignStatus.CERTIFIED if cert.certified else DesignStatus.REJECTED
    reason = f"{prefix}{label} <= {gamma:.4g}{opt_txt}: " + (cert.reason if cert.certified
                                                              else "certification failed: " + cert.reason)
    return DesignResult(status, cert.certified, reason, shown, np.asarray(P).tolist(), {**cert.margins, **extra},
                        gamma, stats, variant)
