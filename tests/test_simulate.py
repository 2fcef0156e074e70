"""Ground truth physics: linear range vs bicycle model, nonlinear range, load transfer, friction,
accelerometer gravity leak, determinism, compiled == interpreted, divergence guard."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from roadtruth.harness.errors import InputError, ScenarioError
from roadtruth.harness.signals import CANONICAL
from roadtruth.harness.truth.friction_map import FrictionMap, Patch
from roadtruth.harness.truth.scenario import load_scenario, parse_scenario
from roadtruth.harness.truth.simulate import simulate
from roadtruth.harness.truth.suspension_statics import linear_understeer_gradient
from roadtruth.harness.truth.vehicle import Aero, G, load_vehicle


def _scenario(duration: float, steer: dict, **extra):
    data = {"name": "test", "vehicle": "sedan", "duration_s": duration, "initial_speed_mps": 20.0,
            "driver": {"steer": steer}}
    data.update(extra)
    return parse_scenario(data, "test")


@pytest.fixture(scope="module")
def sedan():
    return load_vehicle("sedan")


@pytest.fixture(scope="module")
def step_1deg():
    return simulate(_scenario(4.0, {"type": "step", "t_start_s": 0.5, "amplitude_deg": 1.0}))


@pytest.fixture(scope="module")
def step_3deg():
    return simulate(_scenario(3.5, {"type": "step", "t_start_s": 0.5, "amplitude_deg": 3.0}))


def test_frame_has_every_canonical_signal_and_extras(step_1deg) -> None:
    f = step_1deg.frame
    assert step_1deg.status == "ok"
    assert len(f) == 4001 and np.allclose(np.diff(f.t_s), 0.001)
    for name in CANONICAL:
        assert name in f.columns, name
    for name in ("wx_body_radps", "dwz_body_radps2", "az_body_mps2", "vz_mps", "s_m", "lead_x_m", "steer_cmd_rad",
                 "drive_torque_Nm", "brake_torque_Nm"):
        assert name in f.columns, name
    no_lead = {"range_m", "range_rate_mps", "lead_x_m", "lead_y_m", "lead_v_mps", "lead_accel_mps2"}
    assert np.isfinite(f.drop(columns=list(no_lead)).to_numpy()).all()
    assert f.range_m.isna().all()
    assert step_1deg.qpos.shape == (4001, 17)


def test_starts_in_static_equilibrium(sedan) -> None:
    # Aerodynamic lift is not part of the built equilibrium (it depends on the speed): without it
    # the car must start at rest in heave, pitch and roll.
    still = dataclasses.replace(sedan, aero=Aero(), tires=dataclasses.replace(sedan.tires, rolling_resistance=0.0))
    run = simulate(_scenario(0.5, {"type": "step", "t_start_s": 0.5, "amplitude_deg": 1.0}), still)
    before = run.frame[run.frame.t_s < 0.5]
    assert np.abs(before.vz_mps).max() < 1e-3
    assert np.abs(before.pitch_rad).max() < 5e-4 and np.abs(before.roll_rad).max() < 1e-6
    total = before[["fz_fl_N", "fz_fr_N", "fz_rl_N", "fz_rr_N"]].sum(axis=1)
    assert np.allclose(total, sedan.mass_kg * G, rtol=2e-3)


def _lateral_only(v):
    """The car without drag and rolling resistance: their drive force takes a share of the rear tires'
    friction (combined slip) that a linear lateral model does not have."""
    return dataclasses.replace(v, aero=Aero(), tires=dataclasses.replace(v.tires, rolling_resistance=0.0))


def test_linear_step_steer_matches_bicycle_model(step_1deg, sedan) -> None:
    run = simulate(_scenario(4.0, {"type": "step", "t_start_s": 0.5, "amplitude_deg": 1.0}), _lateral_only(sedan))
    late = run.frame[run.frame.t_s > 3.0]
    r_ss = late.yaw_rate_radps.mean()
    vx, delta = late.vx_mps.mean(), late.delta_rad.mean()
    roll_gradient = abs(late.roll_rad.mean() / late.ay_mps2.mean())
    k = linear_understeer_gradient(sedan, roll_gradient)
    # The linear car with the aligning torque and roll camber of its tires: within 1 %.
    assert r_ss == pytest.approx(vx * delta / (sedan.wheelbase_m + k * vx**2), rel=0.01)
    # The bare bicycle model (no aligning torque, no camber) misses those terms: 3-8 % more yaw rate.
    assert 1.03 < sedan.steady_yaw_rate(vx, delta) / r_ss < 1.08
    # The aligning moments turn the road wheels back through the steering's compliance (servo).
    assert 0.9 * math.radians(1.0) < late.delta_rad.mean() < math.radians(1.0)
    # Understeering car at speed: negative sideslip at the CG (rear slips more than kinematics).
    assert late.beta_rad.mean() < 0.0
    # Contract definitions agree with the per-wheel physics in the linear range.
    # The front axle's slip makes its force plus up for the camber thrust of the outward lean.
    lean = (1.0 + sedan.suspension.camber_gain_f_radpm * sedan.track_f_m / 2.0) * abs(late.roll_rad.mean())
    camber_slip = sedan.tires.front.camber_stiffness * sedan.fz_front_static_N * lean / sedan.cornering_stiffness_f_Npr
    assert late.alpha_f_rad.mean() == pytest.approx(
        late.fy_f_N.mean() / sedan.cornering_stiffness_f_Npr + camber_slip, rel=0.03)


def test_wheel_loads_sum_to_weight_and_show_load_transfer(step_3deg, sedan) -> None:
    late = step_3deg.frame[step_3deg.frame.t_s > 2.5]
    fz = late[["fz_fl_N", "fz_fr_N", "fz_rl_N", "fz_rr_N"]].mean()
    vx = late.vx_mps.mean()
    lift = 0.5 * sedan.aero.air_density_kgpm3 * (sedan.aero.lift_area_f_m2 + sedan.aero.lift_area_r_m2) * vx**2
    assert fz.sum() == pytest.approx(sedan.mass_kg * G - lift, rel=2e-3)
    # Left turn: the right (outer) wheels carry more.
    assert fz.fz_fr_N > fz.fz_fl_N + 500 and fz.fz_rr_N > fz.fz_rl_N + 500
    # Moment balance about a ground-level x axis (lateral tire forces act at ground level):
    # sum dFz * track = m ay h + m g h sin(roll) (the rolled body's weight moves outward).
    transfer = (fz.fz_fr_N - fz.fz_fl_N) / 2 * sedan.track_f_m + (fz.fz_rr_N - fz.fz_rl_N) / 2 * sedan.track_r_m
    roll = late.roll_rad.mean()
    expected = sedan.mass_kg * sedan.h_cg_m * (late.ay_mps2.mean() + G * math.sin(roll))
    assert transfer == pytest.approx(expected, rel=0.05)


def test_accelerometer_sees_gravity_through_roll(step_3deg) -> None:
    late = step_3deg.frame[step_3deg.frame.t_s > 2.5]
    roll = late.roll_rad.mean()
    vr = (late.vx_mps * late.yaw_rate_radps).mean()
    f_y = late.fspec_y_body_mps2.mean()  # MuJoCo's accelerometer at the CG (specific force)
    assert roll > math.radians(1.0)  # rolls outward (right side down) in a left turn
    assert f_y == pytest.approx(vr * math.cos(roll) + G * math.sin(roll), rel=0.02)
    assert f_y - vr > 0.7 * G * math.sin(roll)
    assert late.ay_mps2.mean() == pytest.approx(vr, rel=0.02)


def _linear_bicycle_yaw_rate(v, t: np.ndarray, vx: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Yaw rate of the linear single-track model driven by the same delta(t), vx(t) (Euler, dt of t)."""
    m, iz, lf, lr = v.mass_kg, v.yaw_inertia_kgm2, v.lf_m, v.lr_m
    cf, cr = v.cornering_stiffness_f_Npr, v.cornering_stiffness_r_Npr
    vy, r = 0.0, 0.0
    out = np.empty_like(t)
    dt = t[1] - t[0]
    for k in range(t.size):
        out[k] = r
        fyf = cf * (delta[k] - (vy + lf * r) / vx[k])
        fyr = -cr * (vy - lr * r) / vx[k]
        vy += dt * ((fyf + fyr) / m - vx[k] * r)
        r += dt * (lf * fyf - lr * fyr) / iz
    return out


