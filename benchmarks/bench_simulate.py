"""Speed of ``roadtruth.harness.truth.simulate.simulate`` against bare MuJoCo stepping of the model it runs.

Run: ``.venv/bin/python benchmarks/bench_simulate.py [--seconds 30] [--repeats 5] [--scenario curvy_road]``.

One core, 1 ms step. Every configuration is timed ``--repeats`` times, round-robin (so a change of
machine load hits all of them alike); best and median wall time are printed, and the ratios use the
medians and the bests of the same run.

Rows:

- ``simulate() end to end``: model build, set-up, the compiled loop (tires, driver, road projection,
  friction map, logging of every signal), the DataFrame and the truth events.
- ``simulate() compiled loop only``: the ``_run`` call of the same runs.
- ``same, collision check on every step``: the loop with the floor gate off (``CONTACT_GATE_M``
  infinite), so MuJoCo's collision pass runs every step as it did before the gate; interleaved with
  the gated runs, the A/B of the gate.
- The baseline, ``bare mj_step1+2, wheel loads held, contacts off``: the physics model exactly as
  ``simulate()`` builds it, started from the same initial state (pose, speed, spinning wheels), with
  each wheel's static tire load applied through ``xfrc_applied`` as the tire code applies it (at the
  contact point straight below the wheel centre, so no moment about it), stepped by ``mj_step1`` and
  ``mj_step2`` from a numba loop with no tire, driver or logging code. The car rides at its static
  height (printed: chassis height drift, largest suspension travel, constraint rows), instead of
  resting on its chassis box or hanging on its bump stops.
- The same with contacts on: the collision check of the chassis box against the floor runs every
  step as in ``simulate()``, but finds nothing.
- The same with the scenario's visual geoms in the physics model (lane markings, patches, road mesh,
  lead car), as ``simulate()`` stepped it before they moved to the render model.
- ``bare Python loop of mujoco.mj_step``: the same stepping from the interpreter (the official
  bindings), extrapolated from at most 20 000 steps.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

import roadtruth.harness.truth.simulate as sim
from roadtruth.harness.errors import ScenarioError
from roadtruth.harness.files.strict_yaml import load_mapping
from roadtruth.harness.truth.car_model import build_mjcf
from roadtruth.harness.truth.scenario import load_scenario, parse_scenario, scenarios_dir
from roadtruth.harness.truth.vehicle import load_vehicle


@sim.jit
def _replay(step1, step2, m_ptr: int, d_ptr: int, n: int, rows: np.ndarray,  # noqa: ANN001 (ctypes)
            xfrc: np.ndarray, ctrl: np.ndarray, frictionloss: np.ndarray,
            xfrc_rec: np.ndarray, ctrl_rec: np.ndarray, fl_rec: np.ndarray) -> None:
    """mj_step1, the recorded inputs of step k written where ``_run`` writes them, mj_step2."""
    for k in range(n):
        step1(m_ptr, d_ptr)
        for b in range(rows.shape[0]):
            for j in range(6):
                xfrc[rows[b], j] = xfrc_rec[k, b, j]
        for j in range(ctrl.shape[0]):
            ctrl[j] = ctrl_rec[k, j]
        for j in range(frictionloss.shape[0]):
            frictionloss[j] = fl_rec[k, j]
        step2(m_ptr, d_ptr)


class _TimedRun:
    """Stands in for ``roadtruth.harness.truth.simulate._run`` and records the wall time of each call [s]."""

    def __init__(self, original: Any) -> None:
        self.original = original
        self.py_func = original.py_func
        self.times: list[float] = []

    def __call__(self, *a: Any) -> tuple[int, int]:
        t0 = time.perf_counter()
        out = self.original(*a)
        self.times.append(time.perf_counter() - t0)
        return out


@dataclasses.dataclass(frozen=True)
class _Recording:
    """The inputs ``simulate()`` gave MuJoCo at every step, and the state they led to."""

    xfrc: np.ndarray  # (n, nbody, 6) applied forces and moments [N, N m] (tires, aero)
    ctrl: np.ndarray  # (n, nu) steering servo targets [rad] and wheel torques [N m]
    frictionloss: np.ndarray  # (n, nv) brake torques as spin-joint friction [N m]
    qpos_end: np.ndarray  # (nq,) state after the last step
    body_names: tuple[str, ...]


def _record(sc: Any, n: int) -> _Recording:
    """Run ``simulate()``'s compiled loop one step per call and keep what each step applied."""
    p = sim._prepare(sc, None, 0.001)
    m, d = p.model, p.data
    step1, step2 = sim._step_functions()
    xfrc = np.empty((n, m.nbody, 6))
    ctrl = np.empty((n, m.nu))
    fl = np.empty((n, m.nv))
    for k in range(n):
        k_end, code = sim._run(step1, step2, m._address, d._address, k, k + 1, *p.args[2:])
        if code:
            raise SystemExit(f"the scenario diverged at step {k}: pick another one for the benchmark")
        xfrc[k], ctrl[k], fl[k] = d.xfrc_applied, d.ctrl, m.dof_frictionloss
    return _Recording(xfrc, ctrl, fl, d.qpos.copy(), tuple(m.body(i).name for i in range(m.nbody)))


