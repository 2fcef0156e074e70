"""The main job: simulate → emulate sensors → run observers → score → render → report.

``run_suite`` writes a whole run folder (layout in CONTRACT.md, "Files a run writes") inside
``atomic_output_dir``: nothing appears at ``out`` until everything, report included, is written.
Each scenario is an independent task (optionally in parallel processes); its random streams come
from one ``numpy.random.SeedSequence`` per scenario, so results do not depend on ``jobs`` or order:

* without ``seed``: ``SeedSequence(scenario.seed)``;
* with ``seed``: ``SeedSequence(seed, spawn_key=(crc32(scenario name),))`` (one suite seed, a
  distinct stream per scenario);

and ``.spawn(2)`` gives the simulation stream and the sensor stream.

A scenario whose simulation diverges, or whose sensors/observers raise, is reported (its status and
the observers' rows say so) and the suite goes on. Bad user input (unknown scenario, observer, sensor
preset, friction spec) raises an ``InputError`` before any work starts.
"""

from __future__ import annotations

import os

# Offscreen rendering: the GL back-end is chosen when mujoco is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

import contextlib  # noqa: E402
import functools  # noqa: E402
import math  # noqa: E402
import shutil  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
import zlib  # noqa: E402
from collections.abc import Callable, Iterable, Mapping, Sequence  # noqa: E402
from concurrent.futures import Future, as_completed  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from roadtruth.harness.errors import InputError  # noqa: E402
from roadtruth.harness.files.outdir import atomic_output_dir  # noqa: E402
from roadtruth.harness.files.shipped_kernels import kernel_target  # noqa: E402
from roadtruth.harness.files.table_io import check_format, tracks_wide, write_table  # noqa: E402
from roadtruth.harness.jobs.worker_pool import WorkerCrashed, WorkerPool, start_method  # noqa: E402
from roadtruth.harness.progress import Progress  # noqa: E402
from roadtruth.harness.report.rundata import (  # noqa: E402
    FLOAT_FORMAT,
    events_list,
    git_revision,
    new_scenario_folder,
    scenario_info,
    versions,
    write_json,
)

STAGES: tuple[str, ...] = ("simulate", "sensors", "observers", "scoring", "write", "figures", "render")


@dataclass(frozen=True)
class ScenarioTask:
    """Everything one worker needs (picklable)."""

    name: str
    run_dir: Path
    observers: tuple[str, ...]
    seed: int | None
    vehicle: str | None
    friction: str | None
    sensors: str | None
    faults: str | None
    log_rate_hz: float
    render: bool
    observer_timeout_s: float | None = None  # per-observer budget [s]; None = scaled with the duration
    # The scenario's folder in the run, chosen before any worker starts (so two scenario files of one
    # name get the same folders whatever order the workers finish in); None = chosen by the worker.
    folder_label: str | None = None
    # Checked observer options (harness/evaluation/observer_options.py): observer -> {option: value}.
    observer_options: dict[str, dict[str, Any]] | None = None
    table_format: str = "csv"  # csv | parquet (harness/files/table_io.py)
    # Simulated duration [s]: with several workers the longest scenarios are handed out first.
    duration_s: float = math.nan


@dataclass(frozen=True)
class ScenarioOutcome:
    name: str
    metrics: pd.DataFrame
    entry: dict[str, Any]
    runs: dict[str, dict[str, Any]]
    timings: dict[str, float] = field(default_factory=dict)
    #: the report's figures of this scenario, drawn where its files were written (``drawn_figures``)
    figures: dict[Any, list[dict[str, Any]]] = field(default_factory=dict)


def scenario_seeds(scenario_seed: int, name: str, seed: int | None) -> tuple[np.random.SeedSequence, int, int]:
    """The scenario's SeedSequence and the integer seeds of its simulation and sensor streams."""
    if seed is None:
        ss = np.random.SeedSequence(int(scenario_seed))
    else:
        ss = np.random.SeedSequence(int(seed), spawn_key=(zlib.crc32(name.encode()),))
    sim_ss, sensor_ss = ss.spawn(2)
    return ss, int(sim_ss.generate_state(1)[0]), int(sensor_ss.generate_state(1)[0])


def prepare_scenario(name: str, vehicle: str | None, friction: str | None) -> Any:
    from roadtruth.harness.truth.scenario import load_scenario

    sc = load_scenario(name)
    if vehicle:
        sc = sc.with_vehicle(vehicle)
    if friction is not None:
        sc = sc.with_friction(friction)
    return sc


