"""Elevation and bank of a road along its centre line, from a few control points in path coordinate s.

A road in 3D is its centre line (``roadtruth.harness.truth.road``) plus two functions of the path coordinate s:
the centre-line elevation z_c(s) [m] and the bank angle φ_b(s) [rad] (positive = left edge higher,
a positive rotation about the direction of travel, ISO 8855). The surface is then
z(s, e) = z_c(s) + e·tan φ_b(s) at signed lateral offset e (left positive).

Both functions must be C1 for a car: a kink in elevation is a step in grade, which a wheel meets as
a vertical bump (a step in its vertical velocity). Two ways to give the elevation:

* ``grade`` points (s, dz/ds): the grade is linear between points and held beyond them, so the
  elevation, its integral from z(0) = 0, is piecewise quadratic: the parabolic vertical curve of road
  design practice (constant-grade tangents joined by parabolas; AASHTO, *A Policy on Geometric
  Design of Highways and Streets*, 2018, ch. 3.4). C1 by construction, and a "10 % climb" is exactly
  10 % between its points.
* ``elevation`` points (s, z): a monotone piecewise cubic (PCHIP, Fritsch & Carlson, 1980) through
  the points, with zero slope at the first and last point so that holding the end values beyond
  them stays C1. Monotone between points: no overshoot above a crest point or below a sag point.

The bank uses the same monotone cubic through its points (flat at the ends): a ramp from 0 to
φ_b between two points is an S-shaped superelevation runoff with no kink in roll of the surface.
Beyond the first and last point the end values hold.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

Points = tuple[tuple[float, float], ...]

#: Columns of ``roadtruth.harness.truth.road.Road.samples``: the plane centre line, then the 3D profile.
COL_S, COL_X, COL_Y, COL_PSI, COL_RHO, COL_Z, COL_GRADE, COL_BANK = range(8)


@dataclass(frozen=True)
class RoadProfile:
    """Elevation and bank control points (SI units; an empty tuple = zero everywhere).

    Attributes
    ----------
    elevation_m : ((s_m, z_m), ...) strictly increasing s; monotone cubic, flat at the ends.
    grade : ((s_m, dz/ds), ...) strictly increasing s; dimensionless grade (0.1 = 10 %), linear
        between points, held beyond them; elevation = its integral with z(0) = 0. At most one of
        ``elevation_m`` and ``grade`` is given.
    bank_rad : ((s_m, phi_b_rad), ...) strictly increasing s; monotone cubic, flat at the ends.
    """

    elevation_m: Points = ()
    grade: Points = ()
    bank_rad: Points = ()

    def __post_init__(self) -> None:
        if self.elevation_m and self.grade:
            raise ValueError("give the elevation or the grade of a road, not both")
        for name in ("elevation_m", "grade", "bank_rad"):
            pts = getattr(self, name)
            s = [p[0] for p in pts]
            if any(b <= a for a, b in zip(s, s[1:], strict=False)):
                raise ValueError(f"{name}: s must increase strictly (got {s})")

    @property
    def is_flat(self) -> bool:
        """True when every control value is zero (the road is the plane z = 0)."""
        return all(v == 0.0 for pts in (self.elevation_m, self.grade, self.bank_rad) for _, v in pts)

    def columns(self, s_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centre-line elevation z_c [m], grade dz_c/ds [-] and bank φ_b [rad] at path coordinates ``s_m``.

        Exactly zero (not just small) where a profile is not given, so a flat road stays bit-identical.
        """
        s = np.asarray(s_m, dtype=np.float64)
        z = np.zeros_like(s)
        g = np.zeros_like(s)
        if self.elevation_m:
            z, g = _monotone_cubic(self.elevation_m, s)
        elif self.grade:
            z, g = _integrated_linear_grade(self.grade, s)
        b = _monotone_cubic(self.bank_rad, s)[0] if self.bank_rad else np.zeros_like(s)
        return z, g, b

    def max_abs_grade(self) -> tuple[float, float]:
        """(largest |dz/ds| of the interpolated elevation, s where it occurs [m])."""
        pts = self.elevation_m or self.grade
        if not pts:
            return 0.0, 0.0
        s_pts = np.array([p[0] for p in pts])
        # The grade is linear or a quadratic per interval: a fine grid finds its extremum closely.
        s = np.union1d(s_pts, np.linspace(s_pts[0], s_pts[-1], 64 * len(pts)))
        g = np.abs(self.columns(s)[1])
        k = int(np.argmax(g))
        return float(g[k]), float(s[k])


