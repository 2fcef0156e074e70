"""Statistical tests on long streams: noise and bias within χ² / normal bands, dropout rate within
its binomial interval, Gilbert–Elliott burst lengths, exact latency, quantization steps."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats

from roadtruth.harness.sensors import emulate, load_sensor_config
from roadtruth.harness.sensors.faults import gilbert_elliott_states
from roadtruth.harness.sensors.noise import ChannelErrors, apply_channel_errors
from roadtruth.harness.sensors.synthetic import steady_motion_truth
from roadtruth.harness.truth.vehicle import load_vehicle

VEHICLE = load_vehicle("sedan")
ALPHA = 1e-6  # false-alarm probability of each band: these tests must not flake
LONG = steady_motion_truth(60.0, dt_s=0.01, vx_mps=20.0)  # 100 Hz truth is enough for 100 Hz sensors


def chi2_band(n_dof: int) -> tuple[float, float]:
    return stats.chi2.ppf(ALPHA / 2, n_dof), stats.chi2.ppf(1 - ALPHA / 2, n_dof)


def run(overrides, faults=None, seed=7, truth=LONG, **kw):
    return emulate(truth, VEHICLE, load_sensor_config("ideal", overrides=overrides, faults=faults), seed=seed,
                   **kw).frame


def test_white_noise_std_from_density_within_chi2_band():
    density = 0.002  # rad/s/sqrt(Hz) at 100 Hz -> sigma = 0.02 rad/s
    f = run({"imu": {"gyro": {"noise_density": density}}})
    e = f["yaw_rate_radps"].to_numpy()  # truth is 0
    n = e.size
    lo, hi = chi2_band(n)
    assert lo < np.sum(e**2) / (density * 10.0) ** 2 < hi
    # The three axes draw from independent streams.
    assert abs(np.corrcoef(e, f["roll_rate_radps"])[0, 1]) < 5 / math.sqrt(n)


def test_fixed_bias_and_noise_mean_within_band():
    bias, sigma = 0.05, 0.3
    f = run({"gnss": {"position": {"bias": bias, "noise_std": sigma}}})
    e = (f["gnss_y_m"]).to_numpy()  # straight along x: y truth is 0
    z = stats.norm.ppf(1 - ALPHA / 2)
    assert abs(e.mean() - bias) < z * sigma / math.sqrt(e.size)
    lo, hi = chi2_band(e.size - 1)
    assert lo < (e.size - 1) * e.var(ddof=1) / sigma**2 < hi


def test_turn_on_bias_spread_across_seeds():
    bias_std, n = 0.05, 400
    truth = steady_motion_truth(0.05, dt_s=0.01)
    cfg = load_sensor_config("ideal", overrides={"imu": {"accel": {"bias_std": bias_std}}})
    b = np.array([emulate(truth, VEHICLE, cfg, seed=s).frame["ax_mps2"].iloc[0] for s in range(n)])
    lo, hi = chi2_band(n)
    assert lo < np.sum(b**2) / bias_std**2 < hi
    # Constant within a run.
    f = emulate(truth, VEHICLE, cfg, seed=3).frame
    assert f["ax_mps2"].nunique() == 1


def test_bias_random_walk_increments_within_chi2_band():
    walk, rate = 0.01, 100.0
    y = apply_channel_errors(np.zeros(20000), ChannelErrors(bias_walk=walk), rate, seed=5, key=("imu", "x"))
    d = np.diff(y)
    lo, hi = chi2_band(d.size)
    assert lo < np.sum(d**2) / (walk**2 / rate) < hi


def test_gauss_markov_variance_and_correlation():
    std, tau, rate = 2.0, 0.1, 100.0
    y = apply_channel_errors(np.zeros(200000), ChannelErrors(gm_std=std, gm_tau_s=tau), rate, seed=9,
                             key=("gnss", "x"))
    a = math.exp(-1 / (rate * tau))
    assert abs(np.corrcoef(y[:-1], y[1:])[0, 1] - a) < 0.01
    assert abs(y.std() / std - 1) < 0.06  # ~ 4 sigma for ~ 10^4 effective samples


def test_dropout_rate_within_binomial_interval():
    p = 0.2
    f = run({}, faults="imu:dropout=0.2")
    n, lost = len(f), int((f["imu_valid"] == 0).sum())
    ci = stats.binomtest(lost, n, p).proportion_ci(confidence_level=1 - ALPHA)
    assert ci.low < p < ci.high
    assert f.loc[f["imu_valid"] == 0, "ax_mps2"].isna().all()


def _runs(mask: np.ndarray) -> np.ndarray:
    """Lengths of runs of True."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return np.flatnonzero(d == -1) - np.flatnonzero(d == 1)


def test_gilbert_elliott_burst_lengths_and_loss_fraction():
    p_enter, mean_len, n = 0.02, 5.0, 400000
    bad = gilbert_elliott_states(n, p_enter, 1 / mean_len, np.random.default_rng(11))
    runs = _runs(bad)
    p_exit = 1 / mean_len
    se = math.sqrt((1 - p_exit) / p_exit**2 / runs.size)  # geometric sojourn
    z = stats.norm.ppf(1 - ALPHA / 2)
    assert abs(runs.mean() - mean_len) < z * se
    good = _runs(~bad)
    assert abs(good.mean() - 1 / p_enter) < z * math.sqrt((1 - p_enter) / p_enter**2 / good.size)
    assert abs(bad.mean() - p_enter / (p_enter + p_exit)) < 0.01


