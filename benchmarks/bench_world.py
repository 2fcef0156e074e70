"""Cost of the world lookups the compiled loop makes every step: road projection and friction.

Run: ``python benchmarks/bench_world.py``. Prints ns per call of ``road_project`` (hinted, as in
the loop; and with a far-off hint, the worst case) and of ``mu_at`` (0 and 4 patches), plus the
time to build and load every shipped scenario.
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit

from roadtruth.harness.truth.friction_map import mu_at
from roadtruth.harness.truth.road import road_project
from roadtruth.harness.truth.scenario import available_scenarios, load_scenario


@njit(cache=True)
def _project_loop(samples: np.ndarray, ds: float, xs: np.ndarray, ys: np.ndarray, hint0: int, reset: bool) -> float:
    acc = 0.0
    h = hint0
    for k in range(xs.shape[0]):
        i, s, e, psi, rho = road_project(samples, ds, xs[k], ys[k], hint0 if reset else h)
        h = i
        acc += s + e
    return acc


@njit(cache=True)
def _mu_loop(mu0: float, verts: np.ndarray, meta: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> float:
    acc = 0.0
    for k in range(xs.shape[0]):
        acc += mu_at(mu0, verts, meta, xs[k], ys[k], k * 1e-3)
    return acc


def _ns_per_call(fn, n: int, *args) -> float:  # type: ignore[no-untyped-def]
    fn(*args)  # compile
    t0 = time.perf_counter()
    fn(*args)
    return (time.perf_counter() - t0) / n * 1e9


def main() -> None:
    t0 = time.perf_counter()
    scenarios = [load_scenario(n) for n in available_scenarios()]
    print(f"load {len(scenarios)} scenarios: {(time.perf_counter() - t0) * 1e3:.0f} ms")

    sc = next(s for s in scenarios if s.name == "gnss_outage")
    road = sc.road
    n = 200_000
    s = np.linspace(0.0, road.length_m - 1.0, n)
    x, y, psi = road.pose_at(s)
    x, y = x - 0.4 * np.sin(psi), y + 0.4 * np.cos(psi)
    print(f"road: {road.samples.shape[0]} samples")
    print(f"road_project hinted:   {_ns_per_call(_project_loop, n, road.samples, road.ds_m, x, y, 0, False):7.0f} ns/call")
    m = 2000
    print(f"road_project hint 0:   {_ns_per_call(_project_loop, m, road.samples, road.ds_m, x[-m:], y[-m:], 0, True):7.0f} ns/call"
          " (walks the whole road)")
    xo, yo = x[-m:] + 30.0, y[-m:] + 30.0
    print(f"road_project off-road: {_ns_per_call(_project_loop, m, road.samples, road.ds_m, xo, yo, 0, False):7.0f} ns/call"
          " (global scan)")

    for name in ("step_steer", "mu_step"):
        fm = next(s for s in scenarios if s.name == name).friction
        verts, meta = fm.arrays()
        print(f"mu_at, {len(fm.patches)} patches:   {_ns_per_call(_mu_loop, n, fm.mu_default, verts, meta, x, y):7.0f} ns/call")


if __name__ == "__main__":
    main()