def sensor_config(sc: Any, sensors: str | None, faults: str | None) -> Any:
    from roadtruth.harness.sensors import load_sensor_config

    return load_sensor_config(sensors or sc.sensors, sc.sensor_overrides, faults)


def _observer_run_dict(run: Any) -> dict[str, Any]:
    keys = ("status", "us_per_step", "certified", "design_reason", "n_steps", "design_status", "detail")
    out = {k: getattr(run, k, None) for k in keys}
    if isinstance(out["us_per_step"], float) and not math.isfinite(out["us_per_step"]):
        out["us_per_step"] = None
    return out


@dataclass(frozen=True)
class SkippedRun:
    status: str
    us_per_step: float = math.nan
    certified: bool | None = None
    design_reason: str = ""
    n_steps: int = 0


@dataclass(frozen=True, eq=False)
class FailedTruth:
    """Stands in for a ``Truth`` when the simulation raised: empty, with the error as status."""

    status: str
    frame: pd.DataFrame = field(default_factory=lambda: pd.DataFrame({"t_s": np.empty(0)}))
    qpos: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))
    model_xml: str = ""
    events: tuple[tuple[float, str], ...] = ()
    ok: bool = False

    def at_rate(self, hz: float) -> pd.DataFrame:
        return self.frame


def _best_beta_observer(metrics: pd.DataFrame) -> str | None:
    m = metrics[(metrics["state"] == "beta_rad") & metrics["status"].str.startswith("ok")
                & metrics["rmse"].notna()]
    if m.empty:
        return None
    return str(m.sort_values(["rmse", "observer"]).iloc[0]["observer"])


@dataclass(frozen=True)
class RenderJob:
    """A render of one scenario, runnable in another process (picklable)."""

    source: Any  # roadtruth.harness.report.render.RenderSource
    run_dir: Path
    name: str
    beta: pd.DataFrame | None
    observer: str | None


def render_job(job: RenderJob) -> tuple[dict[str, Any], float]:
    """Run a render job; returns the run.json ``render`` entry and the seconds it took."""
    from roadtruth.harness.report.render import render_scenario

    t = time.perf_counter()
    result = render_scenario(job.source, job.run_dir, job.name, beta_estimates=job.beta, observer=job.observer)
    return result.to_dict(), time.perf_counter() - t


def run_scenario(task: ScenarioTask, before_observers: Callable[[], None] | None = None) -> ScenarioOutcome:
    """Simulate, sense, estimate, score, write and (if ``task.render``) render one scenario into
    ``task.run_dir / task.name``. Expected failures become statuses; nothing here raises for them.
    ``before_observers``: see :func:`evaluate_scenario`."""
    outcome, job = compute_scenario(task, before_observers=before_observers)
    if job is not None:
        entry, seconds = render_job(job)
        outcome.entry["render"] = entry
        outcome.timings["render"] = seconds
        outcome.entry["timings_s"]["render"] = round(seconds, 4)
    return outcome


@dataclass(frozen=True, eq=False)
class Stages:
    """What the stages of one scenario produced, before anything is written or scored.

    ``tracks``: observer -> ``EstimateTrack`` (arrays on the measurement times; what scoring and the
    wide table take); ``estimates`` gives them as the long frame. ``runs`` is None when no observer
    ran: the simulation failed (``truth.ok`` is False) or a later stage crashed (``error`` holds its
    one-line ``error: …`` status, ``traceback`` the details).
    """

    truth: Any
    measurements: Any | None
    tracks: Mapping[str, Any]
    runs: dict[str, Any] | None
    error: str | None = None
    traceback: str | None = None

    @functools.cached_property
    def estimates(self) -> pd.DataFrame:
        """The tracks as the long frame ``t_s, observer, state, value, lo, hi, var``."""
        from roadtruth.harness.evaluation.estimate import long_estimates

        return long_estimates(self.tracks)


