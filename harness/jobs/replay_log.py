"""Recorded logs for ``replay``: read a file, map its columns to canonical signals, check plausibility.

A log is a table with a time column and any number of channels, in CSV, gzip CSV, Parquet, MATLAB
``.mat`` (v5/v7; a struct of vectors or plain vector variables), ASAM MDF4 ``.mf4`` or a ROS 2 MCAP
bag (``harness/jobs/replay_formats.py``). A *column map* (YAML,
``harness/replay_maps/*.yaml``) says which log column feeds which canonical signal and in what unit::

    time: {column: t, scale: 1.0}                  # -> t_s
    vx_mps: {column: Ux, scale: 1.0}               # scale/offset: si = raw * unit * scale + offset
    yaw_rate_radps: {column: r, unit: deg/s}       # unit conversion to SI
    reference: [beta_rad, vy_mps, vx_mps]          # scored truth
    measured: [delta_rad, yaw_rate_radps, vx_mps]  # fed to the observers

An entry may also be derived from other columns (``{expr: ...}`` or ``{derive: ...}``,
``harness/jobs/replay_channels.py``), and the time may be a sample rate (``time: {rate_hz: 200}``) for a
file without a time vector.

Everything that can be wrong with a log (unreadable file, empty table, a mapped column missing,
time going backwards, a unit that is off by a factor 57 or 1000) raises ``LogError`` with a one-line
message naming the file and the column; the CLI turns it into exit 2.
"""

from __future__ import annotations

import math
import re
from operator import attrgetter
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.errors import LogError
from roadtruth.harness.jobs.replay_channels import VEHICLE_NAMES, ExpressionError, evaluate

# The column maps live in replay_column_map; their names are re-exported here, where callers have
# always found them.
from roadtruth.harness.jobs.replay_column_map import (  # noqa: F401
    DEFAULT_REFERENCE,
    G0,
    MEASUREMENT_COLUMNS,
    UNITS,
    ChannelSpec,
    ColumnMap,
    SegmentRules,
    available_maps,
    identity_map,
    load_column_map,
    parse_column_map,
    replay_maps_dir,
    resolve_vehicle,
    si_unit_of,
)

# Plausibility: (bound on |x| in SI, what a violation usually means). A channel fails when more than
# PLAUSIBLE_FRACTION of its finite samples exceed the bound, so one glitch does not reject a log.
PLAUSIBLE_FRACTION = 1e-3
_PLAUSIBLE: tuple[tuple[str, float, str], ...] = (
    ("beta_rad", math.pi / 2, "degrees instead of rad?"),
    ("delta_rad", 1.0, "degrees, or the handwheel angle instead of the road-wheel angle?"),
    ("delta_fl_rad", 1.0, "degrees, or the handwheel angle instead of the road-wheel angle?"),
    ("delta_fr_rad", 1.0, "degrees, or the handwheel angle instead of the road-wheel angle?"),
    ("handwheel_rad", 4.0 * math.pi, "degrees instead of rad?"),
    ("alpha_", 1.0, "degrees instead of rad?"),
    ("roll_rad", 1.0, "degrees instead of rad?"),
    ("pitch_rad", 1.0, "degrees instead of rad?"),
    ("yaw_rate_radps", 3.0, "deg/s instead of rad/s?"),
    ("roll_rate_radps", 3.0, "deg/s instead of rad/s?"),
    ("pitch_rate_radps", 3.0, "deg/s instead of rad/s?"),
    ("omega_", 600.0, "rpm instead of rad/s?"),
    ("yaw_acc_radps2", 30.0, "deg/s^2 instead of rad/s^2?"),
    ("ax_mps2", 30.0, "wrong unit (mm/s^2, ft/s^2, or g with a scale)?"),
    ("ay_mps2", 30.0, "wrong unit (mm/s^2, ft/s^2, or g with a scale)?"),
    ("az_mps2", 40.0, "wrong unit (mm/s^2, ft/s^2, or g with a scale)?"),
    ("vx_mps", 110.0, "km/h or mph instead of m/s?"),
    ("vy_mps", 30.0, "km/h instead of m/s?"),
    ("ogs_vx_mps", 110.0, "km/h or mph instead of m/s?"),
    ("ogs_vy_mps", 30.0, "km/h instead of m/s?"),
    ("gnss_speed_mps", 110.0, "km/h or mph instead of m/s?"),
)

