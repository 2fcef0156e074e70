"""How cost grows: ``simulate()`` wall time against simulated duration, the observer stage against
the number of observers.

Run: ``.venv/bin/python benchmarks/bench_scaling.py [--durations 5,20,80,320] [--observers 1,2,4,8,16]
[--repeats 3] [--seed 7]`` (about 2-3 minutes on a quiet 2-core machine with the default arguments).

1. ``simulate()`` end to end (model build, compiled loop, DataFrame, truth events) of the
   ``curvy_road`` scenario parsed with each duration (its road is extended straight to fit the run).
2. The observer stage as ``roadtruth run`` runs it (``roadtruth.harness.evaluation.estimate.run_observers``: each observer
   designed and run in its host process) on one fixed truth and its seeded measurements, for the
   first N of a fixed list of lateral observers (those that come out ``ok`` in a warm-up run, which
   also loads designs and compiled code). Each observer is also timed alone, so the stage's time can
   be set against the sum of its members' own times: the observers differ in cost, and only that
   ratio isolates what running them together adds.

Each figure is the median (and best) of ``--repeats`` runs taken round-robin. Printed: a least-squares
line (seconds per simulated second, seconds per observer), the cost per unit at each size, the ratio
of the per-unit cost at the largest size to the one at the smallest, and the slope of the last
segment over the slope of the first: growth faster than linear shows as ratios above 1 (a fixed
start-up cost pulls the per-unit ratio below 1).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Sequence

import bench_env
import numpy as np

from roadtruth.harness.errors import ScenarioError
from roadtruth.harness.evaluation.estimate import run_observers
from roadtruth.harness.files.strict_yaml import load_mapping
from roadtruth.harness.jobs.pipeline import sensor_config
from roadtruth.harness.sensors import emulate
from roadtruth.harness.truth.scenario import parse_scenario, scenarios_dir
from roadtruth.harness.truth.simulate import simulate

#: Lateral observers of the registry in the order they join the stage (printed or design-free
#: gains first, so that a cold design does not dominate the timing).
OBSERVER_POOL: tuple[str, ...] = (
    "kinematic_vy", "kf_bicycle", "ekf_bicycle", "ukf_bicycle", "open_loop_bicycle", "algebraic_vy_yacine",
    "lpv_wang_printed", "lpv_wang_h2_printed", "lpv_wang_hinf_printed", "interval_wang_printed",
    "flpv_interval_bessafa_printed", "nonlinear_wang_printed", "lpv_wang_unstructured_h2_printed",
    "lpv_wang_unstructured_hinf_printed", "finite_time_chaibdraa", "pi_observer_nguyen", "uio_nguyen",
    "ts_yacine", "interval_efimov_lpv", "reference_beta",
)
SCENARIO = "curvy_road"


def _scenario(duration_s: float) -> object:
    path = scenarios_dir() / f"{SCENARIO}.yaml"
    data = load_mapping(path, ScenarioError)
    data["duration_s"] = float(duration_s)
    return parse_scenario(data, str(path))


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip()]


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x.strip()]


def _report(unit: str, sizes: Sequence[float], times: dict[float, list[float]]) -> None:
    """Table of best/median per size, the fitted line and the growth ratios."""
    med = np.array([statistics.median(times[s]) for s in sizes])
    x = np.asarray(sizes, dtype=float)
    slope, intercept = np.polyfit(x, med, 1)
    print(f"{unit:>12s} {'best [s]':>9s} {'median [s]':>10s} {'per ' + unit + ' [s]':>16s} {'fit [s]':>8s}")
    for s, m in zip(sizes, med, strict=True):
        print(f"{s:12g} {min(times[s]):9.3f} {m:10.3f} {m / s:16.4f} {intercept + slope * s:8.3f}")
    per_unit = med / x
    print(f"fitted line: {slope:.4f} s per {unit} + {intercept:.3f} s")
    print(f"per-{unit} cost at {x[-1]:g} / at {x[0]:g}: {per_unit[-1] / per_unit[0]:.2f}; "
          f"slope of the last segment / of the first: "
          f"{((med[-1] - med[-2]) / (x[-1] - x[-2])) / ((med[1] - med[0]) / (x[1] - x[0])):.2f}")


def main() -> None:
    bench_env.with_bytecode()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--durations", type=_floats, default=[5.0, 20.0, 80.0, 320.0], help="simulated seconds")
    ap.add_argument("--observers", type=_ints, default=[1, 2, 4, 8, 16], help="observer counts")
    ap.add_argument("--observer-duration", type=float, default=20.0, help="simulated seconds of the fixed truth")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=7, help="seed of the sensor noise of the fixed truth")
    args = ap.parse_args()

    # ---- simulate() against duration -------------------------------------------------------------
    scenarios = {d: _scenario(d) for d in args.durations}
    simulate(_scenario(0.05))  # compile / load the numba cache
    sim_times: dict[float, list[float]] = {d: [] for d in args.durations}
    for _ in range(args.repeats):
        for d in args.durations:
            t0 = time.perf_counter()
            truth = simulate(scenarios[d])
            sim_times[d].append(time.perf_counter() - t0)
            if not truth.ok:
                raise SystemExit(f"{SCENARIO} at {d:g} s: {truth.status}")
    load = os.getloadavg()[0]
    print(f"simulate() of {SCENARIO}, 1 ms step, median/best of {args.repeats}; load average {load:.2f}")
    _report("sim s", args.durations, sim_times)

    # ---- observer stage against the number of observers --------------------------------------------
    sc = _scenario(args.observer_duration)
    truth = simulate(sc)
    v = truth.vehicle
    meas = emulate(truth.frame, v, sensor_config(sc, None, None), args.seed, outages=sc.outages,
                   lane_gaps=sc.lane_gaps).frame
    _, runs = run_observers(meas, v, list(OBSERVER_POOL))  # warm-up: hosts, designs, compiled code
    usable = [n for n in OBSERVER_POOL if runs[n].status == "ok"]
    counts = [c for c in args.observers if c <= len(usable)]
    if len(counts) < 2:
        raise SystemExit(f"only {len(usable)} observers came out ok: {', '.join(usable)}")
    names = usable[:counts[-1]]
    alone: dict[str, list[float]] = {n: [] for n in names}
    stage: dict[float, list[float]] = {c: [] for c in counts}
    for _ in range(args.repeats):
        for n in names:
            t0 = time.perf_counter()
            run_observers(meas, v, [n])
            alone[n].append(time.perf_counter() - t0)
        for c in counts:
            t0 = time.perf_counter()
            _, got = run_observers(meas, v, names[:c])
            stage[c].append(time.perf_counter() - t0)
            if any(r.status != "ok" for r in got.values()):
                raise SystemExit(f"an observer failed in the timed runs: { {k: r.status for k, r in got.items()} }")
    load = os.getloadavg()[0]
    print(f"\nobserver stage (run_observers) on one {args.observer_duration:g} s {SCENARIO} truth, seed "
          f"{args.seed}, median/best of {args.repeats}; load average {load:.2f}")
    print("observers in joining order: " + ", ".join(names))
    left_out = [f"{n} ({runs[n].status})" for n in OBSERVER_POOL if runs[n].status != "ok"]
    if left_out:
        print("left out (not ok in the warm-up): " + ", ".join(left_out))
    _report("observer", [float(c) for c in counts], {float(c): stage[c] for c in counts})
    print("(the observers differ in cost, so the per-observer figures follow which ones have joined; the "
          "like-for-like test of growth is the stage time over the sum of its members' own times)")
    own = np.cumsum([statistics.median(alone[n]) for n in names])
    print("stage time / sum of its observers' own times: "
          + ", ".join(f"{c}: {statistics.median(stage[c]) / own[c - 1]:.2f}" for c in counts))


if __name__ == "__main__":
    main()
