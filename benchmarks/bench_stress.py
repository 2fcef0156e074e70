"""Cost of ``roadtruth stress`` sweeps: one worker against two, and a Dask cluster against local
processes (the figures of docs/STRESS.md, "Cost").

Run: ``python benchmarks/bench_stress.py [--repeats N] [--seeds N] [--skip-dask]``. The sweep is
``step_steer`` with ``kf_bicycle,lpv_wang``, μ ∈ {1.0, 0.6, 0.3, ice} × faults {none, gnss dropout}
× 12 seeds = 96 cases, base seed 0, ``--fresh`` (every case computed, none read from the case
cache). Each measurement is the wall time of the whole command in a fresh interpreter (imports,
worker start-up and writing included: what a user waits for), after one unmeasured warm-up sweep
(design and numba caches warm). The executors alternate, so a change of machine load hits each;
printed: best-of-N and median per executor, the speed-up of ``--jobs 2`` over ``--jobs 1`` and the
ratio of ``--dask local --jobs 2`` (a real LocalCluster on loopback) to ``--jobs 2``, with the load
average before and after, then the medians of each sweep's phases from its ``timings.json``
(start: checks and the workers' start-up; work: the cases; finish: tables and page; and the
command's imports and exit), how much faster the cases alone ran on two workers, and the median CPU
seconds the whole machine spent during each sweep (``/proc/stat``: every process of it). Ratios of two
workers can only be judged with both cores free.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bench_env

ROOT = Path(__file__).resolve().parents[1]
#: The folder the commands run from: this checkout, or the one that runs ``--root``'s code.
ROOT_DIR = [ROOT]
#: What makes the commands import that tree's code (``bench_env.source_tree``).
TREE_ENV: dict[str, str] = {}
SWEEP = ["--scenario", "step_steer", "--observer", "kf_bicycle,lpv_wang", "--friction", "1.0,0.6,0.3,ice",
         "--faults", "none;gnss:dropout=0.2", "--seed", "0", "--fresh"]


#: label -> each measured sweep's phases from its timings.json (code that writes them), in seconds.
PHASES: dict[str, list[dict[str, float]]] = {}
#: label -> the CPU seconds the machine spent during each measured sweep (``bench_env.busy_cpu_seconds``).
CPUS: dict[str, list[float]] = {}


def sweep_once(label: str, extra: list[str], seeds: int, out: Path) -> float:
    """Wall time [s] of one ``roadtruth stress`` of the benchmark sweep with ``extra`` options."""
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), **TREE_ENV}
    cmd = [sys.executable, "-m", "roadtruth.harness.cli", "stress", *SWEEP, "--seeds", str(seeds), *extra,
           "--out", str(out / f"{label}-{(stamp := time.monotonic_ns())}")]
    cpu, t = bench_env.busy_cpu_seconds(), time.perf_counter()
    subprocess.run(cmd, cwd=ROOT_DIR[0], env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t
    CPUS.setdefault(label, []).append(bench_env.busy_cpu_seconds() - cpu)
    parts = bench_env.phases_of(out / f"{label}-{stamp}", wall)
    if parts:
        PHASES.setdefault(label, []).append(parts)
    return wall


def main() -> None:
    bench_env.with_bytecode()
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3, help="measured sweeps per executor (default 3)")
    p.add_argument("--seeds", type=int, default=12, help="seeds per (friction, faults): 8 x this cases (default 12)")
    p.add_argument("--skip-dask", action="store_true", help="skip the Dask LocalCluster sweeps")
    p.add_argument("--root", type=Path, default=ROOT, help="source tree to run (default: this checkout)")
    a = p.parse_args()
    env, ROOT_DIR[0] = bench_env.source_tree(a.root)
    TREE_ENV.update(env)
    n = 8 * a.seeds
    executors = {"--jobs 1": ["--jobs", "1"], "--jobs 2": ["--jobs", "2"]}
    if not a.skip_dask:
        executors["--dask local --jobs 2"] = ["--dask", "local", "--jobs", "2"]
    print(f"cores: {os.cpu_count()}, load average before: {os.getloadavg()[0]:.2f}; {n} cases per sweep")
    times: dict[str, list[float]] = {k: [] for k in executors}
    with tempfile.TemporaryDirectory(prefix="bench-stress-") as tmp:
        sweep_once("warm-up", ["--jobs", "2"], a.seeds, Path(tmp))
        for _ in range(a.repeats):
            for label, extra in executors.items():
                times[label].append(sweep_once(label.replace(" ", ""), extra, a.seeds, Path(tmp)))
    for label, ts in times.items():
        print(f"stress {label:24s} best {min(ts):6.2f} s  median {statistics.median(ts):6.2f} s  "
              f"{n / min(ts):5.1f} cases/s  ({', '.join(f'{t:.2f}' for t in ts)})")

    def ratio(num: str, den: str) -> str:
        return (f"best {min(times[num]) / min(times[den]):.2f}x  "
                f"median {statistics.median(times[num]) / statistics.median(times[den]):.2f}x")

    print(f"speed-up --jobs 2 over --jobs 1 (time 1 / time 2): {ratio('--jobs 1', '--jobs 2')}")
    print("  CPU of the whole machine during the sweep, median (every process; on an idle machine): "
          + ", ".join(f"{label} {statistics.median(CPUS[label.replace(' ', '')]):.2f} s" for label in times))
    medians: dict[str, dict[str, float]] = {}
    for label in times:
        runs = PHASES.get(label.replace(" ", ""), [])
        if runs:
            medians[label] = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
            print(f"  {label} phases, median s (timings.json): "
                  + ", ".join(f"{k} {v:.2f}" for k, v in medians[label].items()))
    if "--jobs 1" in medians and "--jobs 2" in medians:
        one, two = medians["--jobs 1"], medians["--jobs 2"]
        print(f"  the cases alone: {one['work'] / two['work']:.2f}x faster on two workers; the rest "
              f"{sum(two.values()) - two['work']:.2f} s with --jobs 2, {sum(one.values()) - one['work']:.2f} s with --jobs 1")
    if not a.skip_dask:
        print(f"--dask local --jobs 2 over --jobs 2 (time / time): {ratio('--dask local --jobs 2', '--jobs 2')}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
