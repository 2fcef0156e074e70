"""Column maps of ``replay``: which log column (or derived expression) feeds which canonical signal.

A column map (YAML, ``harness/replay_maps/*.yaml``, docs/REPLAY.md) maps log columns to the canonical
signals of CONTRACT.md with their units, says which channels are measured (fed to the observers) and
which are references (scored truth), how time is given (a column, or a sample rate), how the log is
cut into segments, which vehicle it belongs to and what a failed consistency check does. Derived
channels (``expr``/``derive``) are checked here and evaluated by ``replay_log.apply_map``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from importlib.resources import files
from pathlib import Path
from typing import Any

from roadtruth.harness.errors import LogError
from roadtruth.harness.files.strict_yaml import Fields, load_mapping
from roadtruth.harness.jobs.replay_channels import (
    DERIVATIONS,
    VEHICLE_NAMES,
    Expression,
    ExpressionError,
    derivation_expression,
    evaluation_order,
    parse_expression,
)
from roadtruth.harness.signals import CANONICAL, ESTIMABLE

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



def si_unit_of(name: str) -> str:
    """SI unit of a canonical signal or measurement column, from its name (``"yaw_rate_radps"`` → rad/s)."""
    if name in CANONICAL:
        return CANONICAL[name][0]
    for suffix, unit in _SUFFIX_UNITS:
        if name.endswith(suffix):
            return unit
    return "1"


@dataclass(frozen=True)
class ChannelSpec:
    """One mapped channel: canonical ``name`` <- log ``column`` (or ``expr``) as ``raw * factor * scale + offset``.

    A derived channel has ``column == ""`` and an expression ``expr`` (``harness/jobs/replay_channels.py``);
    ``note`` says where it came from (a named derivation, or derived from the handwheel automatically).
    """

    name: str
    column: str
    scale: float = 1.0
    offset: float = 0.0
    unit: str = ""  # as written in the map ("" = already SI)
    expr: str = ""
    note: str = ""

    @property
    def expression(self) -> Expression:
        return parse_expression(self.expr)

    @property
    def label(self) -> str:
        """How messages name the channel's source: the column, or the expression."""
        return repr(self.column) if self.column else f"expression {self.expr!r}"

    @property
    def factor(self) -> float:
        return UNITS[self.unit][0] if self.unit else 1.0


@dataclass(frozen=True)
class SegmentRules:
    """How a log is cut into segments the observers run on (see ``harness/jobs/replay_segments.py``)."""

    min_speed_mps: float = 3.0  # below: standstill, skipped (bicycle models divide by vx)
    gap_factor: float = 5.0  # dt > gap_factor * median dt: a gap, the segment ends there
    min_duration_s: float = 1.0  # shorter valid stretches are skipped, too short to converge
    regular_tolerance: float = 0.01  # |dt / median - 1| above this anywhere: resample the segment


CHECK_MODES = ("error", "warn", "off")
TIME_ORIGINS = ("auto", "start", "log")


@dataclass(frozen=True)
class ColumnMap:
    """A validated column map. ``channels`` holds the time channel under ``"t_s"`` unless the log's time is
    a sample rate (``rate_hz``: ``t = start_s + k / rate_hz``).

    ``vehicle``: the vehicle the map names (a shipped name or a path resolved against the map's folder),
    "" when it names none. ``checks``: what a failed sign/unit consistency check does
    (``harness/jobs/replay_checks.py``). ``origin``: ``auto`` writes time from the log start when the log's
    own clock is too large for the CSV files, ``start`` always, ``log`` never.
    """

    name: str
    source: str
    channels: dict[str, ChannelSpec]
    reference: tuple[str, ...]
    measured: tuple[str, ...]
    rules: SegmentRules = field(default_factory=SegmentRules)
    rate_hz: float | None = None
    start_s: float = 0.0
    origin: str = "auto"
    vehicle: str = ""
    checks: str = "error"

    def to_dict(self) -> dict[str, Any]:
        chans: dict[str, Any] = {}
        for k, c in self.channels.items():
            d: dict[str, Any] = {"column": c.column, "scale": c.scale, "offset": c.offset, "unit": c.unit or "SI"}
            if c.expr:
                d["expr"] = c.expr
            if c.note:
                d["note"] = c.note
            chans[k] = d
        out = {"name": self.name, "source": self.source, "channels": chans,
               "reference": list(self.reference), "measured": list(self.measured),
               "rules": self.rules.__dict__.copy(), "time_origin": self.origin, "checks": self.checks}
        if self.rate_hz is not None:
            out["time"] = {"rate_hz": self.rate_hz, "start_s": self.start_s}
        if self.vehicle:
            out["vehicle"] = self.vehicle
        return out

    @property
    def derived(self) -> tuple[str, ...]:
        """Keys of the derived channels, in an order in which each can be evaluated."""
        deps = {k: c.expression.names & set(self.channels) for k, c in self.channels.items() if c.expr}
        return tuple(evaluation_order(deps))

    def log_columns(self) -> set[str]:
        """Log columns the map reads: mapped columns, ``col()`` names and bare expression names that are
        neither map keys nor vehicle parameters."""
        cols = {c.column for c in self.channels.values() if c.column}
        for c in self.channels.values():
            if c.expr:
                e = c.expression
                cols |= set(e.columns) | {n for n in e.names if n not in self.channels and n not in VEHICLE_NAMES}
        return cols

    def with_rate(self, rate_hz: float) -> ColumnMap:
        """The map with its time given as a sample rate (``--rate-hz``); refused when it maps a time column."""
        if not (math.isfinite(rate_hz) and 0.0 < rate_hz <= 1e5):
            raise LogError(f"--rate-hz must be in (0, 100000] Hz (got {rate_hz:g})")
        if "t_s" in self.channels:
            raise LogError(f"the column map maps time to column {self.channels['t_s'].column!r}: "
                           "give either a time column or --rate-hz, not both", source=self.source)
        return replace(self, rate_hz=float(rate_hz))


