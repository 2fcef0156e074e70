"""Ground-truth road friction mu(x, y, t): a default value plus patches (polygons with time windows).

The tire routine evaluates mu at each wheel's contact point every step (notes on the MuJoCo car,
section 4.4), so per-wheel friction is exact ground truth for any shape: rectangles, polygons,
split-mu half-planes (y > 0 is left, ISO 8855) and "everywhere" patches whose time window makes a
step of mu in time (rain starting). Patches are checked from last to first; the first that contains
the point at time ``t`` (``t_start_s <= t < t_end_s``) gives mu, otherwise ``mu_default``.

Inside test: even-odd ray crossing, with the half-open rule ``(y_i > y) != (y_j > y)`` so a point
on a shared edge belongs to exactly one of two adjacent patches.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

from roadtruth.harness.errors import ScenarioError
from roadtruth.harness.files.strict_yaml import Fields, load_mapping

SURFACES: dict[str, float] = {"dry": 1.0, "wet": 0.6, "snow": 0.3, "ice": 0.1}
MU_MAX = 2.0
# Half-planes and "everywhere" are polygons this far out [m] (far beyond any scenario).
FAR_M = 1.0e6
PATCH_SHAPES = ("rect", "polygon", "split", "everywhere")


@dataclass(frozen=True, eq=False)
class Patch:
    """A region of the road with its own friction, optionally only during a time window.

    Attributes
    ----------
    name : label (shown in reports and events).
    surface : surface name of ``SURFACES`` or "" when mu was given directly.
    mu : friction coefficient (0, 2].
    vertices : (k, 2) float64 polygon [m], k >= 3, either orientation.
    t_start_s, t_end_s : active for ``t_start_s <= t < t_end_s`` [s] (default: always).
    shape : how the file gave it: rect | polygon | split_left | split_right | everywhere
        (renderers draw half-planes and "everywhere" clipped to the road).
    """

    name: str
    surface: str
    mu: float
    vertices: np.ndarray
    t_start_s: float = -math.inf
    t_end_s: float = math.inf
    shape: str = "polygon"


@dataclass(frozen=True, eq=False)
class FrictionMap:
    """Default friction plus patches; the last matching patch wins."""

    mu_default: float = 1.0
    patches: tuple[Patch, ...] = ()

    @classmethod
    def with_uniform(cls, mu: float) -> FrictionMap:
        """A uniform map (no patches). Callable on the class or on an instance (replaces it)."""
        return cls(mu_default=_check_mu(float(mu), "mu", "friction"), patches=())

    @property
    def is_uniform(self) -> bool:
        return not self.patches

    def describe(self) -> str:
        """Short text for reports, e.g. ``"mu 1.0; ice patch 0.1 (rect)"``."""
        parts = [f"mu {self.mu_default:g}"]
        for p in self.patches:
            when = ""
            if math.isfinite(p.t_start_s) or math.isfinite(p.t_end_s):
                when = f" t=[{p.t_start_s:g}, {p.t_end_s:g})"
            parts.append(f"{p.name} {p.mu:g} ({p.shape}{when})")
        return "; ".join(parts)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Patch tables for :func:`mu_at`.

        Returns
        -------
        verts : (n, kmax, 2) float64, polygon vertices [m], padded by repeating the last vertex
            ((0, 1, 2) with no patches).
        meta : (n, 4) float64 ``[nvert, t_start_s, t_end_s, mu]``.
        """
        n = len(self.patches)
        kmax = max((p.vertices.shape[0] for p in self.patches), default=1)
        verts = np.zeros((n, kmax, 2), dtype=np.float64)
        meta = np.zeros((n, 4), dtype=np.float64)
        for j, p in enumerate(self.patches):
            k = p.vertices.shape[0]
            verts[j, :k] = p.vertices
            verts[j, k:] = p.vertices[-1]
            meta[j] = (k, p.t_start_s, p.t_end_s, p.mu)
        return verts, meta

    def mu(self, x_m: np.ndarray | float, y_m: np.ndarray | float, t_s: np.ndarray | float = 0.0) -> np.ndarray:
        """Friction at points (broadcast together) [1]; the NumPy twin of :func:`mu_at`."""
        x, y, t = np.broadcast_arrays(np.asarray(x_m, np.float64), np.asarray(y_m, np.float64),
                                      np.asarray(t_s, np.float64))
        out = np.full(x.shape, self.mu_default, dtype=np.float64)
        decided = np.zeros(x.shape, dtype=bool)
        for p in reversed(self.patches):
            active = (t >= p.t_start_s) & (t < p.t_end_s) & ~decided
            if not active.any():
                continue
            hit = active & _inside(p.vertices, x, y)
            out[hit] = p.mu
            decided |= hit
        return out