def _replay_model(sc: Any, rec: _Recording, *, contacts: bool, visuals: bool) -> Callable[[], float]:
    """A timed replay of the recording on the physics model (or the old one with visuals).

    Returns a function that resets to ``simulate()``'s initial state, replays all steps and returns
    the wall time [s]; it raises if the replay's final state is not bit-equal to the recording's
    (the baseline then does exactly the MuJoCo work ``simulate()`` does)."""
    v = load_vehicle(sc.vehicle)
    m = mujoco.MjModel.from_xml_string(build_mjcf(v, sc, timestep_s=0.001, visuals=visuals))
    if not contacts:
        m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    d = mujoco.MjData(m)
    fl0 = m.dof_frictionloss.copy()
    rows = np.array([m.body(name).id for name in rec.body_names], dtype=np.int64)
    step1, step2 = sim._step_functions()
    n = rec.xfrc.shape[0]

    def run(steps: int = n) -> float:
        sim._initial_state(m, d, v, sc)
        m.dof_frictionloss[:] = fl0
        t0 = time.perf_counter()
        _replay(step1, step2, m._address, d._address, steps, rows, d.xfrc_applied, d.ctrl, m.dof_frictionloss,
                rec.xfrc, rec.ctrl, rec.frictionloss)
        wall = time.perf_counter() - t0
        if steps == n and not np.array_equal(d.qpos, rec.qpos_end):
            raise SystemExit(f"replay (contacts {'on' if contacts else 'off'}, visuals {visuals}) left the "
                             "recorded trajectory: the baseline would not be the same work")
        return wall

    run(10)
    return run


