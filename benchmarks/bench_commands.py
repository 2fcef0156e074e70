"""Wall time of the commands a user waits for, each in a fresh process, against interpreter baselines.

Run by hand: ``python benchmarks/bench_commands.py [--repeat N] [--no-phases] [--against OLD]``. Measures
``roadtruth scenarios``, ``roadtruth observers`` and ``roadtruth simulate step_steer --out <tmp>``
(a 5 s scenario) as fresh subprocesses (what a user sees: imports, work, writing, exit), and in the
same run the baselines ``python -c pass`` (interpreter start) and ``python -c "import numpy"``, so
that figures measured on a loaded machine can be compared as ratios. Prints best and median of N for
each, and each command's ratio to both baselines (best / best). The load average is printed before
and after. ``--against OLD`` also times ``simulate`` as the source tree ``OLD`` (an older checkout)
runs it, interleaved in the same rounds: a before/after on a machine whose speed drifts.

Compiled bytecode: an installed package has its ``.pyc`` files, but a source checkout run with
``PYTHONDONTWRITEBYTECODE=1`` compiles every module of the package at every start (a few tenths
of a second for ``simulate``). The children here write and read bytecode in a private temporary
folder (``PYTHONPYCACHEPREFIX``; the untimed first round fills it), so the figures are those of an
installed package whatever the environment says, and the working tree gets no ``__pycache__``.

Then (unless ``--no-phases``) where ``simulate``'s time goes: the same steps as the command
(garbage collection paused over the imports, numba's BLAS loaded alone) and
``roadtruth.harness.jobs.pipeline.simulate_to_dir`` timed one by one in fresh processes (imports of
numpy, pandas, mujoco and numba, the package's own modules, numba's first dispatch, the simulation,
writing ``truth.csv`` and ``measurements.csv``), best and median of N per phase.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Run in a fresh interpreter: each phase of ``roadtruth simulate step_steer`` [s], printed as JSON.
PHASES_SCRIPT = r"""
import json, os, sys, tempfile, time
from pathlib import Path
t0 = time.perf_counter(); phases = {}
def mark(name):
    global t0
    t = time.perf_counter(); phases[name] = t - t0; t0 = t
import gc; gc.disable()  # as the command: no collection while it imports, then a freeze
import numpy; mark("import numpy")
import pandas; mark("import pandas")
import mujoco; mark("import mujoco")
import numba; mark("import numba")
from roadtruth.harness.jobs.warm_start import load_numba_blas
load_numba_blas(); mark("numba's BLAS and LAPACK (two SciPy extension modules)")
from roadtruth.harness.jobs import pipeline
from roadtruth.harness.truth.simulate import simulate
from roadtruth.harness.sensors import emulate
gc.freeze(); gc.enable()
mark("import roadtruth (simulate path)")
sc = pipeline.prepare_scenario("step_steer", None, None)
veh = sc.vehicle_params(); cfg = pipeline.sensor_config(sc, None, None)
_, sim_seed, sensor_seed = pipeline.scenario_seeds(sc.seed, sc.name, None)
mark("scenario, vehicle, sensor preset")
import numba.np.arraymath; mark("numba target set-up: arraymath")
truth = simulate(sc, seed=sim_seed); first = time.perf_counter() - t0
truth = simulate(sc, seed=sim_seed); second = time.perf_counter() - t0 - first
phases["numba target set-up: rest + kernel load from cache"] = max(first - second, 0.0)
phases["simulate() 5 s (compiled loop + model)"] = second
t0 = time.perf_counter()
out = Path(tempfile.mkdtemp(prefix="bench-phases-"))
pipeline.write_table(truth.at_rate(1000.0), out, "truth", "csv"); mark("write truth.csv (1000 Hz)")
meas = emulate(truth.frame, veh, cfg, sensor_seed, outages=sc.outages, lane_gaps=sc.lane_gaps); mark("emulate sensors")
pipeline.write_table(meas.frame, out, "measurements", "csv"); mark("write measurements.csv")
print(json.dumps(phases)); sys.stdout.flush(); os._exit(0)
"""


def wall_s(argv: list[str], env: dict[str, str], cwd: Path | None = None) -> float:
    """Seconds from starting ``argv`` (in ``cwd``) to its exit (fails loudly if the command fails)."""
    t = time.perf_counter()
    res = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env, cwd=cwd)
    dt = time.perf_counter() - t
    if res.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} exited {res.returncode}: {res.stderr.strip()[-500:]}")
    return dt


def phases_s(env: dict[str, str]) -> dict[str, float]:
    """One fresh process's phases of ``simulate step_steer`` [s], and its whole wall time (start to
    exit, with the interpreter's start and the second, timing-only ``simulate()``)."""
    t = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", PHASES_SCRIPT], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t
    if res.returncode != 0:
        raise SystemExit(f"phase script exited {res.returncode}: {res.stderr.strip()[-500:]}")
    return {**json.loads(res.stdout.strip().splitlines()[-1]), "whole process (wall)": wall}


