"""Wall time of the default suite (``run_suite()``: default scenarios × every observer, rendering on),
broken down by stage. Run by hand: ``python benchmarks/bench_run.py [--jobs N] [--repeat K] [--render-sizes] [--cold]``.

Each run's wall time is printed with its ratio to a baseline measured in the same invocation (a
fresh ``python -c "import numpy"``, best of 3, before and after), so figures from a loaded machine
compare. ``--render-sizes`` also prints what one scenario's render costs per frame at several
resolutions (the render is the critical path of the default suite on a software GL renderer) and the
size of what it writes, to choose the resolution by measurement.

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

os.environ.setdefault("MUJOCO_GL", "egl")


def baseline_s() -> float:
    """Best of 3 wall times of a fresh ``python -c "import numpy"`` [s]."""
    times = []
    for _ in range(3):
        t = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import numpy"], check=True)
        times.append(time.perf_counter() - t)
    return min(times)


def render_sizes(sizes: tuple[tuple[int, int], ...] = ((640, 480), (480, 368), (320, 240))) -> None:
    """Per-frame render cost of ``step_steer`` (key frames + video) at each size, interleaved, best of 2."""
    import roadtruth.harness.report.render as render
    from roadtruth.harness.jobs.pipeline import prepare_scenario
    from roadtruth.harness.truth.simulate import simulate

    source = render.RenderSource.from_truth(simulate(prepare_scenario("step_steer", None, None), seed=1))
    best: dict[tuple[int, int], tuple[float, int, int]] = {}
    default = (render.WIDTH, render.HEIGHT)
    try:
        for _ in range(2):
            for w, h in sizes:
                render.WIDTH, render.HEIGHT = w, h
                with tempfile.TemporaryDirectory(prefix="bench-render-") as d:
                    (Path(d) / "frames").mkdir()
                    t = time.perf_counter()
                    out = render.render_scenario(source, Path(d), "step_steer")
                    per = (time.perf_counter() - t) / max(out.n_rendered, 1)
                    size = sum(f.stat().st_size for f in Path(d).rglob("*") if f.is_file())
                if out.reason:
                    print(f"  render: {out.reason}")
                    return
                if (w, h) not in best or per < best[(w, h)][0]:
                    best[(w, h)] = (per, out.n_rendered, size)
    finally:
        render.WIDTH, render.HEIGHT = default
    ref = best[sizes[0]][0]
    print(f"\nrender of step_steer per frame (load {os.getloadavg()[0]:.1f}):")
    for (w, h), (per, n, size) in best.items():
        print(f"  {w}x{h}: {per * 1e3:6.1f} ms/frame ({per / ref:.2f}x of {sizes[0][0]}x{sizes[0][1]}), "
              f"{n} frames, {size / 1e3:.0f} kB written")


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


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--repeat", type=int, default=2, help="runs (the first may include compilation)")
    p.add_argument("--no-render", action="store_true")
    p.add_argument("--render-sizes", action="store_true", help="also print the render cost per frame by size")
    p.add_argument("--cold", action="store_true",
                   help="also time `roadtruth run` with empty numba and roadtruth caches (a fresh install)")
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
    if a.render_sizes:
        render_sizes()
    if a.cold:
        cold_start(a.jobs, not a.no_render)
    after = baseline_s()
    print(f"\nbaseline after: {after:.2f} s; load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