# ---- column maps -------------------------------------------------------------------------------

def replay_maps_dir() -> Path:
    return Path(str(files("roadtruth.harness") / "replay_maps"))


def available_maps() -> list[str]:
    return sorted(p.stem for p in replay_maps_dir().glob("*.yaml"))


def _allowed_signal(name: str) -> bool:
    return name in CANONICAL or name in MEASUREMENT_COLUMNS


def _channel_fields(c: Fields, signal: str) -> ChannelSpec:
    """A channel from its mapping: exactly one of ``column``, ``expr``, ``derive``, then unit/scale/offset."""
    given = [k for k in ("column", "expr", "derive") if c.has(k)]
    if len(given) != 1:
        raise c.fail(given[1] if given else "column",
                     "give exactly one of column, expr, derive" + (f" (got {', '.join(given)})" if given else ""))
    expr, note, column = "", "", ""
    if given[0] == "column":
        column = c.string("column")
    elif given[0] == "expr":
        expr = c.string("expr")
    else:
        how = c.string("derive", choices=tuple(DERIVATIONS))
        of = c.items("of", None) if c.has("of") else None
        if of is not None and (not of or not all(isinstance(x, str) for x in of)):
            raise c.fail("of", "must be a non-empty list of map keys or log columns")
        cutoff = c.number("cutoff_hz", None, lo=1e-3, hi=1e4) if c.has("cutoff_hz") else None
        if cutoff is not None and how != "derivative":
            raise c.fail("cutoff_hz", f"only the derivative has a cut-off, not {how}")
        expr = derivation_expression(how, of, cutoff)
        note = f"derived by '{how}': {DERIVATIONS[how][2]}"
    if expr:
        try:
            e = parse_expression(expr)
        except ExpressionError as exc:
            raise c.fail(given[0], str(exc)) from None
        if signal in e.names:
            raise c.fail(given[0], f"the expression of {signal} names {signal} itself")
    unit = c.string("unit", "", choices=("", *UNITS))
    if unit and note:
        raise c.fail("unit", "a named derivation is already in SI: no unit")
    spec = ChannelSpec(name=signal, column=column, scale=c.number("scale", 1.0),
                       offset=c.number("offset", 0.0), unit=unit, expr=expr, note=note)
    c.done()
    if unit and UNITS[unit][1] != si_unit_of(signal):
        raise c.fail("unit", f"{unit!r} converts to {UNITS[unit][1]}, but {signal} is in {si_unit_of(signal)}")
    if spec.scale == 0.0:
        raise c.fail("scale", "must not be 0")
    return spec


def _channel(f: Fields, key: str, signal: str) -> ChannelSpec:
    v = f.raw(key)
    if isinstance(v, str):  # shorthand: `vx_mps: Ux`
        return ChannelSpec(name=signal, column=v)
    return _channel_fields(f.sub(key), signal)


