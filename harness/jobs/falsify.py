"""Falsification (``roadtruth falsify``): search a space of roads, manoeuvres, faults and vehicles for
the case that breaks an observer's promise.

Every candidate is a real scenario (:mod:`roadtruth.harness.jobs.falsify_space` builds its mapping), run through the
stage core of ``run`` and ``stress`` (:func:`roadtruth.harness.jobs.pipeline.evaluate_scenario` then
:func:`roadtruth.harness.evaluation.scoring.score`) and judged by a property (:mod:`roadtruth.harness.jobs.falsify_property`) as a signed
robustness: negative = violated. A candidate whose car spun out, rolled over or left the road is
marked (``truth_status``) and never counted as a violation: no observer can be blamed for it; the
sampler is told ``max(robustness, 0)`` for it so the search is not drawn towards spinning cars.

Search. Optuna's TPE sampler (Bergstra et al., 2011), seeded, asked for batches of ``BATCH``
candidates that are evaluated in parallel and told back in candidate order, so the result depends on
the seed only (not on ``--jobs`` or which worker finished first). The first candidate is the nominal
scenario. Why TPE: on an analytic copy of the synthetic test problem (μ patch breaking a μ ≥ 0.6
promise; 4 parameters, 24 evaluations, batches of 4, 30 seeds) TPE reached a mean best robustness of
−0.49 (ideal −0.50) and found a violation in 30/30 runs; CMA-ES (the ``cma`` package, popsize 4,
started at the nominal) −0.39 and 29/30; random sampling −0.43. TPE also takes the categorical
split-μ side as it is. The last ``REFINE_ROUNDS × BATCH`` evaluations of the budget (when the budget is
at least ``MIN_BUDGET_TO_REFINE`` and a violation was found) refine the smallest perturbation: a
sectioning along the segment from the nominal to the violating case closest to it (parameters without a
nominal held), which brackets the breaking point ``BATCH + 1`` times tighter per round.

Resume. Each finished candidate is stored in the cache (:mod:`roadtruth.harness.files.disk_cache`, folder
``falsify-cases``) under a key of everything that determines it (the candidate's scenario, vehicle and
faults, the observer and its source, the property, the roadtruth code and package versions). A rerun
proposes the same candidates, finds them in the cache and evaluates none again.

Output (one folder, written atomically): ``cases.csv`` (every candidate: robustness, verdict, truth
status, distance from the nominal, parameters), ``worst.yaml`` and ``smallest.yaml`` (ready scenarios;
a perturbed vehicle beside them as ``*_vehicle.yaml``), ``worst.txt`` / ``smallest.txt`` (the exact
``roadtruth run`` line, with the faults), ``run.json`` and ``index.html``.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import math  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from collections.abc import Iterator  # noqa: E402
from concurrent.futures import as_completed  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import yaml  # noqa: E402

from roadtruth.harness.errors import InputError  # noqa: E402
from roadtruth.harness.files.outdir import atomic_output_dir  # noqa: E402
from roadtruth.harness.jobs.falsify_property import Property, check_fits, parse_property, robustness  # noqa: E402
from roadtruth.harness.jobs.falsify_space import Space, build_candidate, default_space, load_space  # noqa: E402
from roadtruth.harness.progress import Progress  # noqa: E402

#: Candidates proposed per sampler round (fixed, so the search does not depend on ``--jobs``).
BATCH = 4
REFINE_ROUNDS = 2
MIN_BUDGET_TO_REFINE = 16
#: Random draws of TPE before it models the results.
STARTUP_TRIALS = 8
CACHE_KIND = "falsify-cases"
ENTRY_FORMAT = 1
#: Truth events after which a violation is the road's fault, not the observer's.
EXCLUDING_EVENTS = ("spun out", "rolled over", "left the road")
#: Points of the worst case's truth-vs-bounds plot kept per candidate.
PLOT_POINTS = 500
DEFAULT_SCENARIO = "step_steer"


class FalsifyError(InputError):
    """A ``roadtruth falsify`` option is invalid."""


@dataclass(frozen=True)
class FalsifyTask:
    """One candidate to evaluate (picklable: sent to worker processes and Dask workers)."""

    index: int
    phase: str  # "search" or "refine"
    point: dict[str, Any]
    scenario: dict[str, Any]
    vehicle: dict[str, Any] | None
    faults: str | None
    observer: str
    observer_ref: tuple[str, str]  # module, class name: a plug-in registered by the caller works in workers
    prop: Property
    observer_timeout_s: float | None = None


@dataclass(frozen=True)
class CaseResult:
    index: int
    robustness: float
    truth_status: str
    observer_status: str
    counted: bool  # a violation here is the observer's (truth ok, observer ran)
    plot: dict[str, list[float | None]] = field(default_factory=dict)
    seconds: float = 0.0
    traceback: str | None = None

    @property
    def violated(self) -> bool:
        return self.counted and math.isfinite(self.robustness) and self.robustness < 0.0

    def told(self) -> float:
        """The value the sampler learns (excluded cases are neutral: never better than a pass)."""
        r = self.robustness if math.isfinite(self.robustness) else 0.0
        return r if self.counted else max(r, 0.0)

    def to_entry(self) -> dict[str, Any]:
        return {"format": ENTRY_FORMAT, "robustness": _json_float(self.robustness),
                "truth_status": self.truth_status, "observer_status": self.observer_status,
                "counted": self.counted, "plot": self.plot}


def _json_float(x: float) -> float | str:
    return x if math.isfinite(x) else repr(float(x))


def _from_entry(index: int, e: dict[str, Any]) -> CaseResult:
    r = e["robustness"]
    return CaseResult(index, float(r), str(e["truth_status"]), str(e["observer_status"]), bool(e["counted"]),
                      dict(e["plot"]))


# ---- one candidate -------------------------------------------------------------------------------

def _ensure_registered(name: str, ref: tuple[str, str]) -> None:
    import importlib

    from roadtruth.observers.registry import available_observers, register

    if name not in available_observers():
        obj: Any = importlib.import_module(ref[0])
        for part in ref[1].split("."):
            obj = getattr(obj, part)
        register(obj)


def _plot_series(truth: pd.DataFrame, est: pd.DataFrame, state: str | None, until: float | None) -> dict[str, Any]:
    """Truth, estimate and bounds of one state on the truth time base, thinned to ``PLOT_POINTS``."""
    from roadtruth.harness.evaluation.scoring import align

    if state is None or state not in truth or est.empty:
        return {}
    rows = est[est["state"] == state]
    if rows.empty:
        return {}
    a = align(truth["t_s"].to_numpy(float), truth[state].to_numpy(float), rows, state, math.nan)
    step = max(1, int(math.ceil(a.t_s.size / PLOT_POINTS)))
    pick = np.arange(0, a.t_s.size, step)

    def col(x: np.ndarray) -> list[float | None]:
        return [float(f"{v:.6g}") if math.isfinite(v) else None for v in x[pick]]

    return {"state": [state], "t_s": col(a.t_s), "truth": col(a.truth), "value": col(a.value),
            "lo": col(a.lo), "hi": col(a.hi), "scored_until_s": [until]}


def _plot_state(prop: Property, est: pd.DataFrame) -> str | None:
    if prop.state:
        return prop.state
    column = "lo" if prop.kind == "coverage" else "var" if prop.kind == "nees" else "value"
    have = est.dropna(subset=[column]) if column in est and not est.empty else est.iloc[0:0]
    states = sorted(set(have["state"]))
    return "beta_rad" if "beta_rad" in states else (states[0] if states else None)


def evaluate_case(task: FalsifyTask) -> CaseResult:
    """Simulate, sense, estimate, score and judge one candidate; never raises (a crash becomes an
    ``error: …`` observer status, not a violation)."""
    from roadtruth.harness.evaluation.scoring import score
    from roadtruth.harness.jobs.pipeline import evaluate_scenario, scenario_seeds
    from roadtruth.harness.truth.scenario import parse_scenario
    from roadtruth.harness.truth.truth_events import scored_until_of, status_of

    t0 = time.perf_counter()
    try:
        _ensure_registered(task.observer, task.observer_ref)
        with tempfile.TemporaryDirectory(prefix="roadtruth-falsify-") as tmp:
            data = dict(task.scenario)
            if task.vehicle is not None:
                vpath = Path(tmp) / "vehicle.yaml"
                vpath.write_text(yaml.safe_dump(task.vehicle, sort_keys=False), encoding="utf-8")
                data["vehicle"] = str(vpath)
            sc = parse_scenario(data, f"candidate {task.index}")
            veh = sc.vehicle_params()
            _, sim_seed, sensor_seed = scenario_seeds(sc.seed, sc.name, None)
            st = evaluate_scenario(sc, veh, [task.observer], sim_seed, sensor_seed, faults=task.faults,
                                   observer_timeout_s=task.observer_timeout_s)
        truth_status = status_of(st.truth)
        if st.runs is None:
            status = st.error or f"skipped: simulation {st.truth.status}"
            return CaseResult(task.index, math.nan, truth_status, status, False, seconds=time.perf_counter() - t0,
                              traceback=st.traceback)
        until = scored_until_of(st.truth)
        metrics = score(st.truth.frame, st.estimates, scenario=str(task.scenario.get("name", "")), runs=st.runs,
                        mass_kg=veh.mass_kg, scored_until_s=until)
        mine = metrics[metrics["observer"] == task.observer]
        status = str(mine["status"].iloc[0]) if len(mine) else "error: no rows"
        est = st.estimates[st.estimates["observer"] == task.observer]
        r = robustness(task.prop, st.truth.frame, est, metrics, task.observer, until) if status.startswith("ok") \
            else math.nan
        excluded = any(k in truth_status for k in EXCLUDING_EVENTS)
        plot = _plot_series(st.truth.frame, est, _plot_state(task.prop, est), until)
        return CaseResult(task.index, r, truth_status, status, status.startswith("ok") and not excluded, plot,
                          time.perf_counter() - t0)
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - one broken candidate must not stop the search
        status = f"error: {type(e).__name__}: {e}".splitlines()[0]
        return CaseResult(task.index, math.nan, "error", status, False, seconds=time.perf_counter() - t0,
                          traceback=traceback.format_exc())


# ---- execution -----------------------------------------------------------------------------------

def _run_local(tasks: list[FalsifyTask], pool: Any) -> Iterator[CaseResult]:
    from roadtruth.harness.jobs.worker_pool import WorkerCrashed

    if pool is None:
        for t in tasks:
            yield evaluate_case(t)
        return
    futures = {pool.submit(t): t for t in tasks}
    for fut in as_completed(futures):
        try:
            yield fut.result()
        except WorkerCrashed as crash:
            t = futures[fut]
            yield CaseResult(t.index, math.nan, "error", f"error: {crash}", False, traceback=str(crash))


def _dask_client(address: str, jobs: int) -> tuple[Any, Any]:
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise FalsifyError("--dask needs the dask and distributed packages", field="--dask") from None
    if address == "local":
        cluster = LocalCluster(n_workers=max(1, jobs), threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None)
        return Client(cluster), cluster
    try:
        return Client(address, timeout=30), None
    except (OSError, TimeoutError, ValueError) as e:
        raise FalsifyError(f"cannot connect to Dask scheduler {address!r} ({e})", field="--dask") from None


def _run_dask(tasks: list[FalsifyTask], client: Any) -> Iterator[CaseResult]:
    from distributed import as_completed as dask_completed

    for fut in dask_completed(client.map(evaluate_case, tasks, pure=False)):
        yield fut.result()


# ---- the cache -----------------------------------------------------------------------------------

class _Cache:
    def __init__(self, observer: str, prop: Property, timeout: float | None) -> None:
        from roadtruth.harness.jobs.stress_cache import _observer_source, code_fingerprint
        from roadtruth.harness.report.rundata import versions

        try:
            obs = _observer_source(observer)
        except Exception:  # noqa: BLE001 - an observer without readable source: no caching
            obs = None
        self.base = None if obs is None else {
            "format": ENTRY_FORMAT, "code": code_fingerprint(), "versions": versions(), "observer": [observer, obs],
            "property": [prop.kind, prop.state, _json_float(prop.threshold), prop.rules,
                         Path(prop.rules).read_text(encoding="utf-8") if prop.rules else None],
            "timeout": timeout}

    def key(self, t: FalsifyTask) -> str | None:
        from roadtruth.harness.jobs.stress_cache import Uncacheable, content_digest

        if self.base is None:
            return None
        try:
            return content_digest({**self.base, "scenario": t.scenario, "vehicle": t.vehicle, "faults": t.faults})
        except Uncacheable:
            return None

    def load(self, t: FalsifyTask) -> CaseResult | None:
        from roadtruth.harness.files.disk_cache import cache_folder, read_entry

        k = self.key(t)
        e = read_entry(cache_folder(CACHE_KIND), k) if k else None
        if not isinstance(e, dict) or e.get("format") != ENTRY_FORMAT:
            return None
        try:
            return _from_entry(t.index, e)
        except (KeyError, TypeError, ValueError):
            return None

    def store(self, t: FalsifyTask, r: CaseResult) -> None:
        from roadtruth.harness.files.disk_cache import cache_folder, write_entry

        k = self.key(t)
        if k and r.traceback is None and not r.observer_status.startswith("error"):
            write_entry(cache_folder(CACHE_KIND), k, r.to_entry())


# ---- the search ----------------------------------------------------------------------------------

@dataclass
class _Search:
    space: Space
    base_data: dict[str, Any]
    vehicle_data: dict[str, Any]
    base: Any
    observer: str
    ref: tuple[str, str]
    prop: Property
    timeout: float | None
    cache: _Cache
    runner: Any  # callable(list[FalsifyTask]) -> Iterator[CaseResult]
    bar: Progress
    tasks: list[FalsifyTask] = field(default_factory=list)
    results: dict[int, CaseResult] = field(default_factory=dict)
    n_computed: int = 0

    def task(self, point: dict[str, Any], phase: str) -> FalsifyTask:
        c = build_candidate(self.base_data, self.vehicle_data, self.base, point)
        return FalsifyTask(len(self.tasks), phase, point, c.scenario, c.vehicle, c.faults, self.observer,
                           self.ref, self.prop, self.timeout)

    def evaluate(self, points: list[dict[str, Any]], phase: str) -> list[CaseResult]:
        batch = []
        for p in points:
            t = self.task(p, phase)
            self.tasks.append(t)
            batch.append(t)
        todo = []
        for t in batch:
            hit = self.cache.load(t)
            if hit is not None:
                self.results[t.index] = hit
            else:
                todo.append(t)
        for r in self.runner(todo) if todo else ():
            self.results[r.index] = r
            self.cache.store(self.tasks[r.index], r)
            self.n_computed += 1
            self.bar.item(f"case {r.index}: robustness {r.robustness:.4g} ({r.observer_status}; truth "
                          f"{r.truth_status}), {r.seconds:.1f} s")
        return [self.results[t.index] for t in batch]


def _suggest(trial: Any, space: Space) -> dict[str, Any]:
    point: dict[str, Any] = {}
    for p in space.searched:
        point[p.name] = trial.suggest_categorical(p.name, list(p.choices)) if p.categorical else \
            trial.suggest_float(p.name, p.low, p.high)
    return {**point, **space.fixed_values()}


def _search(s: _Search, budget: int, seed: int) -> None:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    sampler = optuna.samplers.TPESampler(seed=seed, n_startup_trials=STARTUP_TRIALS, constant_liar=True)
    study = optuna.create_study(direction="minimize", sampler=sampler)
    nominal = s.space.nominal_point()
    if nominal is not None:
        study.enqueue_trial({p.name: nominal[p.name] for p in s.space.searched})
    refine = REFINE_ROUNDS * BATCH if budget >= MIN_BUDGET_TO_REFINE else 0
    while len(s.tasks) < budget:
        room = budget - len(s.tasks)
        if refine and room <= refine and any(r.violated for r in s.results.values()):
            _refine(s, room)
            return
        trials = [study.ask() for _ in range(min(BATCH, room))]
        results = s.evaluate([_suggest(t, s.space) for t in trials], "search")
        for t, r in zip(trials, results, strict=True):
            study.tell(t, r.told())


def _closest_violation(s: _Search) -> FalsifyTask | None:
    bad = [s.tasks[i] for i, r in sorted(s.results.items()) if r.violated]
    return min(bad, key=lambda t: (s.space.distance(t.point), t.index)) if bad else None


def _refine(s: _Search, room: int) -> None:
    """Section the segment nominal → closest violation; ``lam`` = 1 is the violating end."""
    target = _closest_violation(s)
    if target is None:
        return
    ends = {p.name: p.nominal for p in s.space.searched if p.nominal is not None and not p.categorical}
    lo, hi = 0.0, 1.0
    while room > 0:
        n = min(BATCH, room)
        lams = [lo + (hi - lo) * (k + 1) / (n + 1) for k in range(n)]
        points = []
        for lam in lams:
            p = dict(target.point)
            for name, nom in ends.items():
                p[name] = float(nom) + lam * (float(target.point[name]) - float(nom))
            points.append(p)
        results = s.evaluate(points, "refine")
        room -= n
        first_bad = next((k for k, r in enumerate(results) if r.violated), None)
        if first_bad is None:
            lo = lams[-1]
        else:
            hi = lams[first_bad]
            lo = lams[first_bad - 1] if first_bad > 0 else lo


# ---- the command ---------------------------------------------------------------------------------

def _observer_ref(name: str) -> tuple[str, str]:
    from roadtruth.observers.registry import observer_class

    cls = observer_class(name)
    return cls.__module__, cls.__qualname__


def run_falsify(*, observer: str, prop: str, scenario: str | None = None, space: str | Path | None = None,
                budget: int = 40, jobs: int = 1, dask: str | None = None, seed: int = 0,
                out: Path = Path("reports/falsify"), progress: bool | None = None,
                observer_timeout_s: float | None = None) -> Path:
    """Search for the case that breaks ``prop`` for ``observer`` and write the output folder.

    Parameters
    ----------
    observer : a registered observer name.
    prop : the ``--property`` text (:func:`roadtruth.harness.jobs.falsify_property.parse_property`).
    scenario : base scenario (a shipped name or a YAML path); default ``DEFAULT_SCENARIO``.
    space : a space YAML (:func:`roadtruth.harness.jobs.falsify_space.load_space`); default: :func:`default_space`.
    budget : candidates evaluated in all (>= 1), the nominal and the refinement included.
    jobs : local worker processes (or Dask workers with ``dask="local"``); the result does not depend on it.
    dask : None, ``"local"`` or a scheduler address (as ``roadtruth stress --dask``).
    seed : seeds the sampler; the same seed gives the same files.
    out : output folder.
    observer_timeout_s : wall-time budget of the observer per candidate [s].

    Raises
    ------
    InputError
        Bad observer, property, scenario, space, budget, jobs or output folder (before any work).
    """
    from roadtruth.harness.evaluation.estimate import check_observer_timeout
    from roadtruth.harness.files.strict_yaml import load_mapping
    from roadtruth.harness.jobs.pipeline import _resolve
    from roadtruth.harness.report.falsify_page import write_outputs
    from roadtruth.harness.truth.scenario import load_scenario
    from roadtruth.harness.truth.vehicle import vehicles_dir

    t_wall = time.perf_counter()
    if not 1 <= int(budget) <= 100_000:
        raise FalsifyError(f"must be in [1, 100000] (got {budget})", field="--budget")
    if jobs < 1:
        raise FalsifyError(f"must be >= 1 (got {jobs})", field="--jobs")
    if int(seed) < 0:
        raise FalsifyError(f"must be >= 0 (got {seed})", field="--seed")
    check_observer_timeout(observer_timeout_s)
    name = scenario or DEFAULT_SCENARIO
    _resolve([name], "default", [observer], None, None, None, None)
    the_prop = parse_property(prop)
    check_fits(the_prop, observer)
    base = load_scenario(name)
    base_data = load_mapping(base.path)
    base_data["vehicle"] = base.vehicle  # a resolved name or path, valid wherever the candidate is parsed
    vpath = Path(base.vehicle) if Path(base.vehicle).suffix.lower() in (".yaml", ".yml") else \
        vehicles_dir() / f"{base.vehicle}.yaml"
    vehicle_data = load_mapping(vpath)
    the_space = load_space(space) if space else default_space(base)
    ref = _observer_ref(observer)
    # Every corner of the space must build a valid scenario and sensor suite before any work starts.
    _check_corners(the_space, base_data, vehicle_data, base)
    out = Path(out)
    bar = Progress(int(budget), progress, desc="roadtruth falsify")
    client = cluster = pool = None
    try:
        with atomic_output_dir(out, command="falsify",
                               inputs=[scenario, str(space) if space else None, the_prop.rules]) as tmp:
            if dask:
                client, cluster = _dask_client(dask, jobs)
                def runner(ts: list[FalsifyTask]) -> Iterator[CaseResult]:
                    return _run_dask(ts, client)
            else:
                if jobs > 1:
                    from roadtruth.harness.jobs.pipeline import process_pool

                    pool = process_pool(evaluate_case, jobs).__enter__()
                def runner(ts: list[FalsifyTask]) -> Iterator[CaseResult]:
                    return _run_local(ts, pool)
            s = _Search(the_space, base_data, vehicle_data, base, observer, ref, the_prop, observer_timeout_s,
                        _Cache(observer, the_prop, observer_timeout_s), runner, bar)
            _search(s, int(budget), int(seed))
            if s.n_computed < len(s.tasks):
                bar.note(f"{len(s.tasks) - s.n_computed} of {len(s.tasks)} cases loaded from the case cache")
            write_outputs(tmp, s, {"observer": observer, "property": the_prop.text, "scenario": base.name,
                                   "budget": int(budget), "seed": int(seed)})
            from roadtruth.harness.report.rundata import write_json

            write_json({"command": "falsify", "n_cases": len(s.tasks), "n_computed": s.n_computed,
                        "n_cached": len(s.tasks) - s.n_computed, "wall_s": round(time.perf_counter() - t_wall, 3)},
                       tmp / "timings.json")
    finally:
        bar.close()
        if pool is not None:
            pool.__exit__(None, None, None)
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    bar.note(f"wrote {out.resolve()}: {len(s.tasks)} cases ({len(s.tasks) - s.n_computed} from the case cache) "
             f"in {time.perf_counter() - t_wall:.1f} s")
    return out.resolve()


def _check_corners(space: Space, base_data: dict[str, Any], vehicle_data: dict[str, Any], base: Any) -> None:
    """Build the low and the high corner of the space (first choices) and validate them fully."""
    from roadtruth.harness.jobs.pipeline import sensor_config
    from roadtruth.harness.truth.scenario import parse_scenario
    from roadtruth.harness.truth.vehicle import parse_vehicle

    for end in ("low", "high"):
        point = {p.name: (p.choices[0] if p.categorical else getattr(p, end)) for p in space.searched}
        point.update(space.fixed_values())
        c = build_candidate(base_data, vehicle_data, base, point)
        data = dict(c.scenario)
        if c.vehicle is not None:
            parse_vehicle(c.vehicle, f"{space.source} ({end} corner)")
            data["vehicle"] = base.vehicle
        sc = parse_scenario(data, f"{space.source} ({end} corner)")
        sensor_config(sc, None, c.faults)


__all__ = ["BATCH", "CaseResult", "FalsifyError", "FalsifyTask", "evaluate_case", "run_falsify"]