LOG_SUFFIXES = (".csv", ".csv.gz", ".gz", ".txt", ".parquet", ".pq", ".mat", ".mf4", ".mdf", ".mcap")

#: Unit strings as MDF4 files write them -> the column map's unit name (``UNITS``).
FILE_UNITS: dict[str, str] = {
    "s": "s", "ms": "ms", "us": "us", "µs": "us", "rad": "rad", "deg": "deg", "°": "deg",
    "rad/s": "rad/s", "deg/s": "deg/s", "°/s": "deg/s", "rpm": "rpm", "1/min": "rpm",
    "m/s": "m/s", "km/h": "km/h", "kph": "km/h", "kmh": "km/h", "mph": "mph",
    "m/s^2": "m/s^2", "m/s²": "m/s^2", "m/s2": "m/s^2", "g": "g", "m": "m", "N": "N", "kN": "kN",
}

#: Clock values that a 10-significant-digit CSV cannot write to a thousandth of a step are made
#: relative to the log start (``time: {origin: auto}``): a Unix-epoch 1.7e9 s at 100 Hz needs 12 digits.
CSV_SIGNIFICANT_DIGITS = 10

#: Plausible median time step of a vehicle log [s]: 100 kHz to 1 Hz. Outside it the time column is
#: almost surely in another unit (µs or ms read as s gives steps of 1 to 10^4 "s"; ns gives < 1e-5).
TIME_STEP_RANGE_S = (1e-5, 1.0)
# A time column named like this is not in seconds unless the map says so (``unit: ms``/``us``).
_TIME_NAME_UNIT = re.compile(r"(?:^|[^a-z])(ms|msec|millis|us|usec|micros|µs|ns|nsec|nanos)$")


def plausible_bound(name: str) -> tuple[float, str] | None:
    """(bound on |x| [SI], hint) for a signal, or None when no range is known."""
    for key, bound, hint in _PLAUSIBLE:
        if name == key or (key.endswith("_") and name.startswith(key)):
            return bound, hint
    return None


# ---- reading -----------------------------------------------------------------------------------

def log_format(path: Path) -> str:
    """``csv``, ``parquet``, ``mat``, ``mdf`` or ``mcap`` from the file name (gzip CSV is ``csv``; a folder
    is a ROS 2 bag, ``mcap``)."""
    name = path.name.lower()
    if path.is_dir() or name.endswith(".mcap"):
        return "mcap"
    if name.endswith((".mf4", ".mdf")):
        return "mdf"
    if name.endswith((".csv", ".csv.gz", ".txt", ".gz", ".tsv")):
        return "csv"
    if name.endswith((".parquet", ".pq")):
        return "parquet"
    if name.endswith(".mat"):
        return "mat"
    raise LogError(f"unreadable format {path.suffix or '(no suffix)'!r}: expected one of "
                   f"{', '.join(LOG_SUFFIXES)}", source=str(path))


def _mat_columns(path: Path) -> dict[str, np.ndarray]:
    """Vectors of a .mat file: top-level ``name`` and struct fields ``struct.field``.

    A struct field is also reachable by its bare ``field`` name when no other vector has that name.
    Scalars, strings and matrices with more than one non-singleton dimension are ignored.
    """
    from scipy.io import loadmat  # scipy is a dependency; imported here to keep CLI start-up light

    try:
        data = loadmat(str(path), simplify_cells=True)
    except NotImplementedError:
        raise LogError("MATLAB v7.3 (HDF5) files are not supported: save with -v7", source=str(path)) from None
    except Exception as exc:  # scipy raises ValueError/TypeError/MatReadError on garbage
        raise LogError(f"unreadable MATLAB file: {exc}".splitlines()[0], source=str(path)) from None
    out: dict[str, np.ndarray] = {}

    def visit(prefix: str, v: Any) -> None:
        if isinstance(v, dict):
            for k, sub in v.items():
                visit(f"{prefix}.{k}" if prefix else k, sub)
            return
        a = np.asarray(v)
        if a.dtype.kind in "biuf" and a.ndim >= 1 and a.squeeze().ndim == 1:
            out[prefix] = a.squeeze().astype(float)

    for k, v in data.items():
        if not k.startswith("__"):
            visit(k, v)
    leaves: dict[str, list[str]] = {}
    for k in out:
        if "." in k:
            leaves.setdefault(k.rsplit(".", 1)[1], []).append(k)
    for leaf, full in leaves.items():
        if len(full) == 1 and leaf not in out:
            out[leaf] = out[full[0]]
    return out