def evaluate_scenario(sc: Any, vehicle: Any, observers: Sequence[str], sim_seed: int, sensor_seed: int, *,
                      sensors: str | None = None, faults: str | None = None,
                      timings: dict[str, float] | None = None,
                      observer_timeout_s: float | None = None,
                      observer_options: dict[str, dict[str, Any]] | None = None,
                      before_observers: Callable[[], None] | None = None) -> Stages:
    """Simulate, sense and estimate one prepared scenario (the shared core of ``run`` and ``stress``).

    Bad input (``InputError``) propagates; any other crash is returned as a status, so one broken
    scenario never stops a suite. ``timings`` (if given) receives the simulate/sensors/observers seconds.
    ``observer_timeout_s``: time budget of each observer [s] (see ``roadtruth.harness.evaluation.estimate.run_observers``);
    ``observer_options``: observer -> {option: value}, checked (``roadtruth.harness.evaluation.observer_options``);
    ``before_observers``: called after the sensors, before the first observer runs (a serial run
    waits there for its warm-up, :class:`roadtruth.harness.jobs.design_warmup.BackgroundWarmup`).
    """
    from roadtruth.harness.evaluation import observer_host
    from roadtruth.harness.evaluation.estimate import run_observer_tracks
    from roadtruth.harness.sensors import emulate
    from roadtruth.harness.truth.simulate import simulate

    if observers:
        # numba's target set-up (~1 s, once per process) is needed by the simulation anyway; done
        # first, a host forked from this process inherits it instead of paying it again.
        from roadtruth.harness.jobs.warm_start import set_up_numba

        set_up_numba()
        observer_host.prestart()  # its imports overlap the simulation
    timings = timings if timings is not None else {}
    empty: dict[str, Any] = {}
    t = time.perf_counter()
    try:
        truth = simulate(sc, seed=sim_seed)
    except InputError:
        raise
    except Exception as e:  # reported with its traceback; the suite goes on
        status = f"error: {type(e).__name__}: {e}".splitlines()[0]
        return Stages(FailedTruth(status=status), None, empty, None, status, traceback.format_exc())
    finally:
        timings["simulate"] = time.perf_counter() - t
    if not truth.ok:
        return Stages(truth, None, empty, None)
    meas = None
    try:
        t = time.perf_counter()
        meas = emulate(truth.frame, vehicle, sensor_config(sc, sensors, faults), sensor_seed,
                       outages=sc.outages, lane_gaps=sc.lane_gaps)
        timings["sensors"] = time.perf_counter() - t
        if before_observers is not None:
            before_observers()
        t = time.perf_counter()
        tracks, runs = run_observer_tracks(meas.frame, vehicle, list(observers), timeout_s=observer_timeout_s,
                                           options=observer_options)
        timings["observers"] = time.perf_counter() - t
    except InputError:
        raise
    except Exception as e:  # one broken stage must not stop the suite
        status = f"error: {type(e).__name__}: {e}".splitlines()[0]
        return Stages(truth, meas, empty, None, status, traceback.format_exc())
    return Stages(truth, meas, tracks, runs)


