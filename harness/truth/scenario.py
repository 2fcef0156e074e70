"""Scenario files: one YAML per driving test (docs/SCENARIOS.md), validated on load.

A scenario names its vehicle, road, friction map, driver, duration and initial speed, plus sensor
preset, scheduled outages, lane-marking gaps and labelled events. Suites are tag queries over the
shipped library ``harness/scenarios/*.yaml`` (``default``, ``ci``, ``stress`` and free tags).

Every mistake in a file raises ``ScenarioError`` with one line naming the file, the field and the
value; the ``driver:`` and ``lead:`` blocks are checked by ``roadtruth.harness.truth.driver``.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
import os
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path
from typing import Any

from roadtruth.harness.errors import ScenarioError
from roadtruth.harness.files.parsed_files import ParsedFiles
from roadtruth.harness.files.strict_yaml import Fields, short_repr, tracing
from roadtruth.harness.truth.driver import DriverSpec, LeadSpec, parse_driver, parse_lead
from roadtruth.harness.truth.friction_map import (
    FrictionMap,
    friction_from_spec,
    parse_friction,
    parse_interval,
)
from roadtruth.harness.truth.road import SEGMENT_KINDS, Road, Segment, build_road
from roadtruth.harness.truth.road_profile import RoadProfile
from roadtruth.harness.truth.scenario_index import scenario_files, scenario_header, scenario_mapping
from roadtruth.harness.truth.vehicle import available_vehicles

#: Below this speed the Magic Formula slip definitions (divided by |vx|) are not meaningful [m/s].
MIN_INITIAL_SPEED_MPS = 3.0
#: Sensors that can be scheduled out (the ``<sensor>_valid`` columns of the measurements; the
#: names of ``roadtruth.harness.sensors.catalog.SENSORS``), or ``all``.
SENSOR_NAMES = ("imu", "wheel_speed", "steering", "gnss", "camera", "radar", "ogs", "all")
SENSOR_PRESETS = ("ideal", "automotive", "consumer")
#: Sharpest curvature a road segment may have (radius 2.5 m) [1/m].
MAX_CURVATURE_1PM = 0.4
#: Steepest grade of a road profile (|dz/ds|; road design keeps main-road grades far below it).
MAX_GRADE_PERCENT = 30.0
#: Largest bank angle of a road profile [deg] (the steepest banked oval tracks are near it).
MAX_BANK_DEG = 30.0
#: Largest elevation of a control point [m] (a bound on typos, not physics).
MAX_ELEVATION_M = 10_000.0
#: Every run gets a road at least this much longer than the distance it can cover [m].
ROAD_MARGIN_M = 100.0


@dataclass(frozen=True)
class Outage:
    """A scheduled sensor outage: the sensor delivers nothing while ``t_start_s <= t < t_end_s``
    and, when ``x_range_m = (x0, x1)`` is given, the car's world x is inside it (a tunnel). The
    sensors convert position zones to times from the truth trajectory."""

    sensor: str
    t_start_s: float = 0.0
    t_end_s: float = math.inf
    x_range_m: tuple[float, float] | None = None


@dataclass(frozen=True)
class Scenario:
    """One validated scenario (SI units; angles in radians)."""

    name: str
    description: str
    standard: str
    tags: tuple[str, ...]
    vehicle: str  # a vehicle set name of harness/vehicles, or a YAML path
    duration_s: float
    initial_speed_mps: float
    road: Road
    lookahead_m: float
    friction: FrictionMap
    driver: DriverSpec
    lead: LeadSpec | None
    sensors: str
    sensor_overrides: dict[str, Any]
    outages: tuple[Outage, ...]
    lane_gaps: tuple[tuple[float, float], ...]
    events: tuple[tuple[float, str], ...]
    seed: int
    path: str

    def with_friction(self, spec: str | float | FrictionMap) -> Scenario:
        """This scenario with its friction map replaced (``--friction``: number, surface or YAML)."""
        fm = spec if isinstance(spec, FrictionMap) else friction_from_spec(spec)
        return dataclasses.replace(self, friction=fm)

    def with_vehicle(self, name_or_path: str) -> Scenario:
        """This scenario driven by another vehicle set (``--vehicle``)."""
        return dataclasses.replace(self, vehicle=_vehicle_ref(str(name_or_path), "command line", "--vehicle"))

    def vehicle_params(self) -> Any:
        """The scenario's ``VehicleParams`` (loaded and validated; see :func:`vehicle_once`)."""
        return vehicle_once(self.vehicle)