def test_ramp_steer_gain_falls_below_linear_model(sedan) -> None:
    tr = simulate(_scenario(5.0, {"type": "ramp", "t_start_s": 0.5, "rate_degps": 1.5, "max_deg": 8.0}),
                  _lateral_only(sedan))
    f = tr.frame
    # The linear single-track model with the car's effective axle stiffness (aligning torque and roll
    # camber as in linear_understeer_gradient, folded into the rear axle's stiffness).
    lin = f[(f.ay_mps2 > 1.0) & (f.ay_mps2 < 2.5)]
    k = linear_understeer_gradient(sedan, float(np.median(np.abs(lin.roll_rad / lin.ay_mps2))))
    cf = sedan.cornering_stiffness_f_Npr
    cr_eff = sedan.lf_m / (sedan.lr_m / cf - k * sedan.wheelbase_m / sedan.mass_kg)
    eff = dataclasses.replace(sedan, tires=dataclasses.replace(
        sedan.tires, rear=dataclasses.replace(sedan.tires.rear, By=cr_eff / (sedan.tires.rear.Cy * sedan.fz_rear_static_N))))
    r_lin = _linear_bicycle_yaw_rate(eff, f.t_s.to_numpy(), f.vx_mps.to_numpy(), f.delta_rad.to_numpy())
    ratio = f.yaw_rate_radps.to_numpy() / np.where(r_lin > 1e-3, r_lin, np.nan)
    ay = f.ay_mps2.to_numpy()
    bins = np.array([np.nanmean(ratio[(ay > a) & (ay < a + 1.5)]) for a in (1.0, 2.5, 4.0, 5.5, 7.0)])
    assert bins[0] == pytest.approx(1.0, abs=0.03)  # linear range: the bicycle model
    assert np.all(np.diff(bins) < 0.0)  # the gain falls as ay grows
    assert bins[-1] < 0.85


