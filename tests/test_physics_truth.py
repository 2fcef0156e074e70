"""Physics of the truth held to analytic statics (roadtruth.harness.truth.suspension_statics) and to the bicycle model:
roll gradient, quasi-static wheel lift, no rollover below the friction limit, banked curve at its
neutral speed, brake to a stop, linear range, camber thrust. Predicted and measured values are in
every assert message."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from roadtruth.harness.errors import ScenarioError
from roadtruth.harness.truth.scenario import available_scenarios, load_scenario, parse_scenario
from roadtruth.harness.truth.simulate import simulate
from roadtruth.harness.truth.suspension_statics import (
    banked_neutral_speed,
    linear_understeer_gradient,
    load_transfer,
    roll_statics,
    wheel_lift,
)
from roadtruth.harness.truth.vehicle import Aero, G, load_vehicle


def _scenario(duration: float, steer: dict, speed: dict | None = None, v0: float = 20.0, mu: float = 1.0):
    data = {"name": "physics", "vehicle": "sedan", "duration_s": duration, "initial_speed_mps": v0,
            "friction": {"mu_default": mu}, "driver": {"steer": steer}}
    if speed is not None:
        data["driver"]["speed"] = speed
    return parse_scenario(data, "physics")


def _smooth(x: np.ndarray, n: int = 101) -> np.ndarray:
    """Centred moving average over n samples (0.1 s at 1 kHz), same length (edges shortened)."""
    k = np.ones(n) / n
    return np.convolve(np.pad(x, n // 2, mode="edge"), k, mode="valid")


@pytest.fixture(scope="module")
def sedan():
    return load_vehicle("sedan")


def test_steady_state_roll_gradient(sedan) -> None:
    """Constant small steer at 20 m/s (a_y ~ 2.5 m/s^2): roll / a_y within 5 % of the statics."""
    tr = simulate(_scenario(5.0, {"type": "step", "t_start_s": 0.5, "amplitude_deg": 1.2}), vehicle=sedan)
    assert tr.status == "ok", tr.status
    late = tr.frame[tr.frame.t_s > 3.5]
    ay, roll = late.ay_mps2.mean(), late.roll_rad.mean()
    assert 1.5 < ay < 3.0, f"a_y {ay:.2f} m/s^2 is not the low-a_y range this test is for"
    measured = roll / ay
    predicted = roll_statics(sedan).roll_gradient_radpmps2
    assert measured == pytest.approx(predicted, rel=0.05), (
        f"roll gradient: measured {math.degrees(measured):.4f} deg/(m/s^2), "
        f"predicted {math.degrees(predicted):.4f} deg/(m/s^2)")


def test_quasi_static_inner_wheel_lift(sedan) -> None:
    """Slow ramp steer (0.8 deg/s road wheel) on high-grip tires: the inner front wheel reaches 5 % of
    its static load at the a_y the linear load transfer predicts (within 10 %)."""
    grippy = sedan.with_overrides(tires=dataclasses.replace(sedan.tires, grip=1.7))
    lift = wheel_lift(grippy)
    assert lift.first == "front" and lift.lift_mps2 < 0.9 * 1.7 * G  # lift comes before the friction limit
    tr = simulate(_scenario(16.0, {"type": "ramp", "t_start_s": 0.5, "rate_degps": 0.8, "max_deg": 12.0}),
                  vehicle=grippy)
    f = tr.frame
    fz0 = roll_statics(grippy).front.static_wheel_load_N
    fz_in = _smooth(f.fz_fl_N.to_numpy())  # left turn: the left wheels are inside
    below = np.flatnonzero(fz_in < 0.05 * fz0)
    assert below.size, (f"inner front wheel never unloaded (min F_z {fz_in.min():.0f} N, predicted lift at "
                        f"a_y {lift.front_mps2:.2f} m/s^2, reached a_y {f.ay_mps2.max():.2f} m/s^2; {tr.status})")
    k = below[0]
    ay_at = _smooth(f.ay_mps2.to_numpy())[k]
    predicted = 0.95 * lift.front_mps2  # 95 % of the static load transferred
    assert ay_at == pytest.approx(predicted, rel=0.10), (
        f"inner front wheel at 5 % load: a_y {ay_at:.2f} m/s^2 measured, {predicted:.2f} m/s^2 predicted "
        f"(t = {f.t_s.iloc[k]:.2f} s)")


def test_no_rollover_of_the_sedan_at_the_friction_limit(sedan) -> None:
    """mu = 1 flat dry road, slow ramp steer far past the limit: the car saturates (a_y near mu g) but
    neither rolls over nor lifts a wheel, since the predicted lift a_y is above mu g."""
    lift = wheel_lift(sedan)
    assert lift.lift_mps2 > 1.15 * G, f"premise: the sedan's predicted lift a_y {lift.lift_mps2:.2f} m/s^2 > mu g"
    tr = simulate(_scenario(14.0, {"type": "ramp", "t_start_s": 0.5, "rate_degps": 1.0, "max_deg": 13.0}),
                  vehicle=sedan)
    f = tr.frame
    peak = float(np.max(np.abs(_smooth(f.ay_mps2.to_numpy()))))
    kinds = [e.kind for e in tr.truth_events]
    assert "rolled over" not in tr.status and "rolled over" not in kinds, (
        f"rolled over: {tr.status}; events {kinds}; peak a_y {peak:.2f} m/s^2, predicted lift "
        f"{lift.lift_mps2:.2f} m/s^2")
    assert "wheel lift" not in kinds, f"a wheel lifted at mu = 1 (peak a_y {peak:.2f}, predicted lift {lift.lift_mps2:.2f})"
    assert peak > 0.85 * G, f"the ramp did not reach the friction limit (peak a_y {peak:.2f} m/s^2)"
    assert float(np.max(np.abs(f.roll_rad))) < math.radians(10.0)


def test_banked_curve_at_its_neutral_speed_needs_no_lateral_tire_force(sedan) -> None:
    """On a banked road at v = sqrt(g R tan phi_b) the road-plane weight component carries the turn:
    sum of F_y ~ 0, and the accelerometer (specific force) points along the body z axis: its body-y
    component ~ 0 while the horizontal centripetal acceleration v^2/R = g tan phi_b is not."""
    if "banked_curve" not in available_scenarios():
        pytest.skip("the banked_curve scenario is not shipped yet")
    sc = load_scenario("banked_curve")
    road = sc.road
    def bank_of(s_m: float) -> float:  # the road's bank column (samples[:, 7], ISO: left edge up > 0)
        return float(np.interp(s_m, road.samples[:, 0], road.samples[:, 7]))
    # The steady arc: where the curvature is at its largest magnitude.
    rho = road.samples[:, 4]
    arc = np.flatnonzero(np.abs(rho) > 0.98 * np.max(np.abs(rho)))
    s_mid = float(road.samples[arc[len(arc) // 2], 0])
    radius = 1.0 / abs(float(rho[arc[len(arc) // 2]]))
    bank = float(np.asarray(bank_of(s_mid)))
    # A left turn needs the right (outer) edge higher: bank < 0 with "left edge higher" positive.
    assert bank * rho[arc[0]] < 0.0, f"the curve is banked the wrong way (bank {bank:.3f} rad, rho {rho[arc[0]]:.4f})"
    v_n = banked_neutral_speed(radius, bank)
    sc = dataclasses.replace(sc, initial_speed_mps=v_n, driver=dataclasses.replace(
        sc.driver, speed=dataclasses.replace(sc.driver.speed, type="hold", target_mps=v_n, points=())))
    tr = simulate(sc, vehicle=sedan)
    assert tr.status == "ok", tr.status
    f = tr.frame
    on_arc = (f.s_m > float(road.samples[arc[0], 0]) + 3.0 * v_n) & (f.s_m < float(road.samples[arc[-1], 0]) - 5.0)
    late = f[on_arc]
    assert len(late) > 1000, "too little of the run on the banked arc"
    fy_sum = late[["fy_fl_N", "fy_fr_N", "fy_rl_N", "fy_rr_N"]].sum(axis=1).mean()
    scale = sedan.mass_kg * G * abs(math.sin(bank))
    assert abs(fy_sum) < 0.05 * scale, (f"lateral tire force sum {fy_sum:.1f} N at the neutral speed "
                                         f"{v_n:.2f} m/s; m g sin(bank) = {scale:.0f} N")
    fy_body = late.fspec_y_body_mps2.mean()
    assert abs(fy_body) < 0.05 * G * abs(math.sin(bank)), (
        f"accelerometer body-y {fy_body:.3f} m/s^2, expected 0 (g sin(bank) = {G * abs(math.sin(bank)):.3f})")
    fz_body = late.fspec_z_body_mps2.mean()
    assert fz_body == pytest.approx(G / math.cos(bank), rel=0.01), f"accelerometer body-z {fz_body:.3f} m/s^2"
    centripetal = (late.vx_mps * late.yaw_rate_radps).mean()
    assert abs(centripetal) == pytest.approx(G * math.tan(abs(bank)), rel=0.05), (
        f"v r = {centripetal:.3f} m/s^2, g tan(bank) = {G * math.tan(abs(bank)):.3f} m/s^2")


def test_brake_to_stop_ends_at_rest(sedan) -> None:
    """6 m/s^2 braking from 20 m/s: at rest (< 0.01 m/s) within 1.5 s of the stop (speed under 0.3
    m/s), the braked wheels never turn back, still 1 s after rest, under 5 mm of creep over 2 s."""
    try:
        sc = _scenario(9.0, {"type": "constant", "t_start_s": 0.0, "amplitude_deg": 0.0},
                       {"type": "brake", "t_start_s": 1.0, "decel_mps2": 6.0})
    except ScenarioError as exc:  # pragma: no cover - the format must keep accepting this
        pytest.fail(str(exc))
    tr = simulate(sc, vehicle=sedan)
    f = tr.frame
    vx, t = f.vx_mps.to_numpy(), f.t_s.to_numpy()
    slow = np.flatnonzero((t > 1.0) & (np.abs(vx) < 0.3))
    assert slow.size, f"never slowed below 0.3 m/s (min speed {np.abs(vx[t > 1.0]).min():.3f} m/s; {tr.status})"
    t_stop = t[slow[0]]
    rest = np.flatnonzero((t > t_stop) & (np.abs(vx) < 0.01))
    assert rest.size and t[rest[0]] - t_stop <= 1.5, (
        f"not at rest within 1.5 s of the stop at t = {t_stop:.2f} s (min |v| after it "
        f"{np.abs(vx[t > t_stop]).min():.4f} m/s)")
    k0 = rest[0]
    # The body rocks back on its suspension as the pitch of braking springs out (its CG moves by a
    # few cm/s), but the braked wheels do not turn backwards: under 0.01 rad (3 mm) of spin.
    for w in ("fl", "fr", "rl", "rr"):
        spin = np.cumsum(f[f"omega_{w}_radps"].to_numpy()[slow[0]:]) * (t[1] - t[0])
        assert spin.min() > -0.01, f"wheel {w} turns back {spin.min():.4f} rad after the stop"
    late = t > t[k0] + 1.0
    assert np.abs(vx[late]).max() < 0.01, f"still moving 1 s after rest: max |v_x| {np.abs(vx[late]).max():.4f} m/s"
    # Creep: the CG's drift over 2 s once the rocking has settled (1 s after rest).
    window = (t >= t[k0] + 1.0) & (t <= t[k0] + 3.0)
    assert t[window][-1] >= t[k0] + 2.99, "run too short for the creep window"
    x, y = f.x_m.to_numpy()[window], f.y_m.to_numpy()[window]
    creep = math.hypot(x[-1] - x[0], y[-1] - y[0])
    assert creep < 0.005, f"creep {creep * 1000:.2f} mm over 2 s at rest"


def test_linear_range_yaw_rate_matches_the_linear_car(sedan) -> None:
    """0.5 deg step at 20 m/s (a_y ~ 1 m/s^2), drag and rolling resistance off: the steady yaw rate is
    the linear car's, v δ / (L + K v²), with K including aligning torque and roll camber (within 1 %);
    the bare bicycle model, which has neither, is 3-8 % off."""
    lateral = sedan.with_overrides(aero=Aero(), tires=dataclasses.replace(sedan.tires, rolling_resistance=0.0))
    tr = simulate(_scenario(4.0, {"type": "step", "t_start_s": 0.5, "amplitude_deg": 0.5}), vehicle=lateral)
    late = tr.frame[tr.frame.t_s > 3.0]
    r_ss, vx, delta = late.yaw_rate_radps.mean(), late.vx_mps.mean(), late.delta_rad.mean()
    k = linear_understeer_gradient(lateral)
    r_linear = vx * delta / (lateral.wheelbase_m + k * vx**2)
    assert r_ss == pytest.approx(r_linear, rel=0.01), f"yaw rate {r_ss:.5f} rad/s, linear car {r_linear:.5f} rad/s"
    r_bicycle = lateral.steady_yaw_rate(vx, delta)
    assert 1.03 < r_bicycle / r_ss < 1.08, f"bicycle {r_bicycle:.5f} rad/s vs {r_ss:.5f} rad/s"


def test_static_camber_gives_opposite_equal_camber_thrust(sedan) -> None:
    """-1 deg static camber (top of each wheel toward the car's centre) on all wheels, straight line:
    each wheel pushes toward the centre line (left F_y < 0, right F_y > 0), equal and opposite."""
    fields = {f.name for f in dataclasses.fields(sedan.suspension)}
    if not {"static_camber_f_rad", "static_camber_r_rad"} <= fields:
        pytest.skip("the vehicle has no static camber fields yet")
    gamma = math.radians(-1.0)
    v = sedan.with_overrides(suspension=dataclasses.replace(sedan.suspension, static_camber_f_rad=gamma,
                                                            static_camber_r_rad=gamma))
    tr = simulate(_scenario(3.0, {"type": "constant", "t_start_s": 0.0, "amplitude_deg": 0.0}), vehicle=v)
    assert tr.status == "ok", tr.status
    late = tr.frame[tr.frame.t_s > 2.0]
    for axle, (left, right) in {"front": ("fy_fl_N", "fy_fr_N"), "rear": ("fy_rl_N", "fy_rr_N")}.items():
        fl, fr = late[left].mean(), late[right].mean()
        c_gamma = getattr(getattr(v.tires, axle), "camber_stiffness", 0.0)
        fz = late[left.replace("fy", "fz")].mean()
        expected = c_gamma * fz * abs(gamma)  # magnitude at zero slip, F_y,gamma = c_gamma F_z gamma
        assert fl < 0.0 < fr, f"{axle}: camber thrust left {fl:.1f} N, right {fr:.1f} N (expected left < 0 < right)"
        assert abs(fl + fr) < 0.05 * max(abs(fl), abs(fr)), f"{axle}: left {fl:.1f} N, right {fr:.1f} N not opposite"
        if expected > 0.0:
            assert abs(fr) == pytest.approx(expected, rel=0.15), (
                f"{axle}: |F_y| {abs(fr):.1f} N, c_gamma F_z |gamma| = {expected:.1f} N")
    assert abs(late.yaw_rate_radps.mean()) < 1e-3 and abs(late.vy_mps.mean()) < 0.02


def test_load_transfer_per_axle_matches_the_statics(sedan) -> None:
    """The steady roll test's wheel loads: each axle's transfer (F_z,out - F_z,in)/2 per unit a_y within
    5 % of the model statics (the front/rear split is what decides which wheel lifts first)."""
    tr = simulate(_scenario(5.0, {"type": "step", "t_start_s": 0.5, "amplitude_deg": 1.2}), vehicle=sedan)
    late = tr.frame[tr.frame.t_s > 3.5]
    ay = late.ay_mps2.mean()
    lt = load_transfer(sedan)
    for axle, (inner, outer), pred in (("front", ("fz_fl_N", "fz_fr_N"), lt.front.model),
                                       ("rear", ("fz_rl_N", "fz_rr_N"), lt.rear.model)):
        measured = (late[outer].mean() - late[inner].mean()) / 2.0 / ay
        assert measured == pytest.approx(pred, rel=0.05), (
            f"{axle} load transfer {measured:.1f} N/(m/s^2) measured, {pred:.1f} predicted")