#: Parsed vehicle sets: a suite asks for each scenario's car when it checks the choices, when it
#: checks the observer options and when it runs. ``VehicleParams`` is frozen all through (numbers,
#: strings and tuples), so one object can be handed to every caller.
_VEHICLES = ParsedFiles()


def vehicle_once(name_or_path: str) -> Any:
    """``roadtruth.harness.truth.vehicle.load_vehicle(name_or_path)``, parsed once while its file is
    unchanged (same path, modification time and size; a name is a shipped set's file)."""
    from roadtruth.harness.truth.vehicle import load_vehicle, vehicles_dir

    ref = str(name_or_path)
    if tracing():
        return load_vehicle(ref)
    path = Path(ref)
    if path.suffix.lower() not in (".yaml", ".yml"):
        path = vehicles_dir() / f"{ref}.yaml"
    # Keyed by the spelling too: VehicleParams.source is the path as given.
    return _VEHICLES.get(path, lambda: load_vehicle(ref), variant=ref)


# ---- the library ---------------------------------------------------------------------------------

@functools.cache
def scenarios_dir() -> Path:
    """The folder of the shipped scenarios (where the package is installed: fixed for the process)."""
    return Path(str(files("roadtruth.harness") / "scenarios"))


def available_scenarios() -> list[str]:
    """Names of the shipped scenarios (file stems of ``harness/scenarios/*.yaml``), sorted."""
    return sorted(p.stem for p in scenarios_dir().glob("*.yaml"))


#: Built scenarios, one per file (and spelling of its path): a suite validates, prepares and runs
#: each scenario several times and a sweep runs one scenario for every case. A ``Scenario`` is
#: frozen and its arrays read-only; its one mutable field, ``sensor_overrides``, is copied for each
#: caller (:func:`load_scenario`), so no caller can change what another one gets.
_SCENARIOS = ParsedFiles()


