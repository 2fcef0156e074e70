r"""Magic Formula axle curves and the nonlinear single-track model of the EKF/UKF baselines.

Axle lateral force (Pacejka, *Tire and Vehicle Dynamics*, 3rd ed., eq. 4.49), pure slip::

    F(alpha) = D sin(C atan(B alpha - E (B alpha - atan(B alpha))))

with the vehicle's per-axle shape ``(By, Cy, Ey)`` and the same friction scaling as the truth engine
(``harness/truth/tire.py``): the peak is ``D = k F_z,static`` with ``k = grip * mu`` (the tire's grip,
``VehicleParams.tires.grip``, times the road friction the filter assumes, option ``mu``) and
``B = By / k``, so the axle cornering stiffness ``B C D = By Cy F_z,static`` does not depend on
either; only the peak (``k m g`` of lateral acceleration over both axles) and the peak slip move.

Single-track model (CONTRACT slip definitions, ``cos delta`` on the front force)::

    alpha_f = delta - atan((v_y + l_f r)/v_x),   alpha_r = -atan((v_y - l_r r)/v_x)
    m (v_y' + v_x r) = F_f cos(delta) + F_r,      I_z r' = l_f F_f cos(delta) - l_r F_r

integrated by RK4 with enough sub-steps for the model's stiffness (``h lambda <= 0.5`` with
``lambda`` the linear model's largest rate at ``v_x``).

Layout: the parameters live in one float array (``model_array``; indices ``M_*``) so the compiled
filter kernels of ``observers/kalman.py`` take them without Python objects. Every function below is
compiled with the project's numba options; its ``py_func`` is the plain-Python twin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.tire import jit
from roadtruth.harness.truth.vehicle import G, VehicleParams

#: Indices of ``model_array``. ``M_FZF``/``M_FZR``: static axle loads [N]; ``M_GRIP``: the peak scale
#: ``k`` the curves have now (``set_grip`` moves it; ``B D = By F_z`` is kept, so is the stiffness).
(M_MASS, M_IZ, M_LF, M_LR, M_BF, M_CF, M_EF, M_DF, M_BR, M_CR, M_ER, M_DR, M_RATE, M_FZF, M_FZR, M_GRIP,
 N_MODEL) = range(17)
#: Largest RK4 sub-steps per filter step (bounds the cost at very low speed).
MAX_SUBSTEPS = 50
#: Largest normalised slip ``B alpha`` the curve inversion returns (far past any tire's peak).
X_MAX = 1.0e4


@dataclass(frozen=True)
class AxleCurve:
    """Magic Formula of one axle: B [1/rad], C, E [1], D (peak force) [N]."""

    B: float
    C: float
    E: float
    D: float


def peak_scale(vehicle: VehicleParams, mu: float) -> float:
    """``grip * mu``: the axle peak force per unit of static load [1]. Raises InputError on a bad ``mu``."""
    if not (isinstance(mu, int | float) and math.isfinite(mu) and 0.05 <= mu <= 2.0):
        raise InputError(f"road friction mu must be a number in [0.05, 2] (got {mu!r})", field="observer option mu")
    return vehicle.tires.grip * float(mu)


def axle_curves(vehicle: VehicleParams, mu: float = 1.0) -> tuple[AxleCurve, AxleCurve]:
    """Front and rear axle curves for road friction ``mu`` (peak ``grip mu F_z``, stiffness kept)."""
    k = peak_scale(vehicle, mu)
    tf, tr = vehicle.tires.front, vehicle.tires.rear
    return (AxleCurve(tf.By / k, tf.Cy, tf.Ey, k * vehicle.fz_front_static_N),
            AxleCurve(tr.By / k, tr.Cy, tr.Ey, k * vehicle.fz_rear_static_N))


def peak_lateral_acceleration(vehicle: VehicleParams, mu: float = 1.0) -> float:
    """Largest steady lateral acceleration the model's axles can give, ``grip mu g`` [m/s^2]."""
    return peak_scale(vehicle, mu) * G


