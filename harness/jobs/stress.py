"""Robustness sweeps (``roadtruth stress``): scenarios × friction × sensor faults × Monte Carlo seeds.

Every *case* is one (scenario, friction override, fault spec, seed index) and runs the whole chain
simulate → sensors → observers → score with the stage functions of :mod:`roadtruth.harness.jobs.pipeline`. Cases
are independent, so they run in local worker processes (``jobs``) or on a Dask cluster (``dask``);
their results are put back in case order, so the files do not depend on how the work was spread.

Seeds. One base seed gives seed index ``k`` the integer
``SeedSequence(base_seed, spawn_key=(k,)).generate_state(1)[0]``; that integer is then the ``--seed``
of a normal run (:func:`roadtruth.harness.jobs.pipeline.scenario_seeds` mixes in the scenario name and splits it into
simulation and sensor streams). The same seed index is shared by every friction and fault of a
scenario (common random numbers), so differences along those axes are not sampling noise.

Output (written atomically): ``stress.csv`` (one row per case × observer × state: the metrics of
``metrics.csv`` plus ``case, friction, mu, faults, seed_index, seed, truth_status`` and truth
extremes), ``summary.csv`` (see :mod:`roadtruth.harness.report.stress_report`), ``run.json`` and ``index.html``.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import dataclasses  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
import uuid  # noqa: E402
from collections.abc import Callable, Iterator  # noqa: E402
from concurrent.futures import as_completed  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from roadtruth.harness.errors import InputError  # noqa: E402
from roadtruth.harness.files.outdir import atomic_output_dir  # noqa: E402
from roadtruth.harness.files.table_io import check_format, write_table  # noqa: E402
from roadtruth.harness.progress import Progress  # noqa: E402
from roadtruth.harness.report.rundata import FLOAT_FORMAT, git_revision, versions, write_json  # noqa: E402
from roadtruth.harness.truth.friction_map import friction_from_spec  # noqa: E402

#: Label of "no override": the scenario's own friction map / no extra faults.
SCENARIO_FRICTION = "scenario"
NO_FAULTS = "none"
#: Base seed when none is given (documented in docs/STRESS.md).
DEFAULT_BASE_SEED = 0
#: Columns stress.csv puts before the metrics of ``roadtruth.harness.evaluation.scoring.COLUMNS``.
CASE_COLUMNS: tuple[str, ...] = ("case", "friction", "mu", "faults", "seed_index", "seed", "truth_status",
                                 "peak_abs_ay_mps2", "peak_abs_beta_rad")


class StressSpecError(InputError):
    """A ``roadtruth stress`` list option (``--friction``, ``--faults``, ``--seeds``, ``--dask``) is invalid."""


# ---- parsing the LIST options --------------------------------------------------------------------

def _items(text: str, sep: str, field: str) -> list[str]:
    raw = [s.strip() for s in str(text).split(sep)]
    if not any(raw):
        raise StressSpecError(f"empty list (got {text!r})", field=field)
    for s in raw:
        if not s:
            raise StressSpecError(f"empty item in {text!r} (items are separated by {sep!r})", field=field)
    return list(dict.fromkeys(raw))  # a repeated item would only repeat cases


def parse_friction_list(text: str) -> list[str]:
    """``--friction`` of stress: comma-separated specs of ``--friction`` (number, surface, YAML file).

    ``"scenario"`` keeps each scenario's own map. Returns the specs (duplicates dropped, order kept);
    each is checked with :func:`roadtruth.harness.truth.friction_map.friction_from_spec`.

    Raises
    ------
    StressSpecError
        Empty list or empty item.
    ScenarioError
        An item that is not a valid friction spec (the message names it).
    """
    specs = _items(text, ",", "--friction")
    for s in specs:
        if s != SCENARIO_FRICTION:
            friction_from_spec(s)
    return specs


def parse_fault_specs(text: str) -> list[str]:
    """``--faults`` of stress: fault specs of ``--faults`` separated by ``;`` (``"none"`` = no faults).

    Inside one spec, several faults are joined with ``,`` (``"gnss:dropout=0.5,imu:bias_step=0.3"``).
    Syntax is checked here with :func:`roadtruth.harness.sensors.faults.parse_faults`; whether the sensor is
    enabled in a scenario's suite is checked by :func:`run_stress` before any work starts.

    Raises
    ------
    StressSpecError
        Empty list or empty item.
    SensorConfigError
        A malformed fault spec (the message names the item).
    """
    from roadtruth.harness.sensors.faults import parse_faults

    specs = _items(text, ";", "--faults")
    for s in specs:
        if s.lower() != NO_FAULTS:
            parse_faults(s, source=f"--faults {s!r}")
    return [NO_FAULTS if s.lower() == NO_FAULTS else s for s in specs]


def parse_seed_count(value: int | str) -> int:
    """``--seeds N``: a whole number >= 1 of Monte Carlo seeds per (scenario, friction, faults)."""
    try:
        n = int(str(value).strip())
    except ValueError:
        raise StressSpecError(f"not a whole number (got {value!r})", field="--seeds") from None
    if not 1 <= n <= 100_000:
        raise StressSpecError(f"must be in [1, 100000] (got {n})", field="--seeds")
    return n


def monte_carlo_seeds(base_seed: int, n: int) -> list[int]:
    """The integer seed of each seed index ``k < n``: ``SeedSequence(base_seed, spawn_key=(k,))``.

    Seed ``k`` does not depend on ``n``: a sweep with more seeds extends one with fewer.
    """
    return [int(np.random.SeedSequence(int(base_seed), spawn_key=(k,)).generate_state(1, np.uint64)[0] >> 1)
            for k in range(n)]


# ---- one case ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class StressCase:
    """One point of the sweep (picklable: sent to worker processes and Dask workers)."""

    index: int
    scenario: str
    friction: str  # a friction spec or SCENARIO_FRICTION
    faults: str  # a fault spec or NO_FAULTS
    seed_index: int
    seed: int
    observers: tuple[str, ...]
    observer_timeout_s: float | None = None  # per-observer budget [s]; None = scaled with the duration
    # Checked observer options (harness/evaluation/observer_options.py): observer -> {option: value}; in the cache key.
    observer_options: dict[str, dict[str, Any]] | None = None
    # Names the sweep the case belongs to: a worker reuses prepared scenarios within one sweep only.
    sweep: str = ""
    # The case cache entry the process that runs the case stores its rows under, as soon as they are
    # scored (same machine, same cache). None: the sweep's own process stores them (Dask workers
    # may be other machines), or the case cannot be keyed.
    cache_key: str | None = None


@dataclass(frozen=True)
class CaseResult:
    index: int
    rows: pd.DataFrame
    seconds: float
    traceback: str | None = None
    #: the process that ran the case has stored it in the case cache (``StressCase.cache_key``)
    stored: bool = False


def _mu_label(sc: Any) -> float:
    """The map's μ when it is uniform, else NaN (a patchy map has no single μ)."""
    fm = sc.friction
    return float(fm.mu_default) if fm.is_uniform else math.nan