def test_burst_fault_end_to_end():
    f = run({}, faults="gnss:burst(p_enter=0.02,mean_len=8)")
    lost = f["gnss_valid"].to_numpy() == 0
    runs = _runs(lost)
    assert runs.size > 60
    se = math.sqrt((1 - 1 / 8) * 64 / runs.size)
    assert abs(runs.mean() - 8) < stats.norm.ppf(1 - ALPHA / 2) * se


def test_latency_is_exact_to_the_sample():
    truth = steady_motion_truth(5.0, vx_mps=20.0)  # 1 kHz, x = 20 t
    f = emulate(truth, VEHICLE, load_sensor_config(
        "ideal", overrides={"gnss": {"rate_hz": 10, "latency_s": 0.1}, "imu": {"latency_s": 0.03}}),
        seed=1).frame
    t = f["t_s"].to_numpy()
    ok = f["gnss_valid"].to_numpy() == 1
    # Samples at 0.0, 0.1, ... 4.9 s arrive 0.1 s later; the one taken at 5.0 s would arrive after the end.
    np.testing.assert_allclose(t[ok], np.arange(1, 51) * 0.1, atol=1e-9)
    np.testing.assert_allclose(f["gnss_x_m"].to_numpy()[ok], 20.0 * (t[ok] - 0.1), atol=1e-9)
    assert f["gnss_x_m"].notna().sum() == 50
    imu = f["imu_valid"].to_numpy() == 1
    assert int(np.argmax(imu)) == 3 and imu[3:].all() and not imu[:3].any()


def test_latency_between_rows_rounds_up_to_the_next_row():
    truth = steady_motion_truth(1.0, range_m=30.0)
    f = emulate(truth, VEHICLE, load_sensor_config("ideal", overrides={"radar": {"latency_s": 0.013}}),
                seed=1).frame
    assert int(np.argmax(f["radar_valid"].to_numpy() == 1)) == 2  # 13 ms -> the 20 ms row


def test_quantization_steps_present():
    res = 0.01
    truth = steady_motion_truth(20.0, dt_s=0.01)
    truth["ay_body_mps2"] = np.linspace(-1.0, 1.0, len(truth))
    f = run({"imu": {"accel": {"resolution": res, "noise_std": 0.003}}}, truth=truth)
    ay = f["ay_mps2"].to_numpy()
    np.testing.assert_allclose(ay / res, np.round(ay / res), atol=1e-9)
    steps = np.unique(np.round(np.abs(np.diff(ay)) / res))
    assert steps.min() == 0 and 1 in steps  # flat stretches and one-step jumps: a staircase
    assert np.unique(np.round(ay / res)).size > 150  # every level of the ramp is visited


def test_saturation_and_scale_factor():
    truth = steady_motion_truth(1.0, dt_s=0.01, vx_mps=20.0, yaw_rate_radps=0.5)  # ay = 10 m/s^2
    f = run({"imu": {"accel": {"range": 8.0}, "gyro": {"scale_error": 0.02}}}, truth=truth)
    assert (f["ay_mps2"] == 8.0).all()
    np.testing.assert_allclose(f["yaw_rate_radps"], 0.5 * 1.02, rtol=1e-12)


def test_spike_rate_and_size():
    f = run({}, faults="imu.ax_mps2:spike(p=0.05,magnitude=3)")
    x = f["ax_mps2"].to_numpy()
    hit = np.abs(x) > 0
    np.testing.assert_array_equal(np.abs(x[hit]), 3.0)
    ci = stats.binomtest(int(hit.sum()), x.size).proportion_ci(confidence_level=1 - ALPHA)
    assert ci.low < 0.05 < ci.high
    assert (f["ay_mps2"].to_numpy() == 0).all()  # the other channels are untouched


def test_bias_step_freeze_and_delay_faults():
    faults = ("gnss.gnss_x_m:freeze(t_start_s=1,t_end_s=2); imu.ay_mps2:bias_step(size=0.5,t_start_s=2);"
              "radar:delay(extra_s=0.05,t_start_s=3)")
    f = emulate(steady_motion_truth(4.0, vx_mps=10.0, range_m=30.0), VEHICLE,
                load_sensor_config("ideal", faults=faults), seed=1).frame
    t = f["t_s"].to_numpy()
    frozen = (t >= 1 - 1e-9) & (t < 2 - 1e-9)
    np.testing.assert_allclose(f["gnss_x_m"].to_numpy()[frozen], 10.0 * 0.99, atol=1e-9)
    np.testing.assert_allclose(f["gnss_x_m"].to_numpy()[~frozen], 10.0 * t[~frozen], atol=1e-9)
    np.testing.assert_allclose(f["ay_mps2"].to_numpy(), np.where(t >= 2 - 1e-9, 0.5, 0.0), atol=1e-12)
    # Delay from 3 s: samples 3.00..3.04 arrive at 3.05..3.09, clashing with nothing; the rows
    # 3.00..3.04 receive nothing (the earlier samples arrived on time at 2.95..2.99).
    radar = f["radar_valid"].to_numpy()
    assert not radar[(t > 3 - 1e-9) & (t < 3.05 - 1e-9)].any()
    late = (t > 3.05 - 1e-9)
    np.testing.assert_allclose(f["range_m"].to_numpy()[late], 30.0 + 0.0 * t[late])
    assert pd.isna(f["range_m"].to_numpy()[(t > 3 - 1e-9) & (t < 3.05 - 1e-9)]).all()