def _working_folder() -> str:
    """The working folder (a relative vehicle path in a scenario is looked up in it first)."""
    try:
        return os.getcwd()
    except OSError:  # the folder was deleted under us: such a path cannot be found there anyway
        return ""


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load a shipped scenario by name (``"step_steer"``) or any scenario YAML by path (absolute or
    relative to the working folder; the run folder's sub-folder is named from the scenario's name).

    The file is parsed and validated once while it is unchanged (same path, modification time
    and size); every call returns a scenario of its own (``sensor_overrides`` is a fresh copy).
    """
    p = Path(name_or_path)
    if p.suffix.lower() not in (".yaml", ".yml"):
        # A name is one of the shipped library, never a path into or out of it ("../x").
        p = scenarios_dir() / f"{name_or_path}.yaml"
        if str(name_or_path) not in available_scenarios() or not p.is_file():
            raise ScenarioError(f"unknown scenario {str(name_or_path)!r} "
                                f"(available: {', '.join(available_scenarios())})")
    if tracing():  # the published schemas are traced from a reading: read, do not remember
        return parse_scenario(copy.deepcopy(scenario_mapping(p)), str(p))
    # The result depends on the path as spelled (Scenario.path, the folder of a relative vehicle
    # path) and on the working folder (where a relative vehicle path is looked up first).
    shared = _SCENARIOS.get(p, lambda: parse_scenario(scenario_mapping(p), str(p)),
                            variant=(str(p), _working_folder()))
    return dataclasses.replace(shared, sensor_overrides=copy.deepcopy(shared.sensor_overrides))


def scenario_summaries() -> list[dict[str, Any]]:
    """One row per shipped scenario for ``roadtruth scenarios [--json]``."""
    rows = []
    for name in available_scenarios():
        s = load_scenario(name)
        rows.append({"name": s.name, "description": s.description, "standard": s.standard,
                     "tags": list(s.tags), "vehicle": s.vehicle, "duration_s": s.duration_s,
                     "initial_speed_mps": s.initial_speed_mps})
    return rows


def suite(name: str) -> list[str]:
    """Scenario names carrying the tag ``name`` (``"all"`` = every shipped scenario).

    Only the files' headers are read (``scenario_index.scenario_header``: the same checks of the
    same fields as a full load); the chosen scenarios are built when they are loaded.
    """
    headers = [scenario_header(p) for p in scenario_files()]
    if name == "all":
        return [h["name"] for h in headers]
    chosen = [h["name"] for h in headers if name in h["tags"]]
    if not chosen:
        known = sorted({t for h in headers for t in h["tags"]} | {"all"})
        raise ScenarioError(f"unknown suite {name!r} (known: {', '.join(known)})", field="--suite")
    return chosen


# ---- parsing -------------------------------------------------------------------------------------

def _vehicle_ref(value: str, source: str, field: str, base: Path | None = None) -> str:
    p = Path(value)
    if p.suffix.lower() in (".yaml", ".yml"):
        if not p.is_absolute() and base is not None and not p.exists():
            p = base / p
        if not p.is_file():
            raise ScenarioError(f"vehicle file not found (got {value!r})", source=source, field=field)
        return str(p)
    if value not in available_vehicles():
        raise ScenarioError(f"unknown vehicle {value!r} (available: {', '.join(available_vehicles())})",
                            source=source, field=field)
    return value


def _road(f: Fields, source: str) -> tuple[Road, float] | None:
    if f.raw("road", None) is None:
        return None
    r = f.sub("road")
    st = r.sub("start", {})
    start = (st.number("x_m", 0.0), st.number("y_m", 0.0), math.radians(st.number("psi_deg", 0.0)))
    st.done()
    lane = r.number("lane_width_m", 3.5, lo=2.0, hi=6.0)
    look = r.number("lookahead_m", 0.5, lo=0.0, hi=50.0)
    ds = r.number("ds_m", 0.25, lo=0.01, hi=2.0)
    segs: list[Segment] = []
    raw = r.items("segments")
    if not raw:
        raise r.fail("segments", "must hold at least one segment (got [])")
    for k, item in enumerate(raw):
        field = f"{r.prefix}.segments[{k}]"
        if not isinstance(item, dict) or len(item) != 1 or next(iter(item)) not in SEGMENT_KINDS:
            raise ScenarioError(f"each segment is one of {', '.join(SEGMENT_KINDS)} with its parameters "
                                f"(got {short_repr(item)})", source=source, field=field)
        kind, params = next(iter(item.items()))
        g = Fields(params, source=source, error=ScenarioError, prefix=f"{field}.{kind}")
        length = g.number("length_m", lo=0.0, hi=1e5, lo_open=True)
        curv: float | None = None
        if kind == "arc":
            curv = g.number("curvature_1pm", None, lo=-MAX_CURVATURE_1PM, hi=MAX_CURVATURE_1PM)
        elif kind == "clothoid":
            curv = g.number("curvature_end_1pm", lo=-MAX_CURVATURE_1PM, hi=MAX_CURVATURE_1PM)
        g.done()
        segs.append(Segment(kind, length, curv))
    profile = _road_profile(r)
    r.done()
    return build_road(start, segs, ds_m=ds, lane_width_m=lane, lookahead_m=look, profile=profile), look


def _profile_points(r: Fields, key: str, unit: str, bound: float) -> tuple[tuple[float, float], ...]:
    """A ``[[s_m, value], ...]`` list: numbers, s >= 0 strictly increasing, |value| <= bound."""
    raw = r.items(key)
    if not raw:
        raise r.fail(key, f"must hold at least one [s_m, {unit}] point (got [])")
    out: list[tuple[float, float]] = []
    for p in raw:
        ok = (isinstance(p, list) and len(p) == 2
              and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in p))
        if not ok:
            raise r.fail(key, f"each point must be [s_m, {unit}] numbers (got {short_repr(p)})")
        s, v = float(p[0]), float(p[1])
        if s < 0.0:
            raise r.fail(key, f"path coordinates must be >= 0 (got s = {s:g})")
        if out and s <= out[-1][0]:
            raise r.fail(key, f"path coordinates must increase strictly (got s = {s:g} after {out[-1][0]:g})")
        if abs(v) > bound:
            raise r.fail(key, f"values must be within +-{bound:g} {unit} (got {v:g} at s = {s:g})")
        out.append((s, v))
    return tuple(out)


def _road_profile(r: Fields) -> RoadProfile:
    """The road's ``elevation_m`` or ``grade_percent`` and ``bank_deg`` profiles (docs/SCENARIOS.md)."""
    if r.has("elevation_m") and r.has("grade_percent"):
        raise r.fail("grade_percent", "give elevation_m or grade_percent, not both")
    elevation = grade = bank = ()
    if r.has("elevation_m"):
        elevation = _profile_points(r, "elevation_m", "m", MAX_ELEVATION_M)
    if r.has("grade_percent"):
        grade = tuple((s, v / 100.0) for s, v in _profile_points(r, "grade_percent", "%", MAX_GRADE_PERCENT))
    if r.has("bank_deg"):
        bank = tuple((s, math.radians(v)) for s, v in _profile_points(r, "bank_deg", "deg", MAX_BANK_DEG))
    profile = RoadProfile(elevation_m=elevation, grade=grade, bank_rad=bank)
    if elevation:
        steepest, at = profile.max_abs_grade()
        if steepest > MAX_GRADE_PERCENT / 100.0 + 1e-12:
            raise r.fail("elevation_m", f"the interpolated road is steeper than {MAX_GRADE_PERCENT:g} % "
                                        f"({100.0 * steepest:.1f} % at s = {at:.1f} m): spread the points")
    return profile


