"""Wall time of the default suite (``run_suite()``: default scenarios × every observer, rendering on),
broken down by stage. Run by hand: ``python benchmarks/bench_run.py [--jobs N] [--repeat K]``.

The first run in a fresh checkout also pays numba compilation (cached on disk afterwards) and the
LMI designs (cached in the user cache folder); later runs show the steady state. Stage times are CPU
seconds summed over scenarios and processes (rendering overlaps the other stages), so they can add
up to more than the wall time.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--repeat", type=int, default=2, help="runs (the first may include compilation)")
    p.add_argument("--no-render", action="store_true")
    a = p.parse_args()

    t_import = time.perf_counter()
    from harness.pipeline import run_suite

    print(f"import harness.pipeline: {time.perf_counter() - t_import:.2f} s   (cores: {os.cpu_count()}, "
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
                  f"{len(run['observers'])} observers, jobs={a.jobs}: wall {wall:.1f} s, "
                  f"output {size / 1e6:.1f} MB, index.html {(out / 'index.html').stat().st_size / 1e6:.1f} MB")
            for stage, sec in timings["stages_s"].items():
                print(f"  {stage:<10} {sec:7.2f} s")
            if frames:
                print(f"  render: {frames} frames, {timings['stages_s']['render'] / frames * 1e3:.0f} ms per frame")
            for name, ts in timings["scenarios_s"].items():
                print(f"    {name:<20} " + " ".join(f"{k}={v:.2f}" for k, v in ts.items()))
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
