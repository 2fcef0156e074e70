"""The numbers a report figure carries: which samples are drawn, and how they are written.

A figure is drawn at about ``PIXEL_COLUMNS`` pixels across. A trace with more samples than four per
pixel column is reduced to its *envelope*: in each column the first, last, lowest and highest
sample (M4; Jugel et al., 2014, "M4: a visualization-oriented time series data aggregation", PVLDB
7(10), sec. 4), which draws the same pixels as the whole trace at that width. Every peak, spike and
step survives, each at the time of its own sample. A shorter trace is drawn exactly as recorded.
The metrics never come from here: scoring reads the full-rate tables.

Values are written as integers on a decimal grid ``10**exp`` fine enough for the axis they are
drawn on (``grid_exponent``: at least ``STEPS_PER_SPAN`` steps across the focused axis, i.e. about
seven steps per pixel of a 280 px panel), stored as differences of consecutive integers, which are
short for a smooth signal. A time axis on a uniform grid is plotly's own ``x0``/``dx``; samples
taken from such a grid are written as their index steps on it. Arrays several traces share are
written once (``ArrayPool``). ``report.js`` expands these compact arrays before plotly draws them;
``expand_figure`` does the same in Python (for tests and tools).

Compact array forms (a JSON object in place of a plotly data array):

- ``{"k0": k0, "dk": text, "exp": e}``: value ``i`` is ``k_i * 10**e``, where ``text`` holds the steps
  ``k1 - k0, k2 - k1, …`` (``varint_text``: a step of at most ±15 grid units is one character), or
  with ``"order": 2`` the differences of those steps (the first step, then each change of step);
- ``{"dk": [...], "step": dt, "offset": t0}``: value ``i`` is ``t0 + k_i * dt`` (a time grid);
- either with ``"nan": [[start, length], ...]``: those samples are missing (a gap in the line);
- ``{"ref": j}``: array ``j`` of the figure's ``arrays`` list;
- a trace without ``x`` nor ``x0`` is drawn on the figure's ``grid`` (``x0``/``dx``: the truth's time
  grid), and every annotation takes the keys of the figure's ``note_defaults`` it does not set;
- ``{"around": [a, j], "side": s}`` (a ``y`` only): trace ``a``'s ``y`` plus ``s`` (±1) times array ``j``
  (a band centred on its estimate, as value ± half width);
- ``{"minus": [a, b], "wrap": w}`` (a ``y`` only): trace ``a``'s ``y`` minus trace ``b``'s, sample by
  sample, wrapped into ``(-w/2, w/2]`` when ``w`` is given (an error drawn from its estimate and the
  truth on the same time grid, instead of a third copy of the numbers).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: Pixel columns a figure is decimated for (a plot about as wide as a 1400 px window allows).
PIXEL_COLUMNS = 1200
#: Integer steps at least across the span of the axis a value is drawn on.
STEPS_PER_SPAN = 2_000
#: Largest integer written (|k| below 2**53 sums exactly in JavaScript's doubles).
_MAX_K = 2.0**50


def envelope_indices(x: np.ndarray, y: np.ndarray, columns: int = PIXEL_COLUMNS) -> np.ndarray:
    """Sorted indices of the samples of ``y(x)`` to draw on a plot ``columns`` pixels wide.

    All indices when there are at most ``4 * columns`` samples. Otherwise, in each of ``columns``
    equal-width bins of ``x`` (from its first to its last finite value), the first, last, minimum
    and maximum finite sample (the first of equal ones), plus the first sample of every run of
    missing values so a gap stays a gap. ``x`` must be non-decreasing.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    n = y.size
    if n <= 4 * columns:
        return np.arange(n, dtype=np.int64)
    finite = np.isfinite(y) & np.isfinite(x)
    whole = bool(finite.all())
    # The samples kept are marked in a mask of all samples and read back in order: sorted and
    # unique as a union of index arrays, without its sort (the figures' largest cost on long logs).
    kept = ~finite & np.r_[True, finite[:-1]]  # first missing sample of each run
    fi = np.arange(n) if whole else np.flatnonzero(finite)
    if fi.size <= 4 * columns:
        kept[fi] = True
        return np.flatnonzero(kept).astype(np.int64)
    xf, yf = (x, y) if whole else (x[fi], y[fi])
    width = xf[-1] - xf[0]
    if not width > 0:
        cols = np.zeros(fi.size, dtype=np.int64)
    else:
        cols = np.minimum(((xf - xf[0]) * (columns / width)).astype(np.int64), columns - 1)
    starts = np.flatnonzero(np.r_[True, cols[1:] != cols[:-1]])
    ends = np.r_[starts[1:], fi.size] - 1
    pos = np.arange(fi.size)
    counts = np.diff(np.r_[starts, fi.size])
    lows = np.repeat(np.minimum.reduceat(yf, starts), counts)
    highs = np.repeat(np.maximum.reduceat(yf, starts), counts)
    first_low = np.minimum.reduceat(np.where(yf == lows, pos, fi.size), starts)
    first_high = np.minimum.reduceat(np.where(yf == highs, pos, fi.size), starts)
    for part in (starts, ends, first_low, first_high):
        kept[fi[part]] = True
    return np.flatnonzero(kept).astype(np.int64)


