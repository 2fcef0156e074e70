"""Published JSON Schemas of the YAML formats, and YAML 1.2 number reading in every loader."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import jsonschema
import pytest
import yaml

from roadtruth.harness import cli
from roadtruth.harness.errors import InputError
from roadtruth.harness.files.config_schema import FORMATS, schema, shipped_files
from roadtruth.harness.files.strict_yaml import load_mapping, parse_yaml
from roadtruth.harness.truth.scenario import parse_scenario
from roadtruth.harness.truth.vehicle import parse_vehicle

ROOT = Path(__file__).resolve().parents[1]


def _validator(fmt: str) -> jsonschema.Draft202012Validator:
    s = schema(fmt)
    jsonschema.Draft202012Validator.check_schema(s)
    return jsonschema.Draft202012Validator(s)


def test_cli_formats_are_the_schema_formats() -> None:
    assert cli._SCHEMA_FORMATS == FORMATS


@pytest.mark.parametrize("fmt", [f for f in FORMATS if shipped_files(f)])
def test_every_shipped_file_validates_against_its_schema(fmt: str) -> None:
    v = _validator(fmt)
    for p in shipped_files(fmt):
        errors = [f"{'/'.join(map(str, e.path))}: {e.message}" for e in v.iter_errors(load_mapping(p))]
        assert not errors, f"{p.name}: {errors[:3]}"


def test_every_shipped_yaml_has_a_format() -> None:
    covered = {p.resolve() for f in FORMATS for p in shipped_files(f)}
    shipped = [p for d in ("harness/vehicles", "harness/scenarios", "harness/sensors/presets", "harness/replay_maps",
                           "harness/thresholds", "examples") for p in (ROOT / d).rglob("*.yaml")]
    assert shipped and {p.resolve() for p in shipped} <= covered


def _sedan() -> dict:
    return load_mapping(ROOT / "harness/vehicles/sedan.yaml")


def _scenario() -> dict:
    return load_mapping(ROOT / "harness/scenarios/step_steer.yaml")


@pytest.mark.parametrize(("fmt", "base", "parse", "edit"), [
    ("vehicle", _sedan, parse_vehicle, lambda d: d.__setitem__("mass_kg", "heavy")),
    ("vehicle", _sedan, parse_vehicle, lambda d: d["suspension"].__setitem__("travel_m", [0.1])),
    ("vehicle", _sedan, parse_vehicle, lambda d: d.__setitem__("mass_kg", 1e6)),  # out of range
    ("vehicle", _sedan, parse_vehicle, lambda d: d["suspension"].__setitem__("travel_mm", 120)),  # typo
    ("scenario", _scenario, parse_scenario, lambda d: d.__setitem__("duration_s", "5 s")),
    ("scenario", _scenario, parse_scenario, lambda d: d["driver"]["steer"].__setitem__("type", "zigzag")),
    ("scenario", _scenario, parse_scenario, lambda d: d.__setitem__("seed", 1.5)),
])
def test_a_file_the_parser_rejects_is_rejected_by_the_schema(fmt, base, parse, edit, tmp_path: Path) -> None:
    data = copy.deepcopy(base())
    source = str(tmp_path / f"{data['name']}.yaml")
    parse(copy.deepcopy(data), source)  # the unedited mapping is valid for both
    assert not list(_validator(fmt).iter_errors(data))
    edit(data)
    with pytest.raises(InputError):
        parse(copy.deepcopy(data), source)
    assert list(_validator(fmt).iter_errors(data)), "the schema accepts what the parser rejects"


def test_schema_ranges_are_the_parser_ranges() -> None:
    s = schema("vehicle")
    assert s["properties"]["mass_kg"] == {"type": "number", "minimum": 50.0, "maximum": 40000.0}
    steer = schema("scenario")["properties"]["driver"]["properties"]["steer"]
    steer = next(v for v in steer.get("anyOf", [steer]) if v.get("type") == "object")
    from roadtruth.harness.truth.driver import STEER_TYPES

    assert set(steer["properties"]["type"]["enum"]) == set(STEER_TYPES)


def test_schema_command_prints_and_writes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["schema", "thresholds"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["$id"].endswith("thresholds.json") and "rules" in printed["properties"]
    out = tmp_path / "thresholds.schema.json"
    assert cli.main(["schema", "thresholds", "--out", str(out)]) == 0
    assert json.loads(out.read_text()) == printed
    assert cli.main(["schema", "thresholds", "--out", str(out)]) == 0  # its own file: rewritten
    mine = tmp_path / "notes.json"
    mine.write_text('{"mine": true}')
    capsys.readouterr()
    assert cli.main(["schema", "vehicle", "--out", str(mine)]) == 2
    assert mine.read_text() == '{"mine": true}'
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


# ---- YAML 1.2 numbers ---------------------------------------------------------------------------

def test_yaml_1_2_numbers() -> None:
    # PyYAML's own resolver (YAML 1.1) reads 1e-3 as text: why every loader goes through parse_yaml.
    assert yaml.safe_load("a: 1e-3")["a"] == "1e-3"
    d = parse_yaml("a: 1e-3\nb: 9.82e2\nc: -2E+1\nd: .5\ne: 0123\nf: yes\ng: 1:20\nh: 0x1F\ni: .inf")
    assert d["a"] == pytest.approx(1e-3) and isinstance(d["a"], float)
    assert d["b"] == pytest.approx(982.0) and d["c"] == pytest.approx(-20.0) and d["d"] == 0.5
    assert d["e"] == 123 and d["f"] == "yes" and d["g"] == "1:20" and d["h"] == 31 and d["i"] == float("inf")


def test_a_vehicle_file_with_exponent_numbers_loads(tmp_path: Path) -> None:
    from roadtruth.harness.truth.vehicle import load_vehicle

    text = (ROOT / "harness/vehicles/sedan.yaml").read_text()
    sedan = load_vehicle("sedan")
    edited = re.sub(r"(?m)^mass_kg:\s*[0-9.]+", f"mass_kg: {sedan.mass_kg / 1000:g}e3", text)
    assert edited != text
    p = tmp_path / "sedan.yaml"
    p.write_text(edited)
    assert load_vehicle(p).mass_kg == pytest.approx(sedan.mass_kg)


def test_no_loader_bypasses_the_yaml_1_2_reader() -> None:
    offenders = []
    for p in list((ROOT / "harness").rglob("*.py")) + list((ROOT / "observers").rglob("*.py")):
        if p.name == "strict_yaml.py":
            continue
        for n, line in enumerate(p.read_text().splitlines(), 1):
            if re.search(r"yaml\.(safe_load|load|full_load|unsafe_load|load_all|safe_load_all)\(", line):
                offenders.append(f"{p.relative_to(ROOT)}:{n}")
    assert not offenders
