r"""Design model and LMI (3.12) of the neuro-adaptive concurrent-learning observer (Bessafa 2024, ch. 3).

H. Bessafa, "Advanced Estimation Algorithms for Connected and Autonomous Vehicle Applications", PhD
thesis, Université de Lorraine (CRAN), 2024, HAL tel-04744305, sec. 3.4-3.5.

Design model (3.26)/(3.27), state ``x = (p, v, a)`` [m, m/s, m/s^2], ``y = p``:

.. math::

    \dot x = A x + B f(x) + B_u u,\quad
    f(x) = -(2K_d/m) x_2 x_3 - (1/\tau)(x_3 + (K_d/m) x_2^2 + d_m/m),\quad B_u = e_3/(m\tau)

with m = 1850 kg, tau = 0.5 s, K_d = 0.3 N s^2/m^2, d_m = 100 N (sec. 3.5.3) and the input u(t) of
(3.30) (S3a). The observer extends the state with ``x_4 = f(x)`` (the lumped unknown term, m/s^3):
``A~ = [[A, F], [0, 0]]`` (a 4-integrator chain), ``C~ = [1, 0, 0, 0]``, ``L~ = [L; K] = P^-1 Y^T``.

LMI (3.12): ``A~^T P + P A~ - Y^T C~ - C~^T Y + lambda I <= 0``, printed with lambda = 1e5 and the
extra constraint ``P <= D = diag(1e-2, 1e-3, 1e-4, 1e-5)``. This is INFEASIBLE: the (4,4) entry of the
LMI is ``2 P_34 + lambda`` (Y does not reach it because C~ only touches the first coordinate), so
``P_34 <= -lambda/2``, while ``|P_34| <= sqrt(P_33 P_44) <= 3.2e-5``: lambda <= 2 sqrt(1e-9) = 6.3e-5
for any gains. What is feasible, and designed here: the same LMI with lambda a decision variable,
**maximised** under ``p_floor I <= P <= D``. The LMI is homogeneous of degree one in (P, Y, lambda, D),
so it is solved and certified in units of ``D_44 = 1e-5`` (all quantities divided by 1e-5) to keep
the solver's strictness and the certificate's margin meaningful; lambda is reported in the thesis's
units. The optimum lambda* = 1.75e-5 hardly depends on the floor; the floor sets the fastest pole
(about ``-0.9 / p_floor`` in the scaled units): the problem is ill-posed without it, the gains grow
without bound as the floor goes to zero. The printed gains have the same shape (one pole at
-3.6e4 rad/s, three at -8 and -2.9 +/- 10j) and certify only up to lambda = 2.0e-7 under ``P <= D``.

Certification (NumPy, :func:`roadtruth.observers.lmi.certify_design`): P > 0, (3.12) at the design lambda,
``P - D <= 0`` and the closed-loop matrix ``A~ - L~ C~`` Hurwitz. The certified decay rate of
``V = e^T P e`` is ``lambda / lambda_max(P)`` (3.20) (tiny: 2e-3 /s: the bound of the theorem is
far from the observed convergence, which the poles set).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

import roadtruth.harness as harness
from roadtruth.observers import lmi
from roadtruth.observers.lmi import DesignResult, DesignStatus, SolverSettings, certify_design, solve_lmi, sym

#: Vehicle of sec. 3.5.3: m [kg], tau [s], K_d [N s^2/m^2], d_m [N].
M7C = {"mass_kg": 1850.0, "tau_s": 0.5, "kd_Ns2pm2": 0.3, "dm_N": 100.0}
A_EXT = np.diag([1.0, 1.0, 1.0], k=1)          # [[A, F], [0, 0]] with F = e_3
C_EXT = np.array([[1.0, 0.0, 0.0, 0.0]])
#: The printed upper bound on P (sec. 3.5.2).
D_PRINTED = np.diag([1e-2, 1e-3, 1e-4, 1e-5])
LAMBDA_PRINTED = 1e5
#: Printed gains (sec. 3.5.2): L = 1e6 [0.0364, 0.5032, 5.6725], K = 3.1690e7.
L_PRINTED = np.array([0.0364e6, 0.5032e6, 5.6725e6, 3.1690e7])
#: Unit of the scaled problem (the LMI is homogeneous of degree one in P, Y, lambda, D).
SCALE = 1e-5


def m7c_f(x2: float, x3: float, mass_kg: float = M7C["mass_kg"], tau_s: float = M7C["tau_s"],
          kd: float = M7C["kd_Ns2pm2"], dm_N: float = M7C["dm_N"]) -> float:
    """Unknown term ``f(x)`` of (3.27) [m/s^3] at speed ``x2`` [m/s] and acceleration ``x3`` [m/s^2]."""
    return -(2.0 * kd / mass_kg) * x2 * x3 - (x3 + (kd / mass_kg) * x2 * x2 + dm_N / mass_kg) / tau_s


def s3a_input(t: float) -> float:
    """Input u(t) of (3.30) (S3a), 0-60 s [N as printed]; 0 outside."""
    if 0.0 < t < 10.0:
        return 0.1 * t
    if 10.0 <= t < 20.0:
        return 1.0
    if 20.0 <= t < 30.0:
        return 5.0 / 3.0 - t / 30.0
    if 30.0 <= t < 40.0:
        return t / 40.0
    if 40.0 <= t < 50.0:
        return 1.0
    if 50.0 <= t < 60.0:
        return 11.0 / 6.0 - t / 60.0
    return 0.0


def simulate_m7c(t: np.ndarray, x0: tuple[float, float, float], u: Callable[[float], float],
                 substeps: int = 10, params: dict[str, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Truth of the design model (3.27) on the grid ``t`` (n,) [s]: classical RK4, ``substeps`` per interval.

    ``u`` is evaluated inside each sub-step only at its own nodes, so a grid that contains the
    input's breakpoints (10, 20, ... s for (3.30)) integrates a piecewise-smooth input without
    straddling a jump. Returns ``x`` (n, 3) and ``f(x)`` (n,) [m/s^3].
    """
    p = {**M7C, **(params or {})}
    m, tau, kd, dm = p["mass_kg"], p["tau_s"], p["kd_Ns2pm2"], p["dm_N"]
    bu = 1.0 / (m * tau)

    def rhs(ts: float, x: np.ndarray, uk: float) -> np.ndarray:
        return np.array([x[1], x[2], m7c_f(x[1], x[2], m, tau, kd, dm) + bu * uk])

    x = np.empty((len(t), 3))
    x[0] = x0
    for i in range(len(t) - 1):
        h = (t[i + 1] - t[i]) / substeps
        xi = x[i].copy()
        for j in range(substeps):
            ts = t[i] + j * h
            # the input of the interval [t_i, t_i+1): evaluated at the interval's interior times only
            u0, um, u1 = u(ts), u(ts + 0.5 * h), u(ts + h) if j < substeps - 1 else u(t[i + 1] - 1e-12)
            k1 = rhs(ts, xi, u0)
            k2 = rhs(ts + 0.5 * h, xi + 0.5 * h * k1, um)
            k3 = rhs(ts + 0.5 * h, xi + 0.5 * h * k2, um)
            k4 = rhs(ts + h, xi + h * k3, u1)
            xi = xi + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
        x[i + 1] = xi
    f = np.array([m7c_f(v, a, m, tau, kd, dm) for v, a in x[:, 1:]])
    return x, f