def compute_scenario(task: ScenarioTask, *, failed: str | None = None,
                     before_observers: Callable[[], None] | None = None) -> tuple[ScenarioOutcome, RenderJob | None]:
    """Everything but the render; returns the render job (None if ``task.render`` is off).

    ``failed``: an ``error: …`` status that stands for the stages instead of running them (a worker
    process that died holding the scenario, see :func:`crashed_scenario`); ``before_observers``: see
    :func:`evaluate_scenario`.
    """
    from roadtruth.harness.evaluation.scoring import score
    from roadtruth.harness.report.render import RenderSource
    from roadtruth.harness.report.sections.scenarios import drawn_figures
    from roadtruth.harness.truth.truth_events import scored_until_of, status_of

    timings = dict.fromkeys(STAGES, 0.0)
    sc = prepare_scenario(task.name, task.vehicle, task.friction)
    # The folder is named from the scenario's sanitised name, never from the path it was given by.
    if task.folder_label is not None:
        label, folder = task.folder_label, task.run_dir / task.folder_label
        folder.mkdir(exist_ok=True)
    else:
        label, folder = new_scenario_folder(task.run_dir, sc.name)
    veh = sc.vehicle_params()
    # Seeded by the scenario's own name, not by the path it was given by: one file, one result.
    ss, sim_seed, sensor_seed = scenario_seeds(sc.seed, sc.name, task.seed)
    entry: dict[str, Any] = {
        "name": label, "description": sc.description, "tags": list(sc.tags), "vehicle": veh.name,
        "duration_s": sc.duration_s, "sensors": task.sensors or sc.sensors,
        "seed": task.seed if task.seed is not None else sc.seed,
        "entropy": str(ss.entropy), "spawn_key": list(ss.spawn_key),
        "simulation_seed": sim_seed, "sensor_seed": sensor_seed, "status": "ok",
    }

    st = (evaluate_scenario(sc, veh, task.observers, sim_seed, sensor_seed, sensors=task.sensors,
                            faults=task.faults, timings=timings, observer_timeout_s=task.observer_timeout_s,
                            observer_options=task.observer_options, before_observers=before_observers)
          if failed is None else
          Stages(FailedTruth(status=failed), None, {}, None, failed))
    truth = st.truth
    entry["status"] = st.error if (st.error and truth.ok) else str(truth.status)
    entry["sim_steps"] = len(truth.frame)
    # What the car did (spun out, left the road, ...) and where scoring stops because of it.
    scored_until = scored_until_of(truth)
    entry["truth_status"] = status_of(truth)
    entry["truth_events"] = [e.to_dict() for e in getattr(truth, "truth_events", ())]
    entry["scored_until_s"] = scored_until
    if st.traceback:
        entry["traceback"] = st.traceback

    t = time.perf_counter()
    write_table(truth.at_rate(task.log_rate_hz), folder, "truth", task.table_format)
    write_json(events_list(truth.events), folder / "events.json")
    write_json(scenario_info(sc, veh), folder / "scenario.json")
    if st.measurements is not None:
        write_table(st.measurements.frame, folder, "measurements", task.table_format)
    timings["write"] += time.perf_counter() - t

    tracks = st.tracks
    if st.runs is not None:
        runs = st.runs
    elif not truth.ok:
        runs = {o: SkippedRun(status=f"skipped: simulation {truth.status}") for o in task.observers}
    else:
        runs = {o: SkippedRun(status=f"skipped: {st.error}") for o in task.observers}

    t = time.perf_counter()
    metrics = score(truth.frame, tracks, scenario=label, runs=runs, mass_kg=veh.mass_kg,
                    scored_until_s=scored_until)
    timings["scoring"] = time.perf_counter() - t

    t = time.perf_counter()
    write_table(tracks_wide(tracks), folder, "estimates", task.table_format)  # one row per time step
    timings["write"] += time.perf_counter() - t
    # Drawn here, from the files just written, rather than by the page at the end: with --jobs the
    # workers draw them while other scenarios still run, and the page, built alone, only assembles.
    t = time.perf_counter()
    figures = drawn_figures(task.run_dir, label, metrics, entry)
    timings["figures"] = time.perf_counter() - t

    entry["render"] = {"frames": [], "video": None, "reason": "rendering switched off (--no-render)"}
    job = None
    if task.render:
        best = _best_beta_observer(metrics)
        beta = None
        if best is not None:
            tr = tracks[best]
            beta = pd.DataFrame({"t_s": tr.t_s, "value": tr.x[:, list(tr.states).index("beta_rad")]})
        job = RenderJob(source=RenderSource.from_truth(truth), run_dir=task.run_dir, name=label,
                        beta=beta, observer=best)
    entry["timings_s"] = {k: round(v, 4) for k, v in timings.items()}
    outcome = ScenarioOutcome(name=task.name, metrics=metrics, entry=entry,
                              runs={k: _observer_run_dict(v) for k, v in runs.items()}, timings=timings,
                              figures=figures)
    return outcome, job


def _line(o: ScenarioOutcome) -> str:
    # Skipped (not applicable, e.g. no radar) is counted apart from failed, as in the report.
    from roadtruth.harness.report.verdicts import count_statuses, run_verdict

    rows = o.metrics.groupby("observer")["status"].agg(list).to_dict() if len(o.metrics) else {}
    c = count_statuses(run_verdict(str(r.get("status", "ok")), rows.get(name, []))
                       for name, r in o.runs.items())
    parts = [f"{c.ok} ok"] + ([f"{c.not_applicable} n/a"] if c.not_applicable else []) + [f"{c.failed} failed"]
    return (f"{o.name}: {o.entry['status']}, {len(o.runs)} observers ({', '.join(parts)}), "
            f"{sum(o.timings.values()):.1f} s")


def _render_line(o: ScenarioOutcome) -> str:
    r = o.entry.get("render", {})
    if r.get("reason"):
        return f"{o.name}: not rendered ({r['reason'][:80]})"
    return f"{o.name}: rendered {r.get('n_rendered', 0)} frames in {o.timings.get('render', 0.0):.1f} s"


