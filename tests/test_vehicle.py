"""Vehicle parameter sets: every shipped set loads; derived bicycle figures; bad values are named."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from roadtruth.harness.errors import InputError, VehicleError
from roadtruth.harness.truth.vehicle import G, available_vehicles, load_vehicle, vehicles_dir


def test_required_sets_are_shipped() -> None:
    assert {"sedan", "wang2014", "yacine2016", "carla_bessafa", "ferrari_250lm"} <= set(available_vehicles())


@pytest.mark.parametrize("name", available_vehicles())
def test_every_set_loads_and_is_consistent(name: str) -> None:
    v = load_vehicle(name)
    assert v.fz_front_static_N + v.fz_rear_static_N == pytest.approx(v.mass_kg * G)
    # The MF initial slope summed over an axle equals the stated axle cornering stiffness.
    assert v.cornering_stiffness_f_Npr == pytest.approx(v.tires.front.By * v.tires.front.Cy * v.fz_front_static_N)


def test_derived_stiffness_matches_the_seed_values() -> None:
    w = load_vehicle("wang2014")
    assert w.cornering_stiffness_f_Npr == pytest.approx(76500.0)
    assert w.cornering_stiffness_r_Npr == pytest.approx(51000.0)
    # Seed 001's car is exactly neutral steer: a*Cf = b*Cr (digest 2.4).
    assert w.understeer_gradient_radpmps2 == pytest.approx(0.0, abs=1e-12)
    f = load_vehicle("ferrari_250lm")
    assert (f.cornering_stiffness_f_Npr, f.cornering_stiffness_r_Npr) == pytest.approx((7.0e4, 1.2e5))


def test_steady_yaw_rate_is_the_bicycle_formula() -> None:
    v = load_vehicle("sedan")
    delta, vx = math.radians(1.0), 20.0
    K = v.mass_kg / v.wheelbase_m * (v.lr_m / v.cornering_stiffness_f_Npr - v.lf_m / v.cornering_stiffness_r_Npr)
    assert v.steady_yaw_rate(vx, delta) == pytest.approx(vx * delta / (v.wheelbase_m + K * vx**2))
    assert K > 0  # the default sedan understeers


def _write(tmp_path: Path, change: dict, drop: str | None = None) -> Path:
    data = yaml.safe_load((vehicles_dir() / "sedan.yaml").read_text())
    for key, value in change.items():
        node = data
        parts = key.split(".")
        for p in parts[:-1]:
            node = node[p]
        node[parts[-1]] = value
    if drop:
        data.pop(drop)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"mass_kg": -1500.0}, "mass_kg"),
        ({"mass_kg": "heavy"}, "mass_kg"),
        ({"lf_m": 0.0}, "lf_m"),
        ({"tires.front.Cy": 9.0}, "tires.front.Cy"),
        ({"drivetrain.layout": "4x4"}, "drivetrain.layout"),
        ({"suspension.stiffnes_f_Npm": 1.0}, "suspension.stiffnes_f_Npm"),
        ({"colour": "red"}, "colour"),
    ],
)
def test_bad_values_name_file_and_field(tmp_path: Path, change: dict, field: str) -> None:
    with pytest.raises(VehicleError) as err:
        load_vehicle(_write(tmp_path, change))
    msg = str(err.value)
    assert "bad.yaml" in msg and field in msg
    assert "\n" not in msg
    assert isinstance(err.value, InputError) and isinstance(err.value, ValueError)


def test_missing_field_and_unknown_name(tmp_path: Path) -> None:
    with pytest.raises(VehicleError, match="yaw_inertia_kgm2: required field is missing"):
        load_vehicle(_write(tmp_path, {}, drop="yaw_inertia_kgm2"))
    with pytest.raises(VehicleError, match="unknown vehicle 'batmobile'"):
        load_vehicle("batmobile")


def test_malformed_yaml(tmp_path: Path) -> None:
    p = tmp_path / "broken.yaml"
    p.write_text("mass_kg: [1500\n")
    with pytest.raises(VehicleError, match="broken.yaml: malformed YAML"):
        load_vehicle(p)


def test_impossible_inertia_is_rejected(tmp_path: Path) -> None:
    with pytest.raises(VehicleError, match="pitch_inertia_kgm2: roll \\+ pitch inertia"):
        load_vehicle(_write(tmp_path, {"pitch_inertia_kgm2": 100.0}))