@pytest.mark.parametrize("mu", [1.0, 0.3])
def test_peak_lateral_acceleration_is_mu_g(mu: float) -> None:
    sc = _scenario(4.5, {"type": "ramp", "t_start_s": 0.5, "rate_degps": 5.0, "max_deg": 20.0},
                   friction={"mu_default": mu})
    f = simulate(sc).frame
    ay = np.convolve(f.ay_mps2, np.ones(101) / 101, mode="valid")  # 0.1 s average
    assert np.max(np.abs(ay)) == pytest.approx(mu * G, rel=0.15)
    assert np.all(f.mu_fl == mu)


def test_ice_patch_builds_up_sideslip() -> None:
    ice = {"patches": [{"name": "ice", "surface": "ice", "rect": {"x_m": [50.0, 200.0], "y_m": [-100.0, 100.0]}}]}
    tr = simulate(_scenario(5.0, {"type": "constant", "t_start_s": 0.3, "amplitude_deg": 2.0}, friction=ice))
    f = tr.frame
    on_ice = f.t_s[(f.mu_rl == 0.1)].min()
    before = np.abs(f.beta_rad[(f.t_s > on_ice - 0.5) & (f.t_s < on_ice)]).max()
    after = np.abs(f.beta_rad[f.t_s > on_ice + 1.0]).max()
    assert after > 5.0 * before and after > math.radians(3.0)
    labels = [e[1] for e in tr.events]
    assert {"fl enters ice (μ 0.1)", "rr enters ice (μ 0.1)"} <= set(labels)
    assert all(m in (1.0, 0.1) for m in np.unique(f[["mu_fl", "mu_fr", "mu_rl", "mu_rr"]]))


def test_same_scenario_twice_gives_identical_truth() -> None:
    sc = load_scenario("step_steer")
    a, b = simulate(sc), simulate(sc)
    assert a.frame.equals(b.frame) and np.array_equal(a.qpos, b.qpos) and a.events == b.events
    assert a.seed == sc.seed and a.status == "ok"


@pytest.mark.parametrize("name", ["car_following", "curvy_road", "split_mu_braking"])
def test_compiled_loop_equals_interpreted_loop(name: str) -> None:
    sc = dataclasses.replace(load_scenario(name), duration_s=0.3)
    a, b = simulate(sc), simulate(sc, compiled=False)
    assert np.array_equal(a.frame.to_numpy(), b.frame.to_numpy(), equal_nan=True)
    assert np.array_equal(a.qpos, b.qpos)


def test_car_following_logs_range_to_the_lead() -> None:
    sc = dataclasses.replace(load_scenario("car_following"), duration_s=1.0)
    f = simulate(sc).frame
    assert f.range_m.iloc[0] == pytest.approx(sc.lead.initial_gap_m, abs=1e-6)
    rr = np.gradient(f.range_m.to_numpy(), f.t_s.to_numpy())
    np.testing.assert_allclose(f.range_rate_mps[5:-5], rr[5:-5], atol=2e-3)


