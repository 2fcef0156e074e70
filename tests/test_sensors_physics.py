"""Sensor physics against closed forms on synthetic truth (no MuJoCo): gravity leak, lever arms,
wheel-tick quantization, steering offset, GNSS antenna, lane gaps, radar field of view."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadtruth.harness.sensors import emulate, load_sensor_config
from roadtruth.harness.sensors.synthetic import steady_motion_truth
from roadtruth.harness.truth.vehicle import G, load_vehicle

VEHICLE = load_vehicle("sedan")


def ideal(**overrides):
    return load_sensor_config("ideal", overrides=overrides)


def arrived(m, col):
    """Rows where the sensor of ``col`` delivered, and the values there."""
    f = m.frame
    ok = f[col].notna().to_numpy()
    return f["t_s"].to_numpy()[ok], f[col].to_numpy()[ok]


def test_accelerometer_gravity_leak_is_g_sin_roll():
    roll = 0.04
    truth = steady_motion_truth(2.0, vx_mps=20.0, yaw_rate_radps=0.1, roll_rad=roll)
    m = emulate(truth, VEHICLE, ideal(), seed=1)
    ay = m.frame["ay_mps2"].to_numpy()
    ay_body = 0.1 * 20.0 * math.cos(roll)  # CG acceleration in the rolled body frame
    np.testing.assert_allclose(ay - ay_body, G * math.sin(roll), rtol=0, atol=1e-12)
    np.testing.assert_allclose(m.frame["az_mps2"], G * math.cos(roll) - 2.0 * math.sin(roll), atol=1e-12)


def test_accelerometer_at_rest_reads_gravity_through_roll_and_pitch():
    roll, pitch = 0.05, -0.03
    truth = steady_motion_truth(1.0, vx_mps=0.0, roll_rad=roll, pitch_rad=pitch)
    f = emulate(truth, VEHICLE, ideal(), seed=1).frame
    np.testing.assert_allclose(f["ax_mps2"], -G * math.sin(pitch), atol=1e-12)
    np.testing.assert_allclose(f["ay_mps2"], G * math.cos(pitch) * math.sin(roll), atol=1e-12)
    np.testing.assert_allclose(f["az_mps2"], G * math.cos(pitch) * math.cos(roll), atol=1e-12)
    # The specific force of a body at rest has magnitude g whatever its attitude.
    np.testing.assert_allclose(np.hypot(np.hypot(f["ax_mps2"], f["ay_mps2"]), f["az_mps2"]), G, atol=1e-12)


def test_imu_lever_arm_adds_centripetal_acceleration():
    r, vx, vy = 0.3, 15.0, -0.4
    rx, ry = 1.0, 0.5
    truth = steady_motion_truth(1.0, vx_mps=vx, vy_mps=vy, yaw_rate_radps=r)
    f = emulate(truth, VEHICLE, ideal(imu={"position_m": [rx, ry, 0.0]}), seed=1).frame
    np.testing.assert_allclose(f["ax_mps2"], -r * vy - r**2 * rx, atol=1e-12)
    np.testing.assert_allclose(f["ay_mps2"], r * vx - r**2 * ry, atol=1e-12)
    np.testing.assert_allclose(f["yaw_rate_radps"], r, atol=1e-15)


def test_gyro_reads_body_rates_of_a_rolled_turning_car():
    r, roll = 0.2, 0.05
    truth = steady_motion_truth(1.0, yaw_rate_radps=r, roll_rad=roll)
    f = emulate(truth, VEHICLE, ideal(), seed=1).frame
    np.testing.assert_allclose(f["pitch_rate_radps"], r * math.sin(roll), atol=1e-15)
    np.testing.assert_allclose(f["yaw_rate_radps"], r * math.cos(roll), atol=1e-15)


def test_boxcar_anti_alias_delays_a_ramp_by_half_an_interval():
    truth = steady_motion_truth(2.0)
    truth["wz_body_radps"] = truth["t_s"]  # a ramp of slope 1
    f = emulate(truth, VEHICLE, ideal(imu={"anti_alias": "mean"}), seed=1).frame
    t, w = f["t_s"].to_numpy(), f["yaw_rate_radps"].to_numpy()
    full = t >= 0.01
    np.testing.assert_allclose(w[full], t[full] - (0.01 - 0.001) / 2, atol=1e-12)


def test_wheel_ticks_count_method_is_quantized_and_coarse_at_low_speed():
    n_ticks, window = 48, 0.1
    quantum = 2 * math.pi / (n_ticks * window)
    cfg = ideal(wheel_speed={"ticks_per_rev": n_ticks, "method": "count", "window_s": window})
    for v in (20.0, 1.0):
        f = emulate(steady_motion_truth(5.0, vx_mps=v), VEHICLE, cfg, seed=3).frame
        w = f["omega_fl_radps"].dropna().to_numpy()
        steps = w / quantum
        np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)  # whole tick counts
        true = v / 0.31
        assert np.all(np.abs(w - true) <= quantum + 1e-9)
        assert abs(w.mean() - true) < 0.02 * quantum * 10
    # At 1 m/s the quantum is 40 % of the reading: the reading jumps between neighbouring counts.
    assert np.unique(np.round(w / quantum)).size >= 2


def test_wheel_period_method_is_fine_at_speed_and_zero_when_crawling():
    cfg = ideal(wheel_speed={"ticks_per_rev": 48, "method": "period", "timer_resolution_s": 1e-6,
                             "timeout_s": 0.5})
    f = emulate(steady_motion_truth(3.0, vx_mps=20.0), VEHICLE, cfg, seed=2).frame
    assert np.max(np.abs(f["vx_mps"].dropna() - 20.0)) < 0.01
    # 0.02 m/s: one edge every 2 pi R / 48 / v = 2 s > timeout -> reads 0 once the timeout has run.
    f = emulate(steady_motion_truth(6.0, vx_mps=0.02), VEHICLE, cfg, seed=2).frame
    late = f["t_s"] > 0.5
    assert np.all(f.loc[late, "omega_fl_radps"].dropna().abs() < 0.2)
    assert (f.loc[late, "omega_fl_radps"] == 0.0).mean() > 0.5


def test_reference_speed_from_non_driven_wheels_in_a_turn():
    truth = steady_motion_truth(1.0, vx_mps=20.0, yaw_rate_radps=0.2)
    f = emulate(truth, VEHICLE, ideal(), seed=1).frame  # RWD: front wheels, symmetric about the CG
    np.testing.assert_allclose(f["vx_mps"], 20.0, atol=1e-12)
    np.testing.assert_allclose(f["omega_fl_radps"], (20.0 - 0.2 * 0.8) / 0.31, atol=1e-12)


def test_steering_offset_and_resolution_show_through_road_wheel_angle():
    res, offset = 0.0017, 0.02
    truth = steady_motion_truth(2.0)
    truth["delta_rad"] = 0.05 * np.sin(2 * math.pi * 0.5 * truth["t_s"])
    cfg = ideal(steering={"handwheel": {"bias": offset, "resolution": res}})
    f = emulate(truth, VEHICLE, cfg, seed=1).frame
    hw = f["handwheel_rad"].to_numpy()
    np.testing.assert_allclose(hw / res, np.round(hw / res), atol=1e-9)
    exact = VEHICLE.steering.ratio * truth["delta_rad"].to_numpy()[::10] + offset
    assert np.max(np.abs(hw - exact)) <= res / 2 + 1e-12
    np.testing.assert_allclose(f["delta_rad"], hw / VEHICLE.steering.ratio, rtol=1e-15)


def test_gnss_antenna_lever_arm_speed_and_course():
    r, vx, psi0 = 0.25, 10.0, 0.3
    ant = (-0.5, 0.2, 1.0)
    truth = steady_motion_truth(2.0, vx_mps=vx, yaw_rate_radps=r, psi0_rad=psi0)
    f = emulate(truth, VEHICLE, ideal(gnss={"antenna_m": list(ant)}), seed=1).frame
    psi = truth["psi_rad"].to_numpy()[::10]
    c, s = np.cos(psi), np.sin(psi)
    np.testing.assert_allclose(f["gnss_x_m"], truth["x_m"].to_numpy()[::10] + c * ant[0] - s * ant[1], atol=1e-9)
    np.testing.assert_allclose(f["gnss_y_m"], truth["y_m"].to_numpy()[::10] + s * ant[0] + c * ant[1], atol=1e-9)
    va = np.array([vx - r * ant[1], r * ant[0]])  # antenna velocity, heading frame
    np.testing.assert_allclose(f["gnss_speed_mps"], np.hypot(*va), atol=1e-12)
    course = np.angle(np.exp(1j * (psi + math.atan2(va[1], va[0]))))
    np.testing.assert_allclose(f["gnss_course_rad"], course, atol=1e-12)


def test_camera_is_blind_in_lane_gaps_and_radar_without_target():
    truth = steady_motion_truth(3.0, vx_mps=10.0)  # s = 10 t, no lead
    m = emulate(truth, VEHICLE, ideal(), seed=1, lane_gaps=[(10.0, 20.0)])
    f = m.frame
    gap = (f["t_s"] >= 1.0) & (f["t_s"] <= 2.0)
    assert (f.loc[gap, "camera_valid"] == 0).all() and f.loc[gap, "y_lane_m"].isna().all()
    assert (f.loc[~gap, "camera_valid"] == 1).all()
    assert (f["radar_valid"] == 0).all() and f["range_m"].isna().all()


def test_radar_field_of_view():
    truth = steady_motion_truth(2.0, range_m=195.0, range_rate_mps=10.0)  # leaves 200 m at t = 0.5 s
    f = emulate(truth, VEHICLE, ideal(radar={"max_range_m": 200.0}), seed=1).frame
    seen = f["radar_valid"] == 1
    np.testing.assert_allclose(f.loc[seen, "t_s"].max(), 0.5, atol=1e-12)
    np.testing.assert_allclose(f.loc[seen, "range_rate_mps"], 10.0)


def test_optical_sensor_behind_cg_sees_yaw_induced_lateral_velocity():
    r, vy = 0.3, -0.5
    truth = steady_motion_truth(1.0, vx_mps=20.0, vy_mps=vy, yaw_rate_radps=r)
    cfg = ideal(ogs={"enabled": True, "position_m": [-1.5, 0.0, 0.0]})
    f = emulate(truth, VEHICLE, cfg, seed=1).frame
    np.testing.assert_allclose(f["ogs_vy_mps"], vy - 1.5 * r, atol=1e-12)
    np.testing.assert_allclose(f["ogs_vx_mps"], 20.0, atol=1e-12)


def test_outage_by_x_zone_and_time():
    class Outage:
        def __init__(self, sensor, t0=None, t1=None, xr=None):
            self.sensor, self.t_start_s, self.t_end_s, self.x_range_m = sensor, t0, t1, xr

    truth = steady_motion_truth(4.0, vx_mps=10.0)  # x = 10 t
    f = emulate(truth, VEHICLE, ideal(), seed=1,
                outages=[Outage("gnss", xr=(15.0, 25.0)), Outage("imu", t0=3.0, t1=3.5)]).frame
    t = f["t_s"]
    tunnel = (t >= 1.5 - 1e-9) & (t <= 2.5 + 1e-9)
    assert (f.loc[tunnel, "gnss_valid"] == 0).all() and (f.loc[~tunnel, "gnss_valid"] == 1).all()
    off = (t >= 3.0 - 1e-9) & (t < 3.5 - 1e-9)
    assert (f.loc[off, "imu_valid"] == 0).all() and (f.loc[~off, "imu_valid"] == 1).all()
    with pytest.raises(Exception, match="unknown sensor"):
        emulate(truth, VEHICLE, ideal(), seed=1, outages=[Outage("sonar", 0.0, 1.0)])