def read_log(path: str | Path, wanted: set[str] | None = None) -> pd.DataFrame:
    """Read a log file into a DataFrame of its own column names (no mapping, no checks of content).

    ``wanted``: the log columns a column map uses (MDF4/MCAP: they pick the time base and the topics
    decoded; other formats read everything). Unit strings a file declares (MDF4) are in
    ``frame.attrs["units"]`` (column -> unit as written in the file).

    Raises
    ------
    LogError
        File missing, empty, or not readable in the format its name says.
    """
    from roadtruth.harness.jobs.replay_formats import read_mcap, read_mdf

    p = Path(path)
    if not (p.is_file() or (p.is_dir() and log_format(p) == "mcap")):
        raise LogError("file not found", source=str(p))
    fmt = log_format(p)
    if p.is_file() and p.stat().st_size == 0:
        raise LogError("empty file", source=str(p))
    units: dict[str, str] = {}
    try:
        if fmt in ("mdf", "mcap"):
            df, units = (read_mdf if fmt == "mdf" else read_mcap)(p, wanted)
        elif fmt == "csv":
            sep = "\t" if p.name.lower().endswith(".tsv") else ","
            df = pd.read_csv(p, sep=sep, compression="infer", low_memory=False)
        elif fmt == "parquet":
            df = pd.read_parquet(p)
        else:
            cols = _mat_columns(p)
            lengths = {len(v) for v in cols.values()}
            if len(lengths) > 1:
                sizes = ", ".join(f"{k}={len(v)}" for k, v in list(cols.items())[:6])
                raise LogError(f"vectors have different lengths ({sizes}); one time base is needed", source=str(p))
            df = pd.DataFrame(cols)
    except LogError:
        raise
    except pd.errors.EmptyDataError:
        raise LogError("empty file (no header)", source=str(p)) from None
    except Exception as exc:  # pandas/pyarrow/gzip raise many types for a corrupt file
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise LogError(f"unreadable as {fmt}: {msg}", source=str(p)) from None
    if len(df) == 0:
        raise LogError("empty file (no data rows)", source=str(p))
    df.columns = [str(c).strip() for c in df.columns]
    df.attrs["units"] = units
    return df


# ---- mapping and validation --------------------------------------------------------------------

def _numeric(raw: pd.DataFrame, column: str, source: str, signal: str) -> np.ndarray:
    s = raw[column]
    if s.dtype.kind in "biuf":
        return s.to_numpy(dtype=float)
    conv = pd.to_numeric(s, errors="coerce")
    bad = conv.isna() & s.notna() & (s.astype(str).str.strip() != "")
    if bad.any():
        i = int(np.flatnonzero(bad.to_numpy())[0])
        raise LogError(f"column {column!r} ({signal}) is not numeric (row {i + 1}: {s.iloc[i]!r})", source=source)
    return conv.to_numpy(dtype=float)


def check_plausible(name: str, values: np.ndarray, column: str, source: str) -> None:
    """Raise ``LogError`` when a channel's SI values are out of its physical range (a unit mistake)."""
    rule = plausible_bound(name)
    if rule is None:
        return
    bound, hint = rule
    x = np.abs(values[np.isfinite(values)])
    if x.size == 0:
        return
    frac = float(np.mean(x > bound))
    if frac > PLAUSIBLE_FRACTION:
        raise LogError(f"column {column!r} as {name}: {100 * frac:.1f} % of samples exceed |{bound:g}| "
                       f"{si_unit_of(name)} (max {x.max():.4g}): {hint} Fix 'unit' or 'scale' in the column map",
                       source=source)


