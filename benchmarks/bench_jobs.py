"""Two cores that count: ``roadtruth run --no-render`` with ``--jobs 2`` against ``--jobs 1``.

Run: ``python benchmarks/bench_jobs.py [--repeats N] [--suite SUITE | --scenarios all|S,S,...] [--root TREE]
[--against OLD]``. ``--scenarios all`` runs every shipped scenario (``roadtruth scenarios``) as one
run. Each measurement is the wall
time of the whole command (``python -m roadtruth.harness.cli run ...`` in a fresh interpreter, imports and
writing included: what a user waits for), with a warm design cache and warm numba caches (one
unmeasured warm-up run first). The two job counts alternate, so a change of machine load hits both;
the script prints best-of-N and median of each and their ratio (the speed-up), and the load average
before and after. A speed-up can only be judged with both cores free: with other work on the
machine, the second worker competes for a core and the ratio understates it. ``--against OLD``
runs the source tree ``OLD`` (an older checkout) in the same rounds, interleaved with this one: a
before/after on a machine whose speed drifts within minutes. Each run's ``timings.json`` splits its
time into start (checks, the workers' start-up), the scenarios, and finish (metrics, run.json, the
page); with the command's imports and exit, medians of these are printed, and how much faster the
scenarios alone ran on two workers. Also printed: the median CPU seconds the whole machine spent
during each command (``/proc/stat``: every process of the run, which a wall time on a machine whose
speed drifts can hide; meaningful only with nothing else running).
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


def run_once(jobs: int, selection: list[str], out: Path,
             tree: tuple[dict[str, str], Path]) -> tuple[float, dict[str, float], float]:
    """Wall time [s] of one ``roadtruth run --no-render --jobs JOBS`` into a new folder under ``out``,
    with the code of ``tree`` (``bench_env.source_tree``: its environment and working folder), the
    run's phases from its ``timings.json`` (empty for code that does not write them) and the CPU
    seconds the machine spent meanwhile (``bench_env.busy_cpu_seconds``)."""
    tree_env, cwd = tree
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), **tree_env}
    folder = out / f"jobs{jobs}-{time.monotonic_ns()}"
    cmd = [sys.executable, "-m", "roadtruth.harness.cli", "run", *selection, "--no-render", "--jobs", str(jobs),
           "--out", str(folder)]
    cpu, t = bench_env.busy_cpu_seconds(), time.perf_counter()
    subprocess.run(cmd, cwd=cwd, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall, cpu = time.perf_counter() - t, bench_env.busy_cpu_seconds() - cpu
    return wall, bench_env.phases_of(folder, wall), cpu


def shipped_scenarios() -> list[str]:
    """Names of every scenario shipped with the package, in ``roadtruth scenarios`` order."""
    from roadtruth.harness.truth.scenario_index import scenario_summaries

    return [str(row["name"]) for row in scenario_summaries()]


def main() -> None:
    bench_env.with_bytecode()
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3, help="measured runs per job count (default 3)")
    p.add_argument("--suite", default="default", help="scenario suite (default: default)")
    p.add_argument("--scenarios", help="these scenarios instead of a suite: 'all' (every shipped scenario) or S,S,...")
    p.add_argument("--root", type=Path, default=ROOT, help="source tree to run (default: this checkout)")
    p.add_argument("--against", type=Path, help="also run this source tree, interleaved (a before/after)")
    a = p.parse_args()
    selection, what = ["--suite", a.suite], f"--suite {a.suite}"
    if a.scenarios:
        names = shipped_scenarios() if a.scenarios == "all" else a.scenarios.split(",")
        selection, what = ["--scenario", ",".join(names)], f"{len(names)} scenarios ({a.scenarios})"
    trees = {a.root.resolve().name: bench_env.source_tree(a.root)}
    if a.against is not None:
        trees[f"{a.against.resolve().name} (against)"] = bench_env.source_tree(a.against)
    print(f"cores: {os.cpu_count()}, load average before: {os.getloadavg()[0]:.2f}")
    times: dict[tuple[str, int], list[float]] = {(name, jobs): [] for name in trees for jobs in (1, 2)}
    phases: dict[tuple[str, int], list[dict[str, float]]] = {key: [] for key in times}
    cpus: dict[tuple[str, int], list[float]] = {key: [] for key in times}
    with tempfile.TemporaryDirectory(prefix="bench-jobs-") as tmp:
        out = Path(tmp)
        for tree in trees.values():
            run_once(2, selection, out, tree)  # warm-up: designs, numba caches, file cache
        for _ in range(a.repeats):
            for name, tree in trees.items():
                for jobs in (1, 2):
                    wall, parts, cpu = run_once(jobs, selection, out, tree)
                    times[(name, jobs)].append(wall)
                    cpus[(name, jobs)].append(cpu)
                    if parts:
                        phases[(name, jobs)].append(parts)
    for name in trees:
        prefix = f"[{name}] " if len(trees) > 1 else ""
        for jobs in (1, 2):
            ts = times[(name, jobs)]
            print(f"{prefix}run {what} --no-render --jobs {jobs}: best {min(ts):6.2f} s  "
                  f"median {statistics.median(ts):6.2f} s  ({', '.join(f'{t:.2f}' for t in ts)})")
        one, two = times[(name, 1)], times[(name, 2)]
        print(f"{prefix}speed-up --jobs 2 / --jobs 1: best {min(one) / min(two):.2f}x  "
              f"median {statistics.median(one) / statistics.median(two):.2f}x")
        print(f"{prefix}  CPU of the whole machine during the command, median: "
              f"{statistics.median(cpus[(name, 1)]):.2f} s with --jobs 1, {statistics.median(cpus[(name, 2)]):.2f} s "
              "with --jobs 2 (every process of the run; on an idle machine)")
        medians = {}
        for jobs in (1, 2):
            runs = phases[(name, jobs)]
            if runs:
                medians[jobs] = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
                print(f"{prefix}  --jobs {jobs} phases, median s (timings.json): "
                      + ", ".join(f"{k} {v:.2f}" for k, v in medians[jobs].items()))
        if len(medians) == 2:
            print(f"{prefix}  the scenarios alone: {medians[1]['work'] / medians[2]['work']:.2f}x faster "
                  f"on two workers; what they cannot share (the rest): {sum(medians[2].values()) - medians[2]['work']:.2f} s "
                  f"with --jobs 2, {sum(medians[1].values()) - medians[1]['work']:.2f} s with --jobs 1")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