def test_a_rollover_stops_with_a_status_not_an_exception(sedan) -> None:
    tall = sedan.with_overrides(h_cg_m=1.3, track_f_m=1.3, track_r_m=1.3, roll_inertia_kgm2=900.0)
    tr = simulate(load_scenario("fishhook").with_friction(1.5), vehicle=tall)
    assert tr.status.startswith("diverged: rolled over at t=")
    assert len(tr.frame) < 6001 and tr.qpos.shape[0] == len(tr.frame)
    assert tr.events[-1][1] == tr.status


def test_non_finite_physics_stops_with_a_status() -> None:
    sc = load_scenario("step_steer")
    bad = FrictionMap(1.0, (Patch("broken", "", float("nan"),
                                  np.array([[20.0, -5.0], [30.0, -5.0], [30.0, 5.0], [20.0, 5.0]])),))
    tr = simulate(dataclasses.replace(sc, friction=bad))
    assert tr.status.startswith("diverged: non-finite tire force at t=0.9")
    assert np.isfinite(tr.frame.fz_fl_N).all() and tr.frame.x_m.iloc[-1] < 20.5


def test_start_below_3_mps_needs_transient_slip() -> None:
    sc = dataclasses.replace(load_scenario("step_steer"), initial_speed_mps=2.0, duration_s=0.5)
    sedan = load_vehicle("sedan")
    kinematic = dataclasses.replace(sedan, tires=dataclasses.replace(sedan.tires, relaxation_length_m=0.0))
    with pytest.raises(ScenarioError, match="initial_speed_mps"):
        simulate(sc, kinematic)
    # With a relaxation length the tire has deflection states and a car may start at any speed.
    assert simulate(dataclasses.replace(sc, initial_speed_mps=0.0), sedan).status == "ok"


def test_at_rate_decimates(step_1deg) -> None:
    f = step_1deg.at_rate(100.0)
    assert len(f) == 401 and np.allclose(np.diff(f.t_s), 0.01)
    assert f.iloc[7].equals(step_1deg.frame.iloc[70])
    with pytest.raises(InputError):
        step_1deg.at_rate(300.0)


def test_stepped_model_has_no_scenario_visuals_and_the_render_model_poses_from_the_truth() -> None:
    import mujoco

    sc = dataclasses.replace(load_scenario("car_following"), duration_s=0.3)
    truth = simulate(sc)
    stepped = mujoco.MjModel.from_xml_string(truth.model_xml)
    render = mujoco.MjModel.from_xml_string(truth.render_xml)
    assert stepped.nmocap == 0 and not np.any(stepped.geom_matid == stepped.mat("marking").id)
    assert render.nmocap == 1 and np.sum(render.geom_matid == render.mat("marking").id) > 20
    # The logged qpos places every car body of the render model where the stepped model had it.
    ds, dr = mujoco.MjData(stepped), mujoco.MjData(render)
    ds.qpos[:] = dr.qpos[:] = truth.qpos[-1]
    mujoco.mj_kinematics(stepped, ds)
    mujoco.mj_kinematics(render, dr)
    for name in ("chassis", "wheel_fl", "wheel_rr", "knuckle_fr"):
        assert np.array_equal(dr.xpos[render.body(name).id], ds.xpos[stepped.body(name).id])
    assert abs(ds.xpos[stepped.body("chassis").id, 0] - truth.frame.x_m.iloc[-1]) < 1e-9
    from roadtruth.harness.report.render import RenderSource

    assert RenderSource.from_truth(truth).model_xml == truth.render_xml  # what a run's renders draw


def test_an_edited_vehicle_file_is_read_again(tmp_path) -> None:
    # simulate() keeps parsed vehicle sets; an edit of the file must still take effect.
    text = open(load_vehicle("sedan").path).read()
    path = tmp_path / "car.yaml"
    path.write_text(text)
    sc = dataclasses.replace(load_scenario("step_steer"), duration_s=0.05)
    assert simulate(sc, vehicle=str(path)).vehicle.mass_kg == pytest.approx(1500.0)
    path.write_text(text.replace("\nmass_kg: 1500.0", "\nmass_kg: 1645.25"))
    assert simulate(sc, vehicle=str(path)).vehicle.mass_kg == pytest.approx(1645.25)
    assert simulate(sc, vehicle=str(path)).vehicle is simulate(sc, vehicle=str(path)).vehicle


