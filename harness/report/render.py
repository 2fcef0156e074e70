"""MuJoCo offscreen frames and a short MP4 per scenario, annotated with truth and estimates.

The model is rebuilt from ``Truth.model_xml`` and posed from the logged ``qpos`` (no stepping), so a
render shows exactly what was simulated. Key frames are taken at the start, the middle, the end and
at every scenario event; the video samples the whole run at ``VIDEO_FPS`` frames per second of
video, at most ``MAX_VIDEO_S`` seconds (longer runs play faster than real time).

Sizes and encoder settings (:class:`RenderSettings`) were chosen by measurement on Mesa's software
renderer (``benchmarks/bench_run.py --render-sizes``): the GL render costs in proportion to the
pixels drawn, so the video, which the report shows 480 pixels wide, is drawn at 480 x 360 into the
same offscreen buffer as the 640 x 480 key frames (which open full size from the report), with its
annotations scaled to the frame; x264's ``ultrafast`` preset encodes it at under half the CPU of
``veryfast`` for a larger file of no lower quality.

Offscreen GL needs ``MUJOCO_GL`` (egl or osmesa) set before mujoco is first imported; this module
sets ``egl`` if nothing was chosen. When no GL context can be made, :func:`render_scenario`
returns a ``RenderResult`` whose ``reason`` says why, and the report says so.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

WIDTH, HEIGHT = 640, 480  # key frames [pixels]
VIDEO_WIDTH, VIDEO_HEIGHT = 480, 360  # video frames [pixels]: the width the report plays it at
VIDEO_FPS = 10
MAX_VIDEO_S = 6.0
ANNOTATION_WIDTH = 640  # frame width [pixels] the annotation layout is drawn for; scaled to others ...
# ... but not below this: at 0.85 a 480-pixel video frame, played 1:1 in the report, reads better than
# a 640-pixel one the browser scales to 480 (at 0.75 the wheel labels blur).
ANNOTATION_MIN_SCALE = 0.85
MAX_KEY_FRAMES = 8
PLANE_GRID_M = 5.0  # render grid of the ground plane [m]
TESSELLATION = (16, 2, 1)  # MuJoCo visual/quality numslices, numstacks, numquads (at most)
WHEELS = ("fl", "fr", "rl", "rr")


@dataclass(frozen=True)
class RenderSettings:
    """How a scenario is rendered: frame sizes [pixels], video rate [frames per second of video] and
    length cap [s], and the H.264 encoder's speed preset and constant rate factor (lower: better)."""

    frame_size: tuple[int, int] = (WIDTH, HEIGHT)
    video_size: tuple[int, int] = (VIDEO_WIDTH, VIDEO_HEIGHT)
    video_fps: float = VIDEO_FPS
    max_video_s: float = MAX_VIDEO_S
    x264_preset: str = "ultrafast"
    x264_crf: int = 30

    def __post_init__(self) -> None:
        for w, h in (self.frame_size, self.video_size):
            if w < 2 or h < 2 or w % 2 or h % 2:  # yuv420p video needs even sizes
                raise ValueError(f"render sizes must be even and at least 2x2 pixels, not {w}x{h}")

    @property
    def buffer_size(self) -> tuple[int, int]:
        """The offscreen buffer both sizes are drawn into [pixels]."""
        return (max(self.frame_size[0], self.video_size[0]), max(self.frame_size[1], self.video_size[1]))