def _outages(f: Fields, source: str) -> tuple[Outage, ...]:
    out = []
    for k, item in enumerate(f.items("outages", [])):
        g = Fields(item, source=source, error=ScenarioError, prefix=f"outages[{k}]")
        sensor = g.string("sensor", choices=SENSOR_NAMES)
        if not (g.has("t_s") or g.has("x_m")):
            raise g.fail("t_s", "give a time window t_s: [t0, t1] and/or a zone x_m: [x0, x1]")
        t0, t1 = (0.0, math.inf)
        if g.has("t_s"):
            t0, t1 = parse_interval(g.raw("t_s"), f"{g.prefix}.t_s", source)
        xr = None
        if g.has("x_m"):
            xr = parse_interval(g.raw("x_m"), f"{g.prefix}.x_m", source, allow_infinite_end=False)
        g.done()
        out.append(Outage(sensor, t0, t1, xr))
    return tuple(out)


def _lane_gaps(f: Fields, source: str) -> tuple[tuple[float, float], ...]:
    out = []
    for k, item in enumerate(f.items("lane_gaps", [])):
        g = Fields(item, source=source, error=ScenarioError, prefix=f"lane_gaps[{k}]")
        s0, s1 = parse_interval(g.raw("s_m"), f"{g.prefix}.s_m", source, allow_infinite_end=False)
        if s0 < 0.0:
            raise g.fail("s_m", f"must start at s >= 0 (got {s0:g})")
        g.done()
        out.append((s0, s1))
    return tuple(sorted(out))


def _events(f: Fields, source: str, duration: float) -> tuple[tuple[float, str], ...]:
    out = []
    for k, item in enumerate(f.items("events", [])):
        g = Fields(item, source=source, error=ScenarioError, prefix=f"events[{k}]")
        t = g.number("t_s", lo=0.0, hi=duration)
        label = g.string("label")
        g.done()
        out.append((t, label))
    return tuple(sorted(out))