def check_time_unit(spec: ChannelSpec, dt_s: np.ndarray, source: str) -> None:
    """Raise ``LogError`` when the time column is evidently not in seconds after the map's unit.

    Evidence: the column's name ends in a unit (``t_us``, ``time_ms``) the map does not state, or the
    median step is outside ``TIME_STEP_RANGE_S`` (a 100 Hz log in µs read as s steps by 10^4 "s").
    """
    hint = _TIME_NAME_UNIT.search(spec.column.strip().lower())
    if hint and not spec.unit and spec.scale == 1.0:
        unit = {"ms": "ms", "msec": "ms", "millis": "ms", "ns": "ns", "nsec": "ns", "nanos": "ns"}.get(
            hint.group(1), "us")
        fix = f"unit: {unit}" if unit in UNITS else "scale: 1e-9"
        raise LogError(f"time column {spec.column!r} is named as {unit} but read as seconds: state it in the "
                       f"column map (time: {{column: {spec.column}, {fix}}})", source=source)
    if dt_s.size == 0:
        return
    h = float(np.median(dt_s))
    lo, hi = TIME_STEP_RANGE_S
    if not lo <= h < hi:
        guess = "µs or ms" if h > hi else "ns"
        raise LogError(f"time column {spec.column!r}: median step {h:.6g} s is implausible for a vehicle log "
                       f"(expected {lo:g} s to below {hi:g} s): a time in {guess} read as seconds? Set 'unit' "
                       "(ms, us) or 'scale' of time in the column map", source=source)


def check_file_unit(name: str, c: ChannelSpec, file_units: dict[str, str], source: str) -> None:
    """Raise ``LogError`` when the file states a unit for the column that the map does not read it in.

    Only when the map gives no ``scale`` of its own (a scale is the user saying how to convert) and the
    file's unit string is one ``FILE_UNITS`` knows.
    """
    declared = FILE_UNITS.get(file_units.get(c.column, "").strip())
    if declared is None or c.scale != 1.0 or UNITS[declared][1] != si_unit_of(name):
        return
    read_as = c.unit or next(u for u, (k, si) in UNITS.items() if si == si_unit_of(name) and k == 1.0)
    if not math.isclose(UNITS[declared][0], UNITS[read_as][0], rel_tol=1e-9):
        raise LogError(f"column {c.column!r} is in {declared} according to the file, but the column map reads "
                       f"it as {read_as} ({name}): set 'unit: {declared}' in the column map", source=source)


def _time_origin(t: np.ndarray, origin: str) -> float:
    """The time subtracted from the log's clock [s] (``ColumnMap.origin``); 0 keeps the log's own times."""
    if origin == "log" or t.size == 0:
        return 0.0
    if origin == "start":
        return float(t[0])
    # auto: shift only a clock whose last digit in the CSV files would exceed a thousandth of a step
    h = float(np.median(np.diff(t))) if t.size >= 2 else 1.0
    resolution = 10.0 ** (math.floor(math.log10(max(abs(t[0]), abs(t[-1]), 1e-300))) + 1 - CSV_SIGNIFICANT_DIGITS)
    return float(t[0]) if resolution > 1e-3 * h else 0.0


