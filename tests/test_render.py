"""Offscreen frames: the reused-context renderer draws what MuJoCo's own renderer draws, and the
files a run writes show the car where MuJoCo puts it.

Rendering keeps one GL context per process (``Offscreen``), draws the video smaller than the key
frames into the same buffer, draws the ground plane on a coarser render grid and the round shapes
with fewer vertices than MuJoCo's defaults; all are speed measures that must not change what a frame
shows. The references are ``mujoco.Renderer`` images of the same model, pose and camera.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

mujoco = pytest.importorskip("mujoco")

from roadtruth.harness.report import render  # noqa: E402
from roadtruth.harness.truth.scenario import load_scenario  # noqa: E402
from roadtruth.harness.truth.simulate import simulate  # noqa: E402

W, H = 320, 240


def _model(xml: str, plane_grid_m: float | None = None, mujoco_tessellation: bool = False,
           buffer: tuple[int, int] = (640, 480)) -> mujoco.MjModel:
    """The render model as rendering builds it; ``plane_grid_m`` overrides its plane grid and
    ``mujoco_tessellation`` restores MuJoCo's default slices, stacks and quads, to compare with."""
    m = render.render_model(xml, buffer)
    if plane_grid_m is not None:
        planes = m.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
        m.geom_size[planes, 2] = plane_grid_m
    if mujoco_tessellation:
        q = mujoco.MjModel.from_xml_string(xml).vis.quality
        m.vis.quality.numslices, m.vis.quality.numstacks, m.vis.quality.numquads = q.numslices, q.numstacks, q.numquads
    return m


def _posed(m: mujoco.MjModel, qpos: np.ndarray) -> mujoco.MjData:
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_forward(m, d)
    return d


def _reference(m: mujoco.MjModel, qpos: np.ndarray, size: tuple[int, int] = (W, H),
               segmentation: bool = False) -> np.ndarray:
    r = mujoco.Renderer(m, height=size[1], width=size[0])
    try:
        if segmentation:
            r.enable_segmentation_rendering()
        r.update_scene(_posed(m, qpos), camera="chase")
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        r.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        return r.render().copy()
    finally:
        r.close()


def _offscreen(m: mujoco.MjModel, qpos: np.ndarray, size: tuple[int, int] = (W, H)) -> np.ndarray:
    r = render.Offscreen.for_model(m, m.vis.global_.offwidth, m.vis.global_.offheight)
    try:
        return r.render(_posed(m, qpos), mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "chase"), size)
    finally:
        r.close()


def _car_mask(m: mujoco.MjModel, qpos: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Pixels (H, W) bool where MuJoCo's renderer shows a geom of the car (chassis and wheels)."""
    seg = _reference(m, qpos, size, segmentation=True)
    chassis = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "chassis")
    car_geoms = np.flatnonzero(m.body_rootid[m.geom_bodyid] == chassis)
    return (seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM) & np.isin(seg[..., 0], car_geoms)


@pytest.fixture(scope="module")
def truths():
    out = []
    for name in ("step_steer", "car_following"):  # a bare road, and one with a lead car
        sc = dataclasses.replace(load_scenario(name), duration_s=1.0)
        out.append(simulate(sc))
    return out


@pytest.fixture(scope="module")
def gl(truths):
    try:
        _reference(_model(truths[0].render_xml), truths[0].qpos[-1])
    except Exception as e:  # no GL in this environment: nothing to compare
        pytest.skip(f"offscreen OpenGL unavailable: {e}")


def test_reused_context_draws_what_mujocos_renderer_draws(truths, gl) -> None:
    refs = [_reference(_model(t.render_xml), t.qpos[-1]) for t in truths]
    # Two models in a row on the one context of this process, then the first again.
    for t, ref in [*zip(truths, refs, strict=True), (truths[0], refs[0])]:
        img = _offscreen(_model(t.render_xml), t.qpos[-1])
        assert img.shape == (H, W, 3) and img.dtype == np.uint8
        assert img.std() > 5.0  # a scene, not a cleared buffer
        assert np.array_equal(img, ref)


def test_video_size_drawn_into_the_key_frame_buffer_is_mujocos_image_of_that_size(truths, gl) -> None:
    s = render.RenderSettings()
    assert s.video_size[0] < s.frame_size[0] and s.buffer_size == s.frame_size
    t = truths[1]
    m = _model(t.render_xml, buffer=s.buffer_size)
    r = render.Offscreen.for_model(m, *s.buffer_size)
    try:
        cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "chase")
        d = _posed(m, t.qpos[-1])
        big = r.render(d, cam, s.frame_size)
        small = r.render(d, cam, s.video_size)  # after a larger image: nothing of it may be left
    finally:
        r.close()
    assert big.shape == (s.frame_size[1], s.frame_size[0], 3)
    assert np.array_equal(small, _reference(m, t.qpos[-1], s.video_size))
    assert np.array_equal(big, _reference(m, t.qpos[-1], s.frame_size))


