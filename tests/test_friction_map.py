"""Friction maps: patch membership, last-wins, split-mu, time windows, parsing, numba = NumPy."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roadtruth.harness.errors import ScenarioError
from roadtruth.harness.truth.friction_map import (
    SURFACES,
    FrictionMap,
    friction_from_spec,
    mu_at,
    parse_friction,
)

SRC = "test.yaml"


def _numba_mu(fm: FrictionMap, x: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    verts, meta = fm.arrays()
    return np.array([mu_at(fm.mu_default, verts, meta, float(a), float(b), float(c)) for a, b, c in zip(x, y, t, strict=True)])


@pytest.fixture(scope="module")
def layered() -> FrictionMap:
    return parse_friction({
        "mu_default": 0.9,
        "patches": [
            {"name": "wet", "surface": "wet", "rect": {"x_m": [0, 100], "y_m": [-5, 5]}},
            {"name": "ice", "surface": "ice", "rect": {"x_m": [40, 60], "y_m": [-5, 5]}},
            {"name": "tri", "mu": 0.45, "polygon": [[200, 0], [260, 0], [230, 30]]},
            {"name": "rain", "surface": "snow", "everywhere": True, "t_s": [10.0, "1e9"]},
        ],
    }, SRC)


def test_membership_and_last_wins(layered: FrictionMap) -> None:
    x = np.array([-10.0, 10.0, 50.0, 99.0, 50.0, 230.0, 230.0, 201.0])
    y = np.array([0.0, 0.0, 0.0, 4.9, 6.0, 10.0, 30.5, 20.0])
    expected = [0.9, 0.6, 0.1, 0.6, 0.9, 0.45, 0.9, 0.9]
    np.testing.assert_array_equal(layered.mu(x, y, 0.0), expected)
    # From t = 10 s the "everywhere" patch (listed last) wins over every other.
    np.testing.assert_array_equal(layered.mu(x, y, 10.0), 0.3)
    np.testing.assert_array_equal(layered.mu(x, y, 9.999), expected)


def test_shared_edge_belongs_to_one_patch() -> None:
    fm = parse_friction({"patches": [{"name": "a", "mu": 0.5, "rect": {"x_m": [0, 10], "y_m": [0, 10]}},
                                     {"name": "b", "mu": 0.2, "rect": {"x_m": [10, 20], "y_m": [0, 10]}}]}, SRC)
    assert fm.mu(10.0, 5.0) in (0.5, 0.2)
    # Along the shared edge each point is in exactly one of them (half-open rule).
    only_a = FrictionMap(1.0, fm.patches[:1]).mu(10.0, 5.0) == 0.5
    only_b = FrictionMap(1.0, fm.patches[1:]).mu(10.0, 5.0) == 0.2
    assert only_a != only_b


def test_split_mu() -> None:
    fm = parse_friction({"mu_default": 1.0, "patches": [{"name": "ice left", "surface": "ice", "split": "left"}]}, SRC)
    np.testing.assert_array_equal(fm.mu([0.0, 500.0, -300.0, 20.0], [0.8, 0.8, 2.0, -0.8]), [0.1, 0.1, 0.1, 1.0])
    right = parse_friction({"patches": [{"name": "r", "mu": 0.3, "split": "right"}]}, SRC)
    np.testing.assert_array_equal(right.mu([0.0, 0.0], [0.8, -0.8]), [1.0, 0.3])


def test_time_window_is_half_open() -> None:
    fm = parse_friction({"patches": [{"name": "rain", "surface": "wet", "everywhere": True, "t_s": [2.0, 5.0]}]}, SRC)
    np.testing.assert_array_equal(fm.mu(0.0, 0.0, [1.99, 2.0, 4.99, 5.0]), [1.0, 0.6, 0.6, 1.0])


def test_numba_equals_numpy(layered: FrictionMap) -> None:
    rng = np.random.default_rng(3)
    x = rng.uniform(-20, 280, 2000)
    y = rng.uniform(-10, 40, 2000)
    t = rng.uniform(0, 20, 2000)
    np.testing.assert_array_equal(_numba_mu(layered, x, y, t), layered.mu(x, y, t))


def test_no_patches() -> None:
    fm = FrictionMap.with_uniform(0.35)
    verts, meta = fm.arrays()
    assert verts.shape == (0, 1, 2) and meta.shape == (0, 4)
    assert mu_at(0.35, verts, meta, 1.0, 2.0, 3.0) == 0.35
    np.testing.assert_array_equal(fm.mu(np.zeros(3), np.zeros(3)), 0.35)


def test_arrays_layout(layered: FrictionMap) -> None:
    verts, meta = layered.arrays()
    assert verts.shape == (4, 4, 2) and verts.dtype == np.float64
    np.testing.assert_array_equal(meta[:, 0], [4, 4, 3, 4])
    np.testing.assert_array_equal(meta[:, 3], [0.6, 0.1, 0.45, 0.3])
    assert meta[3, 1] == 10.0 and meta[3, 2] == 1e9 and meta[0, 1] == -math.inf


@pytest.mark.parametrize("block, field", [
    ({"mu_default": 0.0}, "friction.mu_default"),
    ({"mu_default": 2.5}, "friction.mu_default"),
    ({"mu_default": "slippery"}, "friction.mu_default"),
    ({"patches": [{"name": "p", "mu": -0.1, "everywhere": True}]}, "friction.patches[0].mu"),
    ({"patches": [{"name": "p", "surface": "lava", "everywhere": True}]}, "friction.patches[0].surface"),
    ({"patches": [{"name": "p", "mu": 0.5}]}, "friction.patches[0]"),
    ({"patches": [{"name": "p", "mu": 0.5, "split": "up"}]}, "friction.patches[0].split"),
    ({"patches": [{"name": "p", "mu": 0.5, "rect": {"x_m": [5, 1], "y_m": [0, 1]}}]}, "friction.patches[0].rect.x_m"),
    ({"patches": [{"name": "p", "mu": 0.5, "polygon": [[0, 0], [1, 1]]}]}, "friction.patches[0].polygon"),
    ({"patches": [{"name": "p", "mu": 0.5, "everywhere": True, "t_s": [3, 1]}]}, "friction.patches[0].t_s"),
    ({"patches": [{"name": "p", "mu": 0.5, "everywhere": True, "colour": "red"}]}, "friction.patches[0].colour"),
    ({"mu_default": 1.0, "surface": "dry"}, "friction.mu_default"),
])
def test_bad_blocks_rejected(block: dict, field: str) -> None:
    with pytest.raises(ScenarioError) as err:
        parse_friction(block, SRC)
    msg = str(err.value)
    assert SRC in msg and field in msg and "\n" not in msg


def test_friction_from_spec(tmp_path: Path) -> None:
    assert friction_from_spec("0.3").mu_default == 0.3
    assert friction_from_spec(0.7).is_uniform
    for name, mu in SURFACES.items():
        assert friction_from_spec(name).mu_default == mu
    f = tmp_path / "rain.yaml"
    f.write_text("friction:\n  mu_default: 0.8\n  patches:\n    - {name: ice, surface: ice, split: left}\n")
    fm = friction_from_spec(str(f))
    assert fm.mu_default == 0.8 and fm.mu(0.0, 1.0) == 0.1
    g = tmp_path / "plain.yaml"
    g.write_text("surface: snow\n")
    assert friction_from_spec(str(g)).mu_default == 0.3
    for bad in ("0", "-1", "3.0", "gravel", str(tmp_path / "missing.yaml")):
        with pytest.raises(ScenarioError):
            friction_from_spec(bad)


polygons = st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50)), min_size=3, max_size=7)


@settings(max_examples=60, deadline=None)
@given(polys=st.lists(polygons, min_size=1, max_size=4),
       mus=st.lists(st.floats(0.05, 2.0), min_size=4, max_size=4),
       pts=st.lists(st.tuples(st.floats(-60, 60), st.floats(-60, 60), st.floats(0, 10)), min_size=1, max_size=20))
def test_property_numba_matches_numpy_and_values_come_from_the_map(polys, mus, pts) -> None:
    patches = []
    for k, poly in enumerate(polys):
        v = np.asarray(poly, dtype=np.float64)
        area = 0.5 * abs(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
        if area < 1e-6:
            continue
        patches.append({"name": f"p{k}", "mu": mus[k], "polygon": [list(p) for p in poly], "t_s": [k, k + 5]})
    fm = parse_friction({"mu_default": 0.77, "patches": patches}, SRC)
    x, y, t = (np.array(c) for c in zip(*pts, strict=True))
    got = fm.mu(x, y, t)
    np.testing.assert_array_equal(_numba_mu(fm, x, y, t), got)
    allowed = {0.77, *(p["mu"] for p in patches)}
    assert set(got.tolist()) <= allowed
    # Outside every polygon's bounding box the default applies.
    far = fm.mu(x + 200.0, y, t)
    np.testing.assert_array_equal(far, 0.77)
