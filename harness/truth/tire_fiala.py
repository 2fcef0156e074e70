"""Fiala brush tire with a parabolic pressure distribution, combined slip (compiled kernel).

Fiala (1954); Pacejka, *Tire and Vehicle Dynamics*, 3rd ed. 2012, sec. 3.2 (eqs. 3.14–3.19 for pure
side slip, sec. 3.2.3 combined slip): one friction coefficient μ (static = sliding), theoretical slips

    σ_x = κ/(1 + κ),   σ_y = tan α/(1 + κ),

stiffness-weighted slip components u = C_κ σ_x and v = C_α σ_y + C_γ γ and their resultant
Γ = √(u² + v²). With λ = Γ/(3 μ F_z) (λ = 1 is full sliding)

    F = 3 μ F_z (λ − λ² + λ³/3)  for λ < 1,   F = μ F_z beyond;   F_x = (u/Γ) F,   F_y = (v/Γ) F,

so the slopes at zero slip are C_κ and C_α, |F| ≤ μ F_z everywhere, and the peak is reached at the
sliding limit. Aligning moment: M_z = −t(λ) F_yα with the brush trail

    t(λ) = (a/3) (1 − λ)³ / (1 − λ + λ²/3)   (λ < 1, 0 beyond)

(Pacejka eq. 3.19 divided by eq. 3.16), a the contact half-length; at small slip M_z = −(a/3) C_α α.

Camber (optional, C_γ [N/rad]) is camber thrust entered as a lateral slip equivalent (C_γ γ adds to
C_α σ_y), so it shares the friction circle; its share of F_y carries no trail (F_yα = (C_α σ_y/Γ) F),
because a cambered brush's thrust acts near the contact centre (Pacejka sec. 3.3). The M_z part of
F_x times the lateral deflection (the "s F_x" arm) is not modelled.

Conventions as in docs/PHYSICS.md: α > 0 gives F_y > 0, κ > 0 driving, γ > 0 = top toward +y (thrust
toward +y when C_γ > 0), M_z about +z (M_z < 0 for α > 0). F_z ≤ 0 or μ ≤ 0 gives all zero.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit

#: Coefficient vector layout of ``fiala_forces``.
C_ALPHA, C_KAPPA, HALF_LENGTH, C_GAMMA = 0, 1, 2, 3
N_FIALA_COEF = 4
#: Smallest 1 + κ used in the theoretical slips (a locked wheel, κ = −1, is full sliding).
ONE_PLUS_KAPPA_FLOOR = 1e-6


def fiala_coefficients(c_alpha: float, c_kappa: float, half_length: float, c_gamma: float = 0.0) -> np.ndarray:
    """Coefficient vector of ``fiala_forces``.

    c_alpha : cornering stiffness C_α [N/rad] (> 0); c_kappa : longitudinal slip stiffness C_κ [N] (> 0);
    half_length : contact half-length a [m] (≥ 0); c_gamma : camber stiffness C_γ [N/rad].
    """
    if not (c_alpha > 0.0 and c_kappa > 0.0 and half_length >= 0.0 and math.isfinite(c_gamma)):
        raise ValueError(f"Fiala tire needs c_alpha > 0, c_kappa > 0, half_length >= 0 (got {c_alpha}, {c_kappa}, {half_length})")
    return np.array([c_alpha, c_kappa, half_length, c_gamma], dtype=np.float64)


@jit
def fiala_forces(coef: np.ndarray, fz: float, kappa: float, alpha: float, gamma: float,
                 mu: float) -> tuple[float, float, float]:
    """(F_x, F_y, M_z) [N, N, N m] of the Fiala brush tire (module docstring) at load ``fz`` [N], slip ratio
    ``kappa`` [1], slip angle ``alpha`` [rad], inclination ``gamma`` [rad] and friction ``mu`` [1]."""
    if fz <= 0.0 or mu <= 0.0:
        return 0.0, 0.0, 0.0
    den = max(1.0 + kappa, ONE_PLUS_KAPPA_FLOOR)
    u = coef[C_KAPPA] * kappa / den
    v_alpha = coef[C_ALPHA] * math.tan(alpha) / den
    v = v_alpha + coef[C_GAMMA] * gamma
    gam = math.sqrt(u * u + v * v)
    if gam == 0.0:
        return 0.0, 0.0, 0.0
    fmax = mu * fz
    lam = gam / (3.0 * fmax)
    if lam < 1.0:
        f = 3.0 * fmax * lam * (1.0 - lam + lam * lam / 3.0)
        trail = coef[HALF_LENGTH] / 3.0 * (1.0 - lam) ** 3 / (1.0 - lam + lam * lam / 3.0)
    else:
        f = fmax
        trail = 0.0
    return u / gam * f, v / gam * f, -trail * (v_alpha / gam * f)