def _lmi_3_12(P: np.ndarray, Lt: np.ndarray, lam: float) -> np.ndarray:
    Az = A_EXT - Lt.reshape(4, 1) @ C_EXT
    M = P @ Az
    return M + M.T + lam * np.eye(4)


def _max_lambda_problem(p_floor: float, fixed_gains: np.ndarray | None, strict: float) -> Callable[[], tuple]:
    D = D_PRINTED / SCALE

    def build() -> tuple[Any, dict[str, Any]]:
        import cvxpy as cp

        P = cp.Variable((4, 4), symmetric=True)
        lam = cp.Variable()
        if fixed_gains is None:
            Y = cp.Variable((1, 4))
            M = P @ A_EXT - C_EXT.T @ Y
            exprs: dict[str, Any] = {"P": P, "Y": Y, "lam": lam}
        else:
            M = P @ (A_EXT - fixed_gains.reshape(4, 1) @ C_EXT)
            exprs = {"P": P, "lam": lam}
        cons = [P >> p_floor * np.eye(4), P << D - strict * np.eye(4),
                2 * sym(M) + lam * np.eye(4) << -strict * np.eye(4)]
        return cp.Problem(cp.Maximize(lam), cons), exprs
    return build


def _certify(variant: str, P: np.ndarray, Lt: np.ndarray, lam_scaled: float, claimed: float | None,
             stats: dict[str, Any]) -> DesignResult:
    """Certificate (scaled units) of gains ``Lt`` (4,) with ``P`` (4, 4) at ``lam_scaled``."""
    D = D_PRINTED / SCALE
    cert = certify_design(P=P, lmis={"lmi_3_12": lambda _p: _lmi_3_12(P, Lt, lam_scaled),
                                     "p_below_D": lambda _p: P - D},
                          vertices=np.zeros((1, 1)),
                          closed_loop=lambda _p: A_EXT - Lt.reshape(4, 1) @ C_EXT)
    pmax = float(np.linalg.eigvalsh(P).max())
    poles = np.linalg.eigvals(A_EXT - Lt.reshape(4, 1) @ C_EXT)
    margins = {**cert.margins, "lambda_max_certifiable": lam_scaled * SCALE,
               "decay_rate_V_per_s": lam_scaled / pmax, "fastest_pole_radps": float(poles.real.min()),
               "slowest_pole_radps": float(poles.real.max())}
    gains = {"L": Lt[:3].tolist(), "K": [float(Lt[3])], "P_scaled_by": [SCALE]}
    if claimed is not None and claimed > lam_scaled * SCALE * (1.0 + 1e-6):
        margins["lambda_claimed"] = claimed
        reason = (f"LMI (3.12) infeasible at the printed lambda = {claimed:.3g} with P <= D; these gains "
                  f"certify only up to lambda = {lam_scaled * SCALE:.3g}")
        return DesignResult(DesignStatus.REJECTED, False, reason, gains, (P * SCALE).tolist(), margins, None,
                            stats, variant)
    status = DesignStatus.CERTIFIED if cert.certified else DesignStatus.REJECTED
    reason = (f"(3.12) certified at lambda = {lam_scaled * SCALE:.4g} with P <= diag(1e-2, ..., 1e-5)"
              if cert.certified else cert.reason)
    return DesignResult(status, cert.certified, reason, gains, (P * SCALE).tolist(), margins, None, stats, variant)


