"""Sensor configuration: presets, overrides, the --faults syntax, clear errors, reproducibility."""

from __future__ import annotations

import numpy as np
import pytest

from roadtruth.harness.errors import InputError, SensorConfigError
from roadtruth.harness.sensors import (
    SENSORS,
    available_presets,
    emulate,
    load_sensor_config,
    output_columns,
    parse_faults,
    sensor_config_from_cli,
)
from roadtruth.harness.sensors.synthetic import steady_motion_truth
from roadtruth.harness.truth.vehicle import load_vehicle

VEHICLE = load_vehicle("sedan")
TRUTH = steady_motion_truth(3.0, vx_mps=15.0, yaw_rate_radps=0.1, roll_rad=0.01, range_m=40.0)


def test_presets_load_and_give_the_contract_columns():
    assert {"ideal", "automotive", "consumer"} <= set(available_presets())
    for name in available_presets():
        cfg = load_sensor_config(name, overrides={"ogs": {"enabled": True}})
        m = emulate(TRUTH, VEHICLE, cfg, seed=0)
        expected = ["t_s"] + [c for s in cfg.enabled() for c in output_columns(s)]
        assert list(m.frame.columns) == expected
        assert m.rate_hz == cfg.base_rate_hz == 100.0
        assert not cfg.sensors["ogs"].enabled or name  # ogs is on only because of the override
        assert not load_sensor_config(name).sensors["ogs"].enabled


def test_disabled_sensor_columns_are_omitted():
    f = emulate(TRUTH, VEHICLE, load_sensor_config("consumer"), seed=0).frame
    assert "range_m" not in f and "radar_valid" not in f and "ogs_vx_mps" not in f


@pytest.mark.parametrize("overrides, match", [
    ({"imu": {"accel": {"noise_std": -0.1}}}, r"sensors\.imu\.accel\.noise_std"),
    ({"imu": {"accel": {"noise_std": 0.1, "noise_density": 0.1}}}, "not both"),
    ({"imu": {"rate_hz": 0}}, r"rate_hz"),
    ({"sonar": {"rate_hz": 10}}, "unknown sensor 'sonar'"),
    ({"imu": {"colour": "red"}}, r"sensors\.imu\.colour: unknown field"),
    ({"gnss": {"rate_hz": 30}}, "does not divide the fastest sensor rate"),
    ({"imu": {"faults": [{"fault": "melt"}]}}, "unknown fault 'melt'"),
    ({"imu": {"faults": [{"fault": "dropout", "p": 1.5}]}}, r"\.p: must be"),
    ({"imu": {"position_m": [0, 0]}}, "three numbers"),
    ({"wheel_speed": {"method": "guess"}}, "must be one of"),
])
def test_bad_configuration_is_a_clear_error(overrides, match):
    with pytest.raises(SensorConfigError, match=match) as info:
        load_sensor_config("automotive", overrides=overrides, source="scn.yaml")
    assert isinstance(info.value, InputError) and "\n" not in str(info.value)


def test_rate_above_simulation_rate_is_an_error():
    truth = steady_motion_truth(1.0, dt_s=0.01)  # 100 Hz truth
    cfg = load_sensor_config("ideal", overrides={s: {"rate_hz": 200} for s in SENSORS if s != "ogs"})
    with pytest.raises(SensorConfigError, match="above the simulation rate"):
        emulate(truth, VEHICLE, cfg, seed=0)
    with pytest.raises(SensorConfigError, match="does not divide the simulation rate"):
        emulate(steady_motion_truth(1.0, dt_s=1 / 250), VEHICLE, load_sensor_config("ideal"), seed=0)


def test_unknown_preset_and_bad_seed():
    with pytest.raises(SensorConfigError, match="unknown sensor preset 'lidar'.*automotive"):
        load_sensor_config("lidar")
    with pytest.raises(SensorConfigError, match="file not found"):
        load_sensor_config("/nonexistent/suite.yaml")
    with pytest.raises(SensorConfigError, match="seed"):
        emulate(TRUTH, VEHICLE, load_sensor_config("ideal"), seed=-1)


@pytest.mark.parametrize("spec, match", [
    ("gnss:teleport=1", "unknown fault 'teleport'"),
    ("sonar:dropout=0.1", "unknown sensor 'sonar'"),
    ("gnss dropout", "expected SENSOR"),
    ("gnss:dropout=abc", "not a number"),
    ("gnss:dropout", r"\.p: required"),
    ("gnss:dropout(p=0.1,q=1)", "unknown field"),
    ("gnss.gnss_x_m:dropout=0.1", "takes no channel"),
    ("imu.speed:spike(p=0.1,magnitude=1)", "no channel 'speed'"),
    ("gnss:outage=3", "no shorthand"),
    ("gnss:outage(t_start_s=5,t_end_s=2)", "before t_start_s"),
    ("radar:dropout=0.1", "disabled"),
])
def test_bad_fault_spec_is_a_clear_error(spec, match):
    with pytest.raises(SensorConfigError, match=match):
        load_sensor_config("consumer", faults=spec)


