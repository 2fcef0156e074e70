"""Wall time of the default suite (``run_suite()``: default scenarios × every observer, rendering on),
broken down by stage. Run by hand: ``python benchmarks/bench_run.py [--jobs N] [--repeat K] [--render-sizes] [--cold]``.

Each run's wall time is printed with its ratio to a baseline measured in the same invocation (a
fresh ``python -c "import numpy"``, best of 3, before and after), so figures from a loaded machine
compare. ``--render-sizes`` also prints what one scenario's render costs under several render
settings (video size, frame rate, x264 preset): CPU per frame of the rendering process and of the
ffmpeg encoder (a child process, not in the render stage's time), the bytes written, with ratios to
the settings before the choice, and where one frame's CPU goes (the figures the shipped
``RenderSettings`` rest on).

The first run in a fresh checkout also pays numba compilation (cached on disk afterwards) and the
LMI designs (cached in the user cache folder); later runs show the steady state. Stage times are CPU
seconds summed over scenarios and processes (rendering overlaps the other stages), so they can add
up to more than the wall time.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bench_env

os.environ.setdefault("MUJOCO_GL", "egl")


def baseline_s() -> float:
    """Best of 3 wall times of a fresh ``python -c "import numpy"`` [s]."""
    times = []
    for _ in range(3):
        t = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import numpy"], check=True)
        times.append(time.perf_counter() - t)
    return min(times)


def _cpu_s(who: int) -> float:
    """User + system CPU seconds of this process (all its threads: llvmpipe renders on several) or of
    its waited-for children (the ffmpeg encoder) so far."""
    import resource

    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def render_options() -> dict[str, object]:
    """The render settings compared by ``--render-sizes``: the settings before the choice, one change
    at a time, and the shipped choice at lower frame rates and video sizes."""
    from dataclasses import replace

    from roadtruth.harness.report.render import RenderSettings

    chosen = RenderSettings()
    before = replace(chosen, video_size=(640, 480), x264_preset="veryfast", x264_crf=27)
    return {
        "reference: video 640x480, x264 veryfast crf 27 (the settings before)": before,
        "video 640x480, ultrafast crf 30": replace(before, x264_preset="ultrafast", x264_crf=30),
        "video 480x360, veryfast crf 27": replace(before, video_size=(480, 360)),
        f"chosen: video {chosen.video_size[0]}x{chosen.video_size[1]}, {chosen.x264_preset} crf {chosen.x264_crf}": chosen,
        "chosen at 8 fps": replace(chosen, video_fps=8),
        "chosen at 6 fps": replace(chosen, video_fps=6),
        "chosen, video 400x300": replace(chosen, video_size=(400, 300)),
        "chosen, video 320x240": replace(chosen, video_size=(320, 240)),
    }


def frame_breakdown(source: object, size: tuple[int, int], n: int = 30) -> dict[str, float]:
    """CPU per frame [s] of each step of drawing one frame at ``size``: posing (``mj_forward``), the GL
    render with the colour readback (llvmpipe draws when the pixels are read), the annotation, the PNG."""
    import resource

    import cv2
    import mujoco
    import numpy as np

    import roadtruth.harness.report.render as render

    buffer = (max(size[0], 640), max(size[1], 480))
    model = render.render_model(source.model_xml, buffer)  # type: ignore[attr-defined]
    data = mujoco.MjData(model)
    r = render.Offscreen.for_model(model, *buffer)
    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "chase")
    qpos = source.qpos  # type: ignore[attr-defined]
    rows = np.linspace(0, qpos.shape[0] - 1, n).astype(int)
    spent = dict.fromkeys(("mj_forward", "GL render + readback", "annotate", "PNG write"), 0.0)
    try:
        with tempfile.TemporaryDirectory(prefix="bench-frame-") as d:
            for i in rows:
                data.qpos[:] = qpos[i]
                c = _cpu_s(resource.RUSAGE_SELF)
                mujoco.mj_forward(model, data)
                c1 = _cpu_s(resource.RUSAGE_SELF)
                img = r.render(data, cam, size)
                c2 = _cpu_s(resource.RUSAGE_SELF)
                render.annotate(img, source.frame.iloc[i], beta_est=0.01, observer="ukf", label="")  # type: ignore[attr-defined]
                c3 = _cpu_s(resource.RUSAGE_SELF)
                cv2.imwrite(str(Path(d) / "f.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
                c4 = _cpu_s(resource.RUSAGE_SELF)
                for key, dt in zip(spent, (c1 - c, c2 - c1, c3 - c2, c4 - c3), strict=True):
                    spent[key] += dt / n
    finally:
        r.close()
    return spent


def render_sizes(scenario: str = "mu_step", repeats: int = 2) -> None:
    """What one scenario's render (key frames + video) costs under each of ``render_options()``:
    CPU of the rendering process and of the encoder (its child) per frame, bytes written; options
    interleaved, best of ``repeats``, ratios to the settings before the choice."""
    import resource

    import roadtruth.harness.report.render as render
    from roadtruth.harness.jobs.pipeline import prepare_scenario
    from roadtruth.harness.truth.simulate import simulate

    source = render.RenderSource.from_truth(simulate(prepare_scenario(scenario, None, None), seed=1))
    options = render_options()
    best: dict[str, tuple[float, float, int, int, int, int]] = {}
    with tempfile.TemporaryDirectory(prefix="bench-render-") as d:  # the first render pays the GL context
        render.render_scenario(source, Path(d), scenario, video=False)
    for _ in range(repeats):
        for label, settings in options.items():
            with tempfile.TemporaryDirectory(prefix="bench-render-") as d:
                own, enc = _cpu_s(resource.RUSAGE_SELF), _cpu_s(resource.RUSAGE_CHILDREN)
                out = render.render_scenario(source, Path(d), scenario, settings=settings)  # type: ignore[arg-type]
                own, enc = _cpu_s(resource.RUSAGE_SELF) - own, _cpu_s(resource.RUSAGE_CHILDREN) - enc
                png = sum(f.stat().st_size for f in Path(d).glob("frames/*.png"))
                mp4 = sum(f.stat().st_size for f in Path(d).glob("videos/*.mp4"))
            if out.reason:
                print(f"  render: {out.reason}")
                return
            if label not in best or own + enc < best[label][0] + best[label][1]:
                best[label] = (own, enc, out.n_rendered, len(out.frames), png, mp4)
    ref_label = next(iter(options))
    ref_own, ref_enc = best[ref_label][:2]
    print(f"\nrender of {scenario}, CPU per option (best of {repeats}, load {os.getloadavg()[0]:.1f}); "
          f"ratios to '{ref_label}':")
    for label, (own, enc, n, n_keys, png, mp4) in best.items():
        n_video = max(n - n_keys, 1)
        print(f"  {label:<66} {n_keys} key + {n_video} video frames: render {own / n * 1e3:5.1f} ms/frame, "
              f"encoder {enc / n_video * 1e3:4.1f} ms/video frame; scenario {own + enc:5.2f} s CPU "
              f"({(own + enc) / (ref_own + ref_enc):.2f}x; render {own / ref_own:.2f}x, encoder "
              f"{enc / max(ref_enc, 1e-9):.2f}x); PNG {png / 1e3:.0f} kB, MP4 {mp4 / 1e3:.0f} kB")
    chosen = render.RenderSettings()
    print(f"\nwhere one frame's CPU goes (mean of 30 {scenario} frames, load {os.getloadavg()[0]:.1f}):")
    for size in dict.fromkeys((chosen.frame_size, chosen.video_size, (640, 480), (320, 240))):
        parts = frame_breakdown(source, size)
        total = sum(parts.values())
        print(f"  {size[0]}x{size[1]}: {total * 1e3:5.1f} ms = " + ", ".join(
            f"{k} {v * 1e3:.2f} ms ({v / total:.0%})" for k, v in parts.items()))


def cold_start(jobs: int, render: bool) -> None:
    """``roadtruth run`` as the first command after an install: a child process with an empty numba
    cache (``NUMBA_CACHE_DIR``) and an empty roadtruth cache (``ROADTRUTH_CACHE``; the shipped
    designs still serve), then the same command again with those caches filled."""
    with tempfile.TemporaryDirectory(prefix="bench-cold-") as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tmp) / "numba"), "ROADTRUTH_CACHE": str(Path(tmp) / "cache")}
        walls = []
        for k in range(2):
            cmd = [sys.executable, "-m", "roadtruth.harness.cli", "run", "--out", str(Path(tmp) / f"run{k}"),
                   "--jobs", str(jobs), *([] if render else ["--no-render"])]
            t = time.perf_counter()
            subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            walls.append(time.perf_counter() - t)
        print(f"\nfirst run after install (empty numba and roadtruth caches), jobs={jobs}: {walls[0]:.1f} s; "
              f"the same command again: {walls[1]:.1f} s; one-time compilation ≈ {walls[0] - walls[1]:.0f} s")


def commands(n: int, jobs: int, render: bool, base: float) -> None:
    """Wall time of ``n`` ``roadtruth run`` commands (default suite), each a fresh interpreter with warm
    caches: what a user waits for, start-up and interpreter exit included (the in-process runs above
    share one process's imports, observer host and renderers)."""
    exe = Path(sys.executable).with_name("roadtruth")
    walls = []
    with tempfile.TemporaryDirectory(prefix="bench-run-cmd-") as tmp:
        for k in range(n):
            cmd = [str(exe), "run", "--jobs", str(jobs), "--out", str(Path(tmp) / f"cmd{k}")]
            t = time.perf_counter()
            subprocess.run(cmd + ([] if render else ["--no-render"]), check=True, capture_output=True)
            walls.append(time.perf_counter() - t)
    walls.sort()
    print(f"\n`roadtruth run --jobs {jobs}{'' if render else ' --no-render'}`, fresh process each: best {walls[0]:.1f} s "
          f"({walls[0] / base:.0f}x the baseline), median {walls[len(walls) // 2]:.1f} s "
          f"({', '.join(f'{w:.1f}' for w in walls)})")


def main() -> None:
    bench_env.with_bytecode()
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--repeat", type=int, default=2, help="runs (the first may include compilation)")
    p.add_argument("--no-render", action="store_true")
    p.add_argument("--render-sizes", action="store_true", help="also print the render cost per frame by size")
    p.add_argument("--cold", action="store_true",
                   help="also time `roadtruth run` with empty numba and roadtruth caches (a fresh install)")
    p.add_argument("--commands", type=int, default=0, metavar="N",
                   help="also time N `roadtruth run` commands, each a fresh process (what a user waits for)")
    a = p.parse_args()
    base = baseline_s()
    print(f"baseline (python -c 'import numpy', best of 3): {base:.2f} s")

    t_import = time.perf_counter()
    from roadtruth.harness.jobs.pipeline import run_suite

    print(f"import roadtruth.harness.jobs.pipeline: {time.perf_counter() - t_import:.2f} s   (cores: {os.cpu_count()}, "
          f"load average before: {os.getloadavg()[0]:.2f})")
    with tempfile.TemporaryDirectory(prefix="bench-run-") as tmp:
        for k in range(a.repeat):
            out = Path(tmp) / f"run{k}"
            t = time.perf_counter()
            run_suite(out=out, jobs=a.jobs, render=not a.no_render, progress=False)
            wall = time.perf_counter() - t
            run = json.loads((out / "run.json").read_text())
            timings = json.loads((out / "timings.json").read_text())  # times are kept out of run.json
            frames = sum(s["render"].get("n_rendered", 0) or 0 for s in run["scenarios"])
            sim_s = sum(s["duration_s"] for s in run["scenarios"])
            size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
            print(f"\nrun {k + 1}: {len(run['scenarios'])} scenarios ({sim_s:.0f} s simulated) × "
                  f"{len(run['observers'])} observers, jobs={a.jobs}: wall {wall:.1f} s "
                  f"({wall / base:.0f}x the baseline), "
                  f"output {size / 1e6:.1f} MB, index.html {(out / 'index.html').stat().st_size / 1e6:.1f} MB")
            for stage, sec in timings["stages_s"].items():
                print(f"  {stage:<10} {sec:7.2f} s")
            if frames:
                print(f"  render: {frames} frames, {timings['stages_s']['render'] / frames * 1e3:.0f} ms per frame")
            for name, ts in timings["scenarios_s"].items():
                print(f"    {name:<20} " + " ".join(f"{k}={v:.2f}" for k, v in ts.items()))
    if a.commands:
        commands(a.commands, a.jobs, not a.no_render, base)
    if a.render_sizes:
        render_sizes()
    if a.cold:
        cold_start(a.jobs, not a.no_render)
    after = baseline_s()
    print(f"\nbaseline after: {after:.2f} s; load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
