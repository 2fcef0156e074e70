"""Scenario files are parsed once per process and read again when they change.

A suite validates, prepares and runs each scenario several times and a sweep loads one scenario for
every case, so ``load_scenario`` keeps what it built (``roadtruth.harness.files.parsed_files``).
These tests pin what that must not cost: an edited file is read again (even an edit of the same
size, and even one within the file system's clock tick), a caller cannot change what the next
caller gets, and the result does not depend on which caller came first.
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from roadtruth.harness.files import parsed_files, strict_yaml
from roadtruth.harness.files.parsed_files import RACY_WINDOW_NS, ParsedFiles
from roadtruth.harness.truth import scenario as scenario_module
from roadtruth.harness.truth.scenario import available_scenarios, load_scenario, scenarios_dir, suite
from roadtruth.harness.truth.vehicle import vehicles_dir

OLD_NS = 100 * RACY_WINDOW_NS  # far older than the racy window: only the stat key tells versions apart


@pytest.fixture
def step_steer_copy(tmp_path: Path) -> Path:
    p = tmp_path / "step_steer.yaml"
    shutil.copy(scenarios_dir() / "step_steer.yaml", p)
    return p


def _set_mtime_ns(path: Path, mtime_ns: int) -> None:
    os.utime(path, ns=(mtime_ns, mtime_ns))


def _edit_same_size(path: Path, old: str, new: str) -> None:
    assert len(old) == len(new)
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))


def _count_calls(monkeypatch: pytest.MonkeyPatch, module: object, name: str) -> list[int]:
    calls: list[int] = []
    real = getattr(module, name)

    def counted(*args: object, **kwargs: object) -> object:
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, counted)
    return calls


def test_a_file_is_parsed_and_built_once_while_unchanged(step_steer_copy: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    yaml_reads = _count_calls(monkeypatch, strict_yaml, "load_mapping")
    builds = _count_calls(monkeypatch, scenario_module, "parse_scenario")
    _set_mtime_ns(step_steer_copy, time.time_ns() - OLD_NS)
    first = [load_scenario(step_steer_copy) for _ in range(5)]
    assert len(yaml_reads) == 1 and len(builds) == 1
    assert all(s.road is first[0].road and s.driver == first[0].driver for s in first)


def test_an_edit_of_the_same_size_is_seen_through_the_modification_time(step_steer_copy: Path) -> None:
    """Both versions are older than the racy window, so only (mtime, size) can tell them apart:
    a key that ignored the modification time would hand out the 5 s scenario twice."""
    now = time.time_ns()
    _set_mtime_ns(step_steer_copy, now - 2 * OLD_NS)
    assert load_scenario(step_steer_copy).duration_s == 5.0
    _edit_same_size(step_steer_copy, "duration_s: 5.0", "duration_s: 7.0")
    _set_mtime_ns(step_steer_copy, now - OLD_NS)
    assert load_scenario(step_steer_copy).duration_s == 7.0


def test_an_edit_within_one_clock_tick_is_seen_through_the_content(step_steer_copy: Path) -> None:
    """Same size and the very same modification time (as two writes within one mtime tick give):
    the file is young, so the entry was stored with the digest of its bytes, and the hit compares it."""
    stamp = time.time_ns()
    _set_mtime_ns(step_steer_copy, stamp)
    assert load_scenario(step_steer_copy).initial_speed_mps == 20.0
    _edit_same_size(step_steer_copy, "initial_speed_mps: 20.0", "initial_speed_mps: 25.0")
    _set_mtime_ns(step_steer_copy, stamp)
    assert load_scenario(step_steer_copy).initial_speed_mps == 25.0


def test_a_young_entry_is_trusted_by_its_stat_key_once_the_file_has_aged(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    p = tmp_path / "x.txt"
    p.write_text("one")
    cache, parses = ParsedFiles(), []
    young = time.time_ns()
    _set_mtime_ns(p, young)
    assert cache.get(p, lambda: parses.append(1) or p.read_text()) == "one"
    digests = _count_calls(monkeypatch, parsed_files, "_digest")
    monkeypatch.setattr(parsed_files.time, "time_ns", lambda: young + 2 * RACY_WINDOW_NS)
    for _ in range(3):
        assert cache.get(p, lambda: parses.append(1) or p.read_text()) == "one"
    assert len(parses) == 1 and len(digests) == 1  # compared once after ageing, then trusted


def test_a_caller_cannot_change_what_the_next_caller_gets(step_steer_copy: Path) -> None:
    a = load_scenario(step_steer_copy)
    a.sensor_overrides["imu"] = {"gyro_noise_density": 1.0}  # the one mutable field of a Scenario
    with pytest.raises(ValueError):
        a.road.samples[0, 1] = 99.0  # the road's samples are read-only
    b = load_scenario(step_steer_copy)
    assert b.sensor_overrides == {} and b.sensor_overrides is not a.sensor_overrides
    assert b.road.samples[0, 1] == 0.0
    # The --vehicle / --friction overrides make new scenarios; the stored one keeps its own.
    a.with_vehicle("wang2014")
    a.with_friction(0.3)
    c = load_scenario(step_steer_copy)
    assert c.vehicle == "sedan" and c.friction.mu_default == 1.0


def test_nested_overrides_are_private_copies(step_steer_copy: Path) -> None:
    step_steer_copy.write_text(step_steer_copy.read_text().replace(
        "sensors: {preset: automotive}",
        "sensors: {preset: automotive, overrides: {imu: {rate_hz: 100.0, delay_s: [0.01]}}}"))
    a = load_scenario(step_steer_copy)
    a.sensor_overrides["imu"]["rate_hz"] = 1.0  # nested dict and list: the copy must be deep
    a.sensor_overrides["imu"]["delay_s"].append(0.5)
    a.sensor_overrides["gnss"] = {}
    assert load_scenario(step_steer_copy).sensor_overrides == {"imu": {"rate_hz": 100.0, "delay_s": [0.01]}}


def test_the_path_is_kept_as_spelled_and_a_relative_vehicle_follows_the_working_folder(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    scen_dir, elsewhere, work = tmp_path / "scenarios", tmp_path / "elsewhere", tmp_path / "work"
    for d in (scen_dir, elsewhere, work):
        d.mkdir()
    text = (scenarios_dir() / "step_steer.yaml").read_text().replace("vehicle: sedan", "vehicle: car.yaml")
    (scen_dir / "step_steer.yaml").write_text(text)
    shutil.copy(vehicles_dir() / "sedan.yaml", scen_dir / "car.yaml")
    shutil.copy(vehicles_dir() / "sedan.yaml", work / "car.yaml")
    _set_mtime_ns(scen_dir / "step_steer.yaml", time.time_ns() - OLD_NS)

    monkeypatch.chdir(work)  # car.yaml exists here: the scenario names the working folder's file
    assert load_scenario(scen_dir / "step_steer.yaml").vehicle == "car.yaml"
    monkeypatch.chdir(elsewhere)  # not here: it is the one next to the scenario
    assert load_scenario(scen_dir / "step_steer.yaml").vehicle == str(scen_dir / "car.yaml")
    spelled = scen_dir / ".." / "scenarios" / "step_steer.yaml"
    assert load_scenario(spelled).path == str(spelled)
    assert load_scenario(scen_dir / "step_steer.yaml").path == str(scen_dir / "step_steer.yaml")


def test_suites_from_headers_equal_suites_from_full_loads() -> None:
    loaded = [load_scenario(n) for n in available_scenarios()]
    tags = sorted({t for s in loaded for t in s.tags})
    for tag in tags:
        assert suite(tag) == [s.name for s in loaded if tag in s.tags]
    assert suite("all") == [s.name for s in loaded]


def test_a_repeated_load_gives_equal_scenarios(step_steer_copy: Path) -> None:
    a, b = load_scenario(step_steer_copy), load_scenario(step_steer_copy)
    for f in ("name", "duration_s", "initial_speed_mps", "vehicle", "friction", "driver", "lead", "seed",
              "outages", "events", "lane_gaps", "tags", "sensors", "sensor_overrides", "path"):
        assert getattr(a, f) == getattr(b, f)
    np.testing.assert_array_equal(a.road.samples, b.road.samples)


def test_a_scenario_s_vehicle_is_parsed_once_and_an_edit_is_seen(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from roadtruth.harness.truth import vehicle as vehicle_module

    car = tmp_path / "car.yaml"
    text = (vehicles_dir() / "sedan.yaml").read_text()
    car.write_text(text)
    scen = tmp_path / "step_steer.yaml"
    scen.write_text((scenarios_dir() / "step_steer.yaml").read_text().replace("vehicle: sedan", f"vehicle: {car}"))
    now = time.time_ns()
    _set_mtime_ns(car, now - 2 * OLD_NS)
    parses = _count_calls(monkeypatch, vehicle_module, "parse_vehicle")
    sc = load_scenario(scen)
    first = [sc.vehicle_params() for _ in range(3)]
    assert len(parses) == 1 and all(v is first[0] for v in first)
    assert first[0].mass_kg == 1500.0
    _edit_same_size(car, "mass_kg: 1500.0", "mass_kg: 1600.0")
    _set_mtime_ns(car, now - OLD_NS)
    assert load_scenario(scen).vehicle_params().mass_kg == 1600.0 and len(parses) == 2



def test_a_thresholds_file_is_parsed_once_and_an_edit_is_seen(tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    # A stress page looks up the shipped CI limits once per breaking point.
    from roadtruth.harness.jobs import check_rules
    from roadtruth.harness.report.stress_report import rmse_threshold

    f = tmp_path / "ci.yaml"
    f.write_text("rules:\n  - {metric: rmse, state: beta_rad, max: 0.0350}\n")
    now = time.time_ns()
    _set_mtime_ns(f, now - 2 * OLD_NS)
    parses = _count_calls(monkeypatch, check_rules, "_parse_thresholds")
    first = [check_rules.load_thresholds(f) for _ in range(3)]
    assert len(parses) == 1 and all(t is first[0] for t in first)
    assert first[0].rules[0].max == 0.035
    assert rmse_threshold("step_steer", "kf_bicycle", "beta_rad", first[0].rules)[0] == 0.035
    _edit_same_size(f, "max: 0.0350", "max: 0.0420")
    _set_mtime_ns(f, now - OLD_NS)
    assert check_rules.load_thresholds(f).rules[0].max == 0.042 and len(parses) == 2
    shipped = [check_rules.load_thresholds(check_rules.DEFAULT_THRESHOLDS) for _ in range(2)]
    assert shipped[0] is shipped[1]

# ---- the YAML reader: libyaml's parser under the module's own rules --------------------------------

def _shipped_yaml_files() -> list[Path]:
    root = Path(strict_yaml.__file__).resolve().parents[1]  # the harness package folder
    return sorted(root.rglob("*.yaml"))


def test_libyaml_and_pure_python_parsing_give_identical_values_for_every_shipped_file() -> None:
    files = _shipped_yaml_files()
    assert len(files) >= 20
    for f in files:
        text = f.read_text(encoding="utf-8")
        fast, pure = strict_yaml.parse_yaml(text), strict_yaml.parse_yaml(text, pure_python=True)
        assert repr(fast) == repr(pure), f  # repr: also the types (1 vs 1.0, '1' vs 1)


@pytest.mark.parametrize("pure_python", [False, True])
def test_the_module_rules_hold_with_either_parser(pure_python: bool) -> None:
    parse = lambda text: strict_yaml.parse_yaml(text, pure_python=pure_python)  # noqa: E731
    assert parse("a: 1e-3\nd: 0123\ne: yes\ng: 2024-05-02\nm: {<<: {x: 1}, y: 2}\n") == {
        "a": 1e-3, "d": 123, "e": "yes", "g": "2024-05-02", "m": {"x": 1, "y": 2}}
    nested = "".join("  " * i + f"k{i}:\n" for i in range(80)) + "  " * 80 + "v: 1\n"
    for text, message in ((nested, "nested deeper than 64 levels"), ("a: " + "[" * 70 + "]" * 70, "nested deeper"),
                          ("a: " + "[" * 5000 + "]" * 5000, "nested deeper than 64 levels"), ("a: 1\nb: 2\na: 3\n", "duplicate key 'a'"),
                          ("1: a\n", "mapping key 1 is not a string"), ("a: &a [*a]\n", "infinite expansion")):
        with pytest.raises(strict_yaml.yaml.YAMLError, match=message) as err:
            parse(text)
        assert err.value.problem_mark is not None


def test_a_malformed_file_is_one_line_with_its_line_number(tmp_path: Path) -> None:
    from roadtruth.harness.errors import ScenarioError

    p = tmp_path / "broken.yaml"
    p.write_text("name: broken\nvehicle: sedan\nduration_s: [1,\n")
    with pytest.raises(ScenarioError, match=r"broken\.yaml: malformed YAML at line 4: ") as err:
        strict_yaml.load_mapping(p, ScenarioError)
    assert "\n" not in str(err.value)
