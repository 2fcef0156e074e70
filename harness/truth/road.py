"""Reference roads built from straights, arcs and clothoids, and the projection of a point onto them.

A road is a centre line parametrised by its arc length ``s``. Curvature is piecewise linear in ``s``
(zero on a straight, constant on an arc, linear on a clothoid), so the heading is its exact integral,
a piecewise quadratic:

.. math::  \\psi(s) = \\psi_k + \\rho_k (s - s_k) + \\tfrac12 \\rho'_k (s - s_k)^2 ,

and the position is the Fresnel-type integral :math:`(x, y)(s) = \\int (\\cos\\psi, \\sin\\psi)\\,ds`,
evaluated with 8-point Gauss-Legendre quadrature on every sub-interval between samples and
segment joints (the integrand is analytic there, so the result is exact to rounding for any road
of practical curvature). The road is then stored as uniform samples
``[s, x, y, psi, rho, z, grade, bank]`` which the compiled simulation loop reads through
:func:`road_project` (the plane centre line) and :func:`road_surface` (the 3D surface).

In 3D (``roadtruth.harness.truth.road_profile``) the centre line carries an elevation z_c(s) and a bank angle
φ_b(s) (positive = left edge higher, ISO 8855). With e the signed lateral offset (left positive) of
the foot of the perpendicular on the centre line, the surface is

.. math::  z(x, y) = z_c(s) + e \\tan\\varphi_b(s),

and its unit upward normal is :math:`n = (-\\partial_x z, -\\partial_y z, 1)/\\lVert\\cdot\\rVert` with the
exact gradient (t = (cos ψ, sin ψ), l = (−sin ψ, cos ψ); a step along t at offset e advances s by
1/(1 − ρ e)):

.. math::  \\nabla z = \\frac{z_c'(s) + e\\,\\varphi_b'(s)\\sec^2\\varphi_b}{1 - \\rho e}\\,t + \\tan\\varphi_b\\,l .

On a constant bank the first term is the grade z_c' alone; on a straight the divisor is 1.

Past either end the road continues as a straight line along the end heading with zero curvature,
its end grade and bank (the elevation continues linearly with the end grade).
Heading ``psi`` is unwrapped (continuous), so a full circle ends at ``psi_0 + 2*pi``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from roadtruth.harness.truth.road_profile import COL_Z, RoadProfile, profile_at, profile_np

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

SEGMENT_KINDS = ("straight", "arc", "clothoid")

# Where 1 - rho*e (the metric factor of the path coordinate at offset e) would vanish, i.e. at the
# centre of curvature, the surface gradient is taken with this floor: such a point is off any road.
_MIN_METRIC = 0.05

# Beyond this distance from the centre line the local search is not trusted and a global scan
# decides (a car that left the road, or a stale hint); ~ two lane widths.
_GLOBAL_SEARCH_DISTANCE_M = 8.0
_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(8)


@dataclass(frozen=True)
class Segment:
    """One piece of road. ``curvature_1pm``: for an arc, the constant curvature (None = keep the
    current one); for a clothoid, the curvature at its end (linear change from the current one);
    ignored for a straight (curvature 0)."""

    kind: str
    length_m: float
    curvature_1pm: float | None = None


@dataclass(frozen=True, eq=False)
class Road:
    """A sampled road centre line.

    Attributes
    ----------
    samples : (n, 8) float64 array ``[s_m, x_m, y_m, psi_rad, rho_1pm, z_m, grade, bank_rad]`` at
        uniform ``ds_m`` from s = 0 (read-only). ``psi`` is unwrapped; ``rho > 0`` turns left;
        ``z_m`` is the centre-line elevation, ``grade`` its slope dz/ds [-], ``bank_rad`` the bank
        angle (> 0: left edge higher, ISO 8855). On a flat road the last three are exactly 0.
    ds_m : sample spacing [m].
    lane_width_m : lane width [m] (the centre line is the lane centre).
    lookahead_m : camera look-ahead distance l_s ahead of the CG [m].
    segments : the segments the road was built from (for display).
    profile : the elevation and bank control points the road was built from.
    """

    samples: np.ndarray
    ds_m: float = 0.25
    lane_width_m: float = 3.5
    lookahead_m: float = 0.5
    segments: tuple[Segment, ...] = field(default=())
    profile: RoadProfile = RoadProfile()

    @cached_property
    def is_flat(self) -> bool:
        """True when elevation, grade and bank are zero everywhere (the road is the plane z = 0):
        the stepping loop may then skip :func:`road_surface` (it would return z = 0, n = (0, 0, 1))."""
        return not bool(np.any(self.samples[:, COL_Z:]))

    @property
    def length_m(self) -> float:
        """Arc length of the sampled road [m] (the last sample's s)."""
        return float(self.samples[-1, 0])

    @classmethod
    def straight_default(cls, length_m: float, *, ds_m: float = 0.25, lane_width_m: float = 3.5,
                         lookahead_m: float = 0.5) -> Road:
        """A straight road along +x from the origin, ``length_m`` long."""
        return build_road((0.0, 0.0, 0.0), [Segment("straight", float(length_m))], ds_m=ds_m,
                          lane_width_m=lane_width_m, lookahead_m=lookahead_m)

    def with_length_at_least(self, length_m: float) -> Road:
        """This road, with a straight appended so that it is at least ``length_m`` long."""
        missing = length_m - self.length_m
        if missing <= 0.0:
            return self
        x0, y0, psi0 = (float(v) for v in self.samples[0, 1:4])
        return build_road((x0, y0, psi0), [*self.segments, Segment("straight", missing)], ds_m=self.ds_m,
                          lane_width_m=self.lane_width_m, lookahead_m=self.lookahead_m, profile=self.profile)

    # ---- evaluation --------------------------------------------------------------------------

    def pose_at(self, s_m: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centre-line pose at path coordinate ``s``.

        Parameters
        ----------
        s_m : float or (m,) array [m]; outside [0, length] the road extends straight.

        Returns
        -------
        x_m, y_m, psi_rad : arrays shaped like ``s_m`` (floats for a float) [m, m, rad].
        """
        s = np.asarray(s_m, dtype=np.float64)
        smp = self.samples
        n = smp.shape[0]
        i = np.clip(np.floor(s / self.ds_m).astype(np.int64), 0, n - 1)
        u = s - smp[i, 0]
        # Beyond the ends the road is straight.
        rho = np.where((s < 0.0) | (s > smp[-1, 0]), 0.0, smp[i, 4])
        psi0 = smp[i, 3]
        x, y = _advance_on_arc(smp[i, 1], smp[i, 2], psi0, rho, u)
        psi = psi0 + rho * u
        if s.ndim == 0:
            return float(x), float(y), float(psi)  # type: ignore[return-value]
        return x, y, psi

    def curvature_at(self, s_m: np.ndarray | float) -> np.ndarray:
        """Curvature at ``s`` [1/m], linear between samples, 0 outside the road."""
        s = np.asarray(s_m, dtype=np.float64)
        smp = self.samples
        rho = np.interp(s, smp[:, 0], smp[:, 4])
        return np.where((s < 0.0) | (s > smp[-1, 0]), 0.0, rho)

    def project(self, x_m: np.ndarray | float, y_m: np.ndarray | float,
                s_hint_m: np.ndarray | float | None = None) -> dict[str, np.ndarray]:
        """Vectorised projection of points onto the centre line (NumPy twin of :func:`road_project`).

        Parameters
        ----------
        x_m, y_m : (m,) arrays (or floats) of world positions [m].
        s_hint_m : optional (m,) path coordinates near the expected answer [m] (e.g. the car's ``s_m``
            when projecting a look-ahead point). Needed on roads that pass near themselves (several
            laps of a circle); without it the globally nearest sample decides.

        Returns
        -------
        dict of (m,) arrays: ``i`` (nearest sample index), ``s_m``, ``e_left_m`` (signed lateral
        offset, > 0 left of the centre line), ``psi_rad`` (road heading), ``rho_1pm`` (curvature).
        """
        i, s, e, psi, rho, _ = self._project_arrays(x_m, y_m, s_hint_m)
        return {"i": i, "s_m": s, "e_left_m": e, "psi_rad": psi, "rho_1pm": rho}

    def _project_arrays(self, x_m: np.ndarray | float, y_m: np.ndarray | float,
                        s_hint_m: np.ndarray | float | None) -> tuple[np.ndarray, ...]:
        """:meth:`project` as a tuple, plus the curvature of the circle each foot was found on."""
        x = np.atleast_1d(np.asarray(x_m, dtype=np.float64))
        y = np.atleast_1d(np.asarray(y_m, dtype=np.float64))
        x, y = np.broadcast_arrays(x, y)
        smp = self.samples
        n = smp.shape[0]
        if s_hint_m is None:
            _, i = _tree_of(self).query(np.column_stack([x.ravel(), y.ravel()]))
            i = np.asarray(i, dtype=np.int64).reshape(x.shape)
        else:
            hint = np.clip(np.rint(np.broadcast_to(np.asarray(s_hint_m, np.float64), x.shape) / self.ds_m),
                           0, n - 1).astype(np.int64)
            i = _nearest_in_window(smp, x, y, hint, half_width=int(round(_GLOBAL_SEARCH_DISTANCE_M * 4 / self.ds_m)))
        return (i, *_refine(smp, self.ds_m, x, y, i))

    def surface(self, x_m: np.ndarray | float, y_m: np.ndarray | float,
                s_hint_m: np.ndarray | float | None = None) -> dict[str, np.ndarray]:
        """Road surface height and unit upward normal under world points (NumPy twin of
        :func:`road_surface`; equations in the module docstring).

        Parameters
        ----------
        x_m, y_m : (m,) arrays (or floats) of world positions [m].
        s_hint_m : optional path coordinates near the answer [m] (see :meth:`project`).

        Returns
        -------
        dict: ``z_m`` (m,) surface height [m], ``normal`` (m, 3) unit upward normal (world frame).
        """
        _, s, e, psi, _, rho_osc = (np.ravel(v) for v in self._project_arrays(x_m, y_m, s_hint_m))
        zc, g, b, db = profile_np(self.samples, self.ds_m, s)
        tb = np.tan(b)
        z = zc + e * tb
        a = (g + e * db * (1.0 + tb * tb)) / np.maximum(1.0 - rho_osc * e, _MIN_METRIC)
        c, sn = np.cos(psi), np.sin(psi)
        gx = a * c - tb * sn
        gy = a * sn + tb * c
        inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
        return {"z_m": z, "normal": np.column_stack([(0.0 - gx) * inv, (0.0 - gy) * inv, inv])}


_TREES: dict[int, tuple[np.ndarray, cKDTree]] = {}


def _tree_of(road: Road) -> cKDTree:
    # Imported here: only a projection without a path hint needs it, and scipy.spatial costs
    # a few tenths of a second at import (``roadtruth simulate`` never needs it).
    from scipy.spatial import cKDTree

    key = id(road.samples)
    hit = _TREES.get(key)
    if hit is None or hit[0] is not road.samples:
        if len(_TREES) > 32:
            _TREES.clear()
        hit = (road.samples, cKDTree(road.samples[:, 1:3]))
        _TREES[key] = hit
    return hit[1]


def _advance_on_arc(x0: np.ndarray, y0: np.ndarray, psi0: np.ndarray, rho: np.ndarray,
                    u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position after arc length ``u`` on a circle of curvature ``rho`` (straight when rho ~ 0)."""
    a = rho * u
    small = np.abs(a) < 1e-6
    # sin(a)/rho and (1 - cos a)/rho, with their series where a is tiny.
    safe = np.where(small, 1.0, rho)
    c1 = np.where(small, u * (1.0 - a * a / 6.0), np.sin(a) / safe)
    c2 = np.where(small, u * a / 2.0, (1.0 - np.cos(a)) / safe)
    cp, sp = np.cos(psi0), np.sin(psi0)
    return x0 + c1 * cp - c2 * sp, y0 + c1 * sp + c2 * cp


def _nearest_in_window(smp: np.ndarray, x: np.ndarray, y: np.ndarray, hint: np.ndarray,
                       half_width: int) -> np.ndarray:
    """Index of the sample nearest to each point among ``hint - half_width .. hint + half_width``
    (clipped to the road; the first of equal distances wins)."""
    flat_x = np.ascontiguousarray(x, dtype=np.float64).ravel()
    flat_y = np.ascontiguousarray(y, dtype=np.float64).ravel()
    flat_h = np.ascontiguousarray(hint, dtype=np.int64).ravel()
    return _nearest_in_window_compiled(smp, flat_x, flat_y, flat_h, int(half_width)).reshape(x.shape)


@njit(cache=True)
def _nearest_in_window_compiled(smp: np.ndarray, x: np.ndarray, y: np.ndarray, hint: np.ndarray,
                                half_width: int) -> np.ndarray:
    # Compiled: a hinted projection of a whole truth frame scans ~2 half_width samples per point,
    # which vectorised cost ~0.2 s per 10 000 points (truth events of every simulation).
    n = smp.shape[0]
    out = np.empty(x.shape[0], dtype=np.int64)
    for p in range(x.shape[0]):
        h = hint[p]
        lo = min(max(h - half_width, 0), n - 1)
        hi = min(max(h + half_width, 0), n - 1)
        best_k = lo
        best = math.inf
        for k in range(lo, hi + 1):
            dx = smp[k, 1] - x[p]
            dy = smp[k, 2] - y[p]
            d = dx * dx + dy * dy
            if d < best:
                best = d
                best_k = k
        out[p] = best_k
    return out


def _foot(smp: np.ndarray, j: np.ndarray, x: np.ndarray, y: np.ndarray,
          end: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Foot of the perpendicular on the circle osculating at sample ``j`` (straight where ``end``):
    offset along the road from sample j, signed lateral offset, road heading, the circle's curvature."""
    psi_j = smp[j, 3]
    c, sn = np.cos(psi_j), np.sin(psi_j)
    dx, dy = x - smp[j, 1], y - smp[j, 2]
    a = dx * c + dy * sn
    b = -dx * sn + dy * c
    rho = np.where(end, 0.0, smp[j, 4])
    curved = np.abs(rho) > 1e-9
    r = 1.0 / np.where(curved, rho, 1.0)
    sg = np.sign(r)
    phi = np.arctan2(a, sg * (r - b))
    s_off = np.where(curved, phi * np.abs(r), a)
    e = np.where(curved, r - sg * np.hypot(a, r - b), b)
    return s_off, e, psi_j + np.where(curved, sg * phi, 0.0), np.where(curved, rho, 0.0)


def _refine(smp: np.ndarray, ds: float, x: np.ndarray, y: np.ndarray,
            i: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """NumPy twin of the refinement in :func:`road_project` (+ the osculating circle's curvature)."""
    n = smp.shape[0]
    a = (x - smp[i, 1]) * np.cos(smp[i, 3]) + (y - smp[i, 2]) * np.sin(smp[i, 3])
    end = ((i == n - 1) & (a > 0.0)) | ((i == 0) & (a < 0.0))
    j = np.where(~end & (a < 0.0) & (i > 0), i - 1, i)
    s_off, e, psi, rho_osc = _foot(smp, j, x, y, end)
    s = smp[j, 0] + s_off
    k = np.minimum(j, max(n - 2, 0))
    w = np.clip((s - smp[k, 0]) / ds, 0.0, 1.0)
    rho = np.where(end, 0.0, smp[k, 4] + w * (smp[np.minimum(k + 1, n - 1), 4] - smp[k, 4]))
    return s, e, psi, rho, rho_osc


# ---- compiled projection (used inside the simulation loop) ---------------------------------------

@njit(cache=True, inline="always")
def _d2(samples: np.ndarray, k: int, x: float, y: float) -> float:
    dx = samples[k, 1] - x
    dy = samples[k, 2] - y
    return dx * dx + dy * dy


@njit(cache=True)
def _descend(samples: np.ndarray, x: float, y: float, i: int) -> int:
    """Walk from sample ``i`` to the local minimum of the distance to (x, y)."""
    n = samples.shape[0]
    best = _d2(samples, i, x, y)
    while True:
        moved = False
        if i + 1 < n:
            d = _d2(samples, i + 1, x, y)
            if d < best:
                best, i, moved = d, i + 1, True
        if not moved and i > 0:
            d = _d2(samples, i - 1, x, y)
            if d < best:
                best, i, moved = d, i - 1, True
        if not moved:
            return i


@njit(cache=True, inline="always")
def _project_frame(samples: np.ndarray, ds: float, x: float, y: float,
                   i_hint: int) -> tuple[int, float, float, float, float, float, float, float]:
    """:func:`road_project` plus (cos psi_road, sin psi_road), found without trigonometry, and the
    curvature of the circle the foot was found on (0 on a straight): the exact metric of s there."""
    n = samples.shape[0]
    hint = min(max(i_hint, 0), n - 1)
    i = _descend(samples, x, y, hint)
    if _d2(samples, i, x, y) > _GLOBAL_SEARCH_DISTANCE_M * _GLOBAL_SEARCH_DISTANCE_M:
        # Coarse scan (every ~2 m; the final descent refines), then among the samples within
        # 1 m + one stride of the nearest, the one closest in index to the hint.
        stride = max(1, int(2.0 / ds))
        dmin = math.inf
        for k in range(0, n + stride - 1, stride):
            d = _d2(samples, min(k, n - 1), x, y)
            if d < dmin:
                dmin = d
        lim = (math.sqrt(dmin) + 1.0 + stride * ds) ** 2
        best_k, best_gap = i, n + 1
        for k in range(0, n + stride - 1, stride):
            kk = min(k, n - 1)
            if _d2(samples, kk, x, y) <= lim:
                gap = abs(kk - hint)
                if gap < best_gap:
                    best_gap, best_k = gap, kk
        i = _descend(samples, x, y, best_k)

    # The foot lies in the interval starting at sample j; project on the circle osculating there
    # (its curvature is that interval's, also where the curvature steps at a segment joint).
    c = math.cos(samples[i, 3])
    sn = math.sin(samples[i, 3])
    a = (x - samples[i, 1]) * c + (y - samples[i, 2]) * sn
    end = (i == n - 1 and a > 0.0) or (i == 0 and a < 0.0)
    j = i - 1 if (not end and a < 0.0 and i > 0) else i
    psi_j = samples[j, 3]
    if j != i:
        c = math.cos(psi_j)
        sn = math.sin(psi_j)
    dx = x - samples[j, 1]
    dy = y - samples[j, 2]
    a = dx * c + dy * sn
    b = -dx * sn + dy * c
    rho_j = 0.0 if end else samples[j, 4]
    if abs(rho_j) > 1e-9:
        r = 1.0 / rho_j
        sg = 1.0 if r > 0.0 else -1.0
        phi = math.atan2(a, sg * (r - b))
        s_off = phi * abs(r)
        h = math.hypot(a, r - b)
        e = r - sg * h
        psi = psi_j + sg * phi
        # (cos, sin) of psi without trigonometry: cos(phi) = sg (r - b)/h, sin(phi) = a/h.
        cp = sg * (r - b) / h if h > 0.0 else 1.0
        sp = sg * (a / h) if h > 0.0 else 0.0
        ct = c * cp - sn * sp
        st = sn * cp + c * sp
    else:
        s_off = a
        e = b
        psi = psi_j
        ct = c
        st = sn
        rho_j = 0.0
    s = samples[j, 0] + s_off
    if end:
        rho = 0.0
    else:
        k = min(j, max(n - 2, 0))
        kp = min(k + 1, n - 1)
        w = min(max((s - samples[k, 0]) / ds, 0.0), 1.0)
        rho = samples[k, 4] + w * (samples[kp, 4] - samples[k, 4])
    return i, s, e, psi, rho, ct, st, rho_j


@njit(cache=True)
def road_project(samples: np.ndarray, ds: float, x: float, y: float,
                 i_hint: int) -> tuple[int, float, float, float, float]:
    """Project the point (x, y) onto the road centre line.

    Parameters
    ----------
    samples : (n, 8) float64 ``Road.samples`` (reads columns ``[s, x, y, psi, rho]``).
    ds : sample spacing [m].
    x, y : world position [m].
    i_hint : sample index near the answer (the previous step's ``i``); any value is safe.

    Returns
    -------
    i : nearest sample index (pass it back as the next hint).
    s : path coordinate [m] (< 0 or > length beyond the ends, where the road extends straight).
    e_left : signed lateral offset [m], > 0 left of the centre line.
    psi_road : road heading at s [rad] (unwrapped like ``samples[:, 3]``).
    rho : road curvature at s [1/m].

    Notes
    -----
    A local descent from the hint costs a few samples per call. If it ends farther than
    ~8 m from the road (a car off the road or a stale hint), a coarse global scan (every ~2 m) picks,
    among the samples within ~3 m of the nearest distance, the one closest in index to the hint (so
    on a road that overlaps itself, e.g. laps of a circle, the current lap is kept), and a descent
    from there finds the nearest sample.
    """
    i, s, e, psi, rho, _, _, _ = _project_frame(samples, ds, x, y, i_hint)
    return i, s, e, psi, rho


@njit(cache=True)
def road_project_many(samples: np.ndarray, ds: float, xs: np.ndarray, ys: np.ndarray,
                      i_hint: int) -> np.ndarray:
    """Project a trajectory point by point, each call hinted by the previous answer.

    Returns
    -------
    (m, 5) float64 array ``[i, s, e_left, psi_road, rho]``.
    """
    out = np.empty((xs.shape[0], 5))
    h = i_hint
    for k in range(xs.shape[0]):
        h, s, e, psi, rho = road_project(samples, ds, xs[k], ys[k], h)
        out[k, 0] = h
        out[k, 1] = s
        out[k, 2] = e
        out[k, 3] = psi
        out[k, 4] = rho
    return out


@njit(cache=True, inline="always")
def road_surface(samples: np.ndarray, ds: float, x: float, y: float,
                 i_hint: int) -> tuple[int, float, float, float, float]:
    """Road surface height and unit upward normal under the world point (x, y).

    Parameters
    ----------
    samples : (n, 8) float64 ``Road.samples``.
    ds : sample spacing [m].
    x, y : world position [m].
    i_hint : sample index near the answer (the previous call's ``i`` for the same wheel).

    Returns
    -------
    i : nearest sample index (pass it back as the next hint).
    z : surface height z_c(s) + e tan(phi_b(s)) [m].
    nx, ny, nz : unit upward surface normal in the world frame (module docstring).
    On a flat road exactly (i, 0, 0, 0, 1).
    """
    i, s, e, _, _, c, sn, rho_osc = _project_frame(samples, ds, x, y, i_hint)
    zc, g, b, db = profile_at(samples, ds, s)
    tb = math.tan(b) if b != 0.0 else 0.0  # most of a road is not banked
    z = zc + e * tb
    # Derivative of z along t: d/ds at fixed e, over the metric factor 1 - rho e (rho of the circle
    # the foot was found on, so that the normal is the exact gradient of the z returned).
    a = (g + e * db * (1.0 + tb * tb)) / max(1.0 - rho_osc * e, _MIN_METRIC)
    gx = a * c - tb * sn
    gy = a * sn + tb * c
    inv = 1.0 / math.sqrt(1.0 + gx * gx + gy * gy)
    # 0.0 - g, not -g: a flat road's +-0.0 components become +0.0 (bit-identical flat results).
    return i, z, (0.0 - gx) * inv, (0.0 - gy) * inv, inv


# ---- construction --------------------------------------------------------------------------------

def build_road(start: tuple[float, float, float], segments: list[Segment] | tuple[Segment, ...], *,
               ds_m: float = 0.25, lane_width_m: float = 3.5, lookahead_m: float = 0.5,
               initial_curvature_1pm: float = 0.0, profile: RoadProfile | None = None) -> Road:
    """Build a sampled road from a start pose and a list of segments.

    Parameters
    ----------
    start : (x_m, y_m, psi_rad) of the road start.
    segments : ``Segment`` list, in order; curvature carries over from one segment to the next
        (an arc without a curvature keeps it; a straight sets it to 0).
    ds_m : sample spacing [m].
    initial_curvature_1pm : curvature at s = 0 (what a first arc/clothoid starts from).
    profile : elevation and bank control points (``roadtruth.harness.truth.road_profile``); None = flat.

    Returns
    -------
    Road with ``ceil(L / ds) + 1`` samples at s = 0, ds, 2 ds, ...; when L is not a whole number of
    samples the last (partial) interval continues straight along the end heading.
    """
    if not segments:
        raise ValueError("a road needs at least one segment")
    if ds_m <= 0.0:
        raise ValueError(f"ds_m must be > 0 (got {ds_m})")
    # Per segment: start s, start heading, start curvature, curvature rate.
    s0, psi0, k0, dk = [], [], [], []
    s, psi, k = 0.0, float(start[2]), float(initial_curvature_1pm)
    for seg in segments:
        if seg.kind not in SEGMENT_KINDS:
            raise ValueError(f"unknown segment kind {seg.kind!r}")
        if not seg.length_m > 0.0:
            raise ValueError(f"segment length must be > 0 (got {seg.length_m})")
        if seg.kind == "straight":
            ka, rate = 0.0, 0.0
        elif seg.kind == "arc":
            ka = k if seg.curvature_1pm is None else float(seg.curvature_1pm)
            rate = 0.0
        else:
            ka = k
            end = k if seg.curvature_1pm is None else float(seg.curvature_1pm)
            rate = (end - ka) / seg.length_m
        s0.append(s)
        psi0.append(psi)
        k0.append(ka)
        dk.append(rate)
        L = seg.length_m
        psi += ka * L + 0.5 * rate * L * L
        k = ka + rate * L
        s += L
    n = int(math.ceil(s / ds_m - 1e-9)) + 1
    s_samples = np.arange(n, dtype=np.float64) * ds_m
    total = float(s_samples[-1])
    if total > s:
        # Round the length up to whole samples with a straight stub, so the grid stays uniform.
        s0.append(s)
        psi0.append(psi)
        k0.append(0.0)
        dk.append(0.0)
    seg_s0, seg_psi0, seg_k0, seg_dk = (np.asarray(v, dtype=np.float64) for v in (s0, psi0, k0, dk))
    nseg = len(s0)
    # Integrate over the union of sample points and segment joints so that every quadrature
    # interval lies inside one segment, where the heading is a smooth quadratic.
    knots = np.union1d(s_samples, np.append(seg_s0, total))
    a, b = knots[:-1], knots[1:]
    mid, half = 0.5 * (a + b), 0.5 * (b - a)
    sq = mid[:, None] + half[:, None] * _GAUSS_X[None, :]
    seg_of_q = np.clip(np.searchsorted(seg_s0, mid, side="right") - 1, 0, nseg - 1)[:, None]
    u = sq - seg_s0[seg_of_q]
    heading = seg_psi0[seg_of_q] + seg_k0[seg_of_q] * u + 0.5 * seg_dk[seg_of_q] * u * u
    dx = half * (np.cos(heading) @ _GAUSS_W)
    dy = half * (np.sin(heading) @ _GAUSS_W)
    xk = float(start[0]) + np.concatenate([[0.0], np.cumsum(dx)])
    yk = float(start[1]) + np.concatenate([[0.0], np.cumsum(dy)])
    pick = np.searchsorted(knots, s_samples)

    seg_of_s = np.clip(np.searchsorted(seg_s0, s_samples, side="right") - 1, 0, nseg - 1)
    us = s_samples - seg_s0[seg_of_s]
    psi_s = seg_psi0[seg_of_s] + seg_k0[seg_of_s] * us + 0.5 * seg_dk[seg_of_s] * us * us
    rho_s = seg_k0[seg_of_s] + seg_dk[seg_of_s] * us
    profile = RoadProfile() if profile is None else profile
    z_s, grade_s, bank_s = profile.columns(s_samples)
    samples = np.ascontiguousarray(np.column_stack([s_samples, xk[pick], yk[pick], psi_s, rho_s,
                                                    z_s, grade_s, bank_s]))
    samples.setflags(write=False)
    return Road(samples=samples, ds_m=float(ds_m), lane_width_m=float(lane_width_m),
                lookahead_m=float(lookahead_m), segments=tuple(segments), profile=profile)
