"""Real-time factor of ``harness.simulate.simulate`` vs bare MuJoCo stepping of the same model.

Run: ``.venv/bin/python benchmarks/bench_simulate.py [--seconds 30] [--repeats 3]``.
One core, 1 ms step. ``simulate`` includes tires, driver, road projection, friction map, logging of
every canonical signal, model build and the DataFrame; the loop-only figure excludes the set-up.
Bare stepping: the same MJCF with no tire/driver code, (a) ``mujoco.mj_step`` from a Python loop,
(b) ``mj_step1``+``mj_step2`` from a numba loop (no interpreter overhead). Without tire forces the
car sinks onto its chassis box, so (b) is also given with contacts disabled (no constraint solve).
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import mujoco
import numpy as np

import harness.simulate as sim
from harness.car_model import build_mjcf
from harness.scenario import load_scenario
from harness.vehicle import load_vehicle


@sim.jit
def _bare(step1, step2, m_ptr: int, d_ptr: int, n: int) -> None:  # noqa: ANN001 (ctypes functions)
    for _ in range(n):
        step1(m_ptr, d_ptr)
        step2(m_ptr, d_ptr)


def _best(fn, repeats: int) -> float:  # noqa: ANN001
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="simulated seconds per run")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--scenario", default="curvy_road")
    args = ap.parse_args()

    sc = dataclasses.replace(load_scenario(args.scenario), duration_s=args.seconds)
    v = load_vehicle(sc.vehicle)
    n = int(round(args.seconds / 0.001))
    simulate_s = _best(lambda: sim.simulate(dataclasses.replace(sc, duration_s=0.05)), 1)  # compile / warm
    simulate_s = _best(lambda: sim.simulate(sc), args.repeats)

    # Loop only: time the compiled _run by wrapping it.
    loop_times: list[float] = []
    original = sim._run

    class Timed:
        py_func = original.py_func

        def __call__(self, *a):  # noqa: ANN002, ANN204
            t0 = time.perf_counter()
            out = original(*a)
            loop_times.append(time.perf_counter() - t0)
            return out

    sim._run = Timed()  # type: ignore[assignment]
    try:
        for _ in range(args.repeats):
            sim.simulate(sc)
    finally:
        sim._run = original
    loop_s = min(loop_times)

    xml = build_mjcf(v, sc)
    step1, step2 = sim._step_functions()
    rows = []
    for label, no_contact in (("bare numba mj_step1+2 (contacts on)", False),
                              ("bare numba mj_step1+2 (contacts off)", True)):
        m = mujoco.MjModel.from_xml_string(xml)
        if no_contact:
            m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
        d = mujoco.MjData(m)
        _bare(step1, step2, m._address, d._address, 10)

        def run(m=m, d=d) -> None:  # noqa: ANN001
            mujoco.mj_resetData(m, d)
            _bare(step1, step2, m._address, d._address, n)

        rows.append((label, _best(run, args.repeats)))
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    n_py = min(n, 20000)

    def run_py() -> None:
        mujoco.mj_resetData(m, d)
        for _ in range(n_py):
            mujoco.mj_step(m, d)

    rows.append(("bare Python loop of mujoco.mj_step", _best(run_py, args.repeats) * n / n_py))

    print(f"scenario {args.scenario}, vehicle {v.name}, {args.seconds:g} s simulated at 1 ms ({n} steps), "
          f"best of {args.repeats}")
    print(f"{'configuration':44s} {'wall [s]':>9s} {'steps/s':>10s} {'RTF':>7s}")
    table = [("simulate() end to end", simulate_s), ("simulate() compiled loop only", loop_s), *rows]
    for label, wall in table:
        print(f"{label:44s} {wall:9.3f} {n / wall:10.0f} {args.seconds / wall:7.1f}")
    for label, wall in rows[:2]:
        print(f"simulate() end to end / {label}: {wall / simulate_s:.2f} of bare speed "
              f"(loop only: {wall / loop_s:.2f})")


if __name__ == "__main__":
    main()
