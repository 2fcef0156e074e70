"""Two cores that count: ``roadtruth run --no-render`` with ``--jobs 2`` against ``--jobs 1``.

Run: ``python benchmarks/bench_jobs.py [--repeats N] [--suite SUITE]``. Each measurement is the wall
time of the whole command (``python -m roadtruth.harness.cli run ...`` in a fresh interpreter, imports and
writing included: what a user waits for), with a warm design cache and warm numba caches (one
unmeasured warm-up run first). The two job counts alternate, so a change of machine load hits both;
the script prints best-of-N and median of each and their ratio (the speed-up), and the load average
before and after. A speed-up can only be judged with both cores free: with other work on the
machine, the second worker competes for a core and the ratio understates it.
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


def run_once(jobs: int, suite: str, out: Path) -> float:
    """Wall time [s] of one ``roadtruth run --no-render --jobs JOBS`` into a new folder under ``out``."""
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), **TREE_ENV}
    cmd = [sys.executable, "-m", "roadtruth.harness.cli", "run", "--suite", suite, "--no-render", "--jobs", str(jobs),
           "--out", str(out / f"jobs{jobs}-{time.monotonic_ns()}")]
    t = time.perf_counter()
    subprocess.run(cmd, cwd=ROOT_DIR[0], env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


def main() -> None:
    bench_env.with_bytecode()
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3, help="measured runs per job count (default 3)")
    p.add_argument("--suite", default="default", help="scenario suite (default: default)")
    p.add_argument("--root", type=Path, default=ROOT, help="source tree to run (default: this checkout)")
    a = p.parse_args()
    env, ROOT_DIR[0] = bench_env.source_tree(a.root)
    TREE_ENV.update(env)
    print(f"cores: {os.cpu_count()}, load average before: {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory(prefix="bench-jobs-") as tmp:
        out = Path(tmp)
        run_once(2, a.suite, out)  # warm-up: designs, numba caches, file cache
        times: dict[int, list[float]] = {1: [], 2: []}
        for _ in range(a.repeats):
            for jobs in (1, 2):
                times[jobs].append(run_once(jobs, a.suite, out))
    for jobs, ts in times.items():
        print(f"run --suite {a.suite} --no-render --jobs {jobs}: best {min(ts):6.2f} s  "
              f"median {statistics.median(ts):6.2f} s  ({', '.join(f'{t:.2f}' for t in ts)})")
    print(f"speed-up --jobs 2 / --jobs 1: best {min(times[1]) / min(times[2]):.2f}x  "
          f"median {statistics.median(times[1]) / statistics.median(times[2]):.2f}x")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
