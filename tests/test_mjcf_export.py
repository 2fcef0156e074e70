"""`roadtruth mjcf`: a model file MuJoCo opens, with the car's masses and the scenario's start."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np

from roadtruth.harness.cli import main
from roadtruth.harness.truth.scenario import load_scenario
from roadtruth.harness.truth.vehicle import load_vehicle


def test_model_file_has_the_vehicle_mass_and_the_scenario_start(tmp_path: Path) -> None:
    out = tmp_path / "models" / "car.xml"
    assert main(["mjcf", "sedan", "--scenario", "banked_curve", "--out", str(out)]) == 0
    m = mujoco.MjModel.from_xml_path(str(out))
    v = load_vehicle("sedan")
    assert math.isclose(float(m.body_subtreemass[0]), v.mass_kg, rel_tol=1e-9)
    assert {m.joint(i).name for i in range(m.njnt)} >= {"root", "steer_fl", "steer_fr", "spin_rr", "susp_fl"}
    assert m.geom("road_surface").type == mujoco.mjtGeom.mjGEOM_MESH  # the banked road is in the file
    sc = load_scenario("banked_curve")
    x0, y0, psi0 = sc.road.samples[0, 1:4]
    key = m.key("start")
    np.testing.assert_allclose(key.qpos[:2], [x0, y0], atol=1e-12)
    np.testing.assert_allclose(key.qpos[3:7], [math.cos(psi0 / 2), 0, 0, math.sin(psi0 / 2)], atol=1e-12)
    np.testing.assert_allclose(key.qvel[:2], sc.initial_speed_mps * np.array([math.cos(psi0), math.sin(psi0)]),
                               atol=1e-9)


def test_rewrites_its_own_file_and_never_a_users(tmp_path: Path, capsys) -> None:  # noqa: ANN001
    own = tmp_path / "car.xml"
    assert main(["mjcf", "sedan", "--out", str(own)]) == 0
    first = own.read_text()
    assert "<keyframe>" not in first  # no scenario, no start pose
    assert main(["mjcf", "ferrari_250lm", "--out", str(own)]) == 0
    assert 'model="roadtruth_ferrari_250lm"' in own.read_text()
    user = tmp_path / "mine.xml"
    user.write_text("<mujoco model='my_robot'/>\n")
    capsys.readouterr()
    assert main(["mjcf", "sedan", "--out", str(user)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a model roadtruth wrote" in err[0]
    assert user.read_text() == "<mujoco model='my_robot'/>\n"
    assert main(["mjcf", "no_such_vehicle", "--out", str(tmp_path / "x.xml")]) == 2
    assert not (tmp_path / "x.xml").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["car.xml", "mine.xml"]  # no partial files left