def design(variant: str, p_floor_scaled: float, settings: SolverSettings) -> DesignResult:
    """``variant`` 'lmi' (maximise lambda in (3.12), P between ``p_floor_scaled`` 1e-5 and D) or 'printed'."""
    fixed = L_PRINTED if variant == "printed" else None
    floor = settings.strictness if fixed is not None else p_floor_scaled
    out = solve_lmi(_max_lambda_problem(floor, fixed, settings.strictness), settings)
    if out.status != "optimal":
        status = DesignStatus.INFEASIBLE if out.status == "infeasible" else DesignStatus.SOLVER_FAILED
        return DesignResult(status, False, f"LMI (3.12) {out.status}", solver_stats=out.stats, variant=variant)
    P = sym(out.values["P"])
    lam = float(out.values["lam"][0])
    # certify a hair below the optimum: the optimum sits on the boundary of the feasible set
    lam_c = lam - 2.0 * settings.strictness
    if fixed is not None:
        return _certify(variant, P, fixed, lam_c, LAMBDA_PRINTED, out.stats)
    Lt = np.linalg.solve(P, out.values["Y"].reshape(1, 4).T).reshape(4)
    return _certify(variant, P, Lt, lam_c, None, out.stats)


def cached(variant: str, p_floor_scaled: float, use_cache: bool = True) -> DesignResult:
    """Disk-cached :func:`design`."""
    settings = SolverSettings()
    payload = {"family": "neuro_adaptive", "variant": variant, "p_floor_scaled": p_floor_scaled,
               "solver": settings.to_dict(),
               "code": [harness.__version__, lmi.source_fingerprint(lmi, design, _certify, _lmi_3_12,
                                                                     _max_lambda_problem)]}
    return lmi.cached_design(payload, lambda: design(variant, p_floor_scaled, settings), use_cache=use_cache)


def high_gain_eso_gains(eps: float, l: tuple[float, ...] = (4.0, 6.0, 4.0, 1.0)) -> np.ndarray:
    """CL-AEO gains of Ran & Xie (Bessafa 2024, sec. 3.3.2): ``[l_1/eps, ..., l_4/eps^4]`` (4,).

    The default ``l`` are the coefficients of ``(s + 1)^4``, so ``E`` is Hurwitz and the observer's
    poles are all at ``-1/eps``.
    """
    return np.array([li / eps ** (i + 1) for i, li in enumerate(l)])


def chain_poles_gains(omega: float) -> np.ndarray:
    """Gains ``[4w, 6w^2, 4w^3, w^4]`` placing the 4-chain's poles at ``-omega`` [rad/s]."""
    w = float(omega)
    return np.array([4 * w, 6 * w * w, 4 * w ** 3, w ** 4])