def _tags(f: Fields) -> tuple[str, ...]:
    tags = f.items("tags", [])
    for t in tags:
        if not isinstance(t, str) or not t.strip():
            raise f.fail("tags", f"each tag must be a non-empty string (got {short_repr(t)})")
    return tuple(tags)


def _needed_road_length(initial_speed: float, duration: float, driver: DriverSpec, lead: LeadSpec | None) -> float:
    """Distance the car (or the lead car) can cover in the run, plus a margin [m]."""
    sp = driver.speed
    v = max([initial_speed, sp.target_mps or 0.0, *(p[1] for p in sp.points)])
    need = v * duration
    if lead is not None:
        need = max(need, lead.initial_gap_m + max(p[1] for p in lead.speed_points) * duration)
    return need + ROAD_MARGIN_M


def parse_scenario(data: dict[str, Any], source: str) -> Scenario:
    """Validate a scenario mapping (as read from YAML) and build a ``Scenario``."""
    f = Fields(data, source=source, error=ScenarioError)
    name = f.string("name")
    stem = Path(source).stem
    if Path(source).suffix.lower() in (".yaml", ".yml") and name != stem:
        raise f.fail("name", f"must equal the file name {stem!r} (got {short_repr(name)})")
    description = f.string("description", "")
    standard = f.string("standard", "")
    tags = _tags(f)
    base = Path(source).parent
    vehicle = _vehicle_ref(f.string("vehicle"), source, "vehicle", base)
    duration = f.number("duration_s", lo=0.0, hi=3600.0, lo_open=True)
    v0 = f.number("initial_speed_mps", hi=100.0)
    if v0 < MIN_INITIAL_SPEED_MPS:
        raise f.fail("initial_speed_mps", f"{v0:g} m/s is below what the tire model supports "
                                          f"(>= {MIN_INITIAL_SPEED_MPS:g} m/s)")
    seed = f.number("seed", 0, lo=0.0, hi=2.0**63 - 1, integer=True)
    road_look = _road(f, source)
    friction_block = f.raw("friction", None)
    friction = FrictionMap() if friction_block is None else parse_friction(friction_block, source)
    driver = parse_driver(f.raw("driver"), source)
    lead_block = f.raw("lead", None)
    lead = None if lead_block is None else parse_lead(lead_block, source)
    if driver.speed.type == "follow_lead" and lead is None:
        raise f.fail("driver.speed.type", "follow_lead needs a lead: block (got no lead)")
    sens = f.sub("sensors", {})
    preset = sens.string("preset", "automotive", choices=_sensor_presets())
    overrides = sens.raw("overrides", {})
    if not isinstance(overrides, dict):
        raise sens.fail("overrides", f"must be a mapping (got {short_repr(overrides)})")
    sens.done()
    outages = _outages(f, source)
    lane_gaps = _lane_gaps(f, source)
    events = _events(f, source, duration)
    f.done()

    need = _needed_road_length(v0, duration, driver, lead)
    if road_look is None:
        road, look = Road.straight_default(need), 0.5
    else:
        road, look = road_look[0].with_length_at_least(need), road_look[1]
    return Scenario(name=name, description=description, standard=standard, tags=tags, vehicle=vehicle,
                    duration_s=duration, initial_speed_mps=v0, road=road, lookahead_m=look,
                    friction=friction, driver=driver, lead=lead, sensors=preset, sensor_overrides=overrides,
                    outages=outages, lane_gaps=lane_gaps, events=events, seed=int(seed), path=source)


def _sensor_presets() -> tuple[str, ...]:
    """The three standard presets plus any preset file the sensors package ships."""
    d = Path(str(files("roadtruth.harness"))) / "sensors" / "presets"
    found = {p.stem for p in d.glob("*.yaml")} if d.is_dir() else set()
    return tuple(sorted(set(SENSOR_PRESETS) | found))