def _monotone_cubic(pts: Points, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Value and slope of the PCHIP through ``pts`` with zero end slopes, ends held beyond."""
    # Imported here: only roads with an elevation or bank profile need it (0.2-0.5 s at import).
    from scipy.interpolate import CubicHermiteSpline, PchipInterpolator

    sp = np.array([p[0] for p in pts], dtype=np.float64)
    vp = np.array([p[1] for p in pts], dtype=np.float64)
    if sp.size == 1:
        return np.full_like(s, vp[0]), np.zeros_like(s)
    d = PchipInterpolator(sp, vp).derivative()(sp)
    # Zero end slopes keep the Fritsch-Carlson monotonicity conditions and make the hold beyond C1.
    d[0] = d[-1] = 0.0
    spline = CubicHermiteSpline(sp, vp, d)
    sc = np.clip(s, sp[0], sp[-1])
    return spline(sc), spline.derivative()(sc)


def _integrated_linear_grade(pts: Points, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Elevation (integral from s = 0, z(0) = 0) and grade of a piecewise-linear grade, ends held."""
    sp = np.array([p[0] for p in pts], dtype=np.float64)
    gp = np.array([p[1] for p in pts], dtype=np.float64)
    knots = np.union1d(sp, [0.0])
    gk = np.interp(knots, sp, gp)
    # Trapezoids are exact on every knot interval (the grade is linear there).
    zk = np.concatenate([[0.0], np.cumsum(0.5 * (gk[1:] + gk[:-1]) * np.diff(knots))])
    zk -= zk[np.searchsorted(knots, 0.0)]
    k = np.clip(np.searchsorted(knots, s, side="right") - 1, 0, knots.size - 1)
    g = np.interp(s, sp, gp)
    z = zk[k] + 0.5 * (gk[k] + g) * (s - knots[k])
    return z, g


# ---- reading the profile columns of Road.samples ------------------------------------------------

@njit(cache=True)
def profile_at(samples: np.ndarray, ds: float, s: float) -> tuple[float, float, float, float]:
    """Centre-line elevation [m], grade [-], bank [rad] and dbank/ds [rad/m] at path coordinate s.

    Elevation: cubic Hermite on the sample values and grades (exact where the elevation is a
    quadratic, C1 across samples); bank: linear between samples, its slope the interval's. Beyond
    the ends grade and bank hold and the elevation continues linearly.
    """
    n = samples.shape[0]
    last = n - 1
    if s <= 0.0 or s >= samples[last, COL_S]:
        r = 0 if s <= 0.0 else last
        g = samples[r, COL_GRADE]
        return samples[r, COL_Z] + g * (s - samples[r, COL_S]), g, samples[r, COL_BANK], 0.0
    k = min(int(s / ds), n - 2)
    inv_ds = 1.0 / ds
    d = s - samples[k, COL_S]
    u = d * inv_ds
    z0 = samples[k, COL_Z]
    z1 = samples[k + 1, COL_Z]
    g0 = samples[k, COL_GRADE]
    g1 = samples[k + 1, COL_GRADE]
    b0 = samples[k, COL_BANK]
    db = (samples[k + 1, COL_BANK] - b0) * inv_ds
    uu = u * u
    z = ((2.0 * uu * u - 3.0 * uu + 1.0) * z0 + (uu * u - 2.0 * uu + u) * ds * g0
         + (3.0 * uu - 2.0 * uu * u) * z1 + (uu * u - uu) * ds * g1)
    g = (6.0 * uu - 6.0 * u) * (z0 - z1) * inv_ds + (3.0 * uu - 4.0 * u + 1.0) * g0 + (3.0 * uu - 2.0 * u) * g1
    return z, g, b0 + d * db, db


def profile_np(smp: np.ndarray, ds: float, s: np.ndarray) -> tuple[np.ndarray, ...]:
    """NumPy twin of :func:`profile_at`: centre-line elevation, grade, bank and dbank/ds at ``s``."""
    n = smp.shape[0]
    k = np.clip(np.floor(s / ds).astype(np.int64), 0, max(n - 2, 0))
    kp = np.minimum(k + 1, n - 1)
    inv_ds = 1.0 / ds
    d = s - smp[k, COL_S]
    u = d * inv_ds
    z0, z1, g0, g1 = smp[k, COL_Z], smp[kp, COL_Z], smp[k, COL_GRADE], smp[kp, COL_GRADE]
    b0 = smp[k, COL_BANK]
    db = (smp[kp, COL_BANK] - b0) * inv_ds
    uu = u * u
    z = ((2.0 * uu * u - 3.0 * uu + 1.0) * z0 + (uu * u - 2.0 * uu + u) * ds * g0
         + (3.0 * uu - 2.0 * uu * u) * z1 + (uu * u - uu) * ds * g1)
    g = (6.0 * uu - 6.0 * u) * (z0 - z1) * inv_ds + (3.0 * uu - 4.0 * u + 1.0) * g0 + (3.0 * uu - 2.0 * u) * g1
    b = b0 + d * db
    lo, hi = s <= 0.0, s >= smp[-1, COL_S]
    for mask, r in ((lo, 0), (hi, n - 1)):
        z = np.where(mask, smp[r, COL_Z] + smp[r, COL_GRADE] * (s - smp[r, COL_S]), z)
        g = np.where(mask, smp[r, COL_GRADE], g)
        b = np.where(mask, smp[r, COL_BANK], b)
        db = np.where(mask, 0.0, db)
    return z, g, b, db
