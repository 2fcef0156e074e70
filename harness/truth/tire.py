"""Magic Formula tires: combined slip, friction scaling that keeps the slip stiffness, relaxation, load.

Pure slip (Pacejka, *Tire and Vehicle Dynamics*, 3rd ed., eq. 4.49)::

    F(s) = D sin(C atan(B s − E (B s − atan(B s))))

with D = μ_eff F_z. When the road friction μ changes only the PEAK scales: B → B/μ and D = μ F_z, so
the initial slope B·C·D = B·C·F_z (the cornering / longitudinal slip stiffness) is unchanged and the
peak slip moves to μ times its dry value. The tire's ``grip`` (``VehicleParams.tires.grip``, peak force
per unit of road μ·F_z: 1 for road tires, ~1.3 for racing slicks) enters exactly like μ: the kernels
receive μ_eff = grip·μ_road, so D = grip·μ·F_z and B·C·D stays independent of both. An optional load
sensitivity lowers μ_eff = μ (1 − λ ΔF_z/F_z0) above the static load F_z0.

Combined slip uses the similarity method on the theoretical slips σ_x = κ/(1+κ), σ_y = tan α/(1+κ)
(Pacejka sec. 4.3.2): each is normalised by its pure-slip peak slip, and the resultant normalised slip
s_n drives both curves, F_x = (n_x/s_n) F_x0(s_n s_x*), F_y = (n_y/s_n) F_y0(s_n s_y*). Braking at a
given α therefore lowers F_y (friction ellipse).

Sign convention (ISO 8855 / CONTRACT.md): α = −atan(v_y,wheel / |v_x,wheel|) so that α > 0 gives F_y > 0;
κ = (ω R_e − v_x)/|v_x|. Relaxation is a first-order lag of α and κ with time constant σ/max(|v_x|, v_min)
(Pacejka sec. 7.2.1), updated with the exact exponential of one step. The normal load comes from a
radial tire spring-damper on the wheel centre height above the (flat) road.

Layout: private ``numba`` kernels on floats/arrays (``_mf``, ``_combined``, ``tire_forces_kernel``,
``relax_kernel``, ``radial_load_kernel``), a NumPy reference twin (``*_reference``) used to test them,
and the public wrapper ``combined_slip_forces``. ``NUMBA_OPTIONS`` is the one place the JIT options of
every compiled roadtruth kernel are set (no fastmath: same inputs → same bits).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numba
import numpy as np

from roadtruth.harness.truth.vehicle import AxleTire

#: JIT options of every roadtruth kernel (tire, driver, stepping loop). fastmath stays off so results
#: are bit-reproducible and equal to the interpreted reference; the numpy error model turns a division
#: by zero into inf/nan (caught by the divergence guard) instead of an exception inside the loop.
NUMBA_OPTIONS: dict[str, Any] = {"cache": True, "fastmath": False, "error_model": "numpy", "nogil": True}

#: Slip denominators use max(|v_x|, V_MIN_MPS): the model is meant for rolling above a few m/s.
V_MIN_MPS = 1.0
#: Smallest friction used in the B/μ scaling (keeps B finite on μ → 0).
MU_FLOOR = 0.02
#: Load sensitivity never lowers the peak below this fraction of μ.
LOAD_FACTOR_FLOOR = 0.2


def jit(fn: Callable[..., Any]) -> Callable[..., Any]:
    """``numba.njit`` with the project's options (``NUMBA_OPTIONS``)."""
    return numba.njit(**NUMBA_OPTIONS)(fn)


# ---- peak slip (setup time, plain Python) ---------------------------------------------------------

def peak_slip(B: float, C: float, E: float) -> float:
    """Slip s* at which the pure-slip curve of (B, C, E) peaks (μ = 1) [rad or 1].

    Solves B s − E(B s − atan B s) = tan(π/(2C)); for C ≤ 1 the curve has no peak and the slip where
    the sine argument reaches 0.99·(π/2)·C is used instead (a saturation point).
    """
    target = math.tan(math.pi / (2.0 * C)) if C > 1.0 else math.tan(0.99 * math.pi / 2.0)
    lo, hi = 0.0, 1e4
    g = lambda x: (1.0 - E) * x + E * math.atan(x) - target  # noqa: E731 (monotone for E <= 1)
    if g(hi) < 0.0:
        return hi / B
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if g(mid) < 0.0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi) / B


def shape_array(front: AxleTire, rear: AxleTire) -> np.ndarray:
    """Per-wheel MF shape table (4, 8) [By, Cy, Ey, Bx, Cx, Ex, s_y*, s_x*] for wheels fl, fr, rl, rr."""
    rows = []
    for t in (front, front, rear, rear):
        rows.append([t.By, t.Cy, t.Ey, t.Bx, t.Cx, t.Ex, peak_slip(t.By, t.Cy, t.Ey), peak_slip(t.Bx, t.Cx, t.Ex)])
    return np.array(rows, dtype=np.float64)


