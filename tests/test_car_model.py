"""Generated MJCF: whole-car mass and inertia, static equilibrium, structure, scenario visuals."""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest

from roadtruth.harness.errors import VehicleError
from roadtruth.harness.truth.car_model import build_mjcf, corner_geometry
from roadtruth.harness.truth.scenario import load_scenario
from roadtruth.harness.truth.vehicle import G, available_vehicles, load_vehicle


def _composite_inertia(m: mujoco.MjModel, d: mujoco.MjData) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, CG and inertia tensor (3, 3) of the whole car (every body below the world) at qpos0."""
    mujoco.mj_forward(m, d)
    mass = float(m.body_subtreemass[1])
    c = d.subtree_com[1].copy()
    inertia = np.zeros((3, 3))
    for b in range(1, m.nbody):
        if m.body_rootid[b] != 1:
            continue
        rot = d.ximat[b].reshape(3, 3)
        r = d.xipos[b] - c
        inertia += rot @ np.diag(m.body_inertia[b]) @ rot.T + m.body_mass[b] * (r @ r * np.eye(3) - np.outer(r, r))
    return mass, c, inertia


@pytest.mark.parametrize("name", available_vehicles())
def test_whole_car_has_the_sets_mass_inertia_and_cg(name: str) -> None:
    v = load_vehicle(name)
    m = mujoco.MjModel.from_xml_string(build_mjcf(v))
    mass, cg, inertia = _composite_inertia(m, mujoco.MjData(m))
    assert mass == pytest.approx(v.mass_kg, rel=1e-9)
    np.testing.assert_allclose(cg, [0.0, 0.0, v.h_cg_m], atol=1e-9)
    np.testing.assert_allclose(np.diag(inertia)[[0, 2]], [v.roll_inertia_kgm2, v.yaw_inertia_kgm2], rtol=1e-6)
    # Pitch is exact unless the set itself breaks I_x + I_y >= I_z (then it is raised to make it physical).
    if v.roll_inertia_kgm2 + v.pitch_inertia_kgm2 >= 1.02 * v.yaw_inertia_kgm2:
        assert inertia[1, 1] == pytest.approx(v.pitch_inertia_kgm2, rel=1e-6)
    else:
        assert inertia[1, 1] > v.pitch_inertia_kgm2 and inertia[0, 0] + inertia[1, 1] >= inertia[2, 2]


def test_suspension_holds_the_sprung_load_at_zero_travel() -> None:
    v = load_vehicle("sedan")
    m = mujoco.MjModel.from_xml_string(build_mjcf(v))
    g = corner_geometry(v)
    assert g.fz_static.sum() == pytest.approx(v.mass_kg * G)
    np.testing.assert_allclose(g.tire_deflection * v.tires.radial_stiffness_Npm, g.fz_static)
    for i, c in enumerate(("fl", "fr", "rl", "rr")):
        j = m.joint(f"susp_{c}")
        # The axis is inclined by θ (roll centre): the spring along it carries the load's axial part,
        # and its rate along the axis is the vertical wheel rate times cos^2 θ.
        th = g.incline[i]
        axis = m.jnt_axis[j.id]
        assert axis[2] == pytest.approx(math.cos(th)) and abs(axis[1]) == pytest.approx(math.sin(th))
        assert np.sign(axis[1]) == np.sign(g.position[i, 1])  # bump moves the wheel outward
        spring_force = -m.jnt_stiffness[j.id] * (0.0 - m.qpos_spring[m.jnt_qposadr[j.id]])
        assert -spring_force == pytest.approx((g.fz_static[i] - v.unsprung_mass_kg * G) * math.cos(th), rel=1e-7)
        k = v.suspension.stiffness_f_Npm if i < 2 else v.suspension.stiffness_r_Npm
        assert m.jnt_stiffness[j.id] == pytest.approx(k * math.cos(th) ** 2, rel=1e-9)
        h_rc = v.suspension.roll_centre_f_m if i < 2 else v.suspension.roll_centre_r_m
        assert math.tan(th) == pytest.approx(2.0 * h_rc / (v.track_f_m if i < 2 else v.track_r_m), rel=1e-9)
        np.testing.assert_allclose(m.jnt_range[j.id], np.array([-1.0, 1.0]) * v.suspension.travel_m / math.cos(th))
        # Wheel centre at rest: radius minus the static tire compression.
        assert g.position[i, 2] + v.h_cg_m == pytest.approx(v.wheel_radius_m - g.tire_deflection[i])


def test_model_structure_and_options() -> None:
    v = load_vehicle("sedan")
    xml = build_mjcf(v, timestep_s=0.002)
    m = mujoco.MjModel.from_xml_string(xml)
    assert m.opt.timestep == 0.002 and m.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert m.vis.global_.offwidth == 640 and m.vis.global_.offheight == 480
    root = ET.fromstring(xml)
    assert root.find("compiler").get("angle") == "radian" and root.find("compiler").get("autolimits") == "true"
    for c in ("fl", "fr", "rl", "rr"):
        assert m.geom(f"tire_{c}").contype == 0 and m.geom(f"tire_{c}").conaffinity == 0
        assert m.actuator(f"torque_{c}").trntype == mujoco.mjtTrn.mjTRN_JOINT
    assert m.geom("body").contype & m.geom("floor").conaffinity
    for name in ("steer_fl", "steer_fr"):
        assert m.actuator(name).gainprm[0] > 0  # position servo
    assert {m.camera(i).name for i in range(m.ncam)} == {"chase", "top"}
    assert {m.site(i).name for i in range(m.nsite)} == {"imu", "gnss"}
    th = corner_geometry(v).incline
    assert m.tendon_stiffness[m.tendon("arb_f").id] == pytest.approx(v.suspension.arb_f_Npm * math.cos(th[0]) ** 2)
    assert m.tendon_stiffness[m.tendon("arb_r").id] == pytest.approx(v.suspension.arb_r_Npm * math.cos(th[2]) ** 2)


def test_scenario_visuals_markings_patches_and_lead() -> None:
    sc = load_scenario("mu_step")
    sc_gap = dataclasses.replace(sc, lane_gaps=((0.0, 100.0),))
    v = load_vehicle("sedan")
    m = mujoco.MjModel.from_xml_string(build_mjcf(v, sc, visuals=True))
    m_gap = mujoco.MjModel.from_xml_string(build_mjcf(v, sc_gap, visuals=True))
    patches = [m.geom(i) for i in range(m.ngeom) if m.geom(i).name.startswith("patch_")]
    assert len(patches) == len(sc.friction.patches)
    assert all(g.contype == 0 and g.conaffinity == 0 for g in patches)
    marking = m.mat("marking").id
    n_dash = int(np.sum(m.geom_matid == marking))
    n_dash_gap = int(np.sum(m_gap.geom_matid == marking))
    assert n_dash > 0 and n_dash - n_dash_gap == pytest.approx(2 * 100 / 12, abs=2)
    lead = load_scenario("car_following")
    ml = mujoco.MjModel.from_xml_string(build_mjcf(v, lead, visuals=True))
    assert ml.body("lead").mocapid[0] == 0 and ml.nmocap == 1
    assert m.nmocap == 0


def _geom_names(m: mujoco.MjModel) -> list[str]:
    return sorted(m.geom(i).name for i in range(m.ngeom))


@pytest.mark.parametrize("scenario", ["mu_step", "hill", "car_following", "gnss_outage"])
def test_physics_model_has_no_scenario_visuals_and_the_render_model_has_them(scenario: str) -> None:
    # The markings, patches, road mesh and lead car collide with nothing and weigh nothing, but in
    # the stepped model MuJoCo would place each of them at every step (cost growing with road length).
    sc = load_scenario(scenario)
    v = load_vehicle(sc.vehicle)
    car_only = mujoco.MjModel.from_xml_string(build_mjcf(v))
    physics = mujoco.MjModel.from_xml_string(build_mjcf(v, sc))
    render = mujoco.MjModel.from_xml_string(build_mjcf(v, sc, visuals=True))
    assert _geom_names(physics) == _geom_names(car_only)  # floor, chassis box, cabin, 3 geoms per wheel
    assert physics.ngeom == 2 + 3 * 4 + 1 and physics.nmocap == 0 and physics.nmesh == 0
    assert not np.any(physics.geom_matid == physics.mat("marking").id)
    marking = int(np.sum(render.geom_matid == render.mat("marking").id))
    assert marking >= 2 * int((sc.road.length_m - 3.0) // 12.0) - 2 * 20  # two lines of 3 m dashes every 12 m
    names = _geom_names(render)
    assert sum(n.startswith("patch_") for n in names) == len(sc.friction.patches)
    assert ("road_surface" in names) == (not sc.road.is_flat)
    assert render.nmocap == (1 if sc.lead is not None else 0)
    # Same joints and bodies of the car: the logged qpos poses the render model.
    assert (render.nq, render.nv, render.nu) == (physics.nq, physics.nv, physics.nu)
    assert [render.joint(j).name for j in range(render.njnt)] == [physics.joint(j).name for j in range(physics.njnt)]
    # The floor under the road is the same plane in both (it is the chassis' collision partner).
    assert np.array_equal(render.geom("floor").pos, physics.geom("floor").pos)
    assert np.array_equal(render.geom("floor").size, physics.geom("floor").size)


def test_an_implausible_inertia_is_a_vehicle_error() -> None:
    v = load_vehicle("sedan").with_overrides(roll_inertia_kgm2=60.0)
    with pytest.raises(VehicleError, match="unsprung"):
        build_mjcf(v)


def test_renders_offscreen_640x480() -> None:
    v = load_vehicle("sedan")
    m = mujoco.MjModel.from_xml_string(build_mjcf(v, load_scenario("mu_step"), visuals=True))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    try:
        r = mujoco.Renderer(m, height=480, width=640)
    except Exception as exc:  # no OpenGL on this machine
        pytest.skip(f"offscreen rendering unavailable: {exc}")
    try:
        r.update_scene(d, camera="chase")
        img = r.render()
    finally:
        r.close()
    assert img.shape == (480, 640, 3) and img.std() > 5.0