def _peak(frame: pd.DataFrame, column: str) -> float:
    if column not in frame or frame.empty:
        return math.nan
    return float(np.nanmax(np.abs(frame[column].to_numpy(float))))


#: (sweep, scenario, friction) -> (prepared scenario, its μ label, its vehicle), in this process.
#: Loading a scenario with its vehicle parses two YAML files and validates them, about a fifth of a
#: short case; every seed and fault of a (scenario, friction) shares them. Both are frozen
#: dataclasses, and only the current sweep's are kept, so a file edited between sweeps is re-read.
_PREPARED: dict[tuple[str, str, str], tuple[Any, float, Any]] = {}


def _prepared(case: StressCase) -> tuple[Any, float, Any]:
    """The case's prepared scenario, μ label and vehicle, loaded once per sweep and process."""
    from roadtruth.harness.jobs.pipeline import prepare_scenario

    key = (case.sweep, case.scenario, case.friction)
    hit = _PREPARED.get(key)
    if hit is None:
        if any(k[0] != case.sweep for k in _PREPARED):
            _PREPARED.clear()
        sc = prepare_scenario(case.scenario, None, None if case.friction == SCENARIO_FRICTION else case.friction)
        hit = _PREPARED[key] = (sc, _mu_label(sc), sc.vehicle_params())
    return hit


