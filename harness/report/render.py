"""MuJoCo offscreen frames and a short MP4 per scenario, annotated with truth and estimates.

The model is rebuilt from ``Truth.model_xml`` and posed from the logged ``qpos`` (no stepping), so a
render shows exactly what was simulated. Key frames are taken at the start, the middle, the end and
at every scenario event; the video samples the whole run at ``VIDEO_FPS`` frames per second of
video, at most ``MAX_VIDEO_S`` seconds (longer runs play faster than real time).

Offscreen GL needs ``MUJOCO_GL`` (egl or osmesa) set before mujoco is first imported; this module
sets ``egl`` if nothing was chosen. When no GL context can be made, :func:`render_scenario`
returns a ``RenderResult`` whose ``reason`` says why, and the report says so.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

WIDTH, HEIGHT = 640, 480
VIDEO_FPS = 10
MAX_VIDEO_S = 6.0
MAX_KEY_FRAMES = 8
PLANE_GRID_M = 5.0  # render grid of the ground plane [m]
WHEELS = ("fl", "fr", "rl", "rr")


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


def video_times(t0: float, t1: float) -> np.ndarray:
    """Sample times of the video frames [s]: real time at VIDEO_FPS, capped at MAX_VIDEO_S of video."""
    n = int(min(math.ceil((t1 - t0) * VIDEO_FPS), MAX_VIDEO_S * VIDEO_FPS)) + 1
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


def annotate(img: np.ndarray, row: pd.Series, *, beta_est: float | None, observer: str | None,
             label: str = "") -> np.ndarray:
    """Overlay time, speed, true vs estimated sideslip and mu under each wheel on an RGB image (in place).

    Parameters
    ----------
    img : (H, W, 3) uint8 RGB image; returned, modified.
    row : the truth row shown (t_s, vx_mps, beta_rad, mu_fl … mu_rr).
    beta_est : the estimate of beta [rad] at that time, or None/NaN.
    observer : whose estimate it is.
    label : event label, printed on its own line.
    """
    import cv2

    h, w = img.shape[:2]
    font = cv2.FONT_HERSHEY_SIMPLEX
    label = ascii_text(label)
    box_w = max(330, 24 + cv2.getTextSize(label, font, 0.5, 1)[0][0]) if label else 330
    _shade(img, 8, 8, min(w, 8 + box_w), 100 if label else 84)
    _shade(img, w - 118, h - 128, w - 8, h - 8)

    def put(text: str, y: int, colour: tuple[int, int, int] = (255, 255, 255), x: int = 16) -> None:
        cv2.putText(img, ascii_text(text), (x, y), font, 0.5, colour, 1, cv2.LINE_AA)

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
    cx, cy = w - 63, h - 72
    for wheel, (dx, dy) in zip(WHEELS, ((-24, -34), (16, -34), (-24, 14), (16, 14)), strict=True):
        mu = float(row.get(f"mu_{wheel}", math.nan))
        colour = _mu_colour(mu) if math.isfinite(mu) else (90, 90, 90)
        cv2.rectangle(img, (cx + dx, cy + dy), (cx + dx + 8, cy + dy + 20), colour, -1)
        cv2.putText(img, f"{mu:.1f}" if math.isfinite(mu) else "?", (cx + dx - 22 if dx < 0 else cx + dx + 11,
                    cy + dy + 14), font, 0.36, (255, 255, 255), 1, cv2.LINE_AA)
    cv2.rectangle(img, (cx - 14, cy - 30), (cx + 14, cy + 30), (50, 120, 200), 1)
    cv2.putText(img, "mu", (cx - 9, cy + 54), font, 0.4, (220, 220, 220), 1, cv2.LINE_AA)
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


class Offscreen:
    """Offscreen MuJoCo rendering on one GL context per process, reused for every model it draws.

    ``mujoco.Renderer`` makes a new GL context per model; on Mesa's software renderer the first
    ``MjrContext`` of a context costs ~0.35 s (shader and font set-up), later ones ~0.04 s, so a
    process that renders several scenarios keeps its context. The per-model part (``MjrContext``:
    textures, meshes; the scene) is made by :meth:`for_model` and freed by :meth:`close`.
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
        self.viewport = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), dtype=np.uint8)

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

    def render(self, data: Any, camera: int) -> np.ndarray:
        """RGB image (height, width, 3) uint8 of ``data`` seen from fixed camera ``camera`` (-1: free)."""
        mujoco = self._mujoco
        cam = mujoco.MjvCamera()
        if camera >= 0:
            cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
            cam.fixedcamid = camera
        else:
            mujoco.mjv_defaultFreeCamera(self.model, cam)
        mujoco.mjv_updateScene(self.model, data, self.option, None, cam, mujoco.mjtCatBit.mjCAT_ALL, self.scene)
        mujoco.mjr_render(self.viewport, self.scene, self.context)
        mujoco.mjr_readPixels(self._rgb, None, self.viewport, self.context)
        return np.flipud(self._rgb).copy()  # GL rows run bottom-up; the caller draws on its own copy

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
        model = mujoco.MjModel.from_xml_string(truth.model_xml)
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, WIDTH)
        model.vis.global_.offheight = max(model.vis.global_.offheight, HEIGHT)
        # Multisampling triples the cost on llvmpipe (software GL) for little visible gain.
        model.vis.quality.offsamples = 0
        # A plane is drawn as a grid of quads at its third size (the car model's 0.1 m gives
        # MuJoCo's maximum grid over a road hundreds of metres long); under a directional light
        # a 5 m grid lights the same pixels (mean difference 0.04 of 255) at 0.4x the frame cost.
        planes = model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
        model.geom_size[planes, 2] = np.maximum(model.geom_size[planes, 2], PLANE_GRID_M)
        # znear is relative to the model extent, which the long road makes ~300 m: without this the
        # ground closer than ~6 m to the chase camera is clipped away.
        model.vis.map.znear = min(model.vis.map.znear, 0.2 / max(model.stat.extent, 1e-6))
        data = mujoco.MjData(model)
    except Exception as e:
        return RenderResult(reason=f"model could not be rebuilt for rendering: {e}")
    try:
        renderer = Offscreen.for_model(model, WIDTH, HEIGHT)
    except Exception as e:
        backend = os.environ.get("MUJOCO_GL", "")
        return RenderResult(reason=f"offscreen OpenGL unavailable (MUJOCO_GL={backend or 'unset'}): "
                                   f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}".strip())
    camera = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "chase")
    lead_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "lead")
    lead_mocap = int(model.body_mocapid[lead_body]) if lead_body >= 0 else -1
    t_frame = frame["t_s"].to_numpy(float)
    n_q = min(qpos.shape[0], t_frame.size)
    (run_dir / "frames").mkdir(parents=True, exist_ok=True)

    def draw(t: float, label: str, beta_est: float) -> np.ndarray:
        i = int(_nearest_rows(t_frame[:n_q], np.array([t]))[0])
        data.qpos[:] = qpos[i]
        if lead_mocap >= 0 and "lead_x_m" in frame:
            lx, ly = float(frame["lead_x_m"].iat[i]), float(frame["lead_y_m"].iat[i])
            if math.isfinite(lx) and math.isfinite(ly):
                data.mocap_pos[lead_mocap, :2] = (lx, ly)
        mujoco.mj_forward(model, data)
        rgb = renderer.render(data, camera)
        return annotate(rgb, frame.iloc[i], beta_est=beta_est, observer=observer, label=label)

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
            img = draw(t, label, float(b))
            rel = f"frames/{name}_{j:02d}.png"
            cv2.imwrite(str(run_dir / rel), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
            frames.append({"file": rel, "t_s": round(t, 4), "label": label})
            n_rendered += 1
        if video:
            import imageio_ffmpeg

            (run_dir / "videos").mkdir(parents=True, exist_ok=True)
            video_rel = f"videos/{name}.mp4"
            times = video_times(t0, t1)
            est_v = _estimate_at(beta_estimates, times)
            writer = imageio_ffmpeg.write_frames(
                str(run_dir / video_rel), (WIDTH, HEIGHT), fps=VIDEO_FPS, codec="libx264",
                pix_fmt_out="yuv420p", quality=None, macro_block_size=16, ffmpeg_log_level="error",
                output_params=["-preset", "veryfast", "-crf", "27", "-movflags", "+faststart"])
            writer.send(None)
            for t, b in zip(times, est_v, strict=True):
                writer.send(draw(float(t), "", float(b)))
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
