"""The truth with the other tire models of a vehicle file: an MF 6.1 tire property file (.tir) and a
Fiala brush tire. Each car runs the same manoeuvres as the Magic Formula sedan: the observers' per-axle
Magic Formula is fitted to the truth tire, the linear range follows the linear car, a brake to a stop
ends at rest, and the compiled loop equals the interpreted one bit for bit."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from roadtruth.harness.errors import VehicleError
from roadtruth.harness.truth.scenario import load_scenario, parse_scenario
from roadtruth.harness.truth.simulate import simulate
from roadtruth.harness.truth.suspension_statics import linear_understeer_gradient
from roadtruth.harness.truth.tire_file import read_tire_file, shipped_tire_path
from roadtruth.harness.truth.tire_mf61 import cornering_stiffness
from roadtruth.harness.truth.vehicle import Aero, load_vehicle

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "vehicles"


def _step(amplitude_deg: float, duration: float = 4.0):
    return parse_scenario({"name": "t", "vehicle": "sedan", "duration_s": duration, "initial_speed_mps": 20.0,
                           "driver": {"steer": {"type": "step", "t_start_s": 0.5, "amplitude_deg": amplitude_deg}}},
                          "t")


def _lateral_only(v):
    return dataclasses.replace(v, aero=Aero(), tires=dataclasses.replace(v.tires, rolling_resistance=0.0))


@pytest.fixture(scope="module")
def mf61():
    return load_vehicle(EXAMPLES / "compact_mf61.yaml")


@pytest.fixture(scope="module")
def fiala():
    return load_vehicle(EXAMPLES / "sedan_fiala.yaml")


def test_mf61_vehicle_gets_the_files_cornering_stiffness(mf61) -> None:
    tf = read_tire_file(shipped_tire_path("mf61_205_60R15"))
    fz_wheel = mf61.fz_front_static_N / 2.0
    assert mf61.tires.model == "mf61" and mf61.tires.file.endswith("mf61_205_60R15.tir")
    # The observers' axle stiffness B C F_z equals the file's slope at the static wheel load (x 2 wheels).
    assert mf61.cornering_stiffness_f_Npr == pytest.approx(2.0 * cornering_stiffness(tf, fz_wheel), rel=0.01)
    assert "fitted to mf61_205_60R15.tir" in mf61.tires.front.stiffness_source
    assert 0.01 < mf61.tires.front.trail_m < 0.06  # pneumatic trail of a car tire


def test_fiala_vehicle_keeps_its_stated_axle_stiffness(fiala) -> None:
    assert fiala.cornering_stiffness_f_Npr == pytest.approx(120e3, rel=0.01)
    assert fiala.cornering_stiffness_r_Npr == pytest.approx(142e3, rel=0.01)
    assert fiala.tires.front.trail_m == pytest.approx(0.09 / 3.0)  # brush trail a/3


def test_fiala_linear_range_follows_the_linear_car(fiala) -> None:
    v = _lateral_only(fiala)
    late = simulate(_step(0.5), v).frame.query("t_s > 3.0")
    vx, delta, r = late.vx_mps.mean(), late.delta_rad.mean(), late.yaw_rate_radps.mean()
    k = linear_understeer_gradient(v)
    assert r == pytest.approx(vx * delta / (v.wheelbase_m + k * vx**2), rel=0.015)


def test_mf61_car_understeers_more_than_its_fitted_bicycle_model(mf61) -> None:
    """The file's cornering stiffness falls off with load (and its trail and camber act): with lateral load
    transfer the car needs more steer than the bicycle model built from the fitted axle stiffness."""
    v = _lateral_only(mf61)
    tr = simulate(_step(0.5), v)
    assert tr.status == "ok"
    late = tr.frame.query("t_s > 3.0")
    vx, delta, r = late.vx_mps.mean(), late.delta_rad.mean(), late.yaw_rate_radps.mean()
    assert 1.02 < v.steady_yaw_rate(vx, delta) / r < 1.15


@pytest.mark.parametrize("vehicle", ["compact_mf61", "sedan_fiala"])
def test_brake_to_stop_ends_at_rest_with_each_tire_model(vehicle: str) -> None:
    v = load_vehicle(EXAMPLES / f"{vehicle}.yaml")
    tr = simulate(load_scenario("brake_to_stop"), v)
    f = tr.frame
    assert tr.status == "ok" and [e.kind for e in tr.truth_events] == ["stopped"]
    rest = f[f.t_s > f.t_s.iloc[-1] - 2.0]
    assert np.abs(rest.vx_mps).max() < 0.01 and np.abs(rest.vy_mps).max() < 0.01
    assert math.hypot(rest.x_m.iloc[-1] - rest.x_m.iloc[0], rest.y_m.iloc[-1] - rest.y_m.iloc[0]) < 0.005


@pytest.mark.parametrize("vehicle", ["compact_mf61", "sedan_fiala"])
def test_compiled_loop_equals_interpreted_loop(vehicle: str) -> None:
    v = load_vehicle(EXAMPLES / f"{vehicle}.yaml")
    sc = parse_scenario({"name": "t", "vehicle": "sedan", "duration_s": 0.12, "initial_speed_mps": 20.0,
                         "driver": {"steer": {"type": "step", "t_start_s": 0.0, "amplitude_deg": 10.0}}}, "t")
    a, b = simulate(sc, v), simulate(sc, v, compiled=False)
    assert np.array_equal(a.frame.to_numpy(), b.frame.to_numpy(), equal_nan=True)
    assert np.abs(a.frame.alpha_fl_rad).max() > 0.02


def test_missing_tire_file_is_one_field_error(tmp_path: Path) -> None:
    text = (EXAMPLES / "compact_mf61.yaml").read_text().replace("file: mf61_205_60R15", "file: nowhere.tir")
    p = tmp_path / "car.yaml"
    p.write_text(text)
    with pytest.raises(VehicleError, match=r"tires\.file: .*nowhere\.tir.*not found"):
        load_vehicle(p)


def test_leaving_the_tire_files_range_is_a_truth_event(mf61) -> None:
    tf = read_tire_file(shipped_tire_path("mf61_205_60R15"))
    small = simulate(_step(0.5, 2.0), mf61)
    assert not [e for e in small.truth_events if e.kind == "tire beyond its data"]
    hard = simulate(_step(20.0, 2.0), mf61)
    beyond = [e for e in hard.truth_events if e.kind == "tire beyond its data"]
    assert beyond, [(e.kind, e.detail) for e in hard.truth_events]
    f = hard.frame
    # the event's time is the first sample where a range is left while rolling
    k = int(np.searchsorted(f.t_s.to_numpy(), beyond[0].t_s))
    a = f[[f"alpha_{w}_rad" for w in ("fl", "fr", "rl", "rr")]].to_numpy()
    kap = f[[f"kappa_{w}" for w in ("fl", "fr", "rl", "rr")]].to_numpy()
    out = (a > -tf.alpmin_rad) | (a < -tf.alpmax_rad) | (kap < tf.kpumin) | (kap > tf.kpumax)
    assert out[k].any() or "gamma" in beyond[0].detail or "fz" in beyond[0].detail
