"""Wall time of the commands a user waits for, each in a fresh process, against interpreter baselines.

Run by hand: ``python benchmarks/bench_commands.py [--repeat N]``. Measures ``roadtruth scenarios``,
``roadtruth observers`` and ``roadtruth simulate step_steer --out <tmp>`` (a 5 s scenario) as fresh
subprocesses (what a user sees: imports, work, writing, exit), and in the same run the baselines
``python -c pass`` (interpreter start) and ``python -c "import numpy"``, so that figures measured on
a loaded machine can be compared as ratios. Prints best and median of N for each, and each command's
ratio to both baselines (best / best). The load average is printed before and after.
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


def wall_s(argv: list[str], env: dict[str, str]) -> float:
    """Seconds from starting ``argv`` to its exit (fails loudly if the command fails)."""
    t = time.perf_counter()
    res = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    dt = time.perf_counter() - t
    if res.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} exited {res.returncode}: {res.stderr.strip()[-500:]}")
    return dt


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=5, help="fresh processes per command (default 5)")
    a = p.parse_args()
    py = sys.executable
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    print(f"cores: {os.cpu_count()}, load average before: {os.getloadavg()[0]:.2f}, repeat {a.repeat}")
    with tempfile.TemporaryDirectory(prefix="bench-commands-") as tmp:
        cases: dict[str, list[str]] = {
            "python -c pass": [py, "-c", "pass"],
            "python -c 'import numpy'": [py, "-c", "import numpy"],
            "roadtruth scenarios": [py, "-m", "roadtruth.harness.cli", "scenarios"],
            "roadtruth observers": [py, "-m", "roadtruth.harness.cli", "observers"],
            "roadtruth simulate step_steer": [py, "-m", "roadtruth.harness.cli", "simulate", "step_steer", "--out", ""],
        }
        # One untimed round first: numba's on-disk cache and the OS file cache are warm, as for a user's
        # second command of the day (the first after an install also compiles).
        times: dict[str, list[float]] = {k: [] for k in cases}
        for k in range(a.repeat + 1):
            for name, argv in cases.items():  # interleaved, so load changes hit every case alike
                if argv[-1] == "":
                    argv = [*argv[:-1], str(Path(tmp) / f"sim{k}")]
                dt = wall_s(argv, env)
                if k > 0:
                    times[name].append(dt)
    base, base_np = min(times["python -c pass"]), min(times["python -c 'import numpy'"])
    print(f"\n{'what':<32} {'best s':>7} {'median s':>9} {'x pass':>7} {'x numpy':>8}")
    for name, ts in times.items():
        best, med = min(ts), statistics.median(ts)
        print(f"{name:<32} {best:7.3f} {med:9.3f} {best / base:7.1f} {best / base_np:8.2f}")
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