def _floor_raised(monkeypatch: pytest.MonkeyPatch, dz_m: float) -> None:
    """Build the physics model with its floor plane ``dz_m`` higher, so that the chassis box comes near it."""
    import re

    import roadtruth.harness.truth.simulate as sim

    build = sim.build_mjcf

    def raised(*a, **k):
        def lift(mo: re.Match) -> str:
            x, y, z = (float(v) for v in mo.group(2).split())
            return f'{mo.group(1)}{x!r} {y!r} {z + dz_m!r}"'

        return re.sub(r'(<geom name="floor"[^>]*? pos=")([^"]+)"', lift, build(*a, **k), count=1)

    monkeypatch.setattr(sim, "build_mjcf", raised)


def _contact_skipped_per_step(sc, steps: int) -> list[bool]:
    """Whether MuJoCo's contact pass was switched off for each of the first ``steps`` steps (interpreted loop)."""
    import mujoco

    import roadtruth.harness.truth.simulate as sim

    p = sim._prepare(sc, None, 0.001)
    m, d = p.model, p.data
    skipped: list[bool] = []

    def step1(_m: int, _d: int) -> None:
        skipped.append(bool(m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT))
        mujoco.mj_step1(m, d)

    sim._run.py_func(step1, lambda _m, _d: mujoco.mj_step2(m, d), 0, 0, 0, steps, *p.args[2:])
    return skipped


def test_contact_check_is_skipped_only_far_from_the_floor(monkeypatch: pytest.MonkeyPatch) -> None:
    # At rest on its wheels the chassis box is 0.22 m above the floor: the collision pass is skipped
    # from the second step on (the first has no kinematics yet) ...
    sc = dataclasses.replace(load_scenario("step_steer"), duration_s=0.2)
    skipped = _contact_skipped_per_step(sc, 100)
    assert skipped[0] is False and all(skipped[1:])
    # ... and never with the box 2 cm above the floor (at 20 m/s the gate is 0.05 + 2 dt 20 = 0.09 m).
    _floor_raised(monkeypatch, 0.20)
    assert not any(_contact_skipped_per_step(sc, 100))


def test_skipping_the_contact_check_changes_no_bit_even_when_the_box_touches(monkeypatch: pytest.MonkeyPatch) -> None:
    import roadtruth.harness.truth.simulate as sim

    sc = load_scenario("fishhook")
    free = simulate(sc)
    # Floor 4.5 cm under the box at rest: skipped there (gate 0 + 2 dt |v| = 3.6 cm), while the roll of
    # the fishhook puts the box's lower edge on the floor.
    _floor_raised(monkeypatch, 0.175)
    monkeypatch.setattr(sim, "CONTACT_GATE_M", 0.0)
    gated = simulate(sc)
    monkeypatch.setattr(sim, "CONTACT_GATE_M", math.inf)  # every step checked, as MuJoCo does by itself
    checked = simulate(sc)
    assert gated.status == checked.status == "ok"
    assert np.array_equal(gated.frame.to_numpy(), checked.frame.to_numpy(), equal_nan=True)
    assert np.array_equal(gated.qpos, checked.qpos)
    # The contact did act: the car's roll differs from the run on the real floor.
    assert np.max(np.abs(gated.frame["roll_rad"].to_numpy() - free.frame["roll_rad"].to_numpy())) > 1e-4
    short = dataclasses.replace(sc, duration_s=0.3)
    monkeypatch.setattr(sim, "CONTACT_GATE_M", 0.0)
    a, b = simulate(short), simulate(short, compiled=False)
    assert np.array_equal(a.frame.to_numpy(), b.frame.to_numpy(), equal_nan=True)


def test_disableflags_view_aliases_the_model_and_simulate_restores_it() -> None:
    import mujoco

    import roadtruth.harness.truth.simulate as sim

    p = sim._prepare(load_scenario("step_steer"), None, 0.001)
    flags = p.args[-1]
    assert p.args[3][sim.I_GATE] == 1
    flags[0] = 16
    assert p.model.opt.disableflags == 16
    p.model.opt.disableflags = 0
    assert flags[0] == 0
    m = mujoco.MjModel.from_xml_string('<mujoco><option><flag gravity="disable"/></option><worldbody/></mujoco>')
    view = sim._disableflags_view(m)
    assert view is not None and int(view[0]) == m.opt.disableflags != 0
