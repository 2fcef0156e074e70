"""LMI toolkit: polytopes (Lemmas 9, 10), certification rejects broken gains, the design cache."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial import Delaunay

from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers import lmi
from roadtruth.observers.bicycle import slip_model_terms
from roadtruth.observers.lmi import (
    DesignStatus,
    certify_design,
    is_metzler,
    physical_grid,
    robust_vertices,
    trapezoid_vertices,
)
from roadtruth.observers.lpv_wang_design import _decay_checks
from roadtruth.observers.registry import create

V_RNG, A_RNG = (15 / 3.6, 150 / 3.6), (-8.0, 8.0)


@pytest.fixture(autouse=True)
def _design_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("ROADTRUTH_CACHE", str(tmp_path))  # designs go to tmp_path/designs
    monkeypatch.setenv("ROADTRUTH_SHIPPED_DESIGNS", "0")  # these tests solve designs themselves
    lmi.clear_memory_cache()
    yield
    lmi.clear_memory_cache()


def test_trapezoid_contains_the_scheduling_domain() -> None:
    v = trapezoid_vertices(V_RNG, A_RNG)
    np.testing.assert_allclose(sorted(map(tuple, v.round(4))),
                               [(0.024, -0.192), (0.024, 0.192), (0.24, -1.92), (0.24, 1.92)])
    g = physical_grid([V_RNG, A_RNG], 30)
    pts = np.column_stack([1 / g[:, 0], g[:, 1] / g[:, 0]])
    assert np.all(Delaunay(v).find_simplex(pts, tol=1e-12) >= 0)


def test_sixteen_vertices_match_the_digest_table_and_contain_the_domain() -> None:
    v = robust_vertices(V_RNG, A_RNG, (-0.1, 0.1), (-0.2, 0.2))
    assert v.shape == (16, 4)
    rows = {tuple(r) for r in v.round(5)}
    for row in [(0.24, -1.92, -0.02667, 0.64), (0.24, 1.92, 0.02182, 0.52364), (0.024, 0.192, 0.00218, 0.05236),
                (0.024, -0.192, -0.00267, -0.05236)]:
        assert row in rows
    g = physical_grid([V_RNG, A_RNG, (-0.1, 0.1), (-0.2, 0.2)], 5)
    th1, th2 = 1 / g[:, 0], g[:, 1] / g[:, 0]
    pts = np.column_stack([th1, th2, g[:, 2] / (1 + g[:, 2]) * th1, (g[:, 2] - g[:, 3]) / (1 + g[:, 2]) * th2])
    assert np.all(Delaunay(v).find_simplex(pts, tol=1e-12) >= 0)


def test_certification_rejects_a_gain_unstable_at_one_vertex() -> None:
    A1, _ = slip_model_terms(load_vehicle("sedan"))
    verts = trapezoid_vertices(V_RNG, A_RNG)
    good = [np.zeros((2, 1))] * 3
    lyap, closed = _decay_checks(A1, good, np.eye(2), 0.0)
    assert max(np.linalg.eigvals(closed(p)).real.max() for p in verts) < 0
    # a negative L0 on the front state destabilises the slow (high-speed) vertices only
    bad = [np.array([[-6.0], [0.0]]), np.zeros((2, 1)), np.zeros((2, 1))]
    lyap, closed = _decay_checks(A1, bad, np.eye(2), 0.0)
    unstable = [np.linalg.eigvals(closed(p)).real.max() > 0 for p in verts]
    assert any(unstable) and not all(unstable)
    cert = certify_design(P=np.eye(2), lmis={"lyapunov": lyap}, vertices=verts, closed_loop=closed)
    assert not cert.certified
    assert "vertex" in cert.reason and cert.margins["closed_loop_max_real_eig"] > 0


def test_certification_rejects_a_non_metzler_interval_gain() -> None:
    """Digest 001 O5: the printed interval gain (4.47) is not Metzler at any of the 16 vertices."""
    _, bf0 = slip_model_terms(load_vehicle("wang2014"))
    C = np.array([[1.0, -1.0]])
    L = [np.array([[1.7127], [1.3431]]), np.array([[-58.5902], [-42.9510]]), np.array([[-0.5579], [-0.4398]])]
    eta = trapezoid_vertices(V_RNG, A_RNG)
    xi = lmi.box_corners([(60e3, 90e3), (35e3, 65e3)])
    pts = np.array([[e1, e2, cf, cr] for e1, e2 in eta for cf, cr in xi])

    def a_l(p: np.ndarray) -> np.ndarray:
        A = p[0] * bf0 @ np.diag(p[2:]) - p[1] * np.eye(2)
        return A - (L[0] + p[0] * L[1] + p[1] * L[2]) @ C

    assert not any(is_metzler(a_l(p)) for p in pts)
    cert = certify_design(P=np.eye(2), lmis={}, vertices=pts, metzler=a_l)
    assert not cert.certified and "Metzler" in cert.reason
    assert is_metzler(np.array([[-3.0, 0.1], [0.0, -1.0]]))


def test_cached_design_equals_a_fresh_one(tmp_path) -> None:
    v = load_vehicle("sedan")
    fresh = create("lpv_wang", v).design()
    assert not fresh.from_cache and fresh.certified
    files = list((tmp_path / "designs").glob("*.json"))
    assert len(files) == 1
    json.loads(files[0].read_text())  # plain JSON, not pickle
    lmi.clear_memory_cache()
    again = create("lpv_wang", v).design()
    assert again.from_cache and again == fresh
    # everything the design depends on is in the key: another mass, another design
    heavier = create("lpv_wang", v.with_overrides(mass_kg=1600.0)).design()
    assert heavier.key != fresh.key
    no_cache = create("lpv_wang", v, use_cache=False).design()
    assert not no_cache.from_cache  # solved again: same gains up to solver tolerance
    np.testing.assert_allclose(no_cache.gain("L0"), fresh.gain("L0"), rtol=1e-6, atol=1e-9)


def test_design_result_round_trips_through_json() -> None:
    d = create("lpv_wang_printed", load_vehicle("sedan")).design()
    back = lmi.DesignResult.from_json_dict(json.loads(json.dumps(d.to_json_dict())))
    assert back == d and back.status is DesignStatus.CERTIFIED