def _python_replay(sc: Any, rec: _Recording, steps: int) -> float:
    """Wall time [s] of ``steps`` replayed steps from the interpreter (official bindings)."""
    v = load_vehicle(sc.vehicle)
    m = mujoco.MjModel.from_xml_string(build_mjcf(v, sc, timestep_s=0.001))
    d = mujoco.MjData(m)
    sim._initial_state(m, d, v, sc)
    t0 = time.perf_counter()
    for k in range(steps):
        mujoco.mj_step1(m, d)
        d.xfrc_applied[:] = rec.xfrc[k]
        d.ctrl[:] = rec.ctrl[k]
        m.dof_frictionloss[:] = rec.frictionloss[k]
        mujoco.mj_step2(m, d)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="simulated seconds per run")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs of each configuration")
    ap.add_argument("--scenario", default="curvy_road")
    args = ap.parse_args()

    # Parsed with the new duration, so that its road (and its lane markings) covers the whole run.
    load_scenario(args.scenario)  # an unknown name or a bad file fails here with its own message
    path = Path(args.scenario)
    if path.suffix.lower() not in (".yaml", ".yml"):
        path = scenarios_dir() / f"{args.scenario}.yaml"
    data = load_mapping(path, ScenarioError)
    data["duration_s"] = args.seconds
    sc = parse_scenario(data, str(path))
    n = int(round(args.seconds / 0.001)) + 1  # simulate() steps t = 0 .. duration inclusive
    sim.simulate(dataclasses.replace(sc, duration_s=0.05))  # compile / load the numba cache
    rec = _record(sc, n)

    timed, checked = _TimedRun(sim._run), _TimedRun(sim._run)
    end_to_end: list[float] = []
    gate = sim.CONTACT_GATE_M

    def run_simulate(every_step: bool = False) -> None:
        """One simulate(); ``every_step``: with MuJoCo's collision check on every step (no floor gate)."""
        sim._run = checked if every_step else timed  # type: ignore[assignment]
        sim.CONTACT_GATE_M = math.inf if every_step else gate
        try:
            t0 = time.perf_counter()
            sim.simulate(sc)
            if not every_step:
                end_to_end.append(time.perf_counter() - t0)
        finally:
            sim._run, sim.CONTACT_GATE_M = timed.original, gate

    bare_rows = {
        "baseline: bare mj_step1+2, replayed inputs, contacts off": _replay_model(sc, rec, contacts=False,
                                                                                   visuals=False),
        "bare mj_step1+2, replayed inputs, contacts on": _replay_model(sc, rec, contacts=True, visuals=False),
        "same, old physics model with scenario visuals": _replay_model(sc, rec, contacts=True, visuals=True),
    }
    bare_times: dict[str, list[float]] = {label: [] for label in bare_rows}
    n_py = min(n, 20000)
    py_times: list[float] = []
    for _ in range(args.repeats):
        run_simulate()
        run_simulate(every_step=True)
        for label, run in bare_rows.items():
            bare_times[label].append(run())
        py_times.append(_python_replay(sc, rec, n_py) * n / n_py)

    v = load_vehicle(sc.vehicle)
    geoms = {vis: mujoco.MjModel.from_xml_string(build_mjcf(v, sc, visuals=vis)).ngeom for vis in (False, True)}
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"scenario {args.scenario} (road {sc.road.length_m:.0f} m), vehicle {v.name}, {args.seconds:g} s "
          f"simulated at 1 ms ({n} steps), {args.repeats} runs each, round-robin; load average {load:.2f}")
    print(f"physics model {geoms[False]} geoms; with the scenario's visuals {geoms[True]} geoms. The replays "
          "apply simulate()'s recorded forces, controls and brakes and end bit-equal to its state.")
    table = [("simulate() end to end", end_to_end), ("simulate() compiled loop only", timed.times),
             ("same, collision check on every step (no floor gate)", checked.times),
             *bare_times.items(), ("bare Python loop of mj_step1/mj_step2, replayed", py_times)]
    print(f"{'configuration':58s} {'best [s]':>9s} {'median [s]':>10s} {'us/step':>8s} {'RTF':>7s}")
    for label, times in table:
        best, med = min(times), statistics.median(times)
        print(f"{label:58s} {best:9.3f} {med:10.3f} {1e6 * med / n:8.2f} {args.seconds / med:7.1f}")
    base = next(iter(bare_times.values()))
    for label, times in (("end to end", end_to_end), ("loop only", timed.times)):
        print(f"simulate() {label}: {statistics.median(base) / statistics.median(times):.2f}x the baseline's speed "
              f"(median), {min(base) / min(times):.2f}x (best)")
    gain_med = statistics.median(checked.times) / statistics.median(timed.times)
    gain_best = min(checked.times) / min(timed.times)
    print(f"the floor gate (collision check only near the floor): loop {gain_med:.3f}x faster than checking "
          f"every step (median; {gain_best:.3f}x best)")
    on, vis = bare_times["bare mj_step1+2, replayed inputs, contacts on"], bare_times[
        "same, old physics model with scenario visuals"]
    print(f"stepping the old physics model (with visuals) takes {statistics.median(vis) / statistics.median(on):.2f}x "
          f"the time of the new one (median; {min(vis) / min(on):.2f}x best)")


if __name__ == "__main__":
    main()
