"""Driver: open-loop profiles, parse errors, Ackermann, rate limit, lead kinematics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadtruth.harness.errors import ScenarioError
from roadtruth.harness.truth.driver import (
    HOLD_DECEL_MPS2,
    MAX_DECEL_DEMAND,
    ackermann_angles,
    parse_driver,
    parse_lead,
    rate_limit,
    speed_controller,
)

DT = 0.001
T = np.arange(0.0, 8.0 + DT / 2, DT)


def _steer(block: dict) -> np.ndarray:
    return parse_driver({"steer": block}, "test.yaml").steer_profile(T)


def test_step_reaches_amplitude_after_rise_time() -> None:
    d = _steer({"type": "step", "t_start_s": 1.0, "amplitude_deg": 2.0, "rise_time_s": 0.2})
    assert np.all(d[T < 1.0] == 0.0)
    assert np.all(np.abs(d[T >= 1.2 - 1e-9] - math.radians(2.0)) < 1e-15)
    i = np.searchsorted(T, 1.1)
    assert d[i] == pytest.approx(math.radians(1.0), rel=1e-9)  # linear rise, half way


def test_sine_with_dwell_timing() -> None:
    f, a, dwell, t0 = 0.7, 5.0, 0.5, 1.0
    d = np.degrees(_steer({"type": "sine_with_dwell", "t_start_s": t0, "amplitude_deg": a, "frequency_hz": f,
                           "dwell_s": dwell}))
    assert T[np.argmax(d)] == pytest.approx(t0 + 0.25 / f, abs=DT)
    held = T[np.abs(d + a) < 1e-9]
    assert held[0] == pytest.approx(t0 + 0.75 / f, abs=DT)
    assert held[-1] == pytest.approx(t0 + 0.75 / f + dwell, abs=DT)
    end = t0 + 1.0 / f + dwell
    assert np.all(d[T > end + DT] == 0.0)
    assert abs(d[np.searchsorted(T, end - 0.01)]) < 0.3  # back near zero at the end of the last quarter


def test_fishhook_shape() -> None:
    a, rate, dwell, t0 = 6.0, 48.0, 0.25, 1.0
    d = np.degrees(_steer({"type": "fishhook", "t_start_s": t0, "amplitude_deg": a, "rate_degps": rate,
                           "dwell_s": dwell, "direction": "right"}))
    t1 = t0 + a / rate
    assert d.min() == pytest.approx(-a) and d.max() == pytest.approx(a)
    first = T[np.argmax(np.abs(d + a) < 1e-9)]
    assert first == pytest.approx(t1, abs=DT)  # right first, at the ramp rate
    slope = np.diff(d) / DT
    assert np.max(np.abs(slope)) == pytest.approx(rate, rel=1e-6)
    reach = T[np.argmax(d > a - 1e-9)]
    assert reach == pytest.approx(t1 + dwell + 2 * a / rate, abs=DT)
    assert np.all(d[T > reach] == pytest.approx(a))


def test_ramp_sine_sweep_constant() -> None:
    r = np.degrees(_steer({"type": "ramp", "t_start_s": 0.5, "rate_degps": -4.0, "max_deg": 6.0}))
    assert r[np.searchsorted(T, 1.5)] == pytest.approx(-4.0, abs=1e-9) and r.min() == pytest.approx(-6.0)
    s = np.degrees(_steer({"type": "sine", "t_start_s": 1.0, "amplitude_deg": 3.0, "frequency_hz": 0.5, "cycles": 2}))
    assert s.max() == pytest.approx(3.0, abs=1e-6) and np.all(s[T > 5.0 + DT] == 0.0)
    w = np.degrees(_steer({"type": "sweep", "t_start_s": 0.0, "amplitude_deg": 1.0, "f0_hz": 0.2, "f1_hz": 2.0,
                           "sweep_duration_s": 6.0}))
    crossings = T[1:][np.diff(np.signbit(w)) != 0]
    gaps = np.diff(crossings[crossings < 6.0])
    assert gaps[-1] == pytest.approx(0.5 / 2.0, rel=0.1)  # half a period at f1 = 2 Hz
    assert np.all(np.diff(gaps) < 1e-9)  # the frequency rises
    c = np.degrees(_steer({"type": "constant", "t_start_s": 2.0, "amplitude_deg": -1.5}))
    assert np.allclose(c[T >= 2.0], -1.5, rtol=1e-15) and np.all(c[T < 2.0] == 0.0)


@pytest.mark.parametrize("block, field", [
    ({"steer": {"type": "step", "t_start_s": 1, "amplitude_deg": 2, "bogus": 1}}, "driver.steer.bogus"),
    ({"steer": {"type": "wiggle"}}, "driver.steer.type"),
    ({"steer": {"type": "step", "t_start_s": 1}}, "driver.steer.amplitude_deg"),
    ({"steer": {"type": "fishhook", "t_start_s": 1, "amplitude_deg": 5, "rate_degps": 0, "dwell_s": 0.2}},
     "driver.steer.rate_degps"),
    ({"steer": {"type": "sine", "t_start_s": 1, "amplitude_deg": "two", "frequency_hz": 1}},
     "driver.steer.amplitude_deg"),
    ({"speed": {"type": "profile", "points": [[0, 20], [0, 25]]}}, "driver.speed.points"),
    ({"speed": {"type": "brake", "t_start_s": 1, "decel_mps2": -3}}, "driver.speed.decel_mps2"),
    ({"speed": {"type": "hold"}, "extra": 1}, "driver.extra"),
])
def test_parse_errors_name_file_and_field(block: dict, field: str) -> None:
    with pytest.raises(ScenarioError) as err:
        parse_driver(block, "sc.yaml")
    assert str(err.value).startswith(f"sc.yaml: {field}:")


def test_parse_lead_and_its_kinematics() -> None:
    lead = parse_lead({"initial_gap_m": 30.0, "speed_points": [[0, 20], [10, 25]]}, "sc.yaml")
    s = lead.path_coordinate(T, lf_m=1.2)
    v = lead.speed(T)
    assert v[0] == 20.0 and v[np.searchsorted(T, 5.0)] == pytest.approx(22.5)
    exact = 20.0 * T + 0.25 * T**2  # integral of the linear speed
    np.testing.assert_allclose(s - s[0], exact, atol=1e-9)
    with pytest.raises(ScenarioError, match="lead.speed_points"):
        parse_lead({"initial_gap_m": 30.0, "speed_points": [[0, -1]]}, "sc.yaml")
    with pytest.raises(ScenarioError, match="lead.initial_gap_m"):
        parse_lead({"speed_points": [[0, 20]]}, "sc.yaml")


def test_defaults_drive_straight_at_initial_speed() -> None:
    d = parse_driver(None, "sc.yaml")
    assert np.all(d.steer_profile(T) == 0.0)
    v, dv = d.speed_target(T, 17.0)
    assert np.all(v == 17.0) and np.all(dv == 0.0)


def test_ackermann_mean_is_exact_and_inner_wheel_steers_more() -> None:
    for delta in (0.01, 0.1, 0.4, -0.3):
        dl, dr = ackermann_angles(delta, 2.6, 1.6, 1.0)
        assert 0.5 * (dl + dr) == pytest.approx(delta, abs=1e-15)
        inner, outer = (dl, dr) if delta > 0 else (-dr, -dl)
        assert inner > outer
        # cot(outer) - cot(inner) = track / L (full Ackermann), to third order in delta
        assert 1 / math.tan(outer) - 1 / math.tan(inner) == pytest.approx(1.6 / 2.6, rel=0.05 + delta**2)
    assert ackermann_angles(0.2, 2.6, 1.6, 0.0) == (0.2, 0.2)


def test_rate_limit_and_clip() -> None:
    x = 0.0
    for _ in range(100):
        x = rate_limit(x, 1.0, 2.0, 0.5, DT)
    assert x == pytest.approx(0.2)
    for _ in range(1000):
        x = rate_limit(x, 1.0, 2.0, 0.5, DT)
    assert x == 0.5


def test_speed_controller_brakes_to_a_stop_and_holds() -> None:
    a, _ = speed_controller(1, 2.0, 20.0, 20.0, 0.0, 0.0, 1.0, 6.0, DT)
    assert a == -6.0
    # The brake demand stays on down to standstill: the brakes (joint friction) then hold the car.
    a, _ = speed_controller(1, 2.0, 0.0, 20.0, 0.0, 0.0, 1.0, 6.0, DT)
    assert a == -6.0
    # A stop target reached: the driver holds the car on the brake, the integrator is reset.
    a, i = speed_controller(0, 5.0, 0.2, 0.0, 0.0, 3.0, 0.0, 0.0, DT)
    assert a == -HOLD_DECEL_MPS2 and i == 0.0
    a, _ = speed_controller(0, 5.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, DT)
    assert -MAX_DECEL_DEMAND <= a < 0.0  # still rolling toward the stop: the PI brakes
    a, _ = speed_controller(0, 0.0, 18.0, 20.0, 0.0, 0.0, 0.0, 0.0, DT)
    assert a > 0.0