def process_pool(fn: Any, workers: int, what: str = "worker") -> WorkerPool:
    """Supervised worker processes running ``fn`` (see :mod:`roadtruth.harness.jobs.worker_pool`): they start from a
    fresh interpreter (``start_method()``: forkserver on Linux, never plain fork, which hangs renders
    after an OpenGL context), die with the run, and a crash fails only the task the worker held."""
    assert start_method() != "fork"
    from roadtruth.harness.jobs.worker_pool import FORKSERVER_PRELOAD, RENDER_PRELOAD

    return WorkerPool(fn, workers, what=what, preload=RENDER_PRELOAD if what == "renderer" else FORKSERVER_PRELOAD)


def crashed_scenario(task: ScenarioTask, crash: WorkerCrashed, tasks: Sequence[ScenarioTask] = ()) -> ScenarioOutcome:
    """The outcome of a scenario whose worker process died holding it: status ``error: worker
    crashed (signal N)``, its observers skipped, and the files of a failed scenario in its folder.

    What the worker had half-written is removed first (the folder is inside this run's own temporary
    folder), unless another task of ``tasks`` has a scenario of the same name, whose folder it might be.
    """
    from roadtruth.harness.report.rundata import scenario_folder_name

    def label(t: ScenarioTask) -> str:
        if t.folder_label is not None:
            return t.folder_label
        return scenario_folder_name(prepare_scenario(t.name, t.vehicle, t.friction).name)

    mine = label(task)
    if sum(label(t) == mine for t in tasks if t is not task) == 0:
        shutil.rmtree(task.run_dir / mine, ignore_errors=True)
    outcome, _ = compute_scenario(task, failed=f"error: {crash}")
    if task.render:
        outcome.entry["render"] = {"frames": [], "video": None, "reason": f"not rendered: the {crash}",
                                   "n_rendered": 0}
    return outcome


def _run_tasks(tasks: list[ScenarioTask], jobs: int, progress: Progress,
               clock: dict[str, float] | None = None) -> Iterable[ScenarioOutcome]:
    """Run the scenario tasks; yields outcomes as they complete (any order). ``clock["first"]`` is
    set to ``time.perf_counter()`` when the first scenario is handed out (workers ready, designs
    solved), for ``timings.json``.

    With ``jobs > 1`` each worker process runs whole scenarios, renders included; a worker that dies
    (a segfault in compiled code) costs only its scenario (:func:`crashed_scenario`) and is replaced.
    Otherwise the main process simulates, senses, estimates and scores one scenario after the other
    while renders (the slowest stage with software GL) run in two background processes, so a 2-core
    machine is used even without ``--jobs``. The main process itself never renders (see ``process_pool``).
    """
    if jobs > 1 and len(tasks) > 1:
        with process_pool(run_scenario, min(jobs, len(tasks))) as pool:
            from roadtruth.harness.jobs.design_warmup import presolve_designs
            from roadtruth.harness.report.builder import warm_up

            warm_up()  # fits in the wait for the workers' server to finish its preload, not at the end
            pool.start_workers()  # one solves the designs every worker needs, once; the others start meanwhile
            presolve_designs(pool.submit_call, _warmup(tasks), hosts=min(jobs, len(tasks)))
            if clock is not None:
                clock["first"] = time.perf_counter()
            futures = {pool.submit(task): task for task in longest_first(tasks)}
            for fut in as_completed(futures):
                try:
                    o = fut.result()
                except WorkerCrashed as crash:
                    o = crashed_scenario(futures[fut], crash, tasks)
                progress.item(_line(o))
                if tasks[0].render:
                    progress.item(_render_line(o))
                yield o
        return
    from roadtruth.harness.jobs.design_warmup import BackgroundWarmup

    # On a fresh install the observers' kernels compile on both cores while the first scenario
    # simulates, instead of one after the other in one observer host.
    warm = BackgroundWarmup.start(_warmup(tasks), hosts=2) if tasks else None
    ready = warm.wait if warm is not None else None
    if clock is not None:
        clock["first"] = time.perf_counter()
    if not any(t.render for t in tasks):
        for task in tasks:
            o = run_scenario(task, before_observers=ready)
            progress.item(_line(o))
            yield o
        return
    with process_pool(render_job, min(2, len(tasks)), what="renderer") as renderer:
        pending: list[tuple[ScenarioOutcome, Future | None]] = []
        for task in tasks:
            o, job = compute_scenario(task, before_observers=ready)
            progress.item(_line(o))
            pending.append((o, renderer.submit(job) if job is not None else None))
        for o, fut in pending:
            if fut is not None:
                try:
                    entry, seconds = fut.result()
                except WorkerCrashed as crash:  # a crash in the GL stack costs only this render
                    entry = {"frames": [], "video": None, "reason": f"rendering failed: {crash}", "n_rendered": 0}
                    seconds = 0.0
                o.entry["render"] = entry
                o.timings["render"] = seconds
                o.entry["timings_s"]["render"] = round(seconds, 4)
                progress.item(_render_line(o))
            yield o