def _inside(vertices: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    inside = np.zeros(x.shape, dtype=bool)
    k = vertices.shape[0]
    for a in range(k):
        xi, yi = vertices[a]
        xj, yj = vertices[a - 1]
        crosses = (yi > y) != (yj > y)
        if not crosses.any():
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = (xj - xi) * (y - yi) / (yj - yi) + xi
        inside ^= crosses & (x < x_cross)
    return inside


@njit(cache=True)
def mu_at(mu_default: float, verts: np.ndarray, meta: np.ndarray, x: float, y: float, t: float) -> float:
    """Friction at (x, y) [m] and time t [s] from the tables of ``FrictionMap.arrays()``."""
    for j in range(meta.shape[0] - 1, -1, -1):
        if t < meta[j, 1] or t >= meta[j, 2]:
            continue
        k = int(meta[j, 0])
        inside = False
        for a in range(k):
            b = a - 1 if a > 0 else k - 1
            xi = verts[j, a, 0]
            yi = verts[j, a, 1]
            xj = verts[j, b, 0]
            yj = verts[j, b, 1]
            if (yi > y) != (yj > y):
                x_cross = (xj - xi) * (y - yi) / (yj - yi) + xi
                if x < x_cross:
                    inside = not inside
        if inside:
            return meta[j, 3]
    return mu_default


# ---- parsing -------------------------------------------------------------------------------------

def _field(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


def _check_mu(mu: float, field: str, source: str) -> float:
    if not (math.isfinite(mu) and 0.0 < mu <= MU_MAX):
        raise ScenarioError(f"friction coefficient must be > 0 and <= {MU_MAX:g} (got {mu:g})",
                            source=source, field=field)
    return mu


def _as_float(value: Any, field: str, source: str) -> float:
    """A number from YAML. Also takes numeric strings: PyYAML (YAML 1.1) reads ``1e9`` as a string."""
    if isinstance(value, bool):
        raise ScenarioError(f"must be a number (got {value!r})", source=source, field=field)
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            pass
    raise ScenarioError(f"must be a number (got {value!r})", source=source, field=field)


def parse_interval(value: Any, field: str, source: str, *, allow_infinite_end: bool = True) -> tuple[float, float]:
    """A ``[start, end]`` pair with start < end (used for t_s, x_m, y_m, s_m ranges)."""
    if not isinstance(value, list) or len(value) != 2:
        raise ScenarioError(f"must be a list [start, end] (got {value!r})", source=source, field=field)
    a = _as_float(value[0], field, source)
    b = _as_float(value[1], field, source)
    if math.isnan(a) or math.isnan(b) or math.isinf(a) or (math.isinf(b) and not allow_infinite_end):
        raise ScenarioError(f"must be finite (got {value!r})", source=source, field=field)
    if not a < b:
        raise ScenarioError(f"start must be below end (got {value!r})", source=source, field=field)
    return a, b


def _polygon(value: Any, field: str, source: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) < 3:
        raise ScenarioError(f"must be a list of at least 3 [x, y] points (got {value!r})", source=source,
                            field=field)
    pts = []
    for q in value:
        if not isinstance(q, list) or len(q) != 2:
            raise ScenarioError(f"each point must be [x, y] (got {q!r})", source=source, field=field)
        pts.append((_as_float(q[0], field, source), _as_float(q[1], field, source)))
    v = np.asarray(pts, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise ScenarioError(f"points must be finite (got {value!r})", source=source, field=field)
    area = 0.5 * abs(float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])))
    if area <= 0.0:
        raise ScenarioError("polygon has zero area", source=source, field=field)
    return v


