"""Roads in 3D: elevation and bank profiles, the compiled surface lookup, its NumPy twin, the YAML keys,
the render mesh and the banked-curve and hill scenarios."""

from __future__ import annotations

import copy
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from roadtruth.harness.cli import main
from roadtruth.harness.errors import InputError, ScenarioError
from roadtruth.harness.files.strict_yaml import load_mapping
from roadtruth.harness.truth.road import Road, Segment, build_road, road_surface
from roadtruth.harness.truth.road_mesh import road_surface_mesh
from roadtruth.harness.truth.road_profile import RoadProfile
from roadtruth.harness.truth.scenario import load_scenario, parse_scenario, scenarios_dir
from roadtruth.harness.truth.vehicle import G


def _surface_compiled(road: Road, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """road_surface point by point (each hinted by the previous answer): z (m,), normal (m, 3)."""
    z = np.empty(x.size)
    nrm = np.empty((x.size, 3))
    h = 0
    for k in range(x.size):
        h, z[k], nrm[k, 0], nrm[k, 1], nrm[k, 2] = road_surface(road.samples, road.ds_m, float(x[k]),
                                                                float(y[k]), h)
    return z, nrm


def _points_on(road: Road, s: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points at path coordinate s and lateral offset e (left positive)."""
    x, y, psi = road.pose_at(s)
    return x - e * np.sin(psi), y + e * np.cos(psi)


def _rot_z(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])


def _rot_x(a: float) -> np.ndarray:
    return np.array([[1.0, 0.0, 0.0], [0.0, math.cos(a), -math.sin(a)], [0.0, math.sin(a), math.cos(a)]])


def _rot_y(a: float) -> np.ndarray:
    return np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])


def _curvy_3d_road() -> Road:
    """Straight, clothoid, arc, reverse clothoid, with a grade crest and a bank ramp on the curves."""
    profile = RoadProfile(grade=((10.0, 0.0), (40.0, 0.08), (90.0, -0.06), (130.0, 0.0)),
                          bank_rad=((20.0, 0.0), (60.0, math.radians(-9.0)), (100.0, math.radians(4.0))))
    return build_road((5.0, -3.0, 0.4), [Segment("straight", 20.0), Segment("clothoid", 40.0, 1 / 60.0),
                                         Segment("arc", 40.0), Segment("clothoid", 50.0, -1 / 80.0)],
                      profile=profile)


# ---- flat roads stay exactly flat ------------------------------------------------------------------

def test_flat_road_is_exactly_flat() -> None:
    curvy = build_road((0.0, 0.0, 0.3), [Segment("straight", 30.0), Segment("clothoid", 30.0, 0.02),
                                         Segment("arc", 40.0)])
    for road in (Road.straight_default(200.0), curvy, load_scenario("step_steer").road):
        assert road.samples.shape[1] == 8 and road.is_flat
        assert np.all(road.samples[:, 5:8] == 0.0)
        rng = np.random.default_rng(1)
        s = rng.uniform(-20.0, road.length_m + 20.0, 300)  # beyond both ends too
        x, y = _points_on(road, s, rng.uniform(-4.0, 4.0, s.size))
        z, n = _surface_compiled(road, x, y)
        # Exactly (not nearly) 0 and (0, 0, 1), and no negative zeros: a flat road is bit-identical.
        assert np.all(z == 0.0) and not np.any(np.signbit(z))
        assert np.all(n == np.array([0.0, 0.0, 1.0])) and not np.any(np.signbit(n))
        twin = road.surface(x, y)
        assert np.all(twin["z_m"] == 0.0) and np.all(twin["normal"] == np.array([0.0, 0.0, 1.0]))
    # Zero-valued profile points are flat too; the plane columns do not depend on the profile.
    zero = build_road((0.0, 0.0, 0.3), [Segment("arc", 50.0, 0.01)],
                      profile=RoadProfile(bank_rad=((10.0, 0.0),), grade=((0.0, 0.0),)))
    assert zero.is_flat
    banked = build_road((0.0, 0.0, 0.3), [Segment("arc", 50.0, 0.01)], profile=RoadProfile(bank_rad=((10.0, 0.1),)))
    assert not banked.is_flat
    np.testing.assert_array_equal(banked.samples[:, :5], zero.samples[:, :5])


# ---- banked and graded straights: surface and normal from rotations --------------------------------

@pytest.mark.parametrize("bank_deg", [8.0, -12.0])
def test_banked_straight_height_and_normal(bank_deg: float) -> None:
    phi, psi0 = math.radians(bank_deg), 0.7
    road = build_road((2.0, 1.0, psi0), [Segment("straight", 200.0)], profile=RoadProfile(bank_rad=((0.0, phi),)))
    rng = np.random.default_rng(2)
    s, e = rng.uniform(10.0, 190.0, 200), rng.uniform(-3.5, 3.5, 200)
    x, y = _points_on(road, s, e)
    z, n = _surface_compiled(road, x, y)
    np.testing.assert_allclose(z, e * math.tan(phi), rtol=0, atol=1e-12)
    # Positive bank = left edge higher (ISO 8855): points left of the centre line are higher.
    assert np.all(np.sign(z[np.abs(e) > 0.01]) == np.sign(phi) * np.sign(e[np.abs(e) > 0.01]))
    # The road normal is the world z axis rotated by the bank about the travel direction x, then by
    # the heading about z.
    expected = _rot_z(psi0) @ _rot_x(phi) @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(n, np.broadcast_to(expected, n.shape), rtol=0, atol=1e-12)
    twin = road.surface(x, y)
    np.testing.assert_allclose(twin["z_m"], e * math.tan(phi), rtol=0, atol=1e-12)
    np.testing.assert_allclose(twin["normal"], np.broadcast_to(expected, n.shape), rtol=0, atol=1e-12)


@pytest.mark.parametrize("grade", [0.08, -0.15])
def test_graded_straight_normal_tilts_backward(grade: float) -> None:
    psi0 = -1.1
    road = build_road((0.0, 0.0, psi0), [Segment("straight", 300.0)], profile=RoadProfile(grade=((0.0, grade),)))
    rng = np.random.default_rng(3)
    s, e = rng.uniform(5.0, 295.0, 200), rng.uniform(-3.5, 3.5, 200)
    x, y = _points_on(road, s, e)
    z, n = _surface_compiled(road, x, y)
    np.testing.assert_allclose(z, grade * s, rtol=1e-12, atol=1e-12)
    # Climbing (grade > 0) tilts the normal backward, against the travel direction, by atan(grade):
    # a rotation of -atan(grade) about the lateral (left) axis, then the heading.
    expected = _rot_z(psi0) @ _rot_y(-math.atan(grade)) @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(n, np.broadcast_to(expected, n.shape), rtol=0, atol=1e-12)
    travel = np.array([math.cos(psi0), math.sin(psi0), 0.0])
    np.testing.assert_allclose(n @ travel, -math.sin(math.atan(grade)), rtol=0, atol=1e-12)
    # Beyond the end the grade holds: the elevation continues linearly.
    xe, ye = _points_on(road, np.array([road.length_m + 10.0]), np.array([0.0]))
    ze, _ = _surface_compiled(road, xe, ye)
    np.testing.assert_allclose(ze, grade * (road.length_m + 10.0), rtol=1e-12)


# ---- curved 3D road: the normal is the gradient of the height, both lookups agree -------------------

def test_normal_is_the_gradient_of_the_height_on_a_curved_3d_road() -> None:
    road = _curvy_3d_road()
    rng = np.random.default_rng(4)
    # Mid-interval points (the bank is linear between samples, so its slope steps at them).
    s = (rng.integers(20, int(140 / road.ds_m), 150) + rng.uniform(0.3, 0.7, 150)) * road.ds_m
    e = rng.uniform(-3.5, 3.5, 150)
    x, y = _points_on(road, s, e)
    h = 1e-5
    zx = (road.surface(x + h, y, s)["z_m"] - road.surface(x - h, y, s)["z_m"]) / (2 * h)
    zy = (road.surface(x, y + h, s)["z_m"] - road.surface(x, y - h, s)["z_m"]) / (2 * h)
    n = road.surface(x, y, s)["normal"]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, rtol=0, atol=1e-14)
    # Both terms of the gradient matter here: e * dphi/ds * sec^2 (up to ~1e-2) and the metric
    # 1/(1 - rho e) of the path coordinate (up to ~5e-3 on the grade).
    np.testing.assert_allclose(-n[:, 0] / n[:, 2], zx, rtol=0, atol=1e-7)
    np.testing.assert_allclose(-n[:, 1] / n[:, 2], zy, rtol=0, atol=1e-7)


def test_compiled_and_numpy_surface_agree() -> None:
    road = _curvy_3d_road()
    rng = np.random.default_rng(5)
    s = np.sort(rng.uniform(-10.0, road.length_m + 10.0, 2000))
    x, y = _points_on(road, s, rng.uniform(-4.0, 4.0, s.size))
    z, n = _surface_compiled(road, x, y)
    twin = road.surface(x, y)
    np.testing.assert_allclose(z, twin["z_m"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(n, twin["normal"], rtol=0, atol=1e-12)
    # And the centre line sits at the sampled elevation.
    xs, ys = road.samples[:, 1], road.samples[:, 2]
    np.testing.assert_allclose(road.surface(xs, ys, road.samples[:, 0])["z_m"], road.samples[:, 5],
                               rtol=0, atol=1e-9)


# ---- profiles --------------------------------------------------------------------------------------

def test_grade_profile_is_parabolic_and_c1() -> None:
    prof = RoadProfile(grade=((30.0, 0.0), (105.0, 0.10), (165.0, 0.10), (305.0, -0.10)))
    s = np.arange(40001) / 100.0  # 0.01 m steps, exact at the points
    z, g, b = prof.columns(s)
    assert np.all(b == 0.0)
    np.testing.assert_allclose(g[(s >= 105) & (s <= 165)], 0.10, rtol=0, atol=1e-15)
    # Elevation is the integral of the grade (trapezoid of a linear grade = exact parabola).
    np.testing.assert_allclose(z[s == 105.0], 0.5 * 0.10 * 75.0, rtol=1e-12)
    np.testing.assert_allclose(z[s == 165.0], 3.75 + 6.0, rtol=1e-12)
    np.testing.assert_allclose(np.diff(z) / np.diff(s), 0.5 * (g[1:] + g[:-1]), rtol=0, atol=1e-9)
    assert np.max(np.abs(np.diff(g))) <= 0.2 / 140.0 * 0.01 + 1e-12  # no step in grade: no bump
    np.testing.assert_allclose(g[s > 305.0], -0.10)  # held beyond the last point


def test_elevation_profile_is_monotone_c1_and_flat_at_its_ends() -> None:
    prof = RoadProfile(elevation_m=((50.0, 2.0), (100.0, 2.0), (180.0, 12.0), (260.0, 14.0)))
    s = np.arange(32001) / 100.0
    z, g, _ = prof.columns(s)
    assert z.min() >= 2.0 - 1e-12 and z.max() <= 14.0 + 1e-12  # no overshoot past the points
    assert np.all(g[s >= 100.0] >= -1e-15)  # monotone where the points rise
    np.testing.assert_allclose(z[s <= 100.0], 2.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(z[s >= 260.0], 14.0, rtol=0, atol=1e-12)
    assert abs(g[s == 260.0][0]) < 1e-15  # flat at the last point: holding beyond is C1
    assert np.max(np.abs(np.diff(g))) < 1e-3  # continuous grade
    np.testing.assert_allclose(np.diff(z) / np.diff(s), 0.5 * (g[1:] + g[:-1]), rtol=0, atol=1e-7)
    with pytest.raises(ValueError, match="not both"):
        RoadProfile(elevation_m=((0.0, 1.0),), grade=((0.0, 0.1),))


def test_longer_road_keeps_its_profile() -> None:
    road = _curvy_3d_road()
    longer = road.with_length_at_least(road.length_m + 100.0)
    k = road.samples.shape[0]
    np.testing.assert_array_equal(longer.samples[:k, 5:8], road.samples[:, 5:8])
    assert longer.profile == road.profile and not longer.is_flat


# ---- scenario YAML ---------------------------------------------------------------------------------

def _with_road(extra: dict[str, Any]) -> dict[str, Any]:
    data = copy.deepcopy(load_mapping(scenarios_dir() / "step_steer.yaml"))
    data["road"] = {"segments": [{"straight": {"length_m": 300.0}}], **extra}
    return data


@pytest.mark.parametrize(("extra", "needle"), [
    ({"bank_deg": [[0.0, 0.0], [50.0, 31.0]]}, "road.bank_deg: values must be within +-30 deg (got 31 at s = 50)"),
    ({"grade_percent": [[0.0, 0.0], [50.0, -30.5]]}, "road.grade_percent: values must be within +-30 %"),
    ({"bank_deg": [[0.0, 0.0], [50.0, 5.0], [50.0, 6.0]]}, "road.bank_deg: path coordinates must increase strictly"),
    ({"grade_percent": [[10.0, 1.0], [5.0, 2.0]]}, "must increase strictly (got s = 5 after 10)"),
    ({"bank_deg": [[0.0, "5"]]}, "road.bank_deg: each point must be [s_m, deg] numbers"),
    ({"bank_deg": [[0.0, True]]}, "each point must be [s_m, deg] numbers"),
    ({"elevation_m": [[0.0, 1.0, 2.0]]}, "road.elevation_m: each point must be [s_m, m] numbers"),
    ({"bank_deg": [[-1.0, 2.0]]}, "path coordinates must be >= 0"),
    ({"bank_deg": []}, "must hold at least one [s_m, deg] point"),
    ({"bank_deg": 5.0}, "road.bank_deg: must be a list"),
    ({"elevation_m": [[0.0, 0.0]], "grade_percent": [[0.0, 1.0]]}, "give elevation_m or grade_percent, not both"),
    ({"elevation_m": [[0.0, 0.0], [10.0, 5.0]]}, "road.elevation_m: the interpolated road is steeper than 30 %"),
    ({"bank": [[0.0, 5.0]]}, "road.bank: unknown field"),
])
def test_bad_road_profiles_are_one_line_errors(extra: dict[str, Any], needle: str) -> None:
    with pytest.raises(ScenarioError) as err:
        parse_scenario(_with_road(extra), "step_steer.yaml")
    msg = str(err.value)
    assert needle in msg and "\n" not in msg and msg.startswith("step_steer.yaml: road.")
    assert isinstance(err.value, InputError)


def test_bad_bank_in_a_file_exits_2_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = (scenarios_dir() / "banked_curve.yaml").read_text().replace("[110.0, -10.0]", "[110.0, -45.0]")
    bad = tmp_path / "banked_curve.yaml"
    bad.write_text(text)
    assert main(["simulate", str(bad), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "road.bank_deg" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_yaml_profiles_reach_the_samples() -> None:
    data = _with_road({"bank_deg": [[100.0, -6.0]], "grade_percent": [[0.0, 5.0]]})
    road = parse_scenario(data, "step_steer.yaml").road
    np.testing.assert_allclose(road.samples[:, 7], math.radians(-6.0), rtol=1e-15)
    np.testing.assert_allclose(road.samples[:, 6], 0.05, rtol=1e-15)
    np.testing.assert_allclose(road.samples[:, 5], 0.05 * road.samples[:, 0], rtol=1e-12)
    data = _with_road({"elevation_m": [[50.0, 0.0], [150.0, 10.0]]})
    smp = parse_scenario(data, "step_steer.yaml").road.samples
    np.testing.assert_allclose(smp[smp[:, 0] == 100.0, 5], 5.0, rtol=1e-12)  # the S-curve's middle
    assert np.all(smp[smp[:, 0] <= 50.0, 5] == 0.0) and np.all(smp[smp[:, 0] >= 150.0, 5] == 10.0)


# ---- the two scenarios -----------------------------------------------------------------------------

def test_banked_curve_is_driven_at_its_neutral_speed() -> None:
    sc = load_scenario("banked_curve")
    road = sc.road
    mid = road.samples[np.argmin(np.abs(road.samples[:, 0] - 235.0))]  # the middle of the arc
    radius, bank = 1.0 / mid[4], mid[7]
    assert radius == pytest.approx(150.0, rel=1e-4)
    # A left curve (rho > 0) needs the outer, right edge higher: a negative bank (ISO 8855).
    assert mid[4] > 0.0 and bank == pytest.approx(math.radians(-10.0), abs=1e-12)
    neutral = math.sqrt(G * radius * math.tan(abs(bank)))
    stated = float(re.search(r"= ([0-9.]+) m/s", sc.description).group(1))
    assert stated == pytest.approx(neutral, rel=0.01)
    assert sc.initial_speed_mps == pytest.approx(neutral, rel=0.01)
    assert sc.driver.speed.type == "hold" and sc.driver.steer.type == "path_follower"
    # Level where the curvature is zero, the full bank all along the arc.
    straight = road.samples[:, 0] <= 50.0
    assert np.all(road.samples[straight, 7] == 0.0) and np.all(road.samples[straight, 4] == 0.0)
    arc = (road.samples[:, 0] >= 110.0) & (road.samples[:, 0] <= 360.0)
    np.testing.assert_allclose(road.samples[arc, 7], math.radians(-10.0), rtol=0, atol=1e-15)
    # The outer (right) edge is higher on the surface itself, by half a lane times tan(10 deg).
    x, y = _points_on(road, np.array([235.0, 235.0]), np.array([1.75, -1.75]))
    z = road.surface(x, y)["z_m"]
    np.testing.assert_allclose(z[1] - z[0], 3.5 * math.tan(math.radians(10.0)), rtol=1e-9)
    assert road.length_m >= sc.initial_speed_mps * sc.duration_s


def test_hill_climbs_and_descends_ten_percent_smoothly() -> None:
    sc = load_scenario("hill")
    smp = sc.road.samples
    np.testing.assert_array_equal(smp[:, 2:5], 0.0)  # a straight along +x
    assert smp[:, 6].max() == pytest.approx(0.10, abs=1e-15) and smp[:, 6].min() == pytest.approx(-0.10, abs=1e-15)
    assert smp[np.argmax(smp[:, 5]), 0] == pytest.approx(235.0)  # the crest
    assert smp[:, 5].max() == pytest.approx(13.25, rel=1e-12)
    assert smp[0, 5] == 0.0 and abs(smp[-1, 5]) < 1e-9  # starts and ends level at z = 0
    # C1: the grade changes by at most its vertical-curve rate per sample (0.2 over the 140 m crest).
    assert np.max(np.abs(np.diff(smp[:, 6]))) <= 0.2 / 140.0 * sc.road.ds_m + 1e-12
    assert sc.driver.speed.type == "hold"
    assert sc.road.length_m >= sc.initial_speed_mps * sc.duration_s


def test_scenarios_command_lists_both(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["scenarios", "--json"]) == 0
    names = {r["name"] for r in json.loads(capsys.readouterr().out)}
    assert {"banked_curve", "hill"} <= names


# ---- render mesh -----------------------------------------------------------------------------------

def test_mesh_follows_bank_and_elevation_and_faces_up() -> None:
    road = _curvy_3d_road()
    verts, faces = road_surface_mesh(road, 3.5)
    assert verts.shape[1] == 3 and faces.shape[1] == 3 and faces.max() == verts.shape[0] - 1
    # A short road keeps every sample as a station; each vertex lies on the road surface (left edge
    # at +3.5 m, right edge at -3.5 m). To 1e-5 m: on a clothoid the projection finds the foot on the
    # circle osculating at the nearest sample (exact on arcs and straights), the mesh uses the sample.
    assert verts.shape[0] == 2 * road.samples.shape[0]
    on = road.surface(verts[:, 0], verts[:, 1], np.repeat(road.samples[:, 0], 2))
    np.testing.assert_allclose(verts[:, 2], on["z_m"], rtol=0, atol=1e-5)
    left = road.project(verts[0::2, 0], verts[0::2, 1], road.samples[:, 0])["e_left_m"]
    np.testing.assert_allclose(left, 3.5, rtol=0, atol=1e-5)
    arc = (road.samples[:, 0] > 61.0) & (road.samples[:, 0] < 99.0)
    np.testing.assert_allclose(verts[0::2, 2][arc], on["z_m"][0::2][arc], rtol=0, atol=1e-12)
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    fn = np.cross(b - a, c - a)
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    assert np.all(fn[:, 2] > 0.9)  # counter-clockwise from above: normals point up
    # On a banked straight each face is the road plane itself.
    phi = math.radians(12.0)
    flat_bank = build_road((0.0, 0.0, 0.5), [Segment("straight", 50.0)], profile=RoadProfile(bank_rad=((0.0, phi),)))
    v2, f2 = road_surface_mesh(flat_bank, 3.5)
    n2 = np.cross(v2[f2[:, 1]] - v2[f2[:, 0]], v2[f2[:, 2]] - v2[f2[:, 0]])
    n2 /= np.linalg.norm(n2, axis=1, keepdims=True)
    np.testing.assert_allclose(n2, np.broadcast_to(_rot_z(0.5) @ _rot_x(phi) @ [0.0, 0.0, 1.0], n2.shape),
                               rtol=0, atol=1e-12)


def test_mesh_of_a_long_road_stays_within_the_triangle_budget() -> None:
    road = build_road((0.0, 0.0, 0.0), [Segment("straight", 2000.0), Segment("arc", 3000.0, 1 / 500.0)],
                      profile=RoadProfile(grade=((0.0, 0.02), (5000.0, -0.02))))
    verts, faces = road_surface_mesh(road, 3.5)
    assert faces.shape[0] <= 4000 and faces.shape[0] >= 3000
    # The strip ends at the road's last sample (right edge = last vertex).
    assert verts[-1, 0] == pytest.approx(road.samples[-1, 1] + 3.5 * math.sin(road.samples[-1, 3]), abs=1e-9)


# ---- lane markings on the render model ---------------------------------------------------------------

@pytest.mark.parametrize("name", ["hill", "banked_curve"])
def test_lane_dashes_lie_on_the_3d_road_surface(name: str) -> None:
    # The compiled render model: each dash is a thin box; its four top corners must sit a few mm
    # above the road surface there (not buried at one end and floating at the other on a grade or
    # a bank), and its top face must be parallel to the surface (z axis = the surface normal).
    import mujoco

    from roadtruth.harness.truth.car_model import build_mjcf
    from roadtruth.harness.truth.vehicle import load_vehicle

    sc = load_scenario(name)
    road = sc.road
    m = mujoco.MjModel.from_xml_string(build_mjcf(load_vehicle(sc.vehicle), sc, visuals=True))
    marking = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_MATERIAL, "marking")
    dashes = np.flatnonzero((m.geom_matid == marking) & (m.geom_type == mujoco.mjtGeom.mjGEOM_BOX))
    assert dashes.size > 50
    corners, axes_z = [], []
    for g in dashes:
        assert m.geom_bodyid[g] == 0  # world geoms: pos and quat are world coordinates
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, m.geom_quat[g])
        rot = rot.reshape(3, 3)
        sx, sy, sz = m.geom_size[g]
        for u, v in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            corners.append(m.geom_pos[g] + rot @ np.array([u * sx, v * sy, sz]))
        axes_z.append(rot[:, 2])
    corners = np.asarray(corners)
    on = road.surface(corners[:, 0], corners[:, 1])
    clearance = corners[:, 2] - on["z_m"]
    assert clearance.min() >= 0.002, f"a dash corner {clearance.min() * 1e3:.1f} mm above the road"
    assert clearance.max() <= 0.020, f"a dash corner {clearance.max() * 1e3:.1f} mm above the road"
    # To 5e-4 (0.03 deg): the normal is taken under the box centre before its lift along the normal.
    centre_normal = road.surface(m.geom_pos[dashes, 0], m.geom_pos[dashes, 1])["normal"]
    np.testing.assert_allclose(np.asarray(axes_z), centre_normal, rtol=0, atol=5e-4)