def beside(work: Callable[[], None]) -> threading.Thread:
    """Start ``work`` (a page's one-time work: templates compiled, plotly.js read) in a daemon
    thread and return it (join it before the page). A serial run's process waits on its observer
    host for much of each scenario, and the thread takes those waits instead of the run's end; an
    exception in it is left for the page itself to raise."""
    def run() -> None:
        with contextlib.suppress(Exception):
            work()

    thread = threading.Thread(target=run, name="roadtruth-page-warm-up", daemon=True)
    thread.start()
    return thread


def run_phases(t_start: float, t_first: float, t_last: float, t_end: float) -> dict[str, float]:
    """A run's or sweep's wall time in three parts [s] (``timings.json``: ``phases_s``): ``start``
    (from its start, after the command's imports, to the first scenario or case handed out: input
    checks, the workers' start-up, the design warm-up's launch), ``work`` (from then to the last
    outcome) and ``finish`` (the tables, run.json and the page)."""
    return {"start": round(t_first - t_start, 3), "work": round(t_last - t_first, 3),
            "finish": round(t_end - t_last, 3)}


def longest_first(tasks: Sequence[ScenarioTask]) -> list[ScenarioTask]:
    """The tasks in the order workers take them: longest simulated duration first (ties, and
    unknown durations last, in the given order), so that the last scenario to finish is a short one
    and no worker waits long for another. The run's files do not depend on the order."""
    return sorted(tasks, key=lambda t: -t.duration_s if math.isfinite(t.duration_s) else math.inf)


def _warmup(tasks: Sequence[ScenarioTask]) -> Any:
    """The designs and kernels the tasks (one at least) need (:class:`roadtruth.harness.jobs.design_warmup.DesignWarmup`)."""
    from roadtruth.harness.jobs.design_warmup import DesignWarmup

    return DesignWarmup.of([(t.name, t.vehicle, t.friction) for t in tasks], [o for t in tasks for o in t.observers],
                           tasks[0].observer_options, tasks[0].observer_timeout_s)


def check_log_rate(hz: float, dt_s: float = 0.001) -> None:
    """``truth.csv`` keeps every k-th simulation step: the rate must divide the simulation rate."""
    k = 1.0 / (hz * dt_s) if hz > 0 else math.nan
    if not (k >= 1.0 - 1e-9 and abs(k - round(k)) <= 1e-6 * k):
        raise InputError(f"log rate {hz:g} Hz must divide the simulation rate {1.0 / dt_s:g} Hz",
                         field="--log-rate")


def _resolve(scenarios: list[str] | None, suite_name: str, observers: list[str] | None,
             vehicle: str | None, friction: str | None, sensors: str | None, faults: str | None) -> tuple[list[str], list[str]]:
    """Validate every user choice up front (raises InputError) and return scenario and observer names."""
    from roadtruth.harness.truth.scenario import suite
    from roadtruth.observers.registry import available_observers

    names = list(dict.fromkeys(scenarios)) if scenarios else suite(suite_name)
    for n in names:
        sc = prepare_scenario(n, vehicle, friction)
        sc.vehicle_params()
        sensor_config(sc, sensors, faults)
    known = available_observers()
    chosen = list(dict.fromkeys(observers)) if observers else list(known)
    unknown = [o for o in chosen if o not in known]
    if unknown:
        raise InputError(f"unknown observer {unknown[0]!r} (available: {', '.join(known)})", field="--observer")
    return names, chosen


def _observer_table(names: list[str]) -> list[dict[str, Any]]:
    from roadtruth.observers.registry import observer_info

    info = {i["name"]: i for i in observer_info()}
    return [{k: v for k, v in info.get(n, {"name": n}).items() if k in ("name", "citation", "states", "inputs", "family")}
            for n in names]