def test_coarse_plane_grid_lights_the_same_pixels(truths, gl) -> None:
    t = truths[0]
    fine = _reference(_model(t.render_xml, 0.1), t.qpos[-1]).astype(float)
    coarse = _reference(_model(t.render_xml, render.PLANE_GRID_M), t.qpos[-1]).astype(float)
    diff = np.abs(coarse - fine).max(axis=2)
    assert diff.mean() < 0.25  # of 255 (measured 0.05)
    # Only the far edge of the plane at the horizon may move by a pixel (measured: 2 pixels).
    assert np.count_nonzero(diff > 8) <= 0.001 * diff.size


def test_fewer_vertices_move_only_a_tyre_outline(truths, gl) -> None:
    for t in truths:
        m_default = _model(t.render_xml, mujoco_tessellation=True)
        m_coarse = _model(t.render_xml)
        assert m_coarse.vis.quality.numslices < m_default.vis.quality.numslices  # the setting is in effect
        size = (640, 480)
        full = _reference(m_default, t.qpos[-1], size).astype(float)
        coarse = _reference(m_coarse, t.qpos[-1], size).astype(float)
        diff = np.abs(coarse - full).max(axis=2)
        assert diff.mean() < 0.25  # of 255 (measured 0.03-0.06)
        moved = diff > 8
        assert np.count_nonzero(moved) <= 0.002 * diff.size  # measured 0.04-0.08 %
        # What moves is the silhouette of the wheels, nothing else in the picture.
        wheels = _car_mask(m_default, t.qpos[-1], size) | _car_mask(m_coarse, t.qpos[-1], size)
        grown = wheels.copy()
        for axis in (0, 1):
            for shift in (-1, 1):
                grown |= np.roll(wheels, shift, axis=axis)
        print(f"tessellation: mean {diff.mean():.3f}, moved {moved.mean():.5f}")
        assert not np.any(moved & ~grown)


def test_key_frames_and_video_show_the_car_where_mujoco_puts_it(truths, gl, tmp_path: Path) -> None:
    import cv2
    import imageio_ffmpeg

    t = truths[0]
    s = render.RenderSettings()
    out = render.render_scenario(t, tmp_path, "step_steer")
    assert out.reason is None and out.video == "videos/step_steer.mp4"
    t_s = t.frame["t_s"].to_numpy(float)
    m = _model(t.render_xml, buffer=s.buffer_size)

    # The last key frame (lossless PNG): the car's pixels are MuJoCo's, exactly.
    key = out.frames[-1]
    png = cv2.cvtColor(cv2.imread(str(tmp_path / key["file"])), cv2.COLOR_BGR2RGB)
    assert png.shape == (s.frame_size[1], s.frame_size[0], 3)
    q = t.qpos[int(render._nearest_rows(t_s, np.array([key["t_s"]]))[0])]
    car = _car_mask(m, q, s.frame_size)
    assert car.mean() > 0.02  # the chase camera has the car in view (measured 0.06)
    ref = _reference(m, q, s.frame_size)
    assert np.array_equal(png[car], ref[car])

    # The video (lossy H.264): its size, its frame count, and the car where MuJoCo draws it.
    reader = imageio_ffmpeg.read_frames(str(tmp_path / out.video))
    meta = next(reader)
    assert tuple(meta["size"]) == s.video_size
    vw, vh = s.video_size
    frames = [np.frombuffer(b, np.uint8).reshape(vh, vw, 3) for b in reader]
    times = render.video_times(float(t_s[0]), float(t_s[-1]), s.video_fps, s.max_video_s)
    assert len(frames) == times.size == out.n_rendered - len(out.frames)
    k = times.size // 2
    q = t.qpos[int(render._nearest_rows(t_s, times[k:k + 1])[0])]
    car = _car_mask(m, q, s.video_size)
    assert car.mean() > 0.02
    ref = _reference(m, q, s.video_size).astype(float)
    err_car = np.abs(frames[k].astype(float) - ref)[car].mean()
    background = np.abs(ref[car] - np.median(ref[~car], axis=0)).mean()  # what "no car" would give
    print(f"car {car.mean():.3f} of the video frame, error there {err_car:.2f}, background {background:.1f}")
    assert err_car < 6.0  # of 255: compression only (measured ~2)
    assert background > 5 * err_car