def _patch(data: Any, source: str, prefix: str) -> Patch:
    f = Fields(data, source=source, error=ScenarioError, prefix=prefix)
    name = f.string("name", prefix.rsplit(".", 1)[-1])
    if f.has("surface") and f.has("mu"):
        raise f.fail("mu", "give either surface or mu, not both")
    if f.has("surface"):
        surface = f.string("surface", choices=tuple(SURFACES))
        mu = SURFACES[surface]
    elif f.has("mu"):
        surface = ""
        mu = _check_mu(_as_float(f.raw("mu"), _field(f.prefix, "mu"), source), _field(f.prefix, "mu"), source)
    else:
        raise f.fail("mu", "required field is missing (give mu or surface)")
    given = [k for k in PATCH_SHAPES if f.has(k)]
    if len(given) != 1:
        raise f.fail("rect", f"give exactly one region: {', '.join(PATCH_SHAPES)} (got {given or 'none'})")
    kind = given[0]
    if kind == "rect":
        r = f.sub("rect")
        x0, x1 = parse_interval(r.raw("x_m"), _field(r.prefix, "x_m"), source, allow_infinite_end=False)
        y0, y1 = parse_interval(r.raw("y_m"), _field(r.prefix, "y_m"), source, allow_infinite_end=False)
        r.done()
        verts, shape = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64), "rect"
    elif kind == "polygon":
        verts, shape = _polygon(f.raw("polygon"), _field(f.prefix, "polygon"), source), "polygon"
    elif kind == "split":
        side = f.string("split", choices=("left", "right"))
        lo, hi = (0.0, FAR_M) if side == "left" else (-FAR_M, 0.0)
        verts = np.array([[-FAR_M, lo], [FAR_M, lo], [FAR_M, hi], [-FAR_M, hi]], dtype=np.float64)
        shape = f"split_{side}"
    else:
        if not f.boolean("everywhere"):
            raise f.fail("everywhere", "must be true when given (got false)")
        verts = np.array([[-FAR_M, -FAR_M], [FAR_M, -FAR_M], [FAR_M, FAR_M], [-FAR_M, FAR_M]])
        shape = "everywhere"
    t0, t1 = -math.inf, math.inf
    if f.has("t_s"):
        t0, t1 = parse_interval(f.raw("t_s"), _field(f.prefix, "t_s"), source)
    f.done()
    verts.setflags(write=False)
    return Patch(name=name, surface=surface, mu=mu, vertices=verts, t_start_s=t0, t_end_s=t1, shape=shape)


def parse_friction(data: Any, source: str, prefix: str = "friction") -> FrictionMap:
    """Validate a ``friction:`` block (see docs/SCENARIOS.md) and build the map.

    ``data`` is the mapping ``{mu_default | surface, patches}``; errors name ``source`` and the field.
    """
    f = Fields(data, source=source, error=ScenarioError, prefix=prefix)
    if f.has("surface") and f.has("mu_default"):
        raise f.fail("mu_default", "give either surface or mu_default, not both")
    if f.has("surface"):
        mu0 = SURFACES[f.string("surface", choices=tuple(SURFACES))]
    else:
        mu0 = _check_mu(_as_float(f.raw("mu_default", 1.0), _field(f.prefix, "mu_default"), source),
                        _field(f.prefix, "mu_default"), source)
    patches = tuple(_patch(p, source, f"{_field(f.prefix, 'patches')}[{k}]")
                    for k, p in enumerate(f.items("patches", [])))
    f.done()
    return FrictionMap(mu_default=mu0, patches=patches)


def friction_from_spec(spec: str | float) -> FrictionMap:
    """The CLI's ``--friction``: a number (uniform mu), a surface name, or a friction YAML file.

    The file holds a friction block, either at its top level or under a single ``friction:`` key.
    """
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        return FrictionMap.with_uniform(_check_mu(float(spec), "--friction", "command line"))
    text = str(spec).strip()
    try:
        value = float(text)
    except ValueError:
        value = None
    if value is not None:
        return FrictionMap(mu_default=_check_mu(value, "--friction", "command line"))
    if text in SURFACES:
        return FrictionMap(mu_default=SURFACES[text])
    p = Path(text)
    if p.suffix.lower() in (".yaml", ".yml") or p.exists():
        data = load_mapping(p, ScenarioError)
        if set(data) == {"friction"}:
            return parse_friction(data["friction"], str(p))
        return parse_friction(data, str(p), prefix="")
    raise ScenarioError(f"not a number, a surface ({', '.join(SURFACES)}) or a friction YAML file "
                        f"(got {text!r})", source="command line", field="--friction")