def _time(f: Fields) -> tuple[ChannelSpec | None, float | None, float, str]:
    """The ``time`` entry: (time channel or None, rate_hz or None, start_s, origin)."""
    v = f.raw("time", None)
    if v is None:  # allowed here: --rate-hz may give it (apply_map refuses a map left without time)
        return None, None, 0.0, "auto"
    if isinstance(v, str):
        return ChannelSpec(name="t_s", column=v), None, 0.0, "auto"
    t = f.sub("time")
    origin = t.string("origin", "auto", choices=TIME_ORIGINS)
    if t.has("rate_hz"):
        if t.has("column"):
            raise t.fail("rate_hz", "give either a time column or rate_hz, not both")
        rate = t.number("rate_hz", lo=1e-3, hi=1e5, lo_open=True)
        start = t.number("start_s", 0.0)
        t.done()
        return None, rate, start, origin
    rest = {k: t.data[k] for k in t.data if k != "origin"}
    if "start_s" in rest:
        raise t.fail("start_s", "only with rate_hz (a time column has its own start)")
    return _channel_fields(Fields(rest, source=f.source, error=LogError, prefix="time"), "t_s"), None, 0.0, origin


def _road_wheel_angle_from_handwheel(channels: dict[str, ChannelSpec], measured: tuple[str, ...]
                                     ) -> tuple[dict[str, ChannelSpec], tuple[str, ...]]:
    """Add ``delta_rad = handwheel_rad / steering ratio`` when the handwheel is measured and δ is not mapped.

    Without it every observer that needs the road-wheel angle would be skipped although the log has
    the steering; the replay prints a note saying so (``ChannelSpec.note``).
    """
    if "handwheel_rad" not in measured or "delta_rad" in channels:
        return channels, measured
    spec = ChannelSpec(name="delta_rad", column="", expr=derivation_expression("road_wheel_angle", None, None),
                       note="derived automatically from handwheel_rad / the vehicle's steering ratio "
                            "(map delta_rad to change it)")
    return {**channels, "delta_rad": spec}, (*measured, "delta_rad")


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
    time_spec, rate_hz, start_s, origin = _time(f)
    channels: dict[str, ChannelSpec] = {"t_s": time_spec} if time_spec is not None else {}
    vehicle = f.string("vehicle", "")
    if vehicle.lower().endswith((".yaml", ".yml")) and not Path(vehicle).is_absolute():
        vehicle = str(Path(source).parent / vehicle)  # a vehicle file next to the map
    checks = f.string("checks", "error", choices=CHECK_MODES)
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
        if key in ("name", "description", "time", "reference", "measured", "segments", "vehicle", "checks"):
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
    channels, measured = _road_wheel_angle_from_handwheel(channels, measured)
    cmap = ColumnMap(name=name, source=source, channels=channels, reference=reference, measured=measured,
                     rules=rules, rate_hz=rate_hz, start_s=start_s, origin=origin, vehicle=vehicle, checks=checks)
    try:
        cmap.derived  # noqa: B018  (checks that the derived channels do not refer to each other in a cycle)
    except ExpressionError as exc:
        raise LogError(str(exc), source=source) from None
    return cmap


def identity_map(columns: list[str], source: str, rate_hz: float | None = None) -> ColumnMap:
    """The map of a log whose columns are already canonical names (``t_s`` required unless ``rate_hz``)."""
    if "t_s" not in columns and rate_hz is None:
        raise LogError("no 't_s' column and no column map: give --columns MAP.yaml, or --rate-hz for a log "
                       f"without a time column (columns found: {', '.join(columns[:12])}"
                       f"{' …' if len(columns) > 12 else ''})", source=source)
    chans = {c: ChannelSpec(c, c) for c in columns if (c == "t_s" and rate_hz is None) or _allowed_signal(c)}
    measured = tuple(c for c in MEASUREMENT_COLUMNS if c in chans)
    reference = tuple(c for c in DEFAULT_REFERENCE if c in chans)
    if not measured:
        raise LogError("no column is a measurement name (e.g. yaw_rate_radps, delta_rad, vx_mps); "
                       "give --columns MAP.yaml", source=source)
    chans, measured = _road_wheel_angle_from_handwheel(chans, measured)
    return ColumnMap(name="identity", source="(identity: canonical column names)", channels=chans,
                     reference=reference, measured=measured, rate_hz=rate_hz)


def resolve_vehicle(vehicle: str | Path | None, cmap: ColumnMap | None) -> str | Path:
    """The replay's vehicle: the one given (``--vehicle``), else the column map's ``vehicle:``.

    Raises ``LogError`` when neither names one: observers built for the wrong car score nothing true.
    """
    if vehicle is not None and str(vehicle) != "":
        return vehicle
    if cmap is not None and cmap.vehicle:
        return cmap.vehicle
    from roadtruth.harness.truth.vehicle import available_vehicles

    raise LogError("no vehicle: give --vehicle NAME or FILE.yaml (shipped: "
                   f"{', '.join(available_vehicles())}; a replay vehicle needs only 8 numbers, docs/VEHICLES.md) "
                   "or a 'vehicle:' key in the column map")