@dataclass(frozen=True)
class RenderResult:
    """What was rendered: key frames (``file`` relative to the run folder, ``t_s``, ``label``),
    the video path (relative) or None, and the reason when nothing could be rendered."""

    frames: tuple[dict[str, Any], ...] = ()
    video: str | None = None
    reason: str | None = None
    seconds: float = 0.0
    n_rendered: int = 0
    notes: tuple[str, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict[str, Any]:
        return {"frames": list(self.frames), "video": self.video, "reason": self.reason,
                "n_rendered": self.n_rendered}


@dataclass(frozen=True, eq=False)
class RenderSource:
    """What rendering needs from a ``Truth`` (picklable, small: only the columns drawn)."""

    frame: pd.DataFrame
    qpos: np.ndarray
    model_xml: str
    events: tuple[tuple[float, str], ...]

    @classmethod
    def from_truth(cls, truth: Any) -> RenderSource:
        cols = [c for c in ("t_s", "vx_mps", "beta_rad", *(f"mu_{w}" for w in WHEELS), "lead_x_m", "lead_y_m")
                if c in truth.frame.columns]
        return cls(frame=truth.frame[cols], qpos=np.asarray(truth.qpos), model_xml=getattr(truth, "render_xml", truth.model_xml),
                   events=tuple(getattr(truth, "events", ()) or ()))


def key_times(t0: float, t1: float, events: list[tuple[float, str]]) -> list[tuple[float, str]]:
    """Start, events, middle and end, sorted, without near-duplicates (< 2 % of the run apart)."""
    cand = [(t0, "start"), *[(t, lab) for t, lab in events if t0 <= t <= t1], (0.5 * (t0 + t1), "middle"),
            (t1, "end")]
    cand.sort(key=lambda p: p[0])
    out: list[tuple[float, str]] = []
    gap = 0.02 * max(t1 - t0, 1e-9)
    for t, lab in cand:
        if out and t - out[-1][0] < gap:
            generic = ("middle", "start", "end")
            if out[-1][1] in generic and lab not in generic:
                out[-1] = (out[-1][0], lab)  # an event beats a generic label at the same time
            continue
        out.append((t, lab))
    if len(out) > MAX_KEY_FRAMES:
        idx = np.unique(np.round(np.linspace(0, len(out) - 1, MAX_KEY_FRAMES)).astype(int))
        out = [out[i] for i in idx]
    return out


def video_times(t0: float, t1: float, fps: float = VIDEO_FPS, max_s: float = MAX_VIDEO_S) -> np.ndarray:
    """Sample times of the video frames [s]: real time at ``fps``, capped at ``max_s`` seconds of video."""
    n = int(min(math.ceil((t1 - t0) * fps), max_s * fps)) + 1
    return np.linspace(t0, t1, max(n, 2))


def _mu_colour(mu: float) -> tuple[int, int, int]:
    """RGB colour of a friction value (ice blue … dry grey), matching the report's map."""
    stops = [(0.1, (120, 180, 255)), (0.3, (200, 225, 250)), (0.6, (110, 140, 190)), (1.0, (205, 200, 190))]
    mu = min(max(mu, 0.1), 1.0)
    for (m0, c0), (m1, c1) in zip(stops, stops[1:], strict=False):
        if mu <= m1:
            w = (mu - m0) / (m1 - m0)
            return tuple(int(a + w * (b - a)) for a, b in zip(c0, c1, strict=True))  # type: ignore[return-value]
    return stops[-1][1]


def ascii_text(text: str) -> str:
    """OpenCV's Hershey fonts draw ASCII only: spell out Greek letters, drop anything else."""
    for greek, latin in (("μ", "mu"), ("β", "beta"), ("α", "alpha"), ("δ", "delta"), ("ψ", "psi"), ("–", "-")):
        text = text.replace(greek, latin)
    return text.encode("ascii", "replace").decode("ascii")


def _shade(img: np.ndarray, x0: int, y0: int, x1: int, y1: int) -> None:
    """Darken a rectangle in place (a translucent panel behind text)."""
    roi = img[y0:y1, x0:x1]
    roi[:] = (roi.astype(np.uint16) * 45 // 100 + 9).astype(np.uint8)


def annotate(img: np.ndarray, row: Mapping[str, float], *, beta_est: float | None, observer: str | None,
             label: str = "") -> np.ndarray:
    """Overlay time, speed, true vs estimated sideslip and mu under each wheel on an RGB image (in place).

    The layout is drawn for a frame ``ANNOTATION_WIDTH`` pixels wide and scaled to the image's width
    (at least by ``ANNOTATION_MIN_SCALE``), so a smaller video frame keeps most of its picture.

    Parameters
    ----------
    img : (H, W, 3) uint8 RGB image; returned, modified.
    row : the truth values shown (t_s, vx_mps, beta_rad, mu_fl … mu_rr), a dict or a Series row.
    beta_est : the estimate of beta [rad] at that time, or None/NaN.
    observer : whose estimate it is.
    label : event label, printed on its own line.
    """
    import cv2

    h, w = img.shape[:2]
    k = max(w / ANNOTATION_WIDTH, ANNOTATION_MIN_SCALE)

    def px(v: float) -> int:
        return int(round(v * k))

    font = cv2.FONT_HERSHEY_SIMPLEX
    label = ascii_text(label)
    box_w = max(330, 24 + cv2.getTextSize(label, font, 0.5, 1)[0][0]) if label else 330
    _shade(img, px(8), px(8), min(w, px(8 + box_w)), px(100 if label else 84))
    _shade(img, w - px(118), h - px(128), w - px(8), h - px(8))

    def put(text: str, y: int, colour: tuple[int, int, int] = (255, 255, 255), x: int = 16) -> None:
        cv2.putText(img, ascii_text(text), (px(x), px(y)), font, 0.5 * k, colour, 1, cv2.LINE_AA)

    t = float(row.get("t_s", math.nan))
    vx = float(row.get("vx_mps", math.nan))
    beta = math.degrees(float(row.get("beta_rad", math.nan)))
    put(f"t = {t:6.2f} s   v = {vx * 3.6:5.1f} km/h", 28)
    put(f"beta true {beta:+6.2f} deg", 50, (255, 230, 120))
    if beta_est is not None and math.isfinite(beta_est):
        put(f"beta est  {math.degrees(beta_est):+6.2f} deg  ({observer})", 72, (150, 255, 150))
    else:
        put("beta est  --", 72, (170, 170, 170))
    if label:
        put(label, 94, (120, 210, 255))
    # A plan view of the four wheels (front up), each filled with the colour of the friction under it.
    cx, cy = w - px(63), h - px(72)
    for wheel, (dx, dy) in zip(WHEELS, ((-24, -34), (16, -34), (-24, 14), (16, 14)), strict=True):
        mu = float(row.get(f"mu_{wheel}", math.nan))
        colour = _mu_colour(mu) if math.isfinite(mu) else (90, 90, 90)
        cv2.rectangle(img, (cx + px(dx), cy + px(dy)), (cx + px(dx + 8), cy + px(dy + 20)), colour, -1)
        cv2.putText(img, f"{mu:.1f}" if math.isfinite(mu) else "?",
                    (cx + px(dx - 22 if dx < 0 else dx + 11), cy + px(dy + 14)), font, 0.36 * k, (255, 255, 255), 1,
                    cv2.LINE_AA)
    cv2.rectangle(img, (cx - px(14), cy - px(30)), (cx + px(14), cy + px(30)), (50, 120, 200), 1)
    cv2.putText(img, "mu", (cx - px(9), cy + px(54)), font, 0.4 * k, (220, 220, 220), 1, cv2.LINE_AA)
    return img


def _nearest_rows(t_frame: np.ndarray, times: np.ndarray) -> np.ndarray:
    return np.clip(np.searchsorted(t_frame, times - 1e-9), 0, t_frame.size - 1)


def _estimate_at(est: pd.DataFrame | None, times: np.ndarray) -> np.ndarray:
    if est is None or est.empty:
        return np.full(times.size, np.nan)
    t = est["t_s"].to_numpy(float)
    v = est["value"].to_numpy(float)
    j = np.searchsorted(t, times + 1e-9, side="right") - 1
    out = np.where(j >= 0, v[np.clip(j, 0, t.size - 1)], np.nan)
    return out


def render_model(model_xml: str, buffer_size: tuple[int, int]) -> Any:
    """The ``MjModel`` of ``model_xml`` set up for cheap offscreen frames of up to ``buffer_size``
    (width, height) [pixels] on a software GL renderer (what each setting saves is said where it is set)."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(model_xml)
    buf_w, buf_h = buffer_size
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, buf_w)
    model.vis.global_.offheight = max(model.vis.global_.offheight, buf_h)
    # Multisampling triples the cost on llvmpipe (software GL) for little visible gain.
    model.vis.quality.offsamples = 0
    # Shadows are off (Offscreen): no shadow map to allocate and clear for every model.
    model.vis.quality.shadowsize = 0
    # Tessellation: software GL pays per vertex, and MuJoCo's defaults (28 slices, 16 stacks, 4x4
    # quads per box face) give the eight wheel cylinders and the car's and markings' boxes
    # thousands of vertices a 40-pixel tyre does not show: 16 slices round a tyre's outline, and
    # under directional lights stacks and face quads change no pixel. Measured: ~0.8x the frame
    # cost; < 0.1 % of pixels move by more than 8 of 255.
    model.vis.quality.numslices = min(model.vis.quality.numslices, TESSELLATION[0])
    model.vis.quality.numstacks = min(model.vis.quality.numstacks, TESSELLATION[1])
    model.vis.quality.numquads = min(model.vis.quality.numquads, TESSELLATION[2])
    # A plane is drawn as a grid of quads at its third size (the car model's 0.1 m gives
    # MuJoCo's maximum grid over a road hundreds of metres long); under a directional light
    # a 5 m grid lights the same pixels (mean difference 0.04 of 255) at 0.4x the frame cost.
    planes = model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
    model.geom_size[planes, 2] = np.maximum(model.geom_size[planes, 2], PLANE_GRID_M)
    # znear is relative to the model extent, which the long road makes ~300 m: without this the
    # ground closer than ~6 m to the chase camera is clipped away.
    model.vis.map.znear = min(model.vis.map.znear, 0.2 / max(model.stat.extent, 1e-6))
    return model


class Offscreen:
    """Offscreen MuJoCo rendering on one GL context per process, reused for every model it draws.

    ``mujoco.Renderer`` makes a new GL context per model; on Mesa's software renderer the first
    ``MjrContext`` of a context costs ~0.35 s (shader and font set-up), later ones ~0.04 s, so a
    process that renders several scenarios keeps its context. The per-model part (``MjrContext``:
    textures, meshes; the scene) is made by :meth:`for_model` and freed by :meth:`close`.

    ``width`` x ``height`` is the largest image drawn (the model's offscreen buffer must be at least
    that big); smaller images are drawn into the lower-left corner of the same buffer, which costs
    in proportion to the pixels drawn and needs no second buffer or context.
    """

    _gl: Any = None           # the process's GL context ...
    _gl_key: tuple[int, int, int] | None = None  # ... (pid, width, height) it was made for

    def __init__(self, model: Any, width: int, height: int) -> None:
        import mujoco

        self._mujoco = mujoco
        self.model = model
        self.width, self.height = width, height
        # MuJoCo's own text overlay is not used (OpenCV draws the labels): the smallest font atlas.
        self.context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_50)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.context)
        self.scene = mujoco.MjvScene(model, maxgeom=10000)
        # Shadows and reflections triple the cost on llvmpipe and add nothing to a diagnosis.
        self.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        self.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        self.option = mujoco.MjvOption()
        if width > self.context.offWidth or height > self.context.offHeight:
            raise ValueError(f"a {width}x{height} image does not fit the model's offscreen buffer "
                             f"({self.context.offWidth}x{self.context.offHeight}: visual/global offwidth, offheight)")
        self._rgb: dict[tuple[int, int], np.ndarray] = {}  # readback buffer per image size

    @classmethod
    def for_model(cls, model: Any, width: int, height: int) -> Offscreen:
        """An offscreen renderer of ``model`` at ``width`` x ``height`` on this process's GL context."""
        import mujoco

        key = (os.getpid(), width, height)
        if cls._gl_key != key:  # none yet, another size, or inherited through fork: make a new one
            cls._gl = mujoco.GLContext(width, height)
            cls._gl_key = key
        cls._gl.make_current()
        return cls(model, width, height)

    def render(self, data: Any, camera: int, size: tuple[int, int] | None = None) -> np.ndarray:
        """RGB image (height, width, 3) uint8 of ``data`` seen from fixed camera ``camera`` (-1: free),
        ``size`` = (width, height) [pixels], at most the renderer's (its size if None)."""
        mujoco = self._mujoco
        width, height = size or (self.width, self.height)
        if width > self.width or height > self.height:
            raise ValueError(f"a {width}x{height} image is larger than this renderer's {self.width}x{self.height}")
        rgb = self._rgb.get((width, height))
        if rgb is None:
            rgb = self._rgb[(width, height)] = np.empty((height, width, 3), dtype=np.uint8)
        viewport = mujoco.MjrRect(0, 0, width, height)
        cam = mujoco.MjvCamera()
        if camera >= 0:
            cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
            cam.fixedcamid = camera
        else:
            mujoco.mjv_defaultFreeCamera(self.model, cam)
        mujoco.mjv_updateScene(self.model, data, self.option, None, cam, mujoco.mjtCatBit.mjCAT_ALL, self.scene)
        mujoco.mjr_render(viewport, self.scene, self.context)
        mujoco.mjr_readPixels(rgb, None, viewport, self.context)  # colour only: depth is not used
        return np.flipud(rgb).copy()  # GL rows run bottom-up; the caller draws on its own copy

    def close(self) -> None:
        """Free the model's GPU resources (the process's GL context stays for the next model)."""
        self.context.free()


def render_scenario(
    truth: Any,
    run_dir: Path,
    name: str,
    *,
    beta_estimates: pd.DataFrame | None = None,
    observer: str | None = None,
    video: bool = True,
    settings: RenderSettings = RenderSettings(),
) -> RenderResult:
    """Render key frames (PNG, ``frames/``) and a video (MP4, ``videos/``) of one simulated scenario.

    Parameters
    ----------
    truth : Truth or RenderSource
        Needs ``frame`` (t_s, vx_mps, beta_rad, mu_<wheel>, lead_x_m/lead_y_m if any), ``qpos``
        (n, nq) at the simulation rate, ``model_xml`` and ``events`` ((t_s, label) pairs).
    run_dir : Path
        Run folder; files are written under ``frames/`` and ``videos/`` and named after ``name``.
    beta_estimates : DataFrame, optional
        ``t_s, value`` of the sideslip estimate to print next to the truth.
    observer : str, optional
        Whose estimate it is (printed).
    video : bool
        Also write the video (key frames only if False).
    settings : RenderSettings
        Frame and video sizes, video rate and length, encoder settings.
    """
    import time

    t_start = time.perf_counter()
    try:
        import mujoco
    except Exception as e:  # GL back-end selection happens at import
        return RenderResult(reason=f"mujoco could not be imported for rendering: {e}")
    frame: pd.DataFrame = truth.frame
    qpos = np.asarray(truth.qpos)
    if frame.empty or qpos.size == 0:
        return RenderResult(reason="nothing to render (empty truth)")
    try:
        buf_w, buf_h = settings.buffer_size
        model = render_model(truth.model_xml, (buf_w, buf_h))
        data = mujoco.MjData(model)
    except Exception as e:
        return RenderResult(reason=f"model could not be rebuilt for rendering: {e}")
    try:
        renderer = Offscreen.for_model(model, buf_w, buf_h)
    except Exception as e:
        backend = os.environ.get("MUJOCO_GL", "")
        return RenderResult(reason=f"offscreen OpenGL unavailable (MUJOCO_GL={backend or 'unset'}): "
                                   f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}".strip())
    camera = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "chase")
    lead_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "lead")
    lead_mocap = int(model.body_mocapid[lead_body]) if lead_body >= 0 else -1
    t_frame = frame["t_s"].to_numpy(float)
    # A frame's values from arrays: a pandas row per frame (frame.iloc) cost more than its annotation.
    columns = {c: frame[c].to_numpy(float) for c in ("t_s", "vx_mps", "beta_rad", *(f"mu_{w}" for w in WHEELS))
               if c in frame}
    n_q = min(qpos.shape[0], t_frame.size)
    (run_dir / "frames").mkdir(parents=True, exist_ok=True)

    def draw(t: float, label: str, beta_est: float, size: tuple[int, int]) -> np.ndarray:
        i = int(_nearest_rows(t_frame[:n_q], np.array([t]))[0])
        data.qpos[:] = qpos[i]
        if lead_mocap >= 0 and "lead_x_m" in frame:
            lx, ly = float(frame["lead_x_m"].iat[i]), float(frame["lead_y_m"].iat[i])
            if math.isfinite(lx) and math.isfinite(ly):
                data.mocap_pos[lead_mocap, :2] = (lx, ly)
        mujoco.mj_forward(model, data)
        rgb = renderer.render(data, camera, size)
        return annotate(rgb, {c: v[i] for c, v in columns.items()}, beta_est=beta_est, observer=observer, label=label)

    import cv2

    t0, t1 = float(t_frame[0]), float(t_frame[n_q - 1])
    events = [(float(t), str(lab)) for t, lab in (getattr(truth, "events", ()) or ())]
    frames: list[dict[str, Any]] = []
    n_rendered = 0
    video_rel: str | None = None
    try:
        keys = key_times(t0, t1, events)
        est_keys = _estimate_at(beta_estimates, np.array([k[0] for k in keys]))
        for j, ((t, label), b) in enumerate(zip(keys, est_keys, strict=True)):
            img = draw(t, label, float(b), settings.frame_size)
            rel = f"frames/{name}_{j:02d}.png"
            cv2.imwrite(str(run_dir / rel), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
            frames.append({"file": rel, "t_s": round(t, 4), "label": label})
            n_rendered += 1
        if video:
            import imageio_ffmpeg

            (run_dir / "videos").mkdir(parents=True, exist_ok=True)
            video_rel = f"videos/{name}.mp4"
            times = video_times(t0, t1, settings.video_fps, settings.max_video_s)
            est_v = _estimate_at(beta_estimates, times)
            # macro_block_size=2: H.264 crops any even size from whole macroblocks itself (as for
            # 1080p); imageio's default (16) would rescale a 480x360 frame to 480x368 in ffmpeg.
            writer = imageio_ffmpeg.write_frames(
                str(run_dir / video_rel), settings.video_size, fps=settings.video_fps, codec="libx264",
                pix_fmt_out="yuv420p", quality=None, macro_block_size=2, ffmpeg_log_level="error",
                output_params=["-preset", settings.x264_preset, "-crf", str(settings.x264_crf),
                               "-movflags", "+faststart"])
            writer.send(None)
            for t, b in zip(times, est_v, strict=True):
                writer.send(draw(float(t), "", float(b), settings.video_size))
                n_rendered += 1
            writer.close()
    except Exception as e:  # a render failure must not cost the rest of the report
        return RenderResult(frames=tuple(frames), video=None, n_rendered=n_rendered,
                            reason=f"rendering failed: {type(e).__name__}: {e}",
                            seconds=time.perf_counter() - t_start)
    finally:
        renderer.close()
    return RenderResult(frames=tuple(frames), video=video_rel, n_rendered=n_rendered,
                        seconds=time.perf_counter() - t_start)