def child_env(pycache: Path) -> dict[str, str]:
    """The children's environment: bytecode written to and read from ``pycache`` (module doc)."""
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYTHONPYCACHEPREFIX": str(pycache)}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=5, help="fresh processes per command (default 5)")
    p.add_argument("--no-phases", action="store_true", help="skip the phase breakdown of simulate")
    p.add_argument("--against", type=Path, help="also time simulate as this source tree runs it, interleaved")
    a = p.parse_args()
    py = sys.executable
    print(f"cores: {os.cpu_count()}, load average before: {os.getloadavg()[0]:.2f}, repeat {a.repeat}")
    if os.environ.get("PYTHONDONTWRITEBYTECODE"):
        print("PYTHONDONTWRITEBYTECODE is set here: the children use a private bytecode folder instead")
    with tempfile.TemporaryDirectory(prefix="bench-commands-") as tmp:
        env = child_env(Path(tmp) / "pycache")
        cases: dict[str, list[str]] = {
            "python -c pass": [py, "-c", "pass"],
            "python -c 'import numpy'": [py, "-c", "import numpy"],
            "roadtruth scenarios": [py, "-m", "roadtruth.harness.cli", "scenarios"],
            "roadtruth observers": [py, "-m", "roadtruth.harness.cli", "observers"],
            "roadtruth simulate step_steer": [py, "-m", "roadtruth.harness.cli", "simulate", "step_steer", "--out", ""],
        }
        envs: dict[str, tuple[dict[str, str], Path | None]] = {name: (env, None) for name in cases}
        if a.against is not None:
            sys.path.insert(0, str(Path(__file__).resolve().parent))
            import bench_env

            old_env, old_cwd = bench_env.source_tree(a.against)
            name = f"  the same, {a.against.name}'s code"
            cases[name] = cases["roadtruth simulate step_steer"]
            envs[name] = ({**env, **old_env}, old_cwd)
        # One untimed round first: numba's on-disk cache, the bytecode folder and the OS file cache
        # are warm, as for a user's second command of the day (the first after an install also compiles).
        times: dict[str, list[float]] = {k: [] for k in cases}
        for k in range(a.repeat + 1):
            for name, argv in cases.items():  # interleaved, so load changes hit every case alike
                if argv[-1] == "":
                    argv = [*argv[:-1], str(Path(tmp) / f"sim{k}")]
                dt = wall_s(argv, *envs[name])
                if k > 0:
                    times[name].append(dt)
        base, base_np = min(times["python -c pass"]), min(times["python -c 'import numpy'"])
        print(f"\n{'what':<32} {'best s':>7} {'median s':>9} {'x pass':>7} {'x numpy':>8}")
        for name, ts in times.items():
            best, med = min(ts), statistics.median(ts)
            print(f"{name:<32} {best:7.3f} {med:9.3f} {best / base:7.1f} {best / base_np:8.2f}")
        if not a.no_phases:
            runs = [phases_s(env) for _ in range(a.repeat)]
            print(f"\nroadtruth simulate step_steer, phase by phase ({a.repeat} fresh processes; "
                  f"x numpy = best / best of 'import numpy' above)")
            print(f"{'phase':<52} {'best s':>7} {'median s':>9} {'x numpy':>8}")
            totals = [sum(v for k, v in r.items() if k != "whole process (wall)") for r in runs]
            for name in [*[k for k in runs[0] if k != "whole process (wall)"], "sum of phases", "whole process (wall)"]:
                ts = totals if name == "sum of phases" else [r[name] for r in runs]
                print(f"{name:<52} {min(ts):7.3f} {statistics.median(ts):9.3f} {min(ts) / base_np:8.2f}")
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
