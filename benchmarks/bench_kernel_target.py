"""What the shipped kernels' portable code costs per step, against code compiled for this CPU.

Run: ``.venv/bin/python benchmarks/bench_kernel_target.py [--runs 3] [--seconds 30] [--rounds 2]``.

The kernels shipped with the package (``harness/compiled/``) are compiled for numba's portable
x86-64 target (``NUMBA_CPU_NAME=generic``: no AVX, no FMA), which every roadtruth command uses
unless ``ROADTRUTH_SHIPPED_KERNELS=0``. This runs ``bench_observers.py --no-design`` and
``bench_simulate.py`` in child processes, for the portable target and for the host CPU in turn,
``--rounds`` times, each target with its own numba cache (empty at first: the first round
compiles, several minutes), and prints the best over rounds of the median us/step of every
observer under both with their ratio (for those of 1 us or more: the table is printed to 0.1 us),
and the simulation loop's. Last, it runs the default suite (``roadtruth run --no-render``) under
both targets and compares every file the two runs wrote, byte for byte (``timings.json`` and the
``us_per_step`` column of ``metrics.csv`` measure the machine and are left out).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _child(script: str, args: list[str], target: str, cache: Path) -> str:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "ROADTRUTH_SHIPPED_KERNELS": "0", "MUJOCO_GL": "egl"}
    env.pop("NUMBA_CPU_NAME", None)
    if target == "generic":
        env["NUMBA_CPU_NAME"] = "generic"
    return subprocess.run([sys.executable, str(HERE / script), *args], env=env, check=True,
                          capture_output=True, text=True).stdout


def _observer_table(text: str) -> dict[str, float]:
    out = {}
    for line in text.splitlines():
        m = re.match(r"^(\w+)\s+([0-9.]+)\s+([0-9.]+)\s", line)
        if m:
            out[m.group(1)] = float(m.group(2))
    return out


def _loop_us(text: str) -> float:
    m = re.search(r"^simulate\(\) compiled loop only\s+\S+\s+\S+\s+([0-9.]+)", text, re.M)
    return float(m.group(1)) if m else float("nan")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--rounds", type=int, default=2, help="rounds of both targets; the best median is kept")
    a = p.parse_args()
    obs: dict[str, dict[str, float]] = {"generic": {}, "host": {}}
    loop: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(a.rounds):
            for target in ("generic", "host"):  # alternating, so a change of machine load hits both
                cache = Path(tmp) / target
                table = _observer_table(_child("bench_observers.py", ["--no-design", "--runs", str(a.runs),
                                                                       "--seconds", str(a.seconds)], target, cache))
                for name, us in table.items():
                    obs[target][name] = min(us, obs[target].get(name, us))
                us = _loop_us(_child("bench_simulate.py", ["--repeats", str(a.runs), "--seconds", "20"], target, cache))
                loop[target] = min(us, loop.get(target, us))
        differ = _compare_runs(Path(tmp))
    print(f"median us/step, {a.seconds:g} s at 100 Hz ({a.runs} runs; best of {a.rounds} rounds); portable = NUMBA_CPU_NAME=generic, "
          f"host = {os.uname().machine} code for this CPU")
    print(f"{'kernel':<38} {'portable':>9} {'host':>9} {'ratio':>6}")
    rows = []
    for name in sorted(set(obs["generic"]) & set(obs["host"])):
        g, h = obs["generic"][name], obs["host"][name]
        # bench_observers prints 0.1 us: below 1 us a ratio is mostly rounding.
        rows.append((g / h if min(g, h) >= 1.0 else 0.0, name, g, h))
    for r, name, g, h in sorted(rows, reverse=True):
        print(f"{name:<38} {g:9.1f} {h:9.1f} {f'{r:6.2f}' if r else '     -'}")
    print(f"{'simulate() compiled loop':<38} {loop['generic']:9.2f} {loop['host']:9.2f} "
          f"{loop['generic'] / loop['host']:6.2f}")
    total_g, total_h = sum(obs["generic"].values()), sum(obs["host"].values())
    print(f"all observers together: {total_g:.1f} vs {total_h:.1f} us/step ({total_g / total_h:.2f}x)")
    print("default suite, every file of the two runs: " + ("byte-identical" if not differ else
                                                           "DIFFERENT: " + ", ".join(differ)))


def _compare_runs(tmp: Path) -> list[str]:
    """Files of ``roadtruth run --no-render`` that differ between the two targets."""
    import pandas as pd

    for target in ("generic", "host"):
        env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp / target), "ROADTRUTH_SHIPPED_KERNELS": "0",
               "ROADTRUTH_CACHE": str(tmp / "cache"), "MUJOCO_GL": "egl"}
        env.pop("NUMBA_CPU_NAME", None)
        if target == "generic":
            env["NUMBA_CPU_NAME"] = "generic"
        subprocess.run([sys.executable, "-m", "roadtruth.harness.cli", "run", "--no-render", "--out",
                        str(tmp / f"run-{target}")], env=env, check=True, capture_output=True)
    a, b = tmp / "run-generic", tmp / "run-host"
    files = sorted({p.relative_to(a) for p in a.rglob("*") if p.is_file()} |
                   {p.relative_to(b) for p in b.rglob("*") if p.is_file()})
    differ = []
    for rel in files:
        if rel.name == "timings.json":
            continue
        if not (a / rel).is_file() or not (b / rel).is_file():
            differ.append(str(rel))
        elif rel.name == "metrics.csv":
            if not pd.read_csv(a / rel).drop(columns="us_per_step").equals(pd.read_csv(b / rel).drop(columns="us_per_step")):
                differ.append(str(rel))
        elif (a / rel).read_bytes() != (b / rel).read_bytes():
            differ.append(str(rel))
    return differ


if __name__ == "__main__":
    main()