def run_cases(cases: list[StressCase]) -> list[CaseResult]:
    """:func:`run_case` of each case, in order: one task of a Dask sweep holds several cases, so
    scheduling costs once per batch and the worker's prepared scenarios serve the whole batch."""
    return [run_case(c) for c in cases]


def run_case(case: StressCase, before_observers: Callable[[], None] | None = None) -> CaseResult:
    """Simulate, sense, estimate and score one case; never raises (a crash becomes ``error: …`` rows).
    ``before_observers``: see :func:`roadtruth.harness.jobs.pipeline.evaluate_scenario`.

    The stages are :func:`roadtruth.harness.jobs.pipeline.evaluate_scenario`, shared with ``run``; a sweep keeps
    metrics only and writes no per-case files.
    """
    from roadtruth.harness.evaluation.scoring import score
    from roadtruth.harness.jobs.pipeline import (
        FailedTruth,
        SkippedRun,
        evaluate_scenario,
        scenario_seeds,
    )
    from roadtruth.harness.truth.truth_events import scored_until_of, status_of

    t0 = time.perf_counter()
    faults = None if case.faults == NO_FAULTS else case.faults
    tb = None
    mu = math.nan
    mass = None
    truth: Any = FailedTruth(status="error: not simulated")
    tracks: dict[str, Any] = {}
    runs: dict[str, Any]
    try:
        sc, mu, veh = _prepared(case)
        mass = veh.mass_kg
        _, sim_seed, sensor_seed = scenario_seeds(sc.seed, case.scenario, case.seed)
        st = evaluate_scenario(sc, veh, case.observers, sim_seed, sensor_seed, faults=faults,
                               observer_timeout_s=case.observer_timeout_s, observer_options=case.observer_options,
                               before_observers=before_observers)
        truth, tracks, tb = st.truth, dict(st.tracks), st.traceback
        if st.runs is not None:
            runs = st.runs
        elif st.error:  # a crashed stage marks the whole case (its truth is not trusted either)
            truth = FailedTruth(status=st.error)
            runs = {o: SkippedRun(status=st.error) for o in case.observers}
        else:
            runs = {o: SkippedRun(status=f"skipped: simulation {truth.status}") for o in case.observers}
    except Exception as e:  # one broken case must not stop the sweep (inputs were validated up front)
        status = f"error: {type(e).__name__}: {e}".splitlines()[0]
        tb = traceback.format_exc()
        if truth.ok:
            truth = FailedTruth(status=status)
        runs = {o: SkippedRun(status=status) for o in case.observers}
    metrics = score(truth.frame, tracks, scenario=case.scenario, runs=runs, mass_kg=mass,
                    scored_until_s=scored_until_of(truth))
    head = {"case": case.index, "friction": case.friction, "mu": mu, "faults": case.faults,
            "seed_index": case.seed_index, "seed": case.seed, "truth_status": status_of(truth),
            "peak_abs_ay_mps2": _peak(truth.frame, "ay_mps2"), "peak_abs_beta_rad": _peak(truth.frame, "beta_rad")}
    for i, (k, v) in enumerate(head.items()):
        metrics.insert(i, k, [v] * len(metrics))
    result = CaseResult(index=case.index, rows=metrics, seconds=time.perf_counter() - t0, traceback=tb)
    if case.cache_key is None:
        return result
    from roadtruth.harness.jobs.stress_cache import store_finished

    # Here rather than in the sweep's process: with worker processes that process shares the two
    # cores with them, and storing a case (its rows as exact JSON) costs about a tenth of running it.
    store_finished(result, case.cache_key)
    return dataclasses.replace(result, stored=True)