def run_suite(
    scenarios: list[str] | None = None,
    suite_name: str = "default",
    observers: list[str] | None = None,
    seed: int | None = None,
    jobs: int = 1,
    out: Path = Path("reports/latest"),
    vehicle: str | None = None,
    friction: str | None = None,
    sensors: str | None = None,
    faults: str | None = None,
    log_rate_hz: float = 100.0,
    render: bool = True,
    progress: bool | None = None,
    observer_timeout_s: float | None = None,
    observer_options: dict[str, dict[str, Any]] | None = None,
    table_format: str = "csv",
) -> Path:
    """Run a suite of scenarios × observers and write the run folder with its report.

    Parameters
    ----------
    scenarios : scenario names (default: the scenarios of ``suite_name``).
    suite_name : suite (tag) used when ``scenarios`` is not given.
    observers : observer names (default: every registered observer).
    seed : one seed for the whole suite (default: each scenario's own seed).
    jobs : parallel worker processes (results are identical for any value).
    out : run folder; replaced atomically when the run is complete.
    vehicle, friction, sensors, faults : overrides applied to every scenario.
    log_rate_hz : rate of ``truth.csv`` [Hz] (scoring uses the full simulation rate).
    render : render MuJoCo frames and videos.
    progress : True = tqdm bar, False = one line per scenario, None = bar only on a terminal.
    observer_timeout_s : wall-time budget of each observer's design + run [s]; default
        max(60 s, 20 × the scenario's simulated duration). Over budget: ``error: timed out after N s``.
    observer_options : observer -> {option: value} (``roadtruth.harness.evaluation.observer_options``; checked against each
        observer's declared options before any work, recorded in run.json).
    table_format : ``"csv"`` (default) or ``"parquet"`` for every table of the run folder.

    Returns
    -------
    Path
        The run folder (resolved).
    """
    from roadtruth.harness.evaluation.estimate import check_observer_timeout
    from roadtruth.harness.report import build_report
    from roadtruth.harness.report.builder import warm_up as build_report_warm_up

    t_wall = time.perf_counter()
    check_log_rate(log_rate_hz)
    check_observer_timeout(observer_timeout_s)
    check_format(table_format)
    if jobs > 1 or render:  # scenario workers or background renderers: their forkserver warms up meanwhile
        from roadtruth.harness.jobs.worker_pool import start_forkserver

        start_forkserver(renders_only=jobs <= 1)
    names, chosen = _resolve(scenarios, suite_name, observers, vehicle, friction, sensors, faults)
    from roadtruth.harness.evaluation.observer_options import check_observer_options, options_record

    # Checked (types, and each observer's own constructor on the first scenario's car) before any work.
    observer_options = check_observer_options(observer_options, chosen,
                                              prepare_scenario(names[0], vehicle, friction).vehicle_params()
                                              if names else None)
    bar = Progress(len(names) * (2 if render else 1), progress, desc="roadtruth run")
    out = Path(out)
    try:
        with atomic_output_dir(out, command="run",
                               inputs=[*(scenarios or []), vehicle, friction, sensors]) as tmp:
            prepared = [prepare_scenario(n, vehicle, friction) for n in names]
            tasks = [ScenarioTask(name=n, run_dir=tmp, observers=tuple(chosen), seed=seed, vehicle=vehicle,
                                  friction=friction, sensors=sensors, faults=faults, log_rate_hz=log_rate_hz,
                                  render=render, observer_timeout_s=observer_timeout_s,
                                  observer_options=observer_options or None, table_format=table_format,
                                  folder_label=new_scenario_folder(tmp, sc.name)[0], duration_s=float(sc.duration_s))
                     for n, sc in zip(names, prepared, strict=True)]
            clock: dict[str, float] = {}
            # Workers: the page's one-time work fits in the wait for their server (_run_tasks).
            page_warm = beside(build_report_warm_up) if tasks and (jobs <= 1 or len(tasks) <= 1) else None
            outcomes = {o.name: o for o in _run_tasks(tasks, jobs, bar, clock)}
            t_last = time.perf_counter()
            if page_warm is not None:
                page_warm.join()
            ordered = [outcomes[n] for n in names]
            metrics = pd.concat([o.metrics for o in ordered], ignore_index=True)
            write_table(metrics, tmp, "metrics", table_format)
            totals = {k: round(sum(o.timings.get(k, 0.0) for o in ordered), 4) for k in STAGES}
            reasons = [o.entry.get("render", {}).get("reason") for o in ordered]
            rendered = render and any(not r for r in reasons)
            run_json = {
                "command": "run", "suite": suite_name if not scenarios else None, "seed": seed,
                "vehicle": vehicle, "friction": friction, "sensors": sensors, "faults": faults,
                "log_rate_hz": log_rate_hz, "jobs": jobs, "float_format": FLOAT_FORMAT,
                "table_format": table_format, "observer_options": options_record(observer_options),
                "scenarios": [{k: v for k, v in o.entry.items() if k != "timings_s"} for o in ordered],
                "observers": _observer_table(chosen),
                "observer_runs": {o.entry["name"]: {obs: {k: v for k, v in r.items() if k != "us_per_step"}
                                           for obs, r in o.runs.items()} for o in ordered},
                "render": {"enabled": rendered,
                           "reason": None if rendered else next((r for r in reasons if r), None)},
                "versions": versions(), "git_revision": git_revision(),
            }
            write_json(run_json, tmp / "run.json")
            t = time.perf_counter()
            build_report(tmp, figures={k: v for o in ordered for k, v in o.figures.items()})
            # Times differ between identical runs, so they live only in timings.json, which run.json and
            # the page never show: those stay byte-identical (and `roadtruth report DIR` rebuilds this page).
            write_json({"command": "run", "stages_s": {**totals, "report": round(time.perf_counter() - t, 4)},
                        "wall_s": round(time.perf_counter() - t_wall, 3),
                        "phases_s": run_phases(t_wall, clock.get("first", t_wall), t_last, time.perf_counter()),
                        "kernel_target": kernel_target(),
                        "scenarios_s": {o.entry["name"]: o.entry.get("timings_s", {}) for o in ordered},
                        "us_per_step": {o.entry["name"]: {obs: r.get("us_per_step") for obs, r in o.runs.items()}
                                        for o in ordered}}, tmp / "timings.json")
    finally:
        bar.close()
    bar.note(f"wrote {out.resolve()} in {time.perf_counter() - t_wall:.1f} s")
    return out.resolve()


