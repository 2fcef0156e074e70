"""Scenario library and scenario-file validation."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from roadtruth.harness.errors import ScenarioError
from roadtruth.harness.truth.driver import DriverSpec
from roadtruth.harness.truth.friction_map import FrictionMap
from roadtruth.harness.truth.road import Road
from roadtruth.harness.truth.scenario import (
    Outage,
    Scenario,
    available_scenarios,
    load_scenario,
    scenario_summaries,
    scenarios_dir,
    suite,
)
from roadtruth.harness.truth.vehicle import load_vehicle

REQUIRED = {"step_steer", "sine_sweep", "double_lane_change", "constant_radius", "slalom", "fishhook",
            "sine_with_dwell", "brake_in_turn", "split_mu_braking", "mu_step", "curvy_road", "car_following",
            "gnss_outage"}


@pytest.fixture(scope="module")
def library() -> dict[str, Scenario]:
    return {n: load_scenario(n) for n in available_scenarios()}


def test_library_is_complete_and_loads(library: dict[str, Scenario]) -> None:
    assert REQUIRED <= set(library)
    for name, s in library.items():
        assert s.name == name and s.description and s.tags
        assert isinstance(s.road, Road) and isinstance(s.friction, FrictionMap)
        assert isinstance(s.driver, DriverSpec)
        load_vehicle(s.vehicle)
        # The road covers the run: the car cannot leave the sampled part at its top speed.
        top = max([s.initial_speed_mps, *(p[1] for p in s.driver.speed.points)])
        assert s.road.length_m >= top * s.duration_s
        # Each file says which standard it follows.
        text = Path(s.path).read_text()
        assert text.lstrip().startswith("#") and s.standard


def test_suites(library: dict[str, Scenario]) -> None:
    default, ci, stress = suite("default"), suite("ci"), suite("stress")
    assert 5 <= len(default) <= 7 and 2 <= len(ci) <= 3 and stress
    assert all(library[n].duration_s <= 10.0 for n in default)
    assert all(library[n].duration_s <= 6.0 for n in ci)
    # The stress suite is the friction one: each has a non-uniform map.
    assert all(not library[n].friction.is_uniform for n in stress)
    assert suite("all") == available_scenarios()
    with pytest.raises(ScenarioError, match="known: .*default"):
        suite("nonexistent")


def test_summaries() -> None:
    rows = scenario_summaries()
    assert [r["name"] for r in rows] == available_scenarios()
    for r in rows:
        assert set(r) == {"name", "description", "standard", "tags", "vehicle", "duration_s", "initial_speed_mps"}


def test_default_road_is_straight_along_x(library: dict[str, Scenario]) -> None:
    s = library["step_steer"]
    np.testing.assert_array_equal(s.road.samples[:, 2:5], 0.0)
    assert s.road.samples[0, 1] == 0.0


def test_double_lane_change_geometry(library: dict[str, Scenario]) -> None:
    road = library["double_lane_change"].road
    # ISO 3888-1: 3.5 m offset reached after 15 m + 30 m (+25 m run-up), held 25 m, back after 25 m.
    _, y, psi = road.pose_at(np.array([70.0, 82.5, 95.0, 120.0]))
    np.testing.assert_allclose(y, [3.5, 3.5, 3.5, 0.0], atol=1e-3)
    np.testing.assert_allclose(psi, 0.0, atol=1e-5)


def test_constant_radius_is_a_40m_circle(library: dict[str, Scenario]) -> None:
    road = library["constant_radius"].road
    np.testing.assert_allclose(road.curvature_at(np.array([60.0, 300.0, 800.0])), 1 / 40.0)


def test_outages_and_gaps(library: dict[str, Scenario]) -> None:
    g = library["gnss_outage"]
    assert 60.0 <= g.duration_s <= 90.0
    assert Outage("gnss", 0.0, math.inf, (500.0, 800.0)) in g.outages
    assert Outage("gnss", 66.0, 69.0, None) in g.outages
    assert library["curvy_road"].lane_gaps == ((110.0, 140.0),)
    assert library["car_following"].lead is not None


def test_outage_sensor_names_match_the_sensor_catalog() -> None:
    from roadtruth.harness.sensors.catalog import SENSORS
    from roadtruth.harness.truth.scenario import SENSOR_NAMES

    assert set(SENSOR_NAMES) == set(SENSORS) | {"all"}


def test_with_friction_and_vehicle(library: dict[str, Scenario], tmp_path: Path) -> None:
    s = library["mu_step"]
    assert s.with_friction("0.3").friction.mu(100.0, 0.0) == 0.3
    assert s.with_friction("ice").friction.is_uniform
    f = tmp_path / "f.yaml"
    f.write_text("mu_default: 0.5\n")
    assert s.with_friction(str(f)).friction.mu_default == 0.5
    assert s.friction.mu(130.0, 0.0) == 0.1  # the original is unchanged
    with pytest.raises(ScenarioError):
        s.with_friction("-2")
    assert s.with_vehicle("ferrari_250lm").vehicle == "ferrari_250lm"
    with pytest.raises(ScenarioError, match="unknown vehicle"):
        s.with_vehicle("tractor")


# ---- bad input -----------------------------------------------------------------------------------

def _base() -> dict[str, Any]:
    return yaml.safe_load((scenarios_dir() / "curvy_road.yaml").read_text())


def _write(tmp_path: Path, data: dict[str, Any], stem: str = "curvy_road") -> Path:
    p = tmp_path / f"{stem}.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _set(data: dict[str, Any], path: str, value: Any) -> None:
    keys = path.split(".")
    for k in keys[:-1]:
        data = data[int(k)] if isinstance(data, list) else data[k]
    if value is _DELETE:
        del data[keys[-1]]
    else:
        data[keys[-1]] = value


_DELETE = object()

BAD = [
    ("colour", "red", "colour"),
    ("duration_s", _DELETE, "duration_s"),
    ("duration_s", 0.0, "duration_s"),
    ("duration_s", "long", "duration_s"),
    ("initial_speed_mps", 2.0, "below what the tire model supports"),
    ("initial_speed_mps", 2.0, "initial_speed_mps"),
    ("vehicle", "tractor", "vehicle"),
    ("vehicle", _DELETE, "vehicle"),
    ("name", "other_name", "name"),
    ("tags", "default", "tags"),
    ("seed", 1.5, "seed"),
    ("friction", {"mu_default": 0.0}, "friction.mu_default"),
    ("friction", {"mu_default": -1.0}, "friction.mu_default"),
    ("road.segments", [{"spiral": {"length_m": 10}}], "road.segments[0]"),
    ("road.segments", [{"arc": {"length_m": -5}}], "road.segments[0].arc.length_m"),
    ("road.segments", [{"clothoid": {"length_m": 5}}], "road.segments[0].clothoid.curvature_end_1pm"),
    ("road.lane_width_m", 0.5, "road.lane_width_m"),
    ("road.start", {"x_m": 0, "heading": 3}, "road.start.heading"),
    ("driver", _DELETE, "driver"),
    ("driver.steer.type", "wobble", "driver.steer.type"),
    ("driver.speed", {"type": "follow_lead"}, "driver.speed.type"),
    ("lead", {"initial_gap_m": 30.0}, "lead.speed_points"),
    ("sensors", {"preset": "perfect"}, "sensors.preset"),
    ("outages", [{"sensor": "lidar", "t_s": [1, 2]}], "outages[0].sensor"),
    ("outages", [{"sensor": "gnss"}], "outages[0]"),
    ("outages", [{"sensor": "gnss", "x_m": [9, 3]}], "outages[0].x_m"),
    ("lane_gaps", [{"s_m": [5]}], "lane_gaps[0].s_m"),
    ("events", [{"t_s": 99.0, "label": "late"}], "events[0].t_s"),
]


@pytest.mark.parametrize("path, value, expected", BAD,
                         ids=[(f"{p}=<deleted>" if v is _DELETE else f"{p}={v!r}")[:40] for p, v, _ in BAD])
def test_bad_scenarios_rejected(tmp_path: Path, path: str, value: Any, expected: str) -> None:
    data = copy.deepcopy(_base())
    _set(data, path, value)
    p = _write(tmp_path, data)
    with pytest.raises(ScenarioError) as err:
        load_scenario(p)
    msg = str(err.value)
    assert str(p) in msg and expected in msg and "\n" not in msg


def test_unknown_scenario_names_the_available_ones() -> None:
    with pytest.raises(ScenarioError, match="step_steer"):
        load_scenario("no_such_scenario")


def test_malformed_yaml(tmp_path: Path) -> None:
    p = tmp_path / "broken.yaml"
    p.write_text("name: broken\nduration_s: [1,\n")
    with pytest.raises(ScenarioError, match="malformed YAML"):
        load_scenario(p)


def test_minimal_file_gets_defaults(tmp_path: Path) -> None:
    p = _write(tmp_path, {"name": "tiny", "vehicle": "sedan", "duration_s": 3.0, "initial_speed_mps": 10.0,
                          "driver": {}}, stem="tiny")
    s = load_scenario(p)
    assert s.friction.mu_default == 1.0 and s.friction.is_uniform
    assert s.road.length_m >= 30.0 and s.lookahead_m == 0.5 and s.sensors == "automotive"
    assert s.lead is None and s.outages == () and s.seed == 0