def build_cases(scenarios: list[str], frictions: list[str], faults: list[str], seeds: list[int],
                observers: list[str], observer_timeout_s: float | None = None,
                observer_options: dict[str, dict[str, Any]] | None = None, sweep: str = "") -> list[StressCase]:
    """The Cartesian product scenarios × frictions × faults × seeds, in that nesting order."""
    cases: list[StressCase] = []
    for sc in scenarios:
        for fr in frictions:
            for fa in faults:
                for k, s in enumerate(seeds):
                    cases.append(StressCase(index=len(cases), scenario=sc, friction=fr, faults=fa,
                                            seed_index=k, seed=s, observers=tuple(observers),
                                            observer_timeout_s=observer_timeout_s,
                                            observer_options=observer_options or None, sweep=sweep))
    return cases


# ---- execution -----------------------------------------------------------------------------------

def _crashed_case(case: StressCase, crash: Exception) -> CaseResult:
    """The rows of a case whose worker process died holding it (``error: worker crashed (signal N)``)."""
    from roadtruth.harness.evaluation.scoring import score
    from roadtruth.harness.jobs.pipeline import FailedTruth, SkippedRun, prepare_scenario

    status = f"error: {crash}"
    truth = FailedTruth(status=status)
    try:
        mu = _mu_label(prepare_scenario(case.scenario, None,
                                        None if case.friction == SCENARIO_FRICTION else case.friction))
    except Exception:  # noqa: BLE001 - the label is cosmetic; the inputs were validated up front
        mu = math.nan
    metrics = score(truth.frame, {}, scenario=case.scenario,
                    runs={o: SkippedRun(status=status) for o in case.observers}, mass_kg=None)
    head = {"case": case.index, "friction": case.friction, "mu": mu, "faults": case.faults,
            "seed_index": case.seed_index, "seed": case.seed, "truth_status": status,
            "peak_abs_ay_mps2": math.nan, "peak_abs_beta_rad": math.nan}
    for i, (k, v) in enumerate(head.items()):
        metrics.insert(i, k, [v] * len(metrics))
    return CaseResult(index=case.index, rows=metrics, seconds=0.0, traceback=status)


def _warmup(cases: list[StressCase]) -> Any:
    """The designs and kernels the cases need (:class:`roadtruth.harness.jobs.design_warmup.DesignWarmup`), made once up front."""
    from roadtruth.harness.jobs.design_warmup import DesignWarmup

    c0 = cases[0]
    return DesignWarmup.of([(c.scenario, None, None if c.friction == SCENARIO_FRICTION else c.friction)
                            for c in cases], c0.observers, c0.observer_options, c0.observer_timeout_s)


def dask_batches(cases: list[StressCase], workers: int) -> list[list[StressCase]]:
    """Consecutive runs of cases, one Dask task each: about four per worker (so a slow batch does not
    leave the others idle at the end), at most 16 cases (so results stream back during the sweep).

    Consecutive cases share their (scenario, friction), so a batch reuses one prepared scenario.
    """
    if not cases:
        return []
    size = max(1, min(16, math.ceil(len(cases) / (4 * max(1, workers)))))
    return [cases[i:i + size] for i in range(0, len(cases), size)]


def _run_local(cases: list[StressCase], jobs: int, clock: dict[str, float]) -> Iterator[CaseResult]:
    """Run the cases in this process or in ``jobs`` supervised worker processes (any order); a worker
    that dies costs only its case (``error: worker crashed (signal N)``) and is replaced.
    ``clock["first"]``: when the first case was handed out (``time.perf_counter()``)."""
    from roadtruth.harness.jobs.design_warmup import BackgroundWarmup, presolve_designs
    from roadtruth.harness.jobs.pipeline import process_pool
    from roadtruth.harness.jobs.worker_pool import WorkerCrashed

    if jobs <= 1 or len(cases) <= 1:
        # On a fresh install the kernels compile on both cores while the first case simulates.
        warm = BackgroundWarmup.start(_warmup(cases), hosts=2) if cases else None
        clock["first"] = time.perf_counter()
        for c in cases:
            yield run_case(c, before_observers=warm.wait if warm is not None else None)
        return
    with process_pool(run_case, min(jobs, len(cases))) as pool:
        # This process would only wait for the workers' server to finish its preload: the page's
        # one-time work fits in that wait instead of at the end of the sweep.
        from roadtruth.harness.report.stress_report import warm_up

        warm_up()
        pool.start_workers()  # the others import while one solves the designs all of them need
        presolve_designs(pool.submit_call, _warmup(cases), hosts=min(jobs, len(cases)))
        # One case per task: a round trip costs well under a millisecond against ~0.1 s per case, and
        # single cases keep the workers evenly loaded to the end and a crash costs one case.
        clock["first"] = time.perf_counter()
        futures = {pool.submit(c): c for c in cases}
        for fut in as_completed(futures):
            try:
                result = fut.result()
            except WorkerCrashed as crash:
                result = _crashed_case(futures[fut], crash)
            yield result