def simulate_to_dir(
    scenario: str,
    out: Path,
    vehicle: str | None = None,
    friction: str | None = None,
    seed: int | None = None,
    log_rate_hz: float = 1000.0,
    sensors: str | None = None,
    faults: str | None = None,
    table_format: str = "csv",
) -> Path:
    """Ground truth and measurements of one scenario (``roadtruth simulate``): ``truth.csv``,
    ``measurements.csv`` (``.parquet`` with ``table_format="parquet"``), ``events.json``,
    ``scenario.json`` and ``run.json`` in ``out``."""
    from roadtruth.harness.sensors import emulate
    from roadtruth.harness.truth.simulate import simulate
    from roadtruth.harness.truth.truth_events import scored_until_of, status_of

    check_log_rate(log_rate_hz)
    check_format(table_format)
    sc = prepare_scenario(scenario, vehicle, friction)
    veh = sc.vehicle_params()
    cfg = sensor_config(sc, sensors, faults)
    ss, sim_seed, sensor_seed = scenario_seeds(sc.seed, sc.name, seed)
    timings: dict[str, float] = {}
    with atomic_output_dir(out, command="simulate", inputs=[scenario, vehicle, friction, sensors]) as tmp:
        t = time.perf_counter()
        truth = simulate(sc, seed=sim_seed)
        timings["simulate"] = time.perf_counter() - t
        write_table(truth.at_rate(log_rate_hz), tmp, "truth", table_format)
        if truth.ok:
            t = time.perf_counter()
            meas = emulate(truth.frame, veh, cfg, sensor_seed, outages=sc.outages, lane_gaps=sc.lane_gaps)
            timings["sensors"] = time.perf_counter() - t
            write_table(meas.frame, tmp, "measurements", table_format)
        write_json(events_list(truth.events), tmp / "events.json")
        write_json(scenario_info(sc, veh), tmp / "scenario.json")
        write_json({"command": "simulate", "scenario": sc.name, "status": str(truth.status),
                    "vehicle": veh.name, "friction": friction, "sensors": sensors or sc.sensors,
                    "faults": faults, "seed": seed if seed is not None else sc.seed,
                    "entropy": str(ss.entropy), "spawn_key": list(ss.spawn_key),
                    "simulation_seed": sim_seed, "sensor_seed": sensor_seed, "log_rate_hz": log_rate_hz,
                    "table_format": table_format, "truth_status": status_of(truth), "scored_until_s": scored_until_of(truth),
                    "truth_events": [e.to_dict() for e in getattr(truth, "truth_events", ())],
                    "sim_steps": len(truth.frame), "versions": versions(), "git_revision": git_revision()},
                   tmp / "run.json")
        # Timings differ between identical runs: kept out of run.json so that it is byte-identical.
        write_json({"timings_s": {k: round(v, 4) for k, v in timings.items()}}, tmp / "timings.json")
    return Path(out).resolve()

