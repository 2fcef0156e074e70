"""Offscreen frames: the reused-context renderer draws what MuJoCo's own renderer draws.

Rendering keeps one GL context per process (``Offscreen``) and draws the ground plane on a coarser
render grid than the car model declares; both are speed measures that must not change a frame. The
references are ``mujoco.Renderer`` images of the same model, pose and camera.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

mujoco = pytest.importorskip("mujoco")

from roadtruth.harness.report import render  # noqa: E402
from roadtruth.harness.truth.scenario import load_scenario  # noqa: E402
from roadtruth.harness.truth.simulate import simulate  # noqa: E402

W, H = 320, 240


def _model(xml: str, plane_grid_m: float | None) -> mujoco.MjModel:
    m = mujoco.MjModel.from_xml_string(xml)
    m.vis.quality.offsamples = 0
    m.vis.map.znear = min(m.vis.map.znear, 0.2 / max(m.stat.extent, 1e-6))
    if plane_grid_m is not None:
        planes = m.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
        m.geom_size[planes, 2] = plane_grid_m
    return m


def _reference(m: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_forward(m, d)
    r = mujoco.Renderer(m, height=H, width=W)
    try:
        r.update_scene(d, camera="chase")
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        r.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        return r.render().copy()
    finally:
        r.close()


def _offscreen(m: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_forward(m, d)
    r = render.Offscreen.for_model(m, W, H)
    try:
        return r.render(d, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "chase"))
    finally:
        r.close()


@pytest.fixture(scope="module")
def truths():
    out = []
    for name in ("step_steer", "car_following"):  # a bare road, and one with a lead car
        sc = dataclasses.replace(load_scenario(name), duration_s=1.0)
        out.append(simulate(sc))
    return out


def test_reused_context_draws_what_mujocos_renderer_draws(truths) -> None:
    try:
        refs = [_reference(_model(t.render_xml, None), t.qpos[-1]) for t in truths]
    except Exception as e:  # no GL in this environment: nothing to compare
        pytest.skip(f"offscreen OpenGL unavailable: {e}")
    # Two models in a row on the one context of this process, then the first again.
    for t, ref in [*zip(truths, refs, strict=True), (truths[0], refs[0])]:
        img = _offscreen(_model(t.render_xml, None), t.qpos[-1])
        assert img.shape == (H, W, 3) and img.dtype == np.uint8
        assert img.std() > 5.0  # a scene, not a cleared buffer
        assert np.array_equal(img, ref)


def test_coarse_plane_grid_lights_the_same_pixels(truths) -> None:
    t = truths[0]
    try:
        fine = _reference(_model(t.render_xml, 0.1), t.qpos[-1]).astype(float)
    except Exception as e:
        pytest.skip(f"offscreen OpenGL unavailable: {e}")
    coarse = _reference(_model(t.render_xml, render.PLANE_GRID_M), t.qpos[-1]).astype(float)
    diff = np.abs(coarse - fine).max(axis=2)
    assert diff.mean() < 0.25  # of 255 (measured 0.05)
    # Only the far edge of the plane at the horizon may move by a pixel (measured: 2 pixels).
    assert np.count_nonzero(diff > 8) <= 0.001 * diff.size