def _run_dask(cases: list[StressCase], address: str, jobs: int, info: dict[str, Any]) -> Iterator[CaseResult]:
    """Run the cases on ``distributed.Client(address)``; ``address == "local"`` starts a LocalCluster
    of ``jobs`` worker processes on loopback for this run and closes it afterwards."""
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:
        raise StressSpecError("--dask needs the dask and distributed packages "
                              "(pip install 'dask[distributed]')", field="--dask") from None
    from roadtruth.harness.jobs.design_warmup import presolve_designs

    t = time.perf_counter()
    cluster = None
    if address == "local":
        from roadtruth.harness.jobs.dask_setup import local_cluster

        cluster = local_cluster(jobs)
        client = Client(cluster)
    else:
        try:
            client = Client(address, timeout=30)
        except (OSError, TimeoutError, ValueError) as e:
            raise StressSpecError(f"cannot connect to Dask scheduler {address!r} ({e})", field="--dask") from None
    try:
        info["startup_s"] = round(time.perf_counter() - t, 3)
        info["workers"] = len(client.scheduler_info().get("workers", {}))
        # A local cluster's workers share this machine's cores; a remote worker's cores are unknown.
        presolve_designs(lambda fn, arg: client.submit(fn, arg, pure=False), _warmup(cases),
                         hosts=jobs if cluster is not None else 1)
        info["first"] = time.perf_counter()
        futures = client.map(run_cases, dask_batches(cases, info["workers"] or jobs), pure=False)
        for fut in dask_completed(futures):
            yield from fut.result()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


# ---- the sweep -----------------------------------------------------------------------------------

def _resolve(scenarios: list[str] | None, suite_name: str, observers: list[str] | None,
             frictions: list[str], faults: list[str]) -> tuple[list[str], list[str]]:
    """Scenario and observer names, with every (scenario, friction) and (scenario, faults) checked."""
    from roadtruth.harness.jobs.pipeline import _resolve as resolve_run
    from roadtruth.harness.jobs.pipeline import prepare_scenario, sensor_config

    names, chosen = resolve_run(scenarios, suite_name, observers, None, None, None, None)
    if not names:
        raise StressSpecError(f"suite {suite_name!r} has no scenarios", field="--suite")
    for n in names:
        for fr in frictions:
            prepare_scenario(n, None, None if fr == SCENARIO_FRICTION else fr)
        sc = prepare_scenario(n, None, None)
        for fa in faults:
            sensor_config(sc, None, None if fa == NO_FAULTS else fa)
    return names, chosen


