"""Property-based tests (hypothesis): whatever faults are stacked on whichever sensors, a missing
sample is NaN in every channel with ``<sensor>_valid = 0``, faults never create a value where the
sensor had none, and a healthy sensor is never missing."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from roadtruth.harness.sensors import SENSORS, FaultSpec, emulate, load_sensor_config, valid_column
from roadtruth.harness.sensors.faults import FAULT_KINDS
from roadtruth.harness.sensors.synthetic import steady_motion_truth
from roadtruth.harness.truth.vehicle import load_vehicle

VEHICLE = load_vehicle("sedan")
DURATION = 3.0
LANE_GAPS = ((10.0, 15.0),)


def make_truth():
    truth = steady_motion_truth(DURATION, vx_mps=15.0, yaw_rate_radps=0.15, roll_rad=0.02, range_m=35.0,
                                range_rate_mps=-1.0)
    truth.loc[truth["t_s"] < 1.5, ["range_m", "range_rate_mps"]] = np.nan  # the lead cuts in at 1.5 s
    return truth


TRUTH = make_truth()
OVERRIDES = {"ogs": {"enabled": True}}
BASE = load_sensor_config("automotive", overrides=OVERRIDES)
prob = st.floats(0.0, 1.0)
when = st.floats(0.0, DURATION)


@st.composite
def faults(draw):
    sensor = draw(st.sampled_from(list(SENSORS)))
    # partial faults blank channels of delivered samples by design (tested in test_observers_gnss_kinematic)
    kind = draw(st.sampled_from([k for k in FAULT_KINDS if FAULT_KINDS[k].scope != "partial"]))
    channel = None
    if FAULT_KINDS[kind].per_channel and draw(st.booleans()):
        channel = draw(st.sampled_from(SENSORS[sensor].COLUMNS))
    t0 = draw(when)
    params = {
        "dropout": lambda: {"p": draw(prob)},
        "burst": lambda: {"p_enter": draw(prob), "mean_len": draw(st.floats(1.0, 20.0)),
                          "loss_good": draw(prob), "loss_bad": draw(prob)},
        "outage": lambda: {"t_start_s": t0, "t_end_s": t0 + draw(when)},
        "bias_step": lambda: {"size": draw(st.floats(-5, 5)), "t_start_s": t0},
        "spike": lambda: {"p": draw(prob), "magnitude": draw(st.floats(0.0, 10.0))},
        "freeze": lambda: {"t_start_s": t0, "t_end_s": t0 + draw(when),
                           "value": draw(st.one_of(st.none(), st.floats(-3, 3)))},
        "delay": lambda: {"extra_s": draw(st.floats(0.0, 0.3)), "jitter_s": draw(st.floats(0.0, 0.2)),
                          "t_start_s": t0},
    }[kind]()
    return FaultSpec(sensor=sensor, kind=kind, params=params, channel=channel)


def run(fault_list, seed):
    cfg = load_sensor_config("automotive", overrides=OVERRIDES, faults=list(fault_list))
    return emulate(TRUTH, VEHICLE, cfg, seed=seed, lane_gaps=LANE_GAPS).frame


def check_valid_iff_values(frame):
    for name in BASE.enabled():
        cols = list(SENSORS[name].COLUMNS)
        finite = np.isfinite(frame[cols].to_numpy())
        valid = frame[valid_column(name)].to_numpy() == 1
        assert np.array_equal(finite.all(axis=1), valid), name  # a sample carries every channel
        assert not finite[~valid].any(), name                    # no value without a sample


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fault_list=st.lists(faults(), max_size=5), seed=st.integers(0, 2**32 - 1))
def test_faults_never_invent_values_and_never_lose_healthy_samples(fault_list, seed):
    value_only = [f for f in fault_list if FAULT_KINDS[f.kind].scope == "value"]
    healthy, valued, faulty = run([], seed), run(value_only, seed), run(fault_list, seed)
    for frame in (healthy, valued, faulty):
        check_valid_iff_values(frame)
    for name in BASE.enabled():
        v = valid_column(name)
        # Value faults never remove a sample: where the healthy sensor delivered, it still does.
        np.testing.assert_array_equal(valued[v], healthy[v])
        delayed = any(f.sensor == name and f.kind == "delay" for f in fault_list)
        ok = faulty[v].to_numpy() == 1
        if not delayed:
            # Availability faults only remove samples, and what survives is untouched.
            assert not (ok & (valued[v].to_numpy() == 0)).any(), name
            for c in SENSORS[name].COLUMNS:
                np.testing.assert_array_equal(faulty[c].to_numpy()[ok], valued[c].to_numpy()[ok])
        assert ok.sum() <= (valued[v].to_numpy() == 1).sum(), name


def test_healthy_sensors_deliver_every_sample_they_can():
    frame = run([], seed=3)
    t = frame["t_s"].to_numpy()
    for name in BASE.enabled():
        cfg = BASE.sensors[name]
        step = int(round(100.0 / cfg.rate_hz))
        arrival_rows = np.arange(0, t.size, step) + int(np.ceil(cfg.latency_s * 100.0 - 1e-6))
        arrival_rows = arrival_rows[arrival_rows < t.size]
        expected = np.zeros(t.size, dtype=bool)
        expected[arrival_rows] = True
        sample_t = t - np.ceil(cfg.latency_s * 100.0 - 1e-6) / 100.0
        if name == "radar":
            expected &= sample_t >= 1.5 - 1e-9
        if name == "camera":
            s = 15.0 * sample_t
            expected &= ~((s >= 10.0) & (s <= 15.0))
        if name == "wheel_speed":
            expected &= sample_t > 0.005  # no edge pair yet at t = 0
        valid = frame[valid_column(name)].to_numpy() == 1
        if name == "camera":  # the preset's own 1 % random dropout
            assert not (valid & ~expected).any() and valid.sum() >= expected.sum() - 4
        else:
            np.testing.assert_array_equal(valid, expected, err_msg=name)