def grid_exponent(span: float, values: np.ndarray | None = None) -> int:
    """The decimal exponent ``e`` of the grid ``10**e`` values drawn on an axis of ``span`` are
    written on: the largest with at least ``STEPS_PER_SPAN`` steps across the span, coarsened only
    if ``values`` would otherwise need integers beyond what JavaScript sums exactly."""
    span = abs(float(span))
    e = math.floor(math.log10(span / STEPS_PER_SPAN)) if span > 0 and math.isfinite(span) else -6
    if values is not None:
        v = np.asarray(values, dtype=float)
        v = np.abs(v[np.isfinite(v)])
        if v.size and v.max() > 0:
            e = max(e, math.ceil(math.log10(float(v.max()) / _MAX_K)))
    return int(e)


def largest_magnitude(values: np.ndarray) -> float:
    """The largest ``|v|`` of the finite values (0.0 when none is finite): what ``grid_exponent``
    needs of ``values``, taken one array at a time instead of from their concatenation."""
    v = np.asarray(values, dtype=float)
    finite = np.isfinite(v)
    if finite.all():
        return float(np.abs(v).max()) if v.size else 0.0
    return float(np.abs(v[finite]).max()) if finite.any() else 0.0


def _gap_runs(missing: np.ndarray) -> list[list[int]]:
    """``[[start, length], ...]`` of the runs of True in ``missing``."""
    if not missing.any():
        return []
    m = np.r_[False, missing, False].astype(np.int8)
    d = np.diff(m)
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return [[int(a), int(b - a)] for a, b in zip(starts, stops, strict=True)]


#: The 64 characters of a varint text, each 5 bits of a number and a "more follows" bit (32).
_ALPHABET = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_"
_CODE = {c: i for i, c in enumerate(_ALPHABET.decode("ascii"))}
_ALPHABET_CODES = np.frombuffer(_ALPHABET, dtype=np.uint8)


def varint_text(d: np.ndarray) -> str:
    """Integers ``d`` as text: each zigzag-coded (0, -1, 1, -2 … as 0, 1, 2, 3 …) and written 5 bits
    to a character, low bits first, every character but a number's last one plus 32. A step of
    ±15 or less is one character (a JSON list needs 2-4 for it, with its comma)."""
    d = np.asarray(d, dtype=np.int64)
    if not d.size:
        return ""
    z = (d << 1) ^ (d >> 63)
    top, g = int(z.max()), 1
    while top >> (5 * g):
        g += 1
    if g == 1:
        return _ALPHABET_CODES[z].tobytes().decode("ascii")
    # Characters per number, where each number's characters start, then one pass per 5 bits
    # (a few: the steps of a drawn line are small).
    groups = np.ones(z.size, dtype=np.int64)
    for i in range(1, g):
        groups += z >= (1 << (5 * i))
    starts = np.cumsum(groups) - groups
    out = np.empty(int(starts[-1] + groups[-1]), dtype=np.int64)
    out[starts] = z & 31
    rest = z >> 5
    for i in range(1, g):
        sel = np.flatnonzero(groups > i)
        out[starts[sel] + i - 1] |= 32
        out[starts[sel] + i] = rest[sel] & 31
        rest = rest >> 5
    return _ALPHABET_CODES[out].tobytes().decode("ascii")