def model_array(vehicle: VehicleParams, mu: float = 1.0) -> np.ndarray:
    """Parameters of the single-track model, (N_MODEL,) float array indexed by ``M_*``.

    ``M_RATE`` is ``((C_f + C_r)/m + (l_f^2 C_f + l_r^2 C_r)/I_z)`` [N/(kg rad) ...]: divided by ``v_x``
    it bounds the linear model's fastest rate [1/s], which sets the RK4 sub-steps.
    """
    f, r = axle_curves(vehicle, mu)
    m, iz, lf, lr = vehicle.mass_kg, vehicle.yaw_inertia_kgm2, vehicle.lf_m, vehicle.lr_m
    cf, cr = vehicle.cornering_stiffness_f_Npr, vehicle.cornering_stiffness_r_Npr
    out = np.zeros(N_MODEL)
    out[M_MASS], out[M_IZ], out[M_LF], out[M_LR] = m, iz, lf, lr
    out[M_BF], out[M_CF], out[M_EF], out[M_DF] = f.B, f.C, f.E, f.D
    out[M_BR], out[M_CR], out[M_ER], out[M_DR] = r.B, r.C, r.E, r.D
    out[M_RATE] = (cf + cr) / m + (lf * lf * cf + lr * lr * cr) / iz
    out[M_FZF], out[M_FZR] = vehicle.fz_front_static_N, vehicle.fz_rear_static_N
    out[M_GRIP] = peak_scale(vehicle, mu)
    return out


# ---- compiled model ---------------------------------------------------------------------------------

@jit
def set_grip(par: np.ndarray, k: float) -> None:
    """Rescale both axle curves in place to the peak ``k F_z,static`` [N], keeping ``B D`` (so the
    cornering stiffness ``B C D``) and the shape: the same friction scaling as ``axle_curves``."""
    kold = par[M_GRIP]
    if k == kold:
        return
    par[M_BF] *= kold / k
    par[M_BR] *= kold / k
    par[M_DF] = k * par[M_FZF]
    par[M_DR] = k * par[M_FZR]
    par[M_GRIP] = k


@jit
def peak_slip(B: float, C: float, E: float) -> float:
    """Slip angle of the Magic Formula's peak [rad]: where ``C atan(u) = pi/2``, ``u = x - E (x - atan x)``,
    ``x = B alpha`` (solved by ``inverse_shape``). A curve with ``C <= 1`` rises towards
    ``D sin(C pi/2)`` without a peak: its "peak" is where it reaches 99.9 % of that."""
    if C > 1.0:
        return inverse_shape(math.tan(0.5 * math.pi / C), E) / B
    return inverse_shape(math.tan(math.asin(0.999 * math.sin(0.5 * math.pi * C)) / C), E) / B


@jit
def inverse_shape(u: float, E: float) -> float:
    """``x >= 0`` with ``x - E (x - atan x) = u`` for ``u >= 0`` and ``E <= 1`` [1].

    ``u(x)`` is increasing for ``E <= 1``. Newton's method safeguarded by a bracket (bisection when a
    Newton step leaves it); where no root exists below ``X_MAX`` (``E = 1`` and ``u >= pi/2``) it
    returns ``X_MAX``.
    """
    lo, hi = 0.0, 1.0
    while hi < X_MAX and hi - E * (hi - math.atan(hi)) < u:
        hi *= 2.0
    if hi >= X_MAX:
        return X_MAX
    x = 0.5 * (lo + hi)
    for _ in range(60):
        f = x - E * (x - math.atan(x)) - u
        if f > 0.0:
            hi = x
        else:
            lo = x
        df = 1.0 - E + E / (1.0 + x * x)
        xn = x - f / df if df > 0.0 else 0.5 * (lo + hi)
        if not lo < xn < hi:
            xn = 0.5 * (lo + hi)
        if abs(xn - x) <= 1e-13 * (1.0 + x):
            return xn
        x = xn
    return x