def apply_map(raw: pd.DataFrame, cmap: ColumnMap, source: str, vehicle: Any = None) -> pd.DataFrame:
    """Canonical frame ``t_s`` + every mapped channel in SI, checked.

    Parameters
    ----------
    raw : DataFrame
        The log as read (``read_log``), n rows.
    cmap : ColumnMap
    source : str
        Log file name for messages.
    vehicle : VehicleParams, optional
        The replay's vehicle, for expressions naming its parameters (``steering_ratio`` …).

    Returns
    -------
    DataFrame
        (n, 1 + channels) with ``t_s`` strictly increasing [s]; channels may hold NaN.
        ``attrs["time_origin_s"]``: the log clock's value at ``t_s = 0`` (0 when times are the log's own).
    """
    missing = [c for c in cmap.channels.values() if c.column and c.column not in raw.columns]
    if missing:
        c = missing[0]
        near = [k for k in raw.columns if k.lower() == c.column.lower()]
        extra = f" (did you mean {near[0]!r}?)" if near else ""
        raise LogError(f"missing required column {c.column!r} (mapped to {c.name} by {cmap.source}){extra}",
                       source=source)
    n = len(raw)
    out: dict[str, np.ndarray] = {}
    raw_cache: dict[str, np.ndarray] = {}

    def raw_column(column: str, key: str) -> np.ndarray:
        if column not in raw_cache:
            raw_cache[column] = _numeric(raw, column, source, key)
        return raw_cache[column]

    def derive(key: str, c: ChannelSpec, t: np.ndarray) -> np.ndarray:
        def lookup(name: str) -> np.ndarray:
            if name in out:
                return out[name]
            if name in VEHICLE_NAMES:
                if vehicle is None:
                    raise LogError(f"{key}: expression {c.expr!r} needs the vehicle's {name}: give --vehicle",
                                   source=cmap.source)
                return np.asarray(float(attrgetter(VEHICLE_NAMES[name])(vehicle)))
            if name in raw.columns:
                return raw_column(name, key)
            near = [k for k in raw.columns if k.lower() == name.lower()]
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise LogError(f"{key}: expression {c.expr!r} names {name!r}, which is not a map key, a vehicle "
                           f"parameter ({', '.join(VEHICLE_NAMES)}) or a column of {Path(source).name}{hint}",
                           source=cmap.source)

        def column(name: str) -> np.ndarray:
            if name not in raw.columns:
                raise LogError(f"{key}: col({name!r}) is not a column of {Path(source).name}", source=cmap.source)
            return raw_column(name, key)

        return evaluate(c.expression, lookup, column, t) * (c.factor * c.scale) + c.offset

    if cmap.rate_hz is not None:
        t = cmap.start_s + np.arange(n) / cmap.rate_hz
    elif "t_s" not in cmap.channels:
        raise LogError("time: required field is missing: a time column (time: {column: t}) or a sample rate "
                       "(time: {rate_hz: 200}, or --rate-hz 200)", source=cmap.source)
    else:
        tc = cmap.channels["t_s"]
        t = (derive("time", tc, np.arange(n, dtype=float)) if tc.expr
             else raw_column(tc.column, "t_s") * (tc.factor * tc.scale) + tc.offset)
    out["t_s"] = t
    for name, c in cmap.channels.items():
        if name == "t_s" or c.expr:
            continue
        out[name] = raw_column(c.column, name) * (c.factor * c.scale) + c.offset
        inf = np.isinf(out[name])
        if inf.any():
            # An overflow or "no data" marker of the logger, not a measurement: refused rather than
            # silently turned into NaN (an empty cell is how a log says "missing").
            i = int(np.flatnonzero(inf)[0])
            raise LogError(f"column {c.column!r} ({name}) has an infinite value at row {i + 1} "
                           f"({'+' if out[name][i] > 0 else '-'}inf; {int(inf.sum())} such rows): leave the "
                           "cell empty for a missing sample", source=source)
    if cmap.rate_hz is None:
        tc = cmap.channels["t_s"]
        bad = ~np.isfinite(t)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise LogError(f"time {tc.label} has a missing/non-finite value at row {i + 1}", source=source)
        dt = np.diff(t)
        if (dt <= 0).any():
            i = int(np.flatnonzero(dt <= 0)[0])
            what = "goes backwards" if dt[i] < 0 else "repeats"
            raise LogError(f"time column {tc.column or tc.expr!r} {what} at row {i + 2} (t={t[i]:.6g} then "
                           f"{t[i + 1]:.6g}); time must strictly increase", source=source)
        check_time_unit(tc, dt, source)
    try:
        order = cmap.derived
    except ExpressionError as exc:
        raise LogError(str(exc), source=cmap.source) from None
    for name in order:
        out[name] = derive(name, cmap.channels[name], t)
    file_units = raw.attrs.get("units", {})
    for name, c in cmap.channels.items():
        if c.column:
            check_file_unit(name, c, file_units, source)
        if name != "t_s":
            check_plausible(name, out[name], c.column or f"= {c.expr}", source)
    origin = _time_origin(t, cmap.origin)
    out["t_s"] = t - origin
    frame = pd.DataFrame(out)
    frame.attrs["time_origin_s"] = origin
    return frame
