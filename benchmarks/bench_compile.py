"""Where the first run after an install spends its time: numba's compilation of every kernel, per
function, on an empty numba cache.

Run: ``python benchmarks/bench_compile.py [SCENARIO ...]`` (default ``brake_in_turn car_following``,
which between them run every observer of the default suite). The script re-runs itself with
``NUMBA_CACHE_DIR`` set to an empty temporary folder (your own cache is left alone), then, in one
process, simulates each scenario, emulates its sensors and designs and runs every observer whose
inputs it has (in this process, not in observer hosts, so that numba's compile events are seen).
Printed: the wall time, the sum of compile times over all functions (exclusive: a function's time
without the functions it compiled on the way), the 30 slowest functions and the slowest observers
(design and run, compilation included). Timings depend on the machine; nothing here is seeded.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from typing import Any


def measure(scenarios: list[str]) -> None:
    from numba.core import event

    exclusive: dict[str, float] = defaultdict(float)
    stack: list[tuple[str, float]] = []

    class CompileTimes(event.Listener):
        def on_start(self, ev: Any) -> None:
            f = ev.data["dispatcher"].py_func
            stack.append((f"{f.__module__}.{f.__qualname__}", time.perf_counter()))

        def on_end(self, ev: Any) -> None:
            name, t0 = stack.pop()
            dt = time.perf_counter() - t0
            exclusive[name] += dt
            if stack:  # the caller's time excludes what it compiled on the way
                exclusive[stack[-1][0]] -= dt

    event.register("numba:compile", CompileTimes())
    t_all = time.perf_counter()
    from roadtruth.harness.evaluation import observer_host
    from roadtruth.harness.jobs.pipeline import prepare_scenario, sensor_config
    from roadtruth.harness.sensors import emulate
    from roadtruth.harness.truth.simulate import simulate
    from roadtruth.observers.registry import available_observers, observer_class

    per_observer: dict[str, float] = {}
    for name in scenarios:
        sc = prepare_scenario(name, None, None)
        vehicle = sc.vehicle_params()
        t = time.perf_counter()
        truth = simulate(sc)
        meas = emulate(truth.frame, vehicle, sensor_config(sc, None, None), 1, outages=sc.outages,
                       lane_gaps=sc.lane_gaps)
        per_observer[f"{name}: simulate + sensors"] = time.perf_counter() - t
        ts = meas.frame["t_s"].to_numpy(float)
        for obs in available_observers():
            cls = observer_class(obs)
            if any(c not in meas.frame.columns for c in cls.inputs):
                continue
            y = meas.frame[list(cls.inputs)].to_numpy(float)
            t = time.perf_counter()
            observer_host.run_request(observer_host.request_for(cls, vehicle, {}, ts, y), in_process=True)
            per_observer[f"{name}: {obs}"] = time.perf_counter() - t
    wall = time.perf_counter() - t_all
    print(f"scenarios {', '.join(scenarios)}; cores {os.cpu_count()}; load average {os.getloadavg()[0]:.2f}")
    print(f"wall {wall:.1f} s; compilation {sum(exclusive.values()):.1f} s over {len(exclusive)} functions "
          f"({sum(1 for v in exclusive.values() if v >= 1.0)} of them 1 s or more)")
    print("slowest functions to compile (exclusive seconds):")
    for k, v in sorted(exclusive.items(), key=lambda kv: -kv[1])[:30]:
        print(f"  {v:6.2f}  {k}")
    print("slowest observers (design + run, compilation included, seconds):")
    for k, v in sorted(per_observer.items(), key=lambda kv: -kv[1])[:15]:
        print(f"  {v:6.2f}  {k}")


def main() -> None:
    scenarios = sys.argv[1:] or ["brake_in_turn", "car_following"]
    if os.environ.get("ROADTRUTH_BENCH_COLD_CHILD") == "1":
        measure(scenarios)
        return
    with tempfile.TemporaryDirectory(prefix="bench-compile-") as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": tmp, "ROADTRUTH_BENCH_COLD_CHILD": "1",
               "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
        subprocess.run([sys.executable, __file__, *scenarios], env=env, check=True)


if __name__ == "__main__":
    main()