def run_stress(*, scenarios: list[str] | None, suite_name: str = "stress", observers: list[str] | None,
               frictions: list[str] | None, faults: list[str] | None, seeds: int = 1,
               base_seed: int | None = None, jobs: int = 1, dask: str | None = None,
               out: Path = Path("reports/stress"), progress: bool | None = None, fresh: bool = False,
               observer_timeout_s: float | None = None,
               observer_options: dict[str, dict[str, Any]] | None = None, table_format: str = "csv") -> Path:
    """Run a robustness sweep and write ``stress.csv``, ``summary.csv``, ``run.json``, ``index.html``.

    Parameters
    ----------
    scenarios : scenario names (default: the scenarios of ``suite_name``).
    suite_name : suite (tag) used when ``scenarios`` is not given.
    observers : observer names (default: every registered observer).
    frictions : friction specs (number, surface, YAML, or ``"scenario"``); default ``["scenario"]``.
        Parse a CLI LIST with :func:`parse_friction_list`.
    faults : fault specs (``--faults`` strings or ``"none"``); default ``["none"]``.
        Parse a CLI LIST with :func:`parse_fault_specs`.
    seeds : Monte Carlo seeds per (scenario, friction, faults), >= 1.
    base_seed : the seed all case seeds derive from (default ``DEFAULT_BASE_SEED``).
    jobs : local worker processes, or Dask workers with ``dask="local"``.
    dask : None (local processes), ``"local"`` (a LocalCluster on 127.0.0.1) or a scheduler address.
    out : output folder; replaced atomically when the sweep is complete.
    progress : True = tqdm bar, False = one line per case, None = bar only on a terminal.
    observer_timeout_s : wall-time budget of each observer's design + run [s] (default: max(60 s,
        20 × the simulated duration)); over budget, the observer's rows say ``error: timed out after N s``.
    observer_options : observer -> {option: value} (``roadtruth.harness.evaluation.observer_options``), checked before any
        work, recorded in run.json and part of every case's cache key.
    table_format : ``"csv"`` (default) or ``"parquet"`` for ``stress`` and ``summary``.
    fresh : compute every case even when the case cache holds it (the cache is refreshed). Otherwise
        a case finished by an earlier sweep is loaded (:mod:`roadtruth.harness.jobs.stress_cache`): a rerun resumes,
        a wider sweep computes only its new cases, and the files are the same bytes either way.

    Returns
    -------
    Path
        The output folder (resolved).

    Raises
    ------
    InputError
        Bad scenario, observer, friction, fault spec, seed count or Dask address (before any work).
    """
    from roadtruth.harness.evaluation.estimate import check_observer_timeout
    from roadtruth.harness.jobs.pipeline import beside, run_phases
    from roadtruth.harness.jobs.stress_cache import case_keys, load_cached, store_finished
    from roadtruth.harness.report.stress_report import summarize, warm_up, write_index

    t_wall = time.perf_counter()
    n_seeds = parse_seed_count(seeds)
    if jobs < 1:
        raise StressSpecError(f"must be >= 1 (got {jobs})", field="--jobs")
    check_observer_timeout(observer_timeout_s)
    base = DEFAULT_BASE_SEED if base_seed is None else int(base_seed)
    if base < 0:
        raise StressSpecError(f"must be >= 0 (got {base})", field="--seed")
    fr_list = list(dict.fromkeys(frictions)) if frictions else [SCENARIO_FRICTION]
    fa_list = [NO_FAULTS if f.lower() == NO_FAULTS else f for f in dict.fromkeys(faults)] if faults else [NO_FAULTS]
    check_format(table_format)
    if jobs > 1 and dask is None:  # the workers' forkserver warms up while the sweep is prepared
        from roadtruth.harness.jobs.worker_pool import start_forkserver

        start_forkserver()
    names, chosen = _resolve(scenarios, suite_name, observers, fr_list, fa_list)
    from roadtruth.harness.evaluation.observer_options import check_observer_options, options_record
    from roadtruth.harness.jobs.pipeline import prepare_scenario

    observer_options = check_observer_options(observer_options, chosen,
                                              prepare_scenario(names[0], None, None).vehicle_params())
    seed_values = monte_carlo_seeds(base, n_seeds)
    cases = build_cases(names, fr_list, fa_list, seed_values, chosen, observer_timeout_s, observer_options,
                        sweep=uuid.uuid4().hex)
    keys = case_keys(cases)
    results: dict[int, CaseResult] = {} if fresh else load_cached(cases, keys)
    todo = [c for c in cases if c.index not in results]
    if dask is None:  # local processes share this machine's case cache: each stores its own cases
        todo = [dataclasses.replace(c, cache_key=keys.get(c.index)) for c in todo]

    execution: dict[str, Any] = {}  # how the cases ran: Dask start-up and workers, when the first was handed out
    bar = Progress(len(todo), progress, desc="roadtruth stress")
    if results:
        bar.note(f"{len(results)} of {len(cases)} cases loaded from the case cache (--fresh recomputes them)")
    out = Path(out)
    try:
        with atomic_output_dir(out, command="stress", inputs=[*(scenarios or []), *fr_list]) as tmp:
            t_run = time.perf_counter()
            # Local workers: the page's one-time work fits in the wait for their server (_run_local).
            page_warm = beside(warm_up) if todo and (dask is not None or jobs <= 1 or len(todo) <= 1) else None
            stream = (_run_dask(todo, dask, jobs, execution) if dask else _run_local(todo, jobs, execution)) if todo else ()
            for r in stream:
                results[r.index] = r
                if not r.stored:  # at once: a killed sweep keeps what it finished
                    store_finished(r, keys.get(r.index))
                c = cases[r.index]
                bar.item(f"case {c.index}: {c.scenario} friction={c.friction} faults={c.faults} "
                         f"seed#{c.seed_index}: {r.rows['truth_status'].iloc[0] if len(r.rows) else '?'}, "
                         f"{r.seconds:.1f} s")
            t_last = time.perf_counter()
            run_s = t_last - t_run
            if page_warm is not None:
                page_warm.join()
            rows = pd.concat([results[c.index].rows for c in cases], ignore_index=True)
            write_table(rows, tmp, "stress", table_format)
            summary = summarize(rows)
            write_table(summary, tmp, "summary", table_format)
            case_s = [results[c.index].seconds for c in todo]
            run_json = {
                "command": "stress", "suite": suite_name if not scenarios else None, "scenarios": names,
                "observers": chosen, "frictions": fr_list, "faults": fa_list, "seeds": n_seeds,
                "base_seed": base, "seed_values": seed_values, "n_cases": len(cases), "jobs": jobs,
                "executor": ("dask " + dask) if dask else ("processes" if jobs > 1 else "in-process"),
                "dask": {"workers": execution["workers"]} if "workers" in execution else None,
                "float_format": FLOAT_FORMAT, "table_format": table_format,
                "observer_options": options_record(observer_options),
                "case_errors": {str(c.index): results[c.index].traceback for c in cases
                                if results[c.index].traceback},
                "versions": versions(), "git_revision": git_revision(),
            }
            write_json(run_json, tmp / "run.json")
            write_index(tmp, summary, run_json)
            # How this sweep was executed (times, cache use) differs between identical sweeps, so it
            # stays out of run.json and the page, which are byte-identical for the same inputs.
            write_json({"command": "stress", "n_cases": len(cases), "n_cached": len(cases) - len(todo),
                        "n_computed": len(todo), "cases_wall_s": round(run_s, 3),
                        "computed_case_sum_s": round(sum(case_s), 3),
                        "computed_case_mean_s": round(sum(case_s) / len(case_s), 3) if case_s else None,
                        "computed_cases_per_s": round(len(todo) / run_s, 4) if todo and run_s > 0 else None,
                        "dask_startup_s": execution.get("startup_s"),
                        "wall_s": round(time.perf_counter() - t_wall, 3),
                        "phases_s": run_phases(t_wall, execution.get("first", t_last), t_last,
                                            time.perf_counter())}, tmp / "timings.json")
    finally:
        bar.close()
    bar.note(f"wrote {out.resolve()}: {len(cases)} cases ({len(cases) - len(todo)} from the case cache) "
             f"in {time.perf_counter() - t_wall:.1f} s")
    return out.resolve()


__all__: list[str] = ["CASE_COLUMNS", "CaseResult", "NO_FAULTS", "SCENARIO_FRICTION", "StressCase",
                      "StressSpecError", "build_cases", "dask_batches", "monte_carlo_seeds", "parse_fault_specs",
                      "parse_friction_list", "parse_seed_count", "run_case", "run_cases", "run_stress"]
