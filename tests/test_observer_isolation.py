"""One observer can never stop, hang or crash a run; workers die with the run; a crashed worker is replaced.

The misbehaving observers are plug-ins (``tests/plugin_observers.py``): registered in this process for
library calls, and through a real entry point (a ``dist-info`` folder on ``PYTHONPATH``) for the
command-line runs, whose worker processes load plug-ins themselves.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import plugin_observers
import pytest
import worker_tasks

from roadtruth.harness.errors import InputError
from roadtruth.harness.evaluation import observer_host
from roadtruth.harness.evaluation.estimate import default_observer_timeout, run_observers
from roadtruth.harness.jobs.pipeline import run_suite
from roadtruth.harness.jobs.worker_pool import WorkerCrashed, WorkerPool
from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers import registry

pytestmark = pytest.mark.usefixtures("isolated_design_cache")

SEDAN = load_vehicle("sedan")
TESTS = Path(__file__).resolve().parent
GOOD = "open_loop_bicycle"  # cheap, no design, and usable on the scenarios used here
LINUX = sys.platform.startswith("linux")

#: (plug-in, time budget [s] or None for the default, the status it must get)
FAILURES = [
    ("plugin_input_error", None, "error: InputError: plugin: plug-in refused its input at run time"),
    ("plugin_design_error", None, "error: RuntimeError: design exploded"),
    ("plugin_sys_exit", None, "error: SystemExit: 3"),
    ("plugin_segfault", None, "error: observer process crashed (signal 11)"),
    ("plugin_hang", 2.0, "error: timed out after 2 s"),
]


@pytest.fixture()
def plugins():
    for cls in plugin_observers.MISBEHAVING:
        registry.register(cls)
    yield
    for cls in plugin_observers.MISBEHAVING:
        registry.unregister(cls.name)


def _frame(n: int = 400, h: float = 0.01) -> pd.DataFrame:
    import numpy as np

    t = np.arange(n) * h
    vx = np.full(n, 15.0)
    r = vx * 0.03 * np.sin(2 * np.pi * 0.4 * t) / 2.8
    delta = 0.03 * np.sin(2 * np.pi * 0.4 * t)
    return pd.DataFrame({"t_s": t, "vx_mps": vx, "yaw_rate_radps": r, "ay_mps2": r * vx, "imu_valid": 1,
                         "delta_rad": delta, "steering_valid": 1})



def test_a_host_freezes_its_imports_out_of_garbage_collection():
    # A full collection walks every object the imports left (0.2-0.7 s), and whichever observer's
    # timed run() it falls in would be charged for it; the host freezes them once it is ready.
    registry.register(plugin_observers.ReportsFrozenObjects)
    try:
        est, runs = run_observers(_frame(), SEDAN, ["plugin_gc_probe"])
    finally:
        registry.unregister("plugin_gc_probe")
    assert runs["plugin_gc_probe"].n_steps == len(_frame())  # ran (a yaw rate of 1e5 reads as diverged)
    assert est["value"].min() > 10_000  # numpy, numba, cvxpy, the observers: tens of thousands

# ---- library level ---------------------------------------------------------------------------------

@pytest.mark.parametrize(("bad", "timeout_s", "status"), FAILURES, ids=[f[0] for f in FAILURES])
def test_a_failing_observer_gets_an_error_status_and_the_others_the_same_numbers(plugins, bad, timeout_s, status):
    f = _frame()
    alone_est, alone = run_observers(f, SEDAN, [GOOD])
    t0 = time.monotonic()
    est, runs = run_observers(f, SEDAN, [bad, GOOD], timeout_s=timeout_s)
    assert runs[bad].status == status
    assert runs[bad].n_steps == 0 and runs[bad].us_per_step != runs[bad].us_per_step  # NaN: it did not run
    assert runs[GOOD].status == "ok" and runs[GOOD].n_steps == len(f)
    assert set(est.observer) == {GOOD}
    pd.testing.assert_frame_equal(est.reset_index(drop=True), alone_est.reset_index(drop=True))
    if timeout_s is not None:  # the budget ends the hang: 2 s plus a fresh observer process
        assert time.monotonic() - t0 < 30.0


def test_default_budget_scales_with_the_duration_and_bad_budgets_are_input_errors(plugins) -> None:
    assert default_observer_timeout(1.0) == 60.0
    assert default_observer_timeout(10.0) == 200.0
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match="--observer-timeout"):
            run_observers(_frame(), SEDAN, [GOOD], timeout_s=bad)
    # bad requests are still the caller's mistake, rejected before any observer runs
    with pytest.raises(InputError, match="unknown observer"):
        run_observers(_frame(), SEDAN, ["plugin_hang", "nope"], timeout_s=1.0)
    with pytest.raises(InputError, match="unknown option"):
        run_observers(_frame(), SEDAN, ["plugin_hang", GOOD], options={GOOD: {"typo": 1}}, timeout_s=1.0)


def _is_host(pid: int) -> bool:
    """An observer host, forked or a fresh interpreter: both name themselves (``/proc/PID/comm``)."""
    try:
        with open(f"/proc/{pid}/comm") as f:
            return f.read().strip() == observer_host.HOST_PROCESS_NAME
    except OSError:
        return False


def _host_pids() -> set[int]:
    me = os.getpid()
    return {pid for pid, (ppid, _) in _processes().items() if ppid == me and _is_host(pid)}


def test_ctrl_c_still_stops_the_run_and_takes_the_observer_process_with_it(plugins) -> None:
    """Guard (held before too): Ctrl-C stops a run; new: the busy observer process does not survive it."""
    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGALRM, interrupt)
    signal.setitimer(signal.ITIMER_REAL, 4.0)
    t0 = time.monotonic()
    try:
        with pytest.raises(KeyboardInterrupt):
            run_observers(_frame(), SEDAN, ["plugin_hang"], timeout_s=300.0)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, old)
    assert time.monotonic() - t0 < 20.0
    idle = {h.process.pid for h in observer_host._idle}
    assert _host_pids() <= idle  # only idle hosts remain; the one running the hang was killed


def test_run_suite_completes_with_every_kind_of_failing_observer(plugins, tmp_path: Path) -> None:
    bad = [c.name for c in plugin_observers.MISBEHAVING]
    alone = run_suite(scenarios=["step_steer"], observers=[GOOD], out=tmp_path / "alone", render=False,
                      progress=False)
    out = run_suite(scenarios=["step_steer"], observers=[*bad, GOOD], out=tmp_path / "mixed", render=False,
                    progress=False, observer_timeout_s=3.0)
    assert (out / "index.html").is_file()
    m = pd.read_csv(out / "metrics.csv")
    status = m.drop_duplicates("observer").set_index("observer")["status"].to_dict()
    want = {name: st.replace("2 s", "3 s") for name, _, st in FAILURES}
    assert {k: status[k] for k in want} == want
    assert status[GOOD] == "ok"
    a = pd.read_csv(alone / "metrics.csv")
    pd.testing.assert_frame_equal(m[m.observer == GOOD].drop(columns="us_per_step").reset_index(drop=True),
                                  a.drop(columns="us_per_step").reset_index(drop=True), check_dtype=False)
    assert (out / "step_steer" / "estimates.csv").read_bytes() == (alone / "step_steer" / "estimates.csv").read_bytes()
    run = json.loads((out / "run.json").read_text())
    assert [s["status"] for s in run["scenarios"]] == ["ok"]


def test_pool_fails_only_the_task_whose_worker_crashed_and_replaces_the_worker() -> None:
    tasks: list[object] = [1, 2, "segv", 3, "raise", 4, 5, "segv", 6]
    with WorkerPool(worker_tasks.square_or_fail, 2) as pool:
        futures = [pool.submit(x) for x in tasks]
    for x, fut in zip(tasks, futures, strict=True):
        if x == "segv":
            with pytest.raises(WorkerCrashed, match=r"^worker crashed \(signal 11\)$"):
                fut.result()
        elif x == "raise":
            with pytest.raises(ValueError, match="task refused"):
                fut.result()
        else:
            assert fut.result() == x * x  # type: ignore[operator]


def test_a_crashed_sweep_case_keeps_the_columns_of_a_case_and_says_why() -> None:
    from roadtruth.harness.jobs.stress import StressCase, _crashed_case, run_case

    case = StressCase(index=3, scenario="step_steer", friction="0.5", faults="none", seed_index=0, seed=7,
                      observers=(GOOD,))
    ran = run_case(case).rows
    crashed = _crashed_case(case, WorkerCrashed(-11))
    assert list(crashed.rows.columns) == list(ran.columns)
    assert crashed.rows[["observer", "state"]].equals(ran[["observer", "state"]])
    assert (crashed.rows["status"] == "error: worker crashed (signal 11)").all()
    assert (crashed.rows["truth_status"] == "error: worker crashed (signal 11)").all()
    assert (crashed.rows["case"] == 3).all() and (crashed.rows["mu"] == 0.5).all()
    assert crashed.traceback  # a crashed case is never stored as finished in the case cache


# ---- command line: worker processes ---------------------------------------------------------------

def _processes() -> dict[int, tuple[int, str]]:
    """pid -> (parent pid, command line) of every live process (zombies left out)."""
    out: dict[int, tuple[int, str]] = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
            with open(f"/proc/{d}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, IndexError):
            continue
        if fields[0] != b"Z":
            out[int(d)] = (int(fields[1]), cmd)
    return out


def _group(pgid: int) -> set[int]:
    """Live processes of process group ``pgid`` (a session started for the test)."""
    found = set()
    for pid in _processes():
        try:
            if os.getpgid(pid) == pgid:
                found.add(pid)
        except OSError:
            continue
    return found


def _wait_for(what: str, pred: Callable[[], object], timeout_s: float, proc: subprocess.Popen) -> object:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        value = pred()
        if value:
            return value
        if proc.poll() is not None:
            pytest.fail(f"the run ended (exit {proc.returncode}) before {what}")
        time.sleep(0.1)
    pytest.fail(f"no {what} within {timeout_s} s")


@pytest.fixture()
def plugin_env(tmp_path: Path) -> dict[str, str]:
    """Environment in which every process (main, workers, observer hosts) loads the plug-ins."""
    dist = tmp_path / "site" / "roadtruth_isolation_plugins-1.0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: roadtruth-isolation-plugins\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[roadtruth.observers]\n" + "".join(
        f"{c.name} = plugin_observers:{c.__name__}\n" for c in plugin_observers.MISBEHAVING))
    path = [str(tmp_path / "site"), str(TESTS), os.environ.get("PYTHONPATH", "")]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in path if p),
            "ROADTRUTH_CACHE": str(tmp_path / "cache"), "MUJOCO_GL": "egl"}


def _roadtruth(args: list[str], env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "roadtruth.harness.cli", *args], env=env, start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.skipif(not LINUX, reason="reads /proc")
def test_a_crashed_scenario_worker_costs_only_its_scenario(tmp_path: Path, plugin_env: dict[str, str]) -> None:
    out = tmp_path / "run"
    scenarios = ["step_steer", "brake_in_turn", "fishhook"]
    proc = _roadtruth(["run", "--jobs", "2", "--no-render", "--scenario", ",".join(scenarios),
                       "--observer", GOOD, "--out", str(out)], plugin_env)
    try:
        def warmed_up() -> bool:
            # Parallel runs first design every observer in one worker (the design warm-up, whose
            # failure is ignored by design); only a worker busy after it holds a scenario.
            return any(p.is_file() for d in (tmp_path / "cache").rglob("design-warmups") for p in d.iterdir())

        def busy_worker() -> int | None:
            # a worker with an observer process is in the middle of a scenario
            if not warmed_up():
                return None
            procs = _processes()
            group = _group(proc.pid)
            for pid, (ppid, _) in procs.items():
                if pid in group and _is_host(pid) and ppid != proc.pid:
                    return ppid
            return None

        worker = _wait_for("busy scenario worker", busy_worker, 120.0, proc)
        os.kill(int(worker), signal.SIGSEGV)  # type: ignore[arg-type]
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr
    run = json.loads((out / "run.json").read_text())
    statuses = {s["name"]: s["status"] for s in run["scenarios"]}
    crashed = [n for n, st in statuses.items() if st == "error: worker crashed (signal 11)"]
    assert len(crashed) == 1, statuses
    assert all(st == "ok" for n, st in statuses.items() if n not in crashed), statuses
    m = pd.read_csv(out / "metrics.csv")
    assert set(m.scenario) == set(scenarios)
    # the other scenarios were scored normally (their verdicts are the observer's, never an error)
    assert not m[m.scenario != crashed[0]]["status"].str.startswith("error").any()
    assert m[m.scenario == crashed[0]]["status"].str.contains("worker crashed").all()
    assert (out / "index.html").is_file()


@pytest.mark.skipif(not LINUX, reason="reads /proc")
def test_kill_9_of_the_parent_leaves_no_process_behind(tmp_path: Path, plugin_env: dict[str, str]) -> None:
    """Workers busy in a hanging observer must still end within 5 s of ``kill -9`` of the main process."""
    proc = _roadtruth(["run", "--jobs", "2", "--no-render", "--scenario", "step_steer,brake_in_turn",
                       "--observer", f"plugin_hang,{GOOD}", "--out", str(tmp_path / "run")], plugin_env)
    try:
        def two_busy_workers() -> bool:
            # grandchildren of the main process: scenario workers (and, here, their observer processes)
            procs = _processes()
            group = _group(proc.pid)
            return sum(1 for pid in group if pid in procs and procs[pid][0] != proc.pid and pid != proc.pid) >= 2

        _wait_for("two scenario workers", two_busy_workers, 120.0, proc)
        time.sleep(8.0)  # into the observer stage, where the plug-in hangs
        assert len(_group(proc.pid)) >= 3
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        t_end = time.monotonic() + 5.0
        left = _group(proc.pid)
        while left and time.monotonic() < t_end:
            time.sleep(0.1)
            left = _group(proc.pid)
        described = {pid: _processes().get(pid, (0, "?"))[1][:120] for pid in left}
        assert not left, f"still running 5 s after kill -9 of the parent: {described}"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        if proc.poll() is None:
            proc.wait()
