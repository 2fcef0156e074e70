"""Recorded logs for ``replay``: read a file, map its columns to canonical signals, check plausibility.

A log is a table with a time column and any number of channels, in CSV, gzip CSV, Parquet or MATLAB
``.mat`` (v5/v7; a struct of vectors or plain vector variables). A *column map* (YAML,
``harness/replay_maps/*.yaml``) says which log column feeds which canonical signal and in what unit::

    time: {column: t, scale: 1.0}                  # -> t_s
    vx_mps: {column: Ux, scale: 1.0}               # scale/offset: si = raw * unit * scale + offset
    yaw_rate_radps: {column: r, unit: deg/s}       # unit conversion to SI
    reference: [beta_rad, vy_mps, vx_mps]          # scored truth
    measured: [delta_rad, yaw_rate_radps, vx_mps]  # fed to the observers

Everything that can be wrong with a log (unreadable file, empty table, a mapped column missing,
time going backwards, a unit that is off by a factor 57 or 1000) raises ``LogError`` with a one-line
message naming the file and the column; the CLI turns it into exit 2.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from importlib.resources import files
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from harness.errors import LogError
from harness.signals import CANONICAL, ESTIMABLE
from harness.strict_yaml import Fields, load_mapping

G0 = 9.80665  # m/s^2, standard gravity (the "g" unit of accelerometers)

#: Measurement columns an observer may ask for (ARCHITECTURE.md, "Measurements").
MEASUREMENT_COLUMNS: tuple[str, ...] = (
    "ax_mps2", "ay_mps2", "az_mps2", "roll_rate_radps", "pitch_rate_radps", "yaw_rate_radps",
    "omega_fl_radps", "omega_fr_radps", "omega_rl_radps", "omega_rr_radps", "vx_mps",
    "handwheel_rad", "delta_rad", "gnss_x_m", "gnss_y_m", "gnss_speed_mps", "gnss_course_rad",
    "y_lane_m", "psi_lane_rad", "rho_1pm", "range_m", "range_rate_mps", "ogs_vx_mps", "ogs_vy_mps",
)

#: Reference channels picked by the identity map (a log whose columns are already canonical).
DEFAULT_REFERENCE: tuple[str, ...] = (
    "beta_rad", "vy_mps", "vx_mps", "alpha_f_rad", "alpha_r_rad", "fy_f_N", "fy_r_N", "roll_rad",
)

#: unit name -> (factor to SI, SI unit). ``si = raw * factor * scale + offset``.
UNITS: dict[str, tuple[float, str]] = {
    "s": (1.0, "s"), "ms": (1e-3, "s"), "us": (1e-6, "s"),
    "rad": (1.0, "rad"), "deg": (math.pi / 180.0, "rad"),
    "rad/s": (1.0, "rad/s"), "deg/s": (math.pi / 180.0, "rad/s"), "rpm": (2.0 * math.pi / 60.0, "rad/s"),
    "rad/s^2": (1.0, "rad/s^2"), "deg/s^2": (math.pi / 180.0, "rad/s^2"),
    "m/s": (1.0, "m/s"), "km/h": (1.0 / 3.6, "m/s"), "mph": (0.44704, "m/s"),
    "m/s^2": (1.0, "m/s^2"), "g": (G0, "m/s^2"),
    "m": (1.0, "m"), "1/m": (1.0, "1/m"), "N": (1.0, "N"), "kN": (1e3, "N"), "1": (1.0, "1"),
}

# SI unit of a signal from its name's suffix (longest suffix first: _radps2 before _radps before _rad).
_SUFFIX_UNITS: tuple[tuple[str, str], ...] = (
    ("_radps2", "rad/s^2"), ("_radps", "rad/s"), ("_rad", "rad"), ("_mps2", "m/s^2"), ("_mps", "m/s"),
    ("_1pm", "1/m"), ("_m", "m"), ("_N", "N"), ("_s", "s"),
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

LOG_SUFFIXES = (".csv", ".csv.gz", ".gz", ".txt", ".parquet", ".pq", ".mat")

#: Plausible median time step of a vehicle log [s]: 100 kHz to 1 Hz. Outside it the time column is
#: almost surely in another unit (µs or ms read as s gives steps of 1 to 10^4 "s"; ns gives < 1e-5).
TIME_STEP_RANGE_S = (1e-5, 1.0)
# A time column named like this is not in seconds unless the map says so (``unit: ms``/``us``).
_TIME_NAME_UNIT = re.compile(r"(?:^|[^a-z])(ms|msec|millis|us|usec|micros|µs|ns|nsec|nanos)$")


def si_unit_of(name: str) -> str:
    """SI unit of a canonical signal or measurement column, from its name (``"yaw_rate_radps"`` → rad/s)."""
    if name in CANONICAL:
        return CANONICAL[name][0]
    for suffix, unit in _SUFFIX_UNITS:
        if name.endswith(suffix):
            return unit
    return "1"


def plausible_bound(name: str) -> tuple[float, str] | None:
    """(bound on |x| [SI], hint) for a signal, or None when no range is known."""
    for key, bound, hint in _PLAUSIBLE:
        if name == key or (key.endswith("_") and name.startswith(key)):
            return bound, hint
    return None


@dataclass(frozen=True)
class ChannelSpec:
    """One mapped channel: canonical ``name`` <- log ``column`` as ``raw * factor * scale + offset``."""

    name: str
    column: str
    scale: float = 1.0
    offset: float = 0.0
    unit: str = ""  # as written in the map ("" = already SI)

    @property
    def factor(self) -> float:
        return UNITS[self.unit][0] if self.unit else 1.0


@dataclass(frozen=True)
class SegmentRules:
    """How a log is cut into segments the observers run on (see ``harness/replay_segments.py``)."""

    min_speed_mps: float = 3.0  # below: standstill, skipped (bicycle models divide by vx)
    gap_factor: float = 5.0  # dt > gap_factor * median dt: a gap, the segment ends there
    min_duration_s: float = 1.0  # shorter valid stretches are skipped, too short to converge
    regular_tolerance: float = 0.01  # |dt / median - 1| above this anywhere: resample the segment


@dataclass(frozen=True)
class ColumnMap:
    """A validated column map. ``channels`` holds the time channel under ``"t_s"``."""

    name: str
    source: str
    channels: dict[str, ChannelSpec]
    reference: tuple[str, ...]
    measured: tuple[str, ...]
    rules: SegmentRules = field(default_factory=SegmentRules)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name, "source": self.source,
            "channels": {k: {"column": c.column, "scale": c.scale, "offset": c.offset, "unit": c.unit or "SI"}
                         for k, c in self.channels.items()},
            "reference": list(self.reference), "measured": list(self.measured),
            "rules": self.rules.__dict__.copy(),
        }


# ---- column maps -------------------------------------------------------------------------------

def replay_maps_dir() -> Path:
    return Path(str(files("harness") / "replay_maps"))


def available_maps() -> list[str]:
    return sorted(p.stem for p in replay_maps_dir().glob("*.yaml"))


def _allowed_signal(name: str) -> bool:
    return name in CANONICAL or name in MEASUREMENT_COLUMNS


def _channel(f: Fields, key: str, signal: str) -> ChannelSpec:
    v = f.raw(key)
    if isinstance(v, str):  # shorthand: `vx_mps: Ux`
        return ChannelSpec(name=signal, column=v)
    c = f.sub(key)
    unit = c.string("unit", "", choices=("", *UNITS))
    spec = ChannelSpec(name=signal, column=c.string("column"), scale=c.number("scale", 1.0),
                       offset=c.number("offset", 0.0), unit=unit)
    c.done()
    if unit and UNITS[unit][1] != si_unit_of(signal):
        raise c.fail("unit", f"{unit!r} converts to {UNITS[unit][1]}, but {signal} is in {si_unit_of(signal)}")
    if spec.scale == 0.0:
        raise c.fail("scale", "must not be 0")
    return spec


def load_column_map(name_or_path: str | Path) -> ColumnMap:
    """Read and check a column map: a shipped name (``"revs_250lm"``) or a YAML path."""
    p = Path(name_or_path)
    if p.suffix.lower() not in (".yaml", ".yml"):
        p = replay_maps_dir() / f"{name_or_path}.yaml"
        if not p.is_file():
            raise LogError(f"unknown column map {str(name_or_path)!r} (shipped: {', '.join(available_maps())})")
    return parse_column_map(load_mapping(p, LogError), str(p))


def parse_column_map(data: dict[str, Any], source: str) -> ColumnMap:
    """Validate a column-map mapping (as read from YAML)."""
    f = Fields(data, source=source, error=LogError)
    name = f.string("name", Path(source).stem)
    f.string("description", "")
    channels: dict[str, ChannelSpec] = {"t_s": _channel(f, "time", "t_s")}
    reference = tuple(f.items("reference", []))
    measured = tuple(f.items("measured"))
    s = f.sub("segments", {})
    rules = SegmentRules(
        min_speed_mps=s.number("min_speed_mps", 3.0, lo=0.0, hi=50.0),
        gap_factor=s.number("gap_factor", 5.0, lo=1.5, hi=1e6),
        min_duration_s=s.number("min_duration_s", 1.0, lo=0.0, hi=1e5),
        regular_tolerance=s.number("regular_tolerance", 0.01, lo=0.0, hi=0.5),
    )
    s.done()
    for key in data:
        if key in ("name", "description", "time", "reference", "measured", "segments"):
            continue
        if not _allowed_signal(key):
            raise f.fail(key, "unknown map key: not a canonical signal or measurement column "
                              "(see CONTRACT.md 'Canonical signals')")
        channels[key] = _channel(f, key, key)
    f.done()
    for role, names, allowed in (("reference", reference, ESTIMABLE), ("measured", measured, MEASUREMENT_COLUMNS)):
        for n in names:
            if not isinstance(n, str) or n not in allowed:
                raise f.fail(role, f"{n!r} is not a{' scoreable state' if role == 'reference' else ' measurement column'}")
            if n not in channels:
                raise f.fail(role, f"{n!r} is listed but has no mapping ({n}: {{column: ...}})")
    if not measured:
        raise f.fail("measured", "must list at least one channel")
    return ColumnMap(name=name, source=source, channels=channels, reference=reference, measured=measured,
                     rules=rules)


def identity_map(columns: list[str], source: str) -> ColumnMap:
    """The map of a log whose columns are already canonical names (``t_s`` required)."""
    if "t_s" not in columns:
        raise LogError("no 't_s' column and no column map: give --columns MAP.yaml "
                       f"(columns found: {', '.join(columns[:12])}{' …' if len(columns) > 12 else ''})",
                       source=source)
    chans = {c: ChannelSpec(c, c) for c in columns if c == "t_s" or _allowed_signal(c)}
    measured = tuple(c for c in MEASUREMENT_COLUMNS if c in chans)
    reference = tuple(c for c in DEFAULT_REFERENCE if c in chans)
    if not measured:
        raise LogError("no column is a measurement name (e.g. yaw_rate_radps, delta_rad, vx_mps); "
                       "give --columns MAP.yaml", source=source)
    return ColumnMap(name="identity", source="(identity: canonical column names)", channels=chans,
                     reference=reference, measured=measured)


# ---- reading -----------------------------------------------------------------------------------

def log_format(path: Path) -> str:
    """``csv``, ``parquet`` or ``mat`` from the file name (gzip CSV is ``csv``)."""
    name = path.name.lower()
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


def read_log(path: str | Path) -> pd.DataFrame:
    """Read a log file into a DataFrame of its own column names (no mapping, no checks of content).

    Raises
    ------
    LogError
        File missing, empty, or not readable in the format its name says.
    """
    p = Path(path)
    if not p.is_file():
        raise LogError("file not found", source=str(p))
    fmt = log_format(p)
    if p.stat().st_size == 0:
        raise LogError("empty file", source=str(p))
    try:
        if fmt == "csv":
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


def apply_map(raw: pd.DataFrame, cmap: ColumnMap, source: str) -> pd.DataFrame:
    """Canonical frame ``t_s`` + every mapped channel in SI, checked.

    Parameters
    ----------
    raw : DataFrame
        The log as read (``read_log``), n rows.
    cmap : ColumnMap
    source : str
        Log file name for messages.

    Returns
    -------
    DataFrame
        (n, 1 + channels) with ``t_s`` strictly increasing [s]; channels may hold NaN.
    """
    missing = [c for c in cmap.channels.values() if c.column not in raw.columns]
    if missing:
        c = missing[0]
        near = [k for k in raw.columns if k.lower() == c.column.lower()]
        extra = f" (did you mean {near[0]!r}?)" if near else ""
        raise LogError(f"missing required column {c.column!r} (mapped to {c.name} by {cmap.source}){extra}",
                       source=source)
    out: dict[str, np.ndarray] = {}
    for name, c in cmap.channels.items():
        out[name] = _numeric(raw, c.column, source, name) * (c.factor * c.scale) + c.offset
    for name, c in cmap.channels.items():
        inf = np.isinf(out[name])
        if inf.any() and name != "t_s":
            # An overflow or "no data" marker of the logger, not a measurement: refused rather than
            # silently turned into NaN (an empty cell is how a log says "missing").
            i = int(np.flatnonzero(inf)[0])
            raise LogError(f"column {c.column!r} ({name}) has an infinite value at row {i + 1} "
                           f"({'+' if out[name][i] > 0 else '-'}inf; {int(inf.sum())} such rows): leave the "
                           "cell empty for a missing sample", source=source)
    t = out["t_s"]
    tcol = cmap.channels["t_s"].column
    bad = ~np.isfinite(t)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise LogError(f"time column {tcol!r} has a missing/non-finite value at row {i + 1}", source=source)
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.flatnonzero(dt <= 0)[0])
        what = "goes backwards" if dt[i] < 0 else "repeats"
        raise LogError(f"time column {tcol!r} {what} at row {i + 2} (t={t[i]:.6g} then {t[i + 1]:.6g}); "
                       "time must strictly increase", source=source)
    check_time_unit(cmap.channels["t_s"], dt, source)
    for name, c in cmap.channels.items():
        if name != "t_s":
            check_plausible(name, out[name], c.column, source)
    return pd.DataFrame(out)
