"""Roads: exact geometry of arcs and clothoids, projection, and numba = NumPy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import fresnel

from roadtruth.harness.truth.road import Road, Segment, build_road, road_project, road_project_many


def test_circle_closes_on_itself() -> None:
    R = 40.0
    road = build_road((3.0, -2.0, 0.3), [Segment("arc", 2 * math.pi * R, 1.0 / R)], ds_m=0.25)
    x, y, psi = road.pose_at(2 * math.pi * R)
    assert x == pytest.approx(3.0, abs=1e-9)
    assert y == pytest.approx(-2.0, abs=1e-9)
    assert psi == pytest.approx(0.3 + 2 * math.pi, abs=1e-12)
    # Every sample is at distance R from the centre, which lies R to the left of the start.
    cx, cy = 3.0 - R * math.sin(0.3), -2.0 + R * math.cos(0.3)
    inside = road.samples[:, 0] <= 2 * math.pi * R
    d = np.hypot(road.samples[inside, 1] - cx, road.samples[inside, 2] - cy)
    np.testing.assert_allclose(d, R, atol=1e-9)


def test_clothoid_curvature_is_linear_and_heading_is_its_integral() -> None:
    k1, L = 0.02, 50.0
    road = build_road((0.0, 0.0, 0.0), [Segment("straight", 10.0), Segment("clothoid", L, k1)], ds_m=0.25)
    smp = road.samples
    on = (smp[:, 0] >= 10.0) & (smp[:, 0] <= 10.0 + L)
    u = smp[on, 0] - 10.0
    np.testing.assert_allclose(smp[on, 4], k1 * u / L, atol=1e-12)
    np.testing.assert_allclose(smp[on, 3], 0.5 * k1 * u**2 / L, atol=1e-12)
    # Position against the Fresnel integrals: x = a sqrt(pi) C(u / (a sqrt(pi))), a^2 = L / k1.
    a = math.sqrt(L / k1)
    S, C = fresnel(u / (a * math.sqrt(math.pi)))
    np.testing.assert_allclose(smp[on, 1], 10.0 + a * math.sqrt(math.pi) * C, atol=1e-9)
    np.testing.assert_allclose(smp[on, 2], a * math.sqrt(math.pi) * S, atol=1e-9)


def test_curvature_carries_over_and_steps() -> None:
    road = build_road((0.0, 0.0, 0.0), [Segment("clothoid", 20.0, 0.01), Segment("arc", 20.0),
                                        Segment("arc", 20.0, -0.02), Segment("straight", 10.0)])
    rho = road.curvature_at(np.array([10.0, 30.0, 50.0, 65.0]))
    np.testing.assert_allclose(rho, [0.005, 0.01, -0.02, 0.0], atol=1e-12)
    # Heading = integral of curvature: 0.5*0.01*20 + 0.01*20 - 0.02*20.
    assert road.pose_at(70.0)[2] == pytest.approx(0.1 + 0.2 - 0.4, abs=1e-12)


def test_samples_are_uniform_and_cover_the_length() -> None:
    road = build_road((0.0, 0.0, 0.0), [Segment("straight", 10.1)], ds_m=0.25)
    np.testing.assert_allclose(np.diff(road.samples[:, 0]), 0.25)
    assert road.length_m >= 10.1
    assert not road.samples.flags.writeable


@pytest.fixture(scope="module")
def bend() -> Road:
    return build_road((0.0, 0.0, 0.0), [Segment("straight", 30.0), Segment("clothoid", 30.0, 0.02),
                                        Segment("arc", 40.0), Segment("clothoid", 40.0, -0.01),
                                        Segment("straight", 20.0)])


def _points_off_the_road(road: Road, s: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x, y, psi = road.pose_at(s)
    return x - e * np.sin(psi), y + e * np.cos(psi)


def test_projection_of_known_points(bend: Road) -> None:
    s = np.array([5.0, 31.3, 47.77, 80.0, 111.1, 150.2])
    e = np.array([1.2, -0.7, 2.5, -3.0, 0.4, 1.9])
    x, y = _points_off_the_road(bend, s, e)
    out = bend.project(x, y)
    np.testing.assert_allclose(out["s_m"], s, atol=2e-4)
    np.testing.assert_allclose(out["e_left_m"], e, atol=2e-4)
    _, _, psi = bend.pose_at(s)
    np.testing.assert_allclose(out["psi_rad"], psi, atol=1e-4)
    np.testing.assert_allclose(out["rho_1pm"], bend.curvature_at(s), atol=1e-4)
    for k in range(s.size):
        i, sk, ek, psik, rhok = road_project(bend.samples, bend.ds_m, x[k], y[k], 0)
        assert sk == pytest.approx(s[k], abs=2e-4)
        assert ek == pytest.approx(e[k], abs=2e-4)


def test_exact_on_an_arc() -> None:
    R = 25.0
    road = build_road((0.0, 0.0, 0.0), [Segment("arc", 100.0, -1.0 / R)])
    s, e = 37.123, 1.5  # left of a right-hand bend = outside, at radius R + e from the centre
    ang = s / R
    x, y = (R + e) * math.sin(ang), -R + (R + e) * math.cos(ang)
    i, sp, ep, psi, rho = road_project(road.samples, road.ds_m, x, y, 50)
    assert sp == pytest.approx(s, abs=1e-9)
    assert ep == pytest.approx(e, abs=1e-9)
    assert psi == pytest.approx(-ang, abs=1e-9)
    assert rho == pytest.approx(-1.0 / R, abs=1e-12)


def test_numba_equals_numpy(bend: Road) -> None:
    rng = np.random.default_rng(7)
    s = rng.uniform(-20.0, bend.length_m + 20.0, 400)
    e = rng.uniform(-4.0, 4.0, 400)
    x, y = _points_off_the_road(bend, s, e)
    np_out = bend.project(x, y)
    nb = np.array([road_project(bend.samples, bend.ds_m, x[k], y[k], int(rng.integers(0, 600)))
                   for k in range(s.size)])
    np.testing.assert_array_equal(nb[:, 0].astype(int), np_out["i"])
    np.testing.assert_allclose(nb[:, 1], np_out["s_m"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(nb[:, 2], np_out["e_left_m"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(nb[:, 3], np_out["psi_rad"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(nb[:, 4], np_out["rho_1pm"], rtol=0, atol=1e-12)


def test_extends_straight_past_both_ends(bend: Road) -> None:
    x_end, y_end, psi_end = (float(v) for v in bend.samples[-1, 1:4])
    d = 15.0
    x = x_end + d * math.cos(psi_end) - 2.0 * math.sin(psi_end)
    y = y_end + d * math.sin(psi_end) + 2.0 * math.cos(psi_end)
    i, s, e, psi, rho = road_project(bend.samples, bend.ds_m, x, y, 0)
    assert (s, e, psi, rho) == pytest.approx((bend.length_m + d, 2.0, psi_end, 0.0), abs=1e-9)
    i, s, e, psi, rho = road_project(bend.samples, bend.ds_m, -7.0, -1.0, 300)
    assert (i, s, e, rho) == pytest.approx((0, -7.0, -1.0, 0.0), abs=1e-12)
    xb, yb, psib = bend.pose_at(np.array([bend.length_m + d]))
    assert (xb[0], yb[0], psib[0]) == pytest.approx((x_end + d * math.cos(psi_end), y_end + d * math.sin(psi_end),
                                                     psi_end), abs=1e-9)


def test_hint_keeps_the_current_lap_of_an_overlapping_road() -> None:
    R = 40.0
    lap = 2 * math.pi * R
    road = build_road((0.0, 0.0, 0.0), [Segment("arc", 2.5 * lap, 1.0 / R)])
    x, y, _ = road.pose_at(lap + 10.0)
    near_second_lap = int((lap + 9.0) / road.ds_m)
    _, s, e, _, _ = road_project(road.samples, road.ds_m, x, y, near_second_lap)
    assert s == pytest.approx(lap + 10.0, abs=1e-6)
    # Far off the road (12 m outside), the global scan still prefers the hinted lap.
    xo, yo = x + 12.0 * (x - 0.0) / R, y + 12.0 * (y - R) / R
    _, s, e, _, _ = road_project(road.samples, road.ds_m, xo, yo, near_second_lap)
    assert s == pytest.approx(lap + 10.0, abs=1e-6)
    assert e == pytest.approx(-12.0, abs=1e-6)
    out = road.project(np.array([x]), np.array([y]), s_hint_m=np.array([lap + 5.0]))
    assert out["s_m"][0] == pytest.approx(lap + 10.0, abs=1e-6)


def test_far_off_hint_recovers(bend: Road) -> None:
    x, y = _points_off_the_road(bend, np.array([120.0]), np.array([0.5]))
    _, s, e, _, _ = road_project(bend.samples, bend.ds_m, x[0], y[0], 10**9)
    assert (s, e) == pytest.approx((120.0, 0.5), abs=2e-4)
    _, s, e, _, _ = road_project(bend.samples, bend.ds_m, x[0], y[0], -5)
    assert (s, e) == pytest.approx((120.0, 0.5), abs=2e-4)


def test_trajectory_projection_follows_hints(bend: Road) -> None:
    s = np.linspace(0.0, bend.length_m, 900)
    x, y = _points_off_the_road(bend, s, 0.3 * np.sin(s / 7.0))
    out = road_project_many(bend.samples, bend.ds_m, x, y, 0)
    np.testing.assert_allclose(out[:, 1], s, atol=2e-4)
    np.testing.assert_allclose(out[:, 2], 0.3 * np.sin(s / 7.0), atol=2e-4)


def test_straight_default() -> None:
    road = Road.straight_default(100.0)
    out = road.project(np.array([42.0]), np.array([-1.25]))
    assert (out["s_m"][0], out["e_left_m"][0], out["psi_rad"][0]) == pytest.approx((42.0, -1.25, 0.0))
    longer = road.with_length_at_least(250.0)
    assert longer.length_m >= 250.0 and longer.samples[-1, 2] == 0.0


def test_bad_segments_rejected() -> None:
    with pytest.raises(ValueError):
        build_road((0.0, 0.0, 0.0), [])
    with pytest.raises(ValueError):
        build_road((0.0, 0.0, 0.0), [Segment("spiral", 10.0)])
    with pytest.raises(ValueError):
        build_road((0.0, 0.0, 0.0), [Segment("straight", 0.0)])


def test_hinted_projection_picks_the_nearest_sample_of_its_window() -> None:
    # The hinted NumPy projection searches the samples within +-half_width of the hint (clipped to the
    # road) and keeps the first of equal distances: brute force over the same window must agree,
    # on a road that passes near itself (two laps of a circle: the window keeps the hinted lap),
    # at both ends, far off the road, with exact ties (points on the circle's centre) and NaN.
    R = 30.0
    road = build_road((0.0, 0.0, 0.0), [Segment("arc", 4 * math.pi * R, 1.0 / R)], ds_m=0.25)
    smp, n = road.samples, road.samples.shape[0]
    rng = np.random.default_rng(7)
    s_true = rng.uniform(-20.0, road.length_m + 20.0, 4000)
    x, y = _points_off_the_road(road, s_true, rng.uniform(-12.0, 12.0, s_true.size))
    hint = s_true + rng.uniform(-30.0, 30.0, s_true.size)
    x = np.concatenate([x, [0.0, 0.0, np.nan]])  # the circle's centre (0, R): every sample ties
    y = np.concatenate([y, [R, R, 1.0]])
    hint = np.concatenate([hint, [5.0, 300.0, 50.0]])
    got = road.project(x, y, s_hint_m=hint)["i"]
    h = np.clip(np.rint(hint / road.ds_m), 0, n - 1).astype(np.int64)
    half = int(round(8.0 * 4 / road.ds_m))
    idx = np.clip(h[:, None] + np.arange(-half, half + 1)[None, :], 0, n - 1)
    d2 = (smp[idx, 1] - x[:, None]) ** 2 + (smp[idx, 2] - y[:, None]) ** 2
    want = idx[np.arange(x.size), np.argmin(d2, axis=1)]
    np.testing.assert_array_equal(got, want)
    # The hinted lap is kept: a point near the start, hinted on the second lap, stays on it.
    assert road.project(1.0, 0.5, s_hint_m=2 * math.pi * R + 1.0)["s_m"][0] > 2 * math.pi * R - 1.0
