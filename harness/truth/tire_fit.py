"""Fit of the simple per-axle Magic Formula (the observers' tire model) to a truth tire's pure-slip curves.

Observers use F(s) = D sin(C atan(B s − E (B s − atan B s))) per axle (``roadtruth.harness.truth.vehicle.AxleTire``).
For a ``.tir`` (MF 6.1) or Fiala truth tire this module fits (B, C, E) to the truth's pure-slip curves
at the axle's static load F_z:

- the curves are first made odd, F_odd(s) = (F(s) − F(−s))/2, so ply-steer and conicity offsets of a
  .tir file (S_Hy, S_Vy) do not bend the symmetric fit;
- D = μ F_z with μ the curve's peak ratio max|F_odd|/F_z over the fit range (α ∈ [0, 15°],
  κ ∈ [0, 0.3]);
- the slope at zero slip K = dF_odd/ds|₀ (central difference) is imposed exactly through B = K/(C D),
  so B·C·D equals the truth's cornering / slip stiffness;
- C ∈ [0.5, 3] and E ∈ [−10, 1] are the least-squares solution (``scipy.optimize.least_squares``,
  trust-region reflective with those bounds) over 61 evenly spaced slips of the range.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

#: Fit ranges: slip angle [rad] and slip ratio [1].
ALPHA_FIT_MAX_RAD = math.radians(15.0)
KAPPA_FIT_MAX = 0.3
N_FIT_POINTS = 61
C_BOUNDS = (0.5, 3.0)
E_BOUNDS = (-10.0, 1.0)


class AxleMagicFormulaFit(NamedTuple):
    """Fitted simple Magic Formula of one axle's tire: shape (B, C, E) per direction and the peak ratios."""

    By: float  # [1/rad]
    Cy: float
    Ey: float
    Bx: float  # [1]
    Cx: float
    Ex: float
    mu_y: float  # peak |F_y|/F_z over the fit range
    mu_x: float  # peak |F_x|/F_z over the fit range


def _magic_formula(s: np.ndarray, B: float, C: float, D: float, E: float) -> np.ndarray:
    bs = B * s
    return D * np.sin(C * np.arctan(bs - E * (bs - np.arctan(bs))))


def _fit_one(curve: Callable[[np.ndarray], np.ndarray], s_max: float, fz: float) -> tuple[float, float, float, float]:
    """(B, C, E, μ) of one pure-slip curve F(s) over s ∈ [0, s_max]."""
    s = np.linspace(0.0, s_max, N_FIT_POINTS)

    def odd(x: np.ndarray) -> np.ndarray:
        return 0.5 * (np.asarray(curve(x), dtype=np.float64) - np.asarray(curve(-x), dtype=np.float64))

    f = odd(s)
    h = 1e-6 * s_max
    slope = float(odd(np.array([h]))[0] / h)
    if not (slope > 0.0 and np.all(np.isfinite(f))):
        raise ValueError(f"tire curve has no positive slope at zero slip (slope {slope:g}); check the sign convention")
    peak = float(np.max(np.abs(f)))
    D = peak

    def residual(p: np.ndarray) -> np.ndarray:
        C, E = p
        return (_magic_formula(s, slope / (C * D), C, D, E) - f) / peak

    # Imported here: only vehicles on a tire file or Fiala tires are fitted, and scipy.optimize
    # costs about 0.3 s at import on every simulate otherwise.
    from scipy.optimize import least_squares

    sol = least_squares(residual, x0=np.array([1.5, 0.0]), bounds=([C_BOUNDS[0], E_BOUNDS[0]], [C_BOUNDS[1], E_BOUNDS[1]]),
                        method="trf", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    C, E = (float(v) for v in sol.x)
    return slope / (C * D), C, E, peak / fz


def fit_axle_magic_formula(fy_of_alpha: Callable[[np.ndarray], np.ndarray],
                           fx_of_kappa: Callable[[np.ndarray], np.ndarray], fz: float) -> AxleMagicFormulaFit:
    """Fit the observers' per-axle Magic Formula to a truth tire at load ``fz`` [N].

    ``fy_of_alpha(alpha_rad)`` and ``fx_of_kappa(kappa)`` are the truth's pure-slip curves (arrays in,
    arrays of N out) in roadtruth's convention (positive slip gives positive force).
    Returns (By, Cy, Ey, Bx, Cx, Ex, mu_y, mu_x); B·C·D (D = μ F_z) equals the truth's slope at zero slip.
    """
    if not fz > 0.0:
        raise ValueError(f"fit load must be positive, got {fz}")
    By, Cy, Ey, mu_y = _fit_one(fy_of_alpha, ALPHA_FIT_MAX_RAD, fz)
    Bx, Cx, Ex, mu_x = _fit_one(fx_of_kappa, KAPPA_FIT_MAX, fz)
    return AxleMagicFormulaFit(By, Cy, Ey, Bx, Cx, Ex, mu_y, mu_x)


def pure_slip_curves(forces: Callable[[float, float, float, float], tuple[float, float, float]], fz: float
                     ) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray]]:
    """(F_y(α), F_x(κ)) curves at load ``fz`` from a kernel-like ``forces(fz, kappa, alpha, gamma) -> (fx, fy, mz)``.

    E.g. ``pure_slip_curves(lambda fz, k, a, g: mf61_forces(coef, fz, k, a, g, 20.0, 1.0, 1.0), fz)``.
    """
    def fy(alpha: np.ndarray) -> np.ndarray:
        return np.array([forces(fz, 0.0, float(a), 0.0)[1] for a in np.atleast_1d(alpha)])

    def fx(kappa: np.ndarray) -> np.ndarray:
        return np.array([forces(fz, float(k), 0.0, 0.0)[0] for k in np.atleast_1d(kappa)])

    return fy, fx
