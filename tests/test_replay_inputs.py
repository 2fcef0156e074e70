"""Replaying recordings of other cars: sample-rate time, derived channels, the vehicle, replay vehicles,
sign/unit consistency, absolute clocks, and the MDF4 / ROS 2 MCAP readers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.io
import yaml

from roadtruth.harness.cli import main
from roadtruth.harness.errors import LogError, VehicleError
from roadtruth.harness.jobs.replay import prepare_log, replay
from roadtruth.harness.jobs.replay_channels import causal_derivative
from roadtruth.harness.jobs.replay_log import load_column_map
from roadtruth.harness.truth.vehicle import load_vehicle

L, K = 2.62, 0.0015  # wheelbase of the replay vehicle below [m], understeer gradient [rad/(m/s^2)]
RATIO, RADIUS = 15.2, 0.31

REPLAY_VEHICLE = {
    "kind": "replay", "name": "test_hatchback", "mass_kg": 1450.0, "yaw_inertia_kgm2": 2300.0, "lf_m": 1.05,
    "lr_m": 1.57, "cornering_stiffness_f_Npr": 110000.0, "cornering_stiffness_r_Npr": 130000.0, "grip": 1.0,
    "steering_ratio": RATIO, "wheel_radius_m": RADIUS,
}


def drive(n: int = 2000, rate_hz: float = 100.0) -> pd.DataFrame:
    """A car on a slow steering sine at 18…22 m/s, in SI with ISO 8855 signs (left positive)."""
    t = np.arange(n) / rate_hz
    vx = 20.0 + 2.0 * np.sin(2 * np.pi * 0.05 * t)
    delta = 0.04 * np.sin(2 * np.pi * 0.2 * t)
    r = vx * delta / (L + K * vx**2)
    beta = 0.2 * delta
    return pd.DataFrame({"t_s": t, "vx_mps": vx, "delta_rad": delta, "yaw_rate_radps": r, "ay_mps2": vx * r,
                         "ax_mps2": np.gradient(vx, t), "beta_rad": beta, "vy_mps": vx * np.tan(beta),
                         "omega_rl_radps": vx / RADIUS, "omega_rr_radps": vx / RADIUS})


def write_yaml(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture
def car(tmp_path: Path) -> Path:
    return write_yaml(tmp_path / "hatchback.yaml", REPLAY_VEHICLE)


def one_error_line(capsys: pytest.CaptureFixture[str], argv: list[str], *needles: str) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, (n, err)
    return err


# ---- 1. a MATLAB file without a time vector ------------------------------------------------------

def test_mat_file_without_time_is_replayed_from_a_sample_rate(tmp_path: Path, car: Path) -> None:
    d = drive(rate_hz=200.0)
    mat = tmp_path / "vw.mat"
    scipy.io.savemat(mat, {"Messung": {"Gier": np.degrees(d.yaw_rate_radps.to_numpy()), "v": d.vx_mps.to_numpy() * 3.6,
                                       "Lenk": d.delta_rad.to_numpy()}})
    cmap = write_yaml(tmp_path / "vw.yaml", {
        "time": {"rate_hz": 200}, "yaw_rate_radps": {"column": "Gier", "unit": "deg/s"},
        "vx_mps": {"column": "v", "unit": "km/h"}, "delta_rad": "Lenk",
        "measured": ["yaw_rate_radps", "vx_mps", "delta_rad"], "reference": ["vx_mps"]})
    rl = prepare_log(mat, cmap)
    assert np.array_equal(rl.frame.t_s.to_numpy(), np.arange(len(d)) / 200.0)
    assert rl.frame.vx_mps.to_numpy() == pytest.approx(d.vx_mps.to_numpy(), rel=1e-12)
    # the same with --rate-hz on a map without time, through the CLI
    no_time = write_yaml(tmp_path / "vw2.yaml", {**yaml.safe_load(cmap.read_text())})
    data = yaml.safe_load(no_time.read_text())
    data.pop("time")
    write_yaml(no_time, data)
    out = tmp_path / "out"
    assert main(["replay", str(mat), "--columns", str(no_time), "--rate-hz", "200", "--vehicle", str(car),
                 "--observer", "kf_bicycle", "--out", str(out)]) == 0
    truth = pd.read_csv(out / "vw" / "truth.csv")
    assert truth.t_s.iloc[-1] == pytest.approx((len(d) - 1) / 200.0, abs=1e-9)


def test_rate_and_time_column_together_are_refused(tmp_path: Path) -> None:
    cmap = write_yaml(tmp_path / "m.yaml", {"time": {"column": "t", "rate_hz": 100}, "vx_mps": "v",
                                            "measured": ["vx_mps"]})
    with pytest.raises(LogError, match="time.rate_hz: give either a time column or rate_hz, not both"):
        load_column_map(cmap)
    d = drive()
    d.to_csv(tmp_path / "log.csv", index=False)
    with pytest.raises(LogError, match="either a time column or --rate-hz"):
        prepare_log(tmp_path / "log.csv", "revs_250lm", rate_hz=100.0)


# ---- 2. derived channels -------------------------------------------------------------------------

def vendor_csv(tmp_path: Path, d: pd.DataFrame) -> Path:
    """The drive as a logger writes it: handwheel in deg, wheel speeds in rpm, body velocities, no β or δ."""
    src = tmp_path / "golf.csv"
    pd.DataFrame({"Zeit": d.t_s, "LRW": np.degrees(d.delta_rad * RATIO), "Gier": d.yaw_rate_radps,
                  "Quer": d.ay_mps2, "Rad RL": d.omega_rl_radps * 60 / (2 * np.pi),
                  "Rad RR": d.omega_rr_radps * 60 / (2 * np.pi), "VelX": d.vx_mps, "VelY": d.vy_mps}).to_csv(src, index=False)
    return src


DERIVED_MAP = {
    "time": "Zeit", "handwheel_rad": {"column": "LRW", "unit": "deg"}, "yaw_rate_radps": "Gier", "ay_mps2": "Quer",
    "omega_rl_radps": {"expr": "col('Rad RL')", "unit": "rpm"}, "omega_rr_radps": {"expr": "col('Rad RR')", "unit": "rpm"},
    "vx_mps": {"derive": "wheel_speed"}, "vy_mps": "VelY",
    "beta_rad": {"expr": "atan2(VelY, VelX)"},
    "ax_mps2": {"derive": "derivative", "of": ["vx_mps"], "cutoff_hz": 4.0},
    "measured": ["handwheel_rad", "yaw_rate_radps", "ay_mps2", "vx_mps", "ax_mps2"],
    "reference": ["beta_rad", "vy_mps"],
}


def test_derived_channels_equal_their_definitions(tmp_path: Path) -> None:
    d = drive()
    src = vendor_csv(tmp_path, d)
    cmap = write_yaml(tmp_path / "golf.yaml", DERIVED_MAP)
    rl = prepare_log(src, cmap, vehicle=load_vehicle(write_yaml(tmp_path / "c.yaml", REPLAY_VEHICLE), replay=True))
    f = rl.frame
    assert f.vx_mps.to_numpy() == pytest.approx(d.vx_mps.to_numpy(), rel=1e-12)  # rpm x 2pi/60 x radius
    assert f.beta_rad.to_numpy() == pytest.approx(np.arctan2(d.vy_mps, d.vx_mps), abs=1e-15)
    # delta derived from the handwheel and the vehicle's steering ratio, and fed to the observers
    assert f.delta_rad.to_numpy() == pytest.approx(d.delta_rad.to_numpy(), abs=1e-12)
    assert "delta_rad" in rl.column_map.measured and "delta_rad" in rl.measurements[0].columns
    assert any(n.startswith("delta_rad: derived automatically from handwheel_rad") for n in rl.notes)
    # a_x = dvx/dt through the causal filter: the true derivative, delayed by 2 tau, after it settles
    tau = 1 / (2 * np.pi * 4.0)
    lagged = np.interp(d.t_s - 2 * tau, d.t_s, d.ax_mps2)
    settled = d.t_s > 1.0
    assert np.max(np.abs(f.ax_mps2[settled] - lagged[settled])) < 0.01 * np.max(np.abs(d.ax_mps2))


def test_causal_derivative_ignores_the_future() -> None:
    t = np.arange(500) * 0.01
    x = np.sin(t)
    y = x.copy()
    y[300:] += 5.0  # a different future
    a, b = causal_derivative(t, x, 2.0), causal_derivative(t, y, 2.0)
    assert np.array_equal(a[:300], b[:300], equal_nan=True) and not np.allclose(a[300:], b[300:])


def test_only_the_handwheel_mapped_no_longer_skips_the_delta_observers(tmp_path: Path, car: Path) -> None:
    d = drive()
    src = tmp_path / "hw.csv"
    d.assign(handwheel_rad=d.delta_rad * RATIO).drop(columns=["delta_rad"]).to_csv(src, index=False)
    out = replay(src, vehicle=car, observers=["kf_bicycle"], out=tmp_path / "out")
    run = json.loads((out / "run.json").read_text())
    assert run["observer_runs"]["hw"]["kf_bicycle"]["status"] == "ok"
    assert run["column_map"]["channels"]["delta_rad"]["expr"] == "handwheel_rad / steering_ratio"
    # the same estimates as with the road-wheel angle logged directly
    d.to_csv(tmp_path / "hw.csv", index=False)
    direct = replay(tmp_path / "hw.csv", vehicle=car, observers=["kf_bicycle"], out=tmp_path / "direct")
    a, b = (pd.read_csv(o / "hw" / "estimates.csv").select_dtypes("number") for o in (out, direct))
    assert len(a) > 1000 and list(a.columns) == list(b.columns)
    assert np.allclose(a.to_numpy(), b.to_numpy(), rtol=1e-9, atol=1e-12, equal_nan=True)


@pytest.mark.parametrize(("expr", "message"), [
    ("__import__('os').system('true')", "function \"__import__('os').system\" is not allowed"),
    ("__import__('os')", "function '__import__' is not allowed"),
    ("VelX.real", "Attribute is not allowed"),
    ("(lambda: 1)()", "function 'lambda: 1' is not allowed"),
    ("VelX if VelY else 0", "IfExp is not allowed"),
    ("VelX // 2", "operator FloorDiv is not allowed"),
    ("VelX +", "is not valid"),
    ("mean()", "mean() takes 1 to 8 positional argument(s)"),
])
def test_unsafe_or_bad_expressions_are_refused_in_one_line(tmp_path: Path, expr: str, message: str) -> None:
    cmap = write_yaml(tmp_path / "m.yaml", {"time": "Zeit", "vx_mps": {"expr": expr}, "measured": ["vx_mps"]})
    with pytest.raises(LogError) as exc:
        load_column_map(cmap)
    text = str(exc.value)
    assert "\n" not in text and "m.yaml: vx_mps.expr: " in text and message in text


def test_expression_errors_name_the_map_key(tmp_path: Path, car: Path) -> None:
    d = drive()
    src = vendor_csv(tmp_path, d)
    cycle = write_yaml(tmp_path / "cycle.yaml", {"time": "Zeit", "vx_mps": {"expr": "ax_mps2 * 2"},
                                                 "ax_mps2": {"expr": "vx_mps / 2"}, "measured": ["vx_mps"]})
    with pytest.raises(LogError, match="cycle: ax_mps2 -> vx_mps -> ax_mps2"):
        load_column_map(cycle)
    unknown = write_yaml(tmp_path / "u.yaml", {"time": "Zeit", "vx_mps": {"expr": "velx * 1"}, "measured": ["vx_mps"]})
    with pytest.raises(LogError, match=r"vx_mps: expression 'velx \* 1' names 'velx'.*did you mean 'VelX'"):
        prepare_log(src, unknown)


# ---- 3. the vehicle is required ------------------------------------------------------------------

def test_replay_without_a_vehicle_exits_2_and_help_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                           car: Path) -> None:
    d = drive()
    d.to_csv(tmp_path / "log.csv", index=False)
    out = tmp_path / "out"
    one_error_line(capsys, ["replay", str(tmp_path / "log.csv"), "--observer", "kf_bicycle", "--out", str(out)],
                   "no vehicle: give --vehicle", "'vehicle:' key in the column map")
    assert not out.exists()
    with pytest.raises(SystemExit):
        main(["replay", "--help"])
    assert "required unless the column map has a 'vehicle:'" in " ".join(capsys.readouterr().out.split())
    # a vehicle: key in the map (a path next to the map) is enough
    cmap = write_yaml(tmp_path / "map.yaml", {"time": "t_s", "vehicle": car.name, "vx_mps": "vx_mps",
                                              "delta_rad": "delta_rad", "yaw_rate_radps": "yaw_rate_radps",
                                              "ay_mps2": "ay_mps2", "beta_rad": "beta_rad",
                                              "measured": ["vx_mps", "delta_rad", "yaw_rate_radps", "ay_mps2"],
                                              "reference": ["beta_rad"]})
    res = replay(tmp_path / "log.csv", columns=cmap, observers=["kf_bicycle"], out=out)
    assert json.loads((res / "run.json").read_text())["vehicle"] == "test_hatchback"


# ---- 4. replay vehicles --------------------------------------------------------------------------

def test_a_replay_vehicle_needs_only_what_observers_use(tmp_path: Path, car: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    v = load_vehicle(car, replay=True)
    assert (v.mass_kg, v.yaw_inertia_kgm2, v.lf_m, v.lr_m, v.steering.ratio, v.wheel_radius_m, v.tires.grip) == (
        1450.0, 2300.0, 1.05, 1.57, RATIO, RADIUS, 1.0)
    assert v.cornering_stiffness_f_Npr == pytest.approx(110000.0, rel=1e-12)
    assert v.cornering_stiffness_r_Npr == pytest.approx(130000.0, rel=1e-12)
    assert v.roll_inertia_kgm2 + v.pitch_inertia_kgm2 >= v.yaw_inertia_kgm2
    with pytest.raises(VehicleError, match="simulating a car needs the full vehicle format"):
        load_vehicle(car)  # not for a simulated run
    d = drive()
    d.to_csv(tmp_path / "log.csv", index=False)
    assert main(["replay", str(tmp_path / "log.csv"), "--vehicle", str(car), "--observer", "kf_bicycle",
                 "--out", str(tmp_path / "out")]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if "replay vehicle test_hatchback: derived" in ln]
    assert len(notes) == 1 and "suspension" in notes[0] and "roll/pitch inertia" in notes[0]


def test_every_field_error_of_a_vehicle_file_is_reported_at_once(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    bad = {**REPLAY_VEHICLE, "mass_kg": -5, "grip": 7.0, "wheelbase": 2.6}
    bad.pop("lr_m")
    path = write_yaml(tmp_path / "bad.yaml", bad)
    d = drive()
    d.to_csv(tmp_path / "log.csv", index=False)
    err = one_error_line(capsys, ["replay", str(tmp_path / "log.csv"), "--vehicle", str(path), "--out",
                                  str(tmp_path / "out")], "bad.yaml: ")
    assert all(f in err for f in ("wheelbase: unknown field", "mass_kg: must be a positive number",
                                  "lr_m: required field is missing")), err
    # a full vehicle file: every range error and unknown field in one line
    full = yaml.safe_load(Path("harness/vehicles/sedan.yaml").read_text())
    full["mass_kg"], full["tires"]["front"]["Cy"], full["suspension"]["travel_m"] = 1e9, 99, 5.0
    full["colour"] = "red"
    with pytest.raises(VehicleError) as exc:
        load_vehicle(write_yaml(tmp_path / "sedan2.yaml", full))
    text = str(exc.value)
    assert "\n" not in text and text.count("; ") == 3
    for f in ("mass_kg: must be", "tires.front.Cy: must be", "suspension.travel_m: must be", "colour: unknown field"):
        assert f in text, text


# ---- 5. signs and units --------------------------------------------------------------------------

def test_lateral_acceleration_positive_to_the_right_is_refused_with_evidence(
        tmp_path: Path, car: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = drive()
    d.assign(ay_mps2=-d.ay_mps2).to_csv(tmp_path / "log.csv", index=False)
    one_error_line(capsys, ["replay", str(tmp_path / "log.csv"), "--vehicle", str(car), "--out",
                            str(tmp_path / "out")],
                   "ay_mps2 has the opposite sign of vx*r in 100 % of", "corr -1.00", "scale: -1")
    assert not (tmp_path / "out").exists()


def test_steering_counted_clockwise_is_refused(tmp_path: Path, car: Path) -> None:
    d = drive()
    d.assign(delta_rad=-d.delta_rad).to_csv(tmp_path / "log.csv", index=False)
    with pytest.raises(LogError, match="delta_rad has the opposite sign of yaw_rate_radps.*so flip delta_rad"):
        prepare_log(tmp_path / "log.csv", vehicle=load_vehicle(car, replay=True))


def test_kmh_read_as_mps_is_caught_in_range(tmp_path: Path, car: Path) -> None:
    d = drive()  # 18…22 m/s: in km/h 65…79 "m/s", inside the 110 m/s range check
    d.assign(vx_mps=d.vx_mps * 3.6).to_csv(tmp_path / "log.csv", index=False)
    veh = load_vehicle(car, replay=True)
    with pytest.raises(LogError, match="vx_mps is 3.6 x the wheel speeds x wheel radius .*km/h read as m/s"):
        prepare_log(tmp_path / "log.csv", vehicle=veh)
    d.assign(vx_mps=d.vx_mps * 3.6).drop(columns=["omega_rl_radps", "omega_rr_radps"]).to_csv(
        tmp_path / "log.csv", index=False)  # no wheel speeds: a_y = v_x r gives it away
    with pytest.raises(LogError, match=r"ay_mps2 is 0.278 x vx\*r .*vx_mps in km/h read as m/s"):
        prepare_log(tmp_path / "log.csv", vehicle=veh)


def test_checks_warn_records_the_evidence_and_goes_on(tmp_path: Path, car: Path) -> None:
    d = drive()
    src = tmp_path / "log.csv"
    d.assign(ay_mps2=-d.ay_mps2).to_csv(src, index=False)
    cols = [c for c in d.columns if c != "t_s"]
    cmap = write_yaml(tmp_path / "m.yaml", {"time": "t_s", "checks": "warn", **{c: c for c in cols},
                                            "measured": ["vx_mps", "delta_rad", "yaw_rate_radps", "ay_mps2"],
                                            "reference": ["beta_rad"]})
    out = replay(src, vehicle=car, columns=cmap, observers=["kf_bicycle"], out=tmp_path / "out")
    run = json.loads((out / "run.json").read_text())
    status = {c["check"]: c["status"] for c in run["input_checks"]}
    assert status["ay_sign"] == "fail" and status["r_vs_delta"] == "ok" and status["speed_vs_wheels"] == "ok"
    assert any("opposite sign of vx*r" in n for n in run["notes"])


def test_the_revs_log_passes_every_consistency_check(revs_log: Path) -> None:
    rl = prepare_log(revs_log, "revs_250lm", vehicle=load_vehicle("ferrari_250lm"))
    status = {c.check: c.status for c in rl.checks}
    assert status == {"ay_sign": "ok", "ay_scale": "ok", "r_vs_delta": "ok", "beta_vs_vy": "ok"}


# ---- 6. Unix-epoch time stamps -------------------------------------------------------------------

def test_epoch_time_is_written_from_the_log_start_at_full_resolution(tmp_path: Path, car: Path) -> None:
    d = drive(n=999)
    t0 = 1_714_650_000.123456
    d.assign(t_s=t0 + d.t_s).to_csv(tmp_path / "epoch.csv", index=False, float_format="%.17g")
    out = replay(tmp_path / "epoch.csv", vehicle=car, observers=["kf_bicycle"], out=tmp_path / "out")
    truth = pd.read_csv(out / "epoch" / "truth.csv")
    assert truth.t_s.nunique() == 999 and truth.t_s.iloc[0] == 0.0
    assert np.diff(truth.t_s.to_numpy()) == pytest.approx(0.01, abs=1e-6)
    assert json.loads((out / "run.json").read_text())["time_origin_s"] == t0
    meas = pd.read_csv(out / "epoch" / "measurements.csv")
    assert meas.t_s.nunique() == len(meas)


# ---- 9. MDF4 and ROS 2 MCAP ----------------------------------------------------------------------

def write_mf4(path: Path, d: pd.DataFrame, speed_unit: str = "km/h") -> Path:
    """An MDF4 file with a 100 Hz IMU channel group and a 10 Hz CAN speed group in km/h."""
    from asammdf import MDF, Signal

    t = d.t_s.to_numpy()
    mdf = MDF(version="4.10")
    mdf.append([Signal(np.degrees(d.yaw_rate_radps.to_numpy()), t, name="GyroZ", unit="deg/s"),
                Signal(d.ay_mps2.to_numpy(), t, name="AccY", unit="m/s²"),
                Signal(np.degrees(d.delta_rad.to_numpy()), t, name="SteerAngle", unit="deg")], comment="imu")
    slow = slice(None, None, 10)
    mdf.append([Signal(d.vx_mps.to_numpy()[slow] * 3.6, t[slow], name="VehSpd", unit=speed_unit)], comment="can")
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


MF4_MAP = {"time": "time", "yaw_rate_radps": {"column": "GyroZ", "unit": "deg/s"}, "ay_mps2": "AccY",
           "delta_rad": {"column": "SteerAngle", "unit": "deg"}, "vx_mps": {"column": "VehSpd", "unit": "km/h"},
           "measured": ["yaw_rate_radps", "ay_mps2", "delta_rad", "vx_mps"], "reference": ["vx_mps"]}


def test_mdf4_channel_groups_are_read_on_one_time_base(tmp_path: Path, car: Path) -> None:
    d = drive()
    src = write_mf4(tmp_path / "drive.mf4", d)
    rl = prepare_log(src, write_yaml(tmp_path / "m.yaml", MF4_MAP), vehicle=load_vehicle(car, replay=True))
    f = rl.frame
    assert len(f) == len(d) and np.allclose(f.t_s, d.t_s)  # the 100 Hz group is the time base
    assert f.yaw_rate_radps.to_numpy() == pytest.approx(d.yaw_rate_radps.to_numpy(), rel=1e-12)
    # the 10 Hz speed is held at its latest sample (zero-order hold), never interpolated
    held = d.vx_mps.to_numpy()[(np.arange(len(d)) // 10) * 10]
    assert f.vx_mps.to_numpy() == pytest.approx(held, rel=1e-12)
    out = replay(src, vehicle=car, columns=write_yaml(tmp_path / "m.yaml", MF4_MAP), observers=["kf_bicycle"],
                 out=tmp_path / "out")
    assert json.loads((out / "run.json").read_text())["observer_runs"]["drive"]["kf_bicycle"]["status"] == "ok"


def test_mdf4_unit_contradicting_the_map_is_refused(tmp_path: Path) -> None:
    src = write_mf4(tmp_path / "drive.mf4", drive())
    wrong = {**MF4_MAP, "vx_mps": "VehSpd"}  # the file says km/h, the map reads m/s
    with pytest.raises(LogError, match="column 'VehSpd' is in km/h according to the file, but the column map "
                                       "reads it as m/s"):
        prepare_log(src, write_yaml(tmp_path / "m.yaml", wrong))


IMU_MSGDEF = """std_msgs/Header header
geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance
geometry_msgs/Vector3 linear_acceleration
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
"""


def write_mcap(path: Path, d: pd.DataFrame, t0_ns: int) -> Path:
    """A ROS 2 MCAP bag: /imu (header-stamped, 100 Hz), /vehicle/speed and /steering (Float64, 50 Hz,
    logged 3 ms after the sample)."""
    from mcap_ros2.writer import Writer

    with path.open("wb") as fh:
        w = Writer(fh)
        imu = w.register_msgdef("sensor_msgs/msg/Imu", IMU_MSGDEF)
        f64 = w.register_msgdef("std_msgs/msg/Float64", "float64 data")
        for k, row in enumerate(d.itertuples()):
            ns = t0_ns + k * 10_000_000
            stamp = {"sec": ns // 10**9, "nanosec": ns % 10**9}
            w.write_message("/imu", imu, {"header": {"stamp": stamp, "frame_id": "base_link"},
                                          "angular_velocity": {"x": 0.0, "y": 0.0, "z": row.yaw_rate_radps},
                                          "angular_velocity_covariance": [0.0] * 9,
                                          "linear_acceleration": {"x": row.ax_mps2, "y": row.ay_mps2, "z": 9.81}},
                            log_time=ns + 1_000_000, publish_time=ns)
            if k % 2 == 0:
                w.write_message("/vehicle/speed", f64, {"data": row.vx_mps}, log_time=ns + 3_000_000, publish_time=ns)
                w.write_message("/steering", f64, {"data": row.delta_rad}, log_time=ns + 3_000_000, publish_time=ns)
        w.finish()
    return path


def test_ros2_mcap_topics_are_columns_on_one_time_base(tmp_path: Path, car: Path) -> None:
    d = drive(n=1000)
    t0_ns = 1_714_650_000 * 10**9
    bag = tmp_path / "bag"
    bag.mkdir()
    write_mcap(bag / "bag_0.mcap", d, t0_ns)
    cmap = write_yaml(tmp_path / "ros.yaml", {
        "time": "time", "yaw_rate_radps": "/imu.angular_velocity.z", "ay_mps2": "/imu.linear_acceleration.y",
        "vx_mps": "/vehicle/speed.data", "delta_rad": "/steering.data",
        "measured": ["yaw_rate_radps", "ay_mps2", "vx_mps", "delta_rad"], "reference": ["vx_mps"]})
    rl = prepare_log(bag, cmap, vehicle=load_vehicle(car, replay=True))
    f = rl.frame
    # the IMU's header stamps are the time base (an absolute clock, so counted from the log start)
    assert rl.time_origin_s == pytest.approx(1_714_650_000.0, abs=1e-6)
    assert np.allclose(f.t_s, d.t_s, atol=1e-6) and len(f) == len(d)
    assert f.yaw_rate_radps.to_numpy() == pytest.approx(d.yaw_rate_radps.to_numpy(), rel=1e-12)
    # the 50 Hz speed has no header: its log time (3 ms after its sample) counts, and it is held until
    # the next one arrives; before the first one nothing is known
    assert np.isnan(f.vx_mps.iloc[0])
    latest = d.vx_mps.to_numpy()[np.maximum(((np.arange(len(d)) - 1) // 2) * 2, 0)]
    assert f.vx_mps.to_numpy()[1:] == pytest.approx(latest[1:], rel=1e-12)
    # the single .mcap file reads the same as the bag folder
    assert prepare_log(bag / "bag_0.mcap", cmap).frame.equals(f)