# ---- compiled kernels ---------------------------------------------------------------------------------

@jit
def _mf(s: float, B: float, C: float, D: float, E: float) -> float:
    bs = B * s
    return D * math.sin(C * math.atan(bs - E * (bs - math.atan(bs))))


@jit
def _combined(alpha: float, kappa: float, fz: float, mu: float, shape: np.ndarray, fz0: float,
              load_sensitivity: float) -> tuple[float, float]:
    """(F_x, F_y) [N] of one wheel; ``shape`` is one row of ``shape_array``."""
    if fz <= 0.0:
        return 0.0, 0.0
    mu_eff = max(mu, MU_FLOOR)
    if load_sensitivity > 0.0 and fz0 > 0.0:
        mu_eff *= max(1.0 - load_sensitivity * (fz - fz0) / fz0, LOAD_FACTOR_FLOOR)
    spy = shape[6] * mu_eff
    spx = shape[7] * mu_eff
    den = max(1.0 + kappa, 0.05)
    nx = kappa / den / spx
    ny = math.tan(alpha) / den / spy
    sn = math.sqrt(nx * nx + ny * ny) + 1e-12
    d = mu_eff * fz
    fx = nx / sn * _mf(sn * spx, shape[3] / mu_eff, shape[4], d, shape[5])
    fy = ny / sn * _mf(sn * spy, shape[0] / mu_eff, shape[1], d, shape[2])
    return fx, fy


@jit
def brush_trail(t0: float, sn: float) -> float:
    """Pneumatic trail [m] at normalised slip ``sn`` (1 = full sliding) of a brush tire with trail t0 at
    zero slip: t = t0 (1 − θ)^3 / (1 − θ + θ²/3), θ = min(sn, 1) (Pacejka 2012, sec. 3.2.2)."""
    th = min(abs(sn), 1.0)
    return t0 * (1.0 - th) ** 3 / (1.0 - th + th * th / 3.0)


@jit
def combined_with_camber(alpha: float, kappa: float, gamma: float, fz: float, mu: float, shape: np.ndarray,
                         fz0: float, load_sensitivity: float, camber_stiffness: float,
                         trail_m: float) -> tuple[float, float, float]:
    """(F_x, F_y, M_z) [N, N, N m] of one wheel of the per-axle Magic Formula tire.

    Camber enters as an equivalent slip angle, tan α_γ = c_γ γ / (B_y C_y), so that at zero slip
    F_y = c_γ F_z γ and the camber thrust shares the friction ellipse with the slips. γ > 0 leans the
    top of the wheel toward +y (roadtruth convention, docs/PHYSICS.md). M_z = −t(s_n) F_y with the
    brush-model trail (``brush_trail``) at the normalised combined slip s_n.
    """
    if fz <= 0.0:
        return 0.0, 0.0, 0.0
    ta = math.tan(alpha) + camber_stiffness * gamma / (shape[0] * shape[1])
    mu_eff = max(mu, MU_FLOOR)
    if load_sensitivity > 0.0 and fz0 > 0.0:
        mu_eff *= max(1.0 - load_sensitivity * (fz - fz0) / fz0, LOAD_FACTOR_FLOOR)
    spy = shape[6] * mu_eff
    spx = shape[7] * mu_eff
    den = max(1.0 + kappa, 0.05)
    nx = kappa / den / spx
    ny = ta / den / spy
    sn = math.sqrt(nx * nx + ny * ny) + 1e-12
    d = mu_eff * fz
    fx = nx / sn * _mf(sn * spx, shape[3] / mu_eff, shape[4], d, shape[5])
    fy = ny / sn * _mf(sn * spy, shape[0] / mu_eff, shape[1], d, shape[2])
    return fx, fy, -brush_trail(trail_m, sn) * fy


@jit
def tire_forces_kernel(alpha: np.ndarray, kappa: np.ndarray, fz: np.ndarray, mu: np.ndarray, shape: np.ndarray,
                       fz0: np.ndarray, load_sensitivity: float, fx: np.ndarray, fy: np.ndarray) -> None:
    """Combined-slip forces of n wheels, written into ``fx``, ``fy`` (n,) [N]. ``shape`` (n, 8)."""
    for i in range(alpha.shape[0]):
        fx[i], fy[i] = _combined(alpha[i], kappa[i], fz[i], mu[i], shape[i], fz0[i], load_sensitivity)


