"""The car's base model ``mjcf/car.xml``: it opens in MuJoCo on its own, every vehicle set keeps its
layout, the set's values are the ones the simulation steps, and an installed package carries it."""

from __future__ import annotations

import fnmatch
import math
import tomllib
from pathlib import Path

import mujoco
import numpy as np
import pytest

from roadtruth.harness.truth.car_model import BASE_MODEL, CORNERS, LEAD_CAR_MODEL, build_mjcf, corner_geometry
from roadtruth.harness.truth.scenario import load_scenario
from roadtruth.harness.truth.simulate import _prepare
from roadtruth.harness.truth.vehicle import G, available_vehicles, load_vehicle
from roadtruth.mjcf import template_path

ROOT = Path(__file__).resolve().parents[1]


def _base() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(template_path(BASE_MODEL))


def _layout(m: mujoco.MjModel) -> dict[str, list]:
    """Everything of a model that is not a number of the vehicle: names, tree, types, wiring."""
    names = {obj: [getattr(m, obj)(i).name for i in range(n)] for obj, n in
             (("body", m.nbody), ("joint", m.njnt), ("geom", m.ngeom), ("site", m.nsite), ("camera", m.ncam),
              ("actuator", m.nu), ("sensor", m.nsensor), ("tendon", m.ntendon), ("mat", m.nmat))}
    return {**names, "parent": m.body_parentid.tolist(), "jnt_type": m.jnt_type.tolist(),
            "jnt_body": m.jnt_bodyid.tolist(), "geom_type": m.geom_type.tolist(), "geom_body": m.geom_bodyid.tolist(),
            "actuator_trn": m.actuator_trnid.tolist(), "actuator_gain": m.actuator_gainprm[:, 0].tolist(),
            "sensor_type": m.sensor_type.tolist(), "contype": m.geom_contype.tolist(),
            "conaffinity": m.geom_conaffinity.tolist(), "wrap": m.wrap_objid.tolist(), "wrap_coef": m.wrap_prm.tolist()}


def test_the_base_file_is_a_car_mujoco_opens_on_its_own() -> None:
    m = _base()
    # The names the simulation loop looks up (simulate._prepare) are all in the file.
    for c in CORNERS:
        assert m.joint(f"susp_{c}").type == mujoco.mjtJoint.mjJNT_SLIDE
        assert m.joint(f"spin_{c}").type == mujoco.mjtJoint.mjJNT_HINGE
        assert m.actuator(f"torque_{c}").trnid[0] == m.joint(f"spin_{c}").id
        assert m.body(f"wheel_{c}").id > m.body(f"upright_{c}").id
    for c in CORNERS[:2]:
        assert m.actuator(f"steer_{c}").trnid[0] == m.joint(f"steer_{c}").id
        assert m.body(f"knuckle_{c}").parentid[0] == m.body(f"upright_{c}").id
    assert m.joint("root").type == mujoco.mjtJoint.mjJNT_FREE and m.body("chassis").parentid[0] == 0
    assert m.sensor("imu_acc").type == mujoco.mjtSensor.mjSENS_ACCELEROMETER
    assert (m.nq, m.nv, m.nu) == (7 + 4 + 2 + 4, 6 + 4 + 2 + 4, 6)
    # On its own it is a plausible sedan: the whole car's CG at the chassis origin, and the springs at
    # q = 0 carry the sprung weight (each spring the axial part W cos θ of its corner's share).
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert d.subtree_com[m.body("chassis").id] == pytest.approx(m.body("chassis").pos, abs=1e-6)
    sprung = m.body_subtreemass[m.body("chassis").id] - sum(m.body_subtreemass[m.body(f"upright_{c}").id] for c in CORNERS)
    carried = sum(m.jnt_stiffness[j] * (0.0 - m.qpos_spring[m.jnt_qposadr[j]]) / m.jnt_axis[j][2]
                  for j in (m.joint(f"susp_{c}").id for c in CORNERS))
    assert carried == pytest.approx(sprung * 9.81, rel=1e-6)


@pytest.mark.parametrize("name", available_vehicles())
def test_every_vehicle_set_keeps_the_base_layout_and_changes_only_numbers(name: str) -> None:
    v = load_vehicle(name)
    m = mujoco.MjModel.from_xml_string(build_mjcf(v, load_scenario("step_steer")))
    assert _layout(m) == _layout(_base())