def read_varint_text(text: str) -> np.ndarray:
    """The integers of ``varint_text``."""
    out, value, shift = [], 0, 0
    for ch in text:
        c = _CODE[ch]
        value |= (c & 31) << shift
        if c & 32:
            shift += 5
            continue
        out.append(-(value + 1) // 2 if value & 1 else value // 2)
        value, shift = 0, 0
    return np.asarray(out, dtype=np.int64)


def _deltas(k: np.ndarray, missing: np.ndarray) -> dict[str, Any]:
    """The difference form of integers ``k`` (missing samples hold the previous value: delta 0)."""
    gaps = bool(missing.any())
    if gaps:
        filled = np.where(missing, 0, k)
        last = np.maximum.accumulate(np.where(missing, -1, np.arange(k.size)))
        k = np.where(last >= 0, filled[np.maximum(last, 0)], 0)
    out: dict[str, Any] = {"dk": ""}
    if k.size:
        d1 = k[1:] - k[:-1]
        d2 = d1.copy()  # the changes of step, the first step itself first
        d2[1:] -= d1[:-1]
        # A smooth line's steps change little: their own differences are shorter to write
        # (compared by size, not written twice: the sum of magnitudes follows the text's length).
        if np.abs(d2).sum() < np.abs(d1).sum():
            out = {"k0": int(k[0]), "dk": varint_text(d2), "order": 2}
        else:
            out = {"k0": int(k[0]), "dk": varint_text(d1)}
    runs = _gap_runs(missing) if gaps else []
    if runs:
        out["nan"] = runs
    return out


def compact_values(values: np.ndarray, exp: int) -> dict[str, Any]:
    """``values`` on the grid ``10**exp`` in difference form; NaN and ±inf are missing samples."""
    v = np.asarray(values, dtype=float)
    missing = ~np.isfinite(v)
    # Dividing by an exact power of ten rounds to the nearest grid value (multiplying by 10**-e
    # would add the rounding error of 10**-e itself).
    scaled = v / 10.0**exp if exp >= 0 else v * 10.0 ** (-exp)
    k = np.rint(np.where(missing, 0.0, scaled)).astype(np.int64)
    return {**_deltas(k, missing), "exp": int(exp)}


def uniform_grid(t: np.ndarray) -> tuple[float, float] | None:
    """``(t0, dt)`` if ``t`` is ``t0 + i * dt`` for every sample (to a millionth of ``dt``), else None.
    Both are rounded to 12 significant digits (``0.01``, not ``0.010000000000000002``)."""
    t = np.asarray(t, dtype=float)
    if t.size < 2 or not np.isfinite(t).all():
        return None
    t0, dt = float(f"{t[0]:.12g}"), float(f"{(t[-1] - t[0]) / (t.size - 1):.12g}")
    if not dt > 0:
        return None
    if np.max(np.abs(t - (t0 + dt * np.arange(t.size)))) > 1e-6 * dt:
        return None
    return t0, dt


class ArrayPool:
    """The x arrays of one figure, each written once however many traces draw it."""

    def __init__(self) -> None:
        self.arrays: list[dict[str, Any]] = []
        self._index: dict[tuple[Any, ...], int] = {}
        # id(t) -> (t, its grid): the observers of a wide table share one time array object. The
        # array is held so its id is not reused while the pool lives.
        self._grids: dict[int, tuple[np.ndarray, tuple[float, float] | None]] = {}

    def _grid(self, t: np.ndarray) -> tuple[float, float] | None:
        hit = self._grids.get(id(t))
        if hit is None or hit[0] is not t:
            hit = self._grids[id(t)] = (t, uniform_grid(t))
        return hit[1]

    def times(self, t: np.ndarray, idx: np.ndarray | None = None) -> dict[str, Any]:
        """A trace's x of times ``t[idx]`` (all of ``t`` without ``idx``), as trace keys: ``x0``/``dx``
        for a whole uniform grid, else ``x`` referring to a pooled array (index steps on the grid
        when ``t`` is uniform; otherwise times on a grid of a thousandth of the median step)."""
        t = np.asarray(t, dtype=float)
        grid = self._grid(t)
        if grid is not None and (idx is None or idx.size == t.size):
            return {"x0": grid[0], "dx": grid[1]}
        sel = t if idx is None else t[idx]
        if grid is not None:
            k = np.arange(t.size, dtype=np.int64) if idx is None else np.asarray(idx, dtype=np.int64)
            key: tuple[Any, ...] = ("grid", grid, k.tobytes())
            make = lambda: {**_deltas(k, np.zeros(k.size, bool)), "step": grid[1], "offset": grid[0]}  # noqa: E731
        else:
            steps = np.diff(t[np.isfinite(t)])
            step = float(np.median(steps)) if steps.size else 1.0
            exp = grid_exponent(step * STEPS_PER_SPAN / 1000.0, sel)
            key = ("exp", exp, sel.tobytes())
            make = lambda: compact_values(sel, exp)  # noqa: E731
        j = self._index.get(key)
        if j is None:
            j = self._index[key] = len(self.arrays)
            self.arrays.append(make())
        return {"x": {"ref": j}}


def expand_array(a: Any, arrays: list[Any] | None = None) -> Any:
    """A compact array (see the module doc) as a list of floats with None for missing samples; a
    plain list is returned as it is. The Python twin of ``expandArray`` in ``report.js``."""
    if isinstance(a, dict) and "ref" in a:
        return expand_array((arrays or [])[a["ref"]])
    if not isinstance(a, dict) or "dk" not in a:
        return a
    steps = read_varint_text(a["dk"])
    if a.get("order") == 2:
        steps = np.cumsum(steps)
    k = np.cumsum(np.r_[np.int64(a["k0"]), steps]) if "k0" in a else np.empty(0, np.int64)
    if "step" in a:
        v = a.get("offset", 0.0) + k * float(a["step"])
    else:
        e = int(a["exp"])
        v = k / 10.0 ** (-e) if e < 0 else k * 10.0**e
    out: list[Any] = v.tolist()
    for start, length in a.get("nan", []):
        out[start:start + length] = [None] * length
    return out


def expand_figure(spec: dict[str, Any]) -> dict[str, Any]:
    """A figure with every compact array expanded to a plain list and the ``x0``/``dx`` of a trace
    written out as its ``x`` (what plotly draws), the same as ``report.js`` does before drawing."""
    arrays = spec.get("arrays", [])
    grid = spec.get("grid", {})
    data = []
    for tr in spec["data"]:
        tr = dict(tr)
        if grid and "x" not in tr and "x0" not in tr:
            tr.update(grid)
        for key in ("x", "y"):
            if key in tr and not (isinstance(tr[key], dict) and ("minus" in tr[key] or "around" in tr[key])):
                tr[key] = expand_array(tr[key], arrays)
        data.append(tr)
    for tr in data:
        y = tr.get("y")
        if isinstance(y, dict) and "around" in y:
            a, j = y["around"]
            c = np.array([np.nan if v is None else v for v in expand_array(data[a]["y"], arrays)], float)
            h = np.array([np.nan if v is None else v for v in expand_array({"ref": j}, arrays)], float)
            tr["y"] = [None if not math.isfinite(v) else v for v in (c + y["side"] * h).tolist()]
    for tr in data:
        y = tr.get("y")
        if isinstance(y, dict) and "minus" in y:
            a, b = (np.array([np.nan if v is None else v for v in data[i]["y"]], float) for i in y["minus"])
            d = a - b
            if y.get("wrap"):
                w = float(y["wrap"])
                d = w / 2 - np.mod(w / 2 - d, w)
            tr["y"] = [None if not math.isfinite(v) else v for v in d.tolist()]
    for tr in data:
        if "x0" in tr and "x" not in tr and isinstance(tr.get("y"), list):
            tr["x"] = (tr["x0"] + tr.get("dx", 1.0) * np.arange(len(tr["y"]))).tolist()
    layout = spec.get("layout", {})
    if spec.get("note_defaults") and layout.get("annotations"):
        layout = {**layout, "annotations": [{**spec["note_defaults"], **a} for a in layout["annotations"]]}
    return {**{k: v for k, v in spec.items() if k not in ("arrays", "grid", "note_defaults")}, "data": data,
            "layout": layout}