@jit
def inverse_magic_formula(F: float, B: float, C: float, E: float, D: float) -> tuple[float, float]:
    """Slip angle [rad] on the rising branch with force ``F`` [N] and the used fraction ``|F|/D`` [1].

    ``|F| >= D`` (more force than the curve's peak) returns the peak slip with fraction 1: the curve
    cannot say more there.
    """
    frac = abs(F) / D
    top = 1.0 if C > 1.0 else 0.999 * math.sin(0.5 * math.pi * C)
    if frac >= top:
        return math.copysign(peak_slip(B, C, E), F), 1.0
    u = math.tan(math.asin(frac) / C)
    return math.copysign(inverse_shape(u, E) / B, F), frac


@jit
def magic_formula(alpha: float, B: float, C: float, E: float, D: float) -> tuple[float, float]:
    """Pure-slip lateral force and its slope: ``(F [N], dF/dalpha [N/rad])``."""
    ba = B * alpha
    u = ba - E * (ba - math.atan(ba))
    phi = math.atan(u)
    du = B - E * (B - B / (1.0 + ba * ba))
    return D * math.sin(C * phi), D * math.cos(C * phi) * C * du / (1.0 + u * u)


@jit
def single_track(vy: float, r: float, delta: float, v: float,
                 par: np.ndarray) -> tuple[float, float, float, float, float, float, float, float]:
    """Model at one state: ``(a_y, v_y', r', dF_f/da_f, dF_r/da_r, k_f, k_r, cos delta)``.

    ``k_f = d alpha_f / d(v_y + l_f r)``, ``k_r = d alpha_r / d(v_y - l_r r)`` [s/m] (for Jacobians);
    ``v`` [m/s] must be positive; ``par`` from ``model_array``.
    """
    lf, lr = par[M_LF], par[M_LR]
    uf = vy + lf * r
    ur = vy - lr * r
    ff, dff = magic_formula(delta - math.atan(uf / v), par[M_BF], par[M_CF], par[M_EF], par[M_DF])
    fr, dfr = magic_formula(-math.atan(ur / v), par[M_BR], par[M_CR], par[M_ER], par[M_DR])
    cd = math.cos(delta)
    ay = (ff * cd + fr) / par[M_MASS]
    kf = -v / (v * v + uf * uf)
    kr = -v / (v * v + ur * ur)
    return ay, ay - v * r, (lf * ff * cd - lr * fr) / par[M_IZ], dff, dfr, kf, kr, cd


@jit
def substeps(h: float, v: float, par: np.ndarray) -> int:
    """RK4 sub-steps for a step ``h`` [s] at speed ``v`` [m/s]: ``h lambda / n <= 0.5``."""
    n = math.ceil(h * par[M_RATE] / v / 0.5)
    return min(MAX_SUBSTEPS, max(1, n))


@jit
def rk4(vy: float, r: float, delta: float, v: float, h: float, par: np.ndarray) -> tuple[float, float]:
    """One classical Runge-Kutta step of ``(v_y, r)`` over ``h`` [s] with ``delta``, ``v`` held."""
    _, k1a, k1b, _, _, _, _, _ = single_track(vy, r, delta, v, par)
    _, k2a, k2b, _, _, _, _, _ = single_track(vy + 0.5 * h * k1a, r + 0.5 * h * k1b, delta, v, par)
    _, k3a, k3b, _, _, _, _, _ = single_track(vy + 0.5 * h * k2a, r + 0.5 * h * k2b, delta, v, par)
    _, k4a, k4b, _, _, _, _, _ = single_track(vy + h * k3a, r + h * k3b, delta, v, par)
    return (vy + h / 6.0 * (k1a + 2.0 * k2a + 2.0 * k3a + k4a), r + h / 6.0 * (k1b + 2.0 * k2b + 2.0 * k3b + k4b))


@jit
def propagate(vy: float, r: float, delta: float, v: float, h: float, par: np.ndarray) -> tuple[float, float]:
    """The model's state after ``h`` [s] (``substeps`` RK4 steps)."""
    n = substeps(h, v, par)
    hs = h / n
    for _ in range(n):
        vy, r = rk4(vy, r, delta, v, hs, par)
    return vy, r