@pytest.mark.parametrize("scenario", ["step_steer", "hill", "car_following", "double_lane_change"])
@pytest.mark.parametrize("name", ["ferrari_250lm", "wang2014"])
def test_the_stepped_model_carries_the_vehicle_files_values(scenario: str, name: str) -> None:
    sc = load_scenario(scenario)
    v = load_vehicle(name)
    p = _prepare(sc, v, 0.002)
    m, base = p.model, _base()
    g = corner_geometry(v)
    assert m.opt.timestep == 0.002 and np.array_equal(m.opt.gravity, [0.0, 0.0, -G])
    assert float(m.body_subtreemass[0]) == pytest.approx(v.mass_kg, rel=1e-12)
    assert m.body("chassis").pos[2] == v.h_cg_m
    for i, c in enumerate(CORNERS):
        h_rc = v.suspension.roll_centre_f_m if i < 2 else v.suspension.roll_centre_r_m
        th = math.atan(2.0 * h_rc / (v.track_f_m if i < 2 else v.track_r_m))
        side = 1.0 if i % 2 == 0 else -1.0
        j = m.joint(f"susp_{c}").id
        np.testing.assert_allclose(m.jnt_axis[j], [0.0, side * math.sin(th), math.cos(th)], rtol=1e-8, atol=1e-12)
        k = v.suspension.stiffness_f_Npm if i < 2 else v.suspension.stiffness_r_Npm
        # 9 significant digits in the text: a 6-digit writer would be off by ~1e-6 relative here.
        assert m.jnt_stiffness[j] == pytest.approx(k * math.cos(th) ** 2, rel=1e-8)
        assert m.qpos_spring[m.jnt_qposadr[j]] == pytest.approx(g.spring_ref[i], rel=1e-8)
        assert m.geom(f"tire_{c}").size[0] == v.wheel_radius_m
        np.testing.assert_allclose(m.body(f"upright_{c}").pos, g.position[i], rtol=1e-8)
        assert m.body(f"wheel_{c}").inertia[1] == pytest.approx(v.wheel_spin_inertia_kgm2, rel=1e-8)
        # Written, not left at the base file's (sedan) values.
        assert m.jnt_stiffness[j] != base.jnt_stiffness[base.joint(f"susp_{c}").id]
        assert not np.array_equal(m.body(f"upright_{c}").pos, base.body(f"upright_{c}").pos)
    mu = v.unsprung_mass_kg
    shares = {"chassis": v.mass_kg / mu - 4.0, "upright_fl": 0.3, "knuckle_fl": 0.1, "wheel_fl": 0.6,
              "upright_rl": 0.4, "wheel_rl": 0.6}
    for body, share in shares.items():
        assert m.body(body).mass[0] == pytest.approx(share * mu, rel=1e-8)
    # The text a truth keeps is the model that was stepped, bit for bit.
    stepped, again = (np.zeros(mujoco.mj_sizeModel(m), np.uint8) for _ in range(2))
    mujoco.mj_saveModel(m, None, stepped)
    mujoco.mj_saveModel(mujoco.MjModel.from_xml_string(p.xml), None, again)
    assert np.array_equal(stepped, again)
    # The floor lies under the road (60 m beyond its ends).
    smp = sc.road.samples
    assert m.geom("floor").size[0] == pytest.approx((smp[:, 1].max() - smp[:, 1].min()) / 2 + 60.0, rel=1e-8)


def test_the_lead_car_of_the_renders_is_the_lead_car_file() -> None:
    lead = mujoco.MjModel.from_xml_path(template_path(LEAD_CAR_MODEL))
    sc = load_scenario("car_following")
    render = mujoco.MjModel.from_xml_string(build_mjcf(load_vehicle(sc.vehicle), sc, visuals=True))
    ids = [i for i in range(render.ngeom) if render.geom_bodyid[i] == render.body("lead").id]
    own = [i for i in range(lead.ngeom) if lead.geom_bodyid[i] == lead.body("lead").id]
    assert len(ids) == len(own) == 2
    np.testing.assert_array_equal(render.geom_size[ids], lead.geom_size[own])
    np.testing.assert_array_equal(render.geom_pos[ids], lead.geom_pos[own])
    # Before the car's bodies, as a visual of the world: the car's body numbers do not depend on it.
    assert render.body("lead").id < render.body("chassis").id and render.body("lead").mocapid[0] == 0


def test_an_installed_package_carries_the_model_files() -> None:
    conf = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    tool = conf["tool"]["setuptools"]
    assert "roadtruth.mjcf" in tool["packages"] and tool["package-dir"]["roadtruth.mjcf"] == "mjcf"
    globs = tool["package-data"]["roadtruth.mjcf"]
    for name in (BASE_MODEL, LEAD_CAR_MODEL):
        assert (ROOT / "mjcf" / name).is_file()
        assert any(fnmatch.fnmatch(name, pat) for pat in globs), f"{name} is not in roadtruth.mjcf's package-data"
        assert Path(template_path(name)).samefile(ROOT / "mjcf" / name)