@jit
def relax_kernel(lagged: float, kinematic: float, vx: float, relaxation_length: float, dt: float) -> float:
    """One step of dα/dt = (α_kin − α)·max(|v_x|, v_min)/σ, exact for α_kin held over the step."""
    if relaxation_length <= 0.0:
        return kinematic
    rate = max(abs(vx), V_MIN_MPS) / relaxation_length
    return kinematic + (lagged - kinematic) * math.exp(-rate * dt)


@jit
def radial_load_kernel(deflection: float, deflection_rate: float, stiffness: float, damping: float) -> float:
    """Normal load of a radial tire spring-damper [N]; zero off the ground, never pulling."""
    if deflection <= 0.0:
        return 0.0
    return max(stiffness * deflection + damping * deflection_rate, 0.0)


# ---- NumPy reference twin ----------------------------------------------------------------------------

def _mf_reference(s: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, E: np.ndarray) -> np.ndarray:
    bs = B * s
    return D * np.sin(C * np.arctan(bs - E * (bs - np.arctan(bs))))


def tire_forces_reference(alpha: np.ndarray, kappa: np.ndarray, fz: np.ndarray, mu: np.ndarray, shape: np.ndarray,
                          fz0: np.ndarray, load_sensitivity: float) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised NumPy twin of ``tire_forces_kernel`` (same equations, (n,) arrays in, (n,) out)."""
    alpha, kappa, fz, mu, fz0 = (np.asarray(a, dtype=np.float64) for a in (alpha, kappa, fz, mu, fz0))
    mu_eff = np.maximum(mu, MU_FLOOR)
    if load_sensitivity > 0.0:
        mu_eff = mu_eff * np.maximum(1.0 - load_sensitivity * (fz - fz0) / fz0, LOAD_FACTOR_FLOOR)
    spy, spx = shape[:, 6] * mu_eff, shape[:, 7] * mu_eff
    den = np.maximum(1.0 + kappa, 0.05)
    nx = kappa / den / spx
    ny = np.tan(alpha) / den / spy
    sn = np.sqrt(nx * nx + ny * ny) + 1e-12
    d = mu_eff * fz
    fx = nx / sn * _mf_reference(sn * spx, shape[:, 3] / mu_eff, shape[:, 4], d, shape[:, 5])
    fy = ny / sn * _mf_reference(sn * spy, shape[:, 0] / mu_eff, shape[:, 1], d, shape[:, 2])
    on = fz > 0.0
    return np.where(on, fx, 0.0), np.where(on, fy, 0.0)


def relax_reference(lagged: np.ndarray, kinematic: np.ndarray, vx: np.ndarray, relaxation_length: float,
                    dt: float) -> np.ndarray:
    """NumPy twin of ``relax_kernel``."""
    if relaxation_length <= 0.0:
        return np.asarray(kinematic, dtype=np.float64)
    rate = np.maximum(np.abs(vx), V_MIN_MPS) / relaxation_length
    return kinematic + (lagged - kinematic) * np.exp(-rate * dt)


# ---- public wrapper ----------------------------------------------------------------------------------

def combined_slip_forces(tire: AxleTire, alpha_rad: np.ndarray, kappa: np.ndarray, fz_N: np.ndarray,
                         mu: np.ndarray | float = 1.0, *, fz_static_N: float | None = None,
                         load_sensitivity: float = 0.0, grip: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Steady-state (F_x, F_y) [N] of one axle's tire for arrays of slip angle, slip ratio and load.

    Parameters
    ----------
    tire : AxleTire
        Magic Formula shape (``VehicleParams.tires.front`` or ``.rear``).
    alpha_rad, kappa, fz_N : (n,) arrays
        Slip angle [rad] (positive gives positive F_y), slip ratio [1], normal load [N]; broadcast.
    mu : float or (n,) array
        Road friction under the tire.
    fz_static_N, load_sensitivity :
        Static wheel load and the peak-μ drop per 100 % overload (``VehicleParams.tires.load_sensitivity``).
    grip : float
        The tire's peak force per unit of road μ·F_z (``VehicleParams.tires.grip``); scales the peak
        like μ, never the slip stiffness.

    Returns
    -------
    fx, fy : (n,) arrays [N], computed by the compiled kernel.
    """
    a, k, fz, m = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, dtype=np.float64)) for v in (alpha_rad, kappa, fz_N, mu)))
    n = a.shape[0]
    row = shape_array(tire, tire)[0]
    shape = np.ascontiguousarray(np.broadcast_to(row, (n, 8)))
    fz0 = np.full(n, fz_static_N if fz_static_N is not None else 1.0)
    fx, fy = np.empty(n), np.empty(n)
    tire_forces_kernel(np.ascontiguousarray(a), np.ascontiguousarray(k), np.ascontiguousarray(fz),
                       np.ascontiguousarray(m * grip), shape, fz0, float(load_sensitivity if fz_static_N else 0.0), fx, fy)
    return fx, fy