def test_fault_syntax():
    faults = parse_faults("gnss:dropout=0.2, imu.ay_mps2:bias_step(size=0.5,t_start_s=10);"
                          "camera:burst(p_enter=0.02,mean_len=8), radar:delay=0.05(jitter_s=0.01)")
    assert [f.label() for f in faults] == [
        "gnss:dropout(p=0.2)",
        "imu.ay_mps2:bias_step(size=0.5,t_start_s=10,t_end_s=inf)",
        "camera:burst(p_enter=0.02,mean_len=8,loss_good=0,loss_bad=1)",
        "radar:delay(extra_s=0.05,jitter_s=0.01,t_start_s=0,t_end_s=inf)",
    ]
    cfg = sensor_config_from_cli(None, "gnss:dropout=0.2")
    assert cfg.name == "automotive" and cfg.sensors["gnss"].faults[-1].kind == "dropout"
    # Preset faults are kept and CLI faults appended.
    assert [f.kind for f in cfg.sensors["camera"].faults] == ["dropout"]


def test_yaml_faults_file_and_preset_file_with_base(tmp_path):
    ff = tmp_path / "faults.yaml"
    ff.write_text("faults:\n  - {sensor: gnss, fault: outage, t_start_s: 1, t_end_s: 2}\n"
                  "  - {sensor: imu, channel: yaw_rate_radps, fault: spike, p: 0.1, magnitude: 0.2}\n")
    pf = tmp_path / "mine.yaml"
    pf.write_text("name: mine\nbase: automotive\nsensors:\n  gnss: {rate_hz: 5}\n  radar: {enabled: false}\n")
    cfg = load_sensor_config(str(pf), faults=str(ff))
    assert cfg.name == "mine" and cfg.sensors["gnss"].rate_hz == 5 and not cfg.sensors["radar"].enabled
    assert cfg.sensors["gnss"].latency_s == 0.1  # inherited from the base
    assert [f.kind for f in cfg.sensors["imu"].faults] == ["spike"]
    bad = tmp_path / "bad.yaml"
    bad.write_text("faults:\n  - {sensor: gnss, fault: outage, t_start_s: 1}\n")
    with pytest.raises(SensorConfigError, match=r"bad\.yaml: faults\[0\]\.t_end_s: required"):
        load_sensor_config("automotive", faults=str(bad))



def test_an_edited_preset_file_is_read_again_and_loads_do_not_share_state(tmp_path):
    # Parsed preset files are kept per process (a sweep loads the same suite for every case).
    pf = tmp_path / "mine.yaml"
    pf.write_text("name: mine\nbase: automotive\nsensors:\n  gnss: {rate_hz: 5}\n")
    assert load_sensor_config(str(pf)).sensors["gnss"].rate_hz == 5
    pf.write_text("name: mine\nbase: automotive\nsensors:\n  gnss: {rate_hz: 10, latency_s: 0.2}\n")
    cfg = load_sensor_config(str(pf))
    assert cfg.sensors["gnss"].rate_hz == 10 and cfg.sensors["gnss"].latency_s == 0.2
    # Overrides merged onto one load must not leak into the next load of the same file.
    over = load_sensor_config(str(pf), overrides={"gnss": {"rate_hz": 2}})
    assert over.sensors["gnss"].rate_hz == 2
    assert load_sensor_config(str(pf)).sensors["gnss"].rate_hz == 10
    assert load_sensor_config("automotive").to_dict() == load_sensor_config("automotive").to_dict()

def _bytes(m) -> bytes:
    return m.frame.to_csv(index=False).encode()


def test_same_seed_same_bytes_and_different_seed_differs():
    cfg = load_sensor_config("automotive", overrides={"ogs": {"enabled": True}},
                             faults="gnss:burst=0.05,imu:spike(p=0.01,magnitude=1),radar:delay(extra_s=0.02,jitter_s=0.05)")
    a, b = emulate(TRUTH, VEHICLE, cfg, seed=42), emulate(TRUTH, VEHICLE, cfg, seed=42)
    assert _bytes(a) == _bytes(b)
    c = emulate(TRUTH, VEHICLE, cfg, seed=43)
    assert _bytes(a) != _bytes(c)


def test_one_sensors_settings_do_not_change_another_sensors_noise():
    base = load_sensor_config("automotive")
    other = load_sensor_config("automotive", overrides={"gnss": {"rate_hz": 5, "position": {"noise_std": 3.0}},
                                                        "wheel_speed": {"enabled": False}},
                               faults="camera:dropout=0.5,gnss:spike=0.1(magnitude=2)")
    fa = emulate(TRUTH, VEHICLE, base, seed=5).frame
    fb = emulate(TRUTH, VEHICLE, other, seed=5).frame
    for col in output_columns("imu") + output_columns("radar") + output_columns("steering"):
        np.testing.assert_array_equal(fa[col].to_numpy(), fb[col].to_numpy())
    # Adding a second fault to a sensor does not change the first fault's draws.
    c1 = load_sensor_config("ideal", faults="imu:dropout=0.3")
    c2 = load_sensor_config("ideal", faults="imu:spike(p=0.2,magnitude=1),imu:dropout=0.3")
    v1 = emulate(TRUTH, VEHICLE, c1, seed=5).frame["imu_valid"]
    v2 = emulate(TRUTH, VEHICLE, c2, seed=5).frame["imu_valid"]
    np.testing.assert_array_equal(v1, v2)


def test_switching_off_a_sensor_with_preset_faults_is_fine():
    cfg = load_sensor_config("consumer", overrides={"camera": {"enabled": False}})
    assert "camera" not in cfg.enabled()


def test_config_to_dict_is_strict_json():
    import json

    cfg = load_sensor_config("automotive", faults="imu:bias_step=0.1,gnss:freeze=3")
    data = json.loads(json.dumps(cfg.to_dict(), allow_nan=False))
    assert data["sensors"]["imu"]["faults"][0]["params"]["t_end_s"] == "inf"
    assert data["sensors"]["gnss"]["rate_hz"] == 10
