"""Filling the design cache, and numba's, before the work that needs them starts.

Why: on a fresh install every observer's LMI design is solved (or read from the shipped designs and
re-certified) and every compiled kernel is built by numba on first use: 70-90 s of CPU for the
default suite, and most of it in the first scenario. Two things go wrong if nothing is done about it:

* parallel workers that start together all need the same designs and kernels at the same moment,
  and each would solve and compile them again, writing the same cache entries;
* a serial run compiles one observer after the other in its one observer host while the second
  core waits.

So, once per code version and cache (a record in the ``design-warmups`` cache folder, see
:func:`warmup_key`), every observer is designed and run on a two-sample input by a pool of observer
hosts working through the list together (:func:`solve_designs`): in one worker before the others
take their first task (:func:`presolve_designs`), or, in a serial run, beside the first scenario's
simulation (:class:`BackgroundWarmup`). The observers' real runs then load their kernels from
numba's on-disk cache and their designs from the design cache. Results never depend on the
warm-up: designs are keyed by their content and a kernel compiles to the same code wherever it is
compiled. A record outlives a cache emptied by hand (numba's ``__pycache__`` files, a design
deleted): then the kernels compile where they are first used, as without the warm-up.
"""

from __future__ import annotations

import functools
import hashlib
import os
import threading
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from roadtruth.harness.files.disk_cache import cache_folder, canonical_json, read_entry, write_entry

#: Sub-folder of warm-up records: "these designs and kernels were put in this cache by this code".
WARMUP_KIND = "design-warmups"


@dataclass(frozen=True)
class DesignWarmup:
    """The designs a set of tasks will need (picklable: sent to a worker).

    ``scenarios``: ``(scenario, vehicle override or None, friction override or None)`` per task,
    resolved to vehicles where the warm-up runs; ``observers``: observer names; ``options``: observer
    -> {option: value}, as the tasks pass them (options change a design, hence its key).
    """

    scenarios: tuple[tuple[str, str | None, str | None], ...]
    observers: tuple[str, ...]
    options: tuple[tuple[str, tuple[tuple[str, Any], ...]], ...] = ()
    #: Budget of each observer's design [s]: the tasks' own, else the least a task has by default
    #: (a design cut short here is solved again by its task, with the task's budget).
    timeout_s: float = 60.0

    @classmethod
    def of(cls, scenarios: Iterable[tuple[str, str | None, str | None]], observers: Iterable[str],
           options: Mapping[str, Mapping[str, Any]] | None = None, timeout_s: float | None = None) -> DesignWarmup:
        opts = tuple(sorted((o, tuple(sorted(dict(v).items()))) for o, v in (options or {}).items() if v))
        return cls(tuple(dict.fromkeys(scenarios)), tuple(dict.fromkeys(observers)), opts,
                   60.0 if timeout_s is None else float(timeout_s))


def solve_designs(warmup: DesignWarmup, hosts: int = 1) -> int:
    """Design every observer of ``warmup`` for every distinct vehicle, with ``hosts`` observer hosts
    working through the list at the same time; returns how many (vehicle, observer) designs were
    requested.

    Each observer is designed and run on a two-sample input in an observer host
    (:func:`roadtruth.harness.evaluation.observer_host.run_isolated`), so a design that crashes or
    hangs is contained and timed out exactly as in a task, and its kernels are compiled (into
    numba's on-disk cache) as its real run will call them. The hosts keep the designs in memory for
    this process's later tasks; the caches on disk serve every other process. Whatever fails here is
    ignored: the tasks meet the same failure and report it.

    The hosts are started from the calling thread (:func:`~roadtruth.harness.evaluation.observer_host.prestart`);
    a caller that runs this in a thread of its own starts them first, from its main thread.
    """
    import pandas as pd

    from roadtruth.harness.evaluation import observer_host
    from roadtruth.harness.evaluation.estimate import measurement_times, observer_inputs
    from roadtruth.harness.jobs.pipeline import prepare_scenario
    from roadtruth.observers.registry import observer_class

    options = {o: dict(v) for o, v in warmup.options}
    vehicles: dict[str, Any] = {}
    for name, vehicle, friction in warmup.scenarios:
        try:
            v = prepare_scenario(name, vehicle, friction).vehicle_params()
        except Exception:  # noqa: BLE001 - a scenario that fails to load fails in its task
            continue
        vehicles.setdefault(repr(v), v)  # the full parameters: a design depends on all of them

    def design(v: Any, o: str) -> None:
        try:
            cls = observer_class(o)
        except Exception:  # noqa: BLE001
            return
        # Made as a task makes its inputs, so that the kernels compiled here are the ones it calls.
        frame = pd.DataFrame({"t_s": [0.0, 0.001], **{c: [0.0, 0.0] for c in cls.inputs}})
        observer_host.run_isolated(cls, v, options.get(o, {}), measurement_times(frame),
                                   observer_inputs(frame, cls.inputs), warmup.timeout_s)

    pairs = [(v, o) for v in vehicles.values() for o in warmup.observers]
    # The variants of a family share its kernels: warmed by one host, one after the other, the
    # first compiles them and the others load them, where two hosts would compile them side by side.
    families: dict[str, list[tuple[Any, str]]] = {}
    for v, o in pairs:
        families.setdefault(_family(o), []).append((v, o))
    hosts = max(1, min(hosts, len(families)))
    observer_host.prestart(hosts)
    if hosts == 1:
        for v, o in pairs:
            design(v, o)
        return len(pairs)
    # A shared queue, not a fixed split: one family compiles in 0.1 s, another in 15 s.
    queue: Iterator[list[tuple[Any, str]]] = iter(families.values())
    lock = threading.Lock()

    def drain() -> None:
        while True:
            with lock:
                family = next(queue, None)
            if family is None:
                return
            for pair in family:
                design(*pair)

    # Daemon threads (not a ThreadPoolExecutor, whose threads the interpreter joins at exit): after
    # Ctrl-C the command ends now, and the hosts, whose parent then dies, end with it.
    threads = [threading.Thread(target=drain, name=f"roadtruth-warmup-{k}", daemon=True) for k in range(hosts)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    return len(pairs)


def _family(observer: str) -> str:
    """The module of an observer's class (its family file), or its name if it does not load."""
    from roadtruth.observers.registry import observer_class

    try:
        return observer_class(observer).__module__
    except Exception:  # noqa: BLE001 - it fails in its task
        return observer


def warmup_key(warmup: DesignWarmup) -> str:
    """Hash of the warm-up, of every file of the installed roadtruth packages (scenarios, vehicles,
    observer code: anything a design or a kernel depends on), of whether shipped designs are read
    and of where numba keeps its cache."""
    from roadtruth.harness.jobs.stress_cache import code_fingerprint

    text = canonical_json({"warmup": repr(warmup), "code": code_fingerprint(),
                           "shipped": os.environ.get("ROADTRUTH_SHIPPED_DESIGNS", ""),
                           "numba_cache": os.environ.get("NUMBA_CACHE_DIR", "")})
    return hashlib.sha256(text.encode()).hexdigest()


def warmup_needed(warmup: DesignWarmup) -> str | None:
    """None if this cache was warmed for ``warmup`` by this code (or there is nothing to warm), else
    the key under which to record the warm-up once it is done."""
    if not warmup.observers or not warmup.scenarios:
        return None
    key = warmup_key(warmup)
    return None if read_entry(cache_folder(WARMUP_KIND), key) is not None else key


def record_warmup(key: str, designs: int) -> None:
    write_entry(cache_folder(WARMUP_KIND), key, {"designs": designs})


def presolve_designs(submit: Callable[[Callable[[Any], Any], Any], Any], warmup: DesignWarmup, hosts: int = 1) -> None:
    """Run :func:`solve_designs` with ``hosts`` observer hosts through ``submit(fn, arg) -> future``
    (``WorkerPool.submit_call``, ``distributed.Client.submit``: in one worker) and wait for it; a
    failure (even a crashed worker) is ignored.

    The warm-up holds every worker back until it is done, so it runs only when this cache has not
    been warmed for the same warm-up by the same code (:func:`warmup_needed`). ``hosts``: the number of
    workers, whose cores would otherwise wait.
    """
    key = warmup_needed(warmup)
    if key is None:
        return
    try:
        n = submit(functools.partial(solve_designs, hosts=hosts), warmup).result()
    except Exception:  # noqa: BLE001 - the tasks design for themselves then, as without the warm-up
        return
    record_warmup(key, n)


class BackgroundWarmup:
    """:func:`solve_designs` in a thread of this process, with ``hosts`` observer hosts: a serial run
    starts it before its first scenario, simulates meanwhile, and calls :meth:`wait` before its
    first observer runs (else that observer would compile the kernels the warm-up is compiling).

    :meth:`start` returns None when this cache is already warm (:func:`warmup_needed`): then nothing runs.
    """

    def __init__(self, warmup: DesignWarmup, key: str, hosts: int) -> None:
        self._warmup, self._key, self._hosts = warmup, key, hosts
        self._designs: int | None = None
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, name="roadtruth-warmup", daemon=True)

    @classmethod
    def start(cls, warmup: DesignWarmup, hosts: int = 2) -> BackgroundWarmup | None:
        key = warmup_needed(warmup)
        if key is None:
            return None
        from roadtruth.harness.evaluation import observer_host
        from roadtruth.harness.jobs.warm_start import set_up_numba

        set_up_numba()  # before the hosts fork, so that they inherit it
        observer_host.prestart(hosts)  # from this (main) thread: see solve_designs
        warm = cls(warmup, key, hosts)
        warm._thread.start()
        return warm

    def _run(self) -> None:
        try:
            self._designs = solve_designs(self._warmup, self._hosts)
        except Exception:  # noqa: BLE001 - the tasks design and compile for themselves then
            self._designs = None
        finally:
            self._done.set()

    def wait(self) -> None:
        """Block until the warm-up is done (at once if it is); the first call records it."""
        self._done.wait()
        if self._designs is not None and self._key:
            record_warmup(self._key, self._designs)
            self._key = ""


__all__ = ["WARMUP_KIND", "BackgroundWarmup", "DesignWarmup", "presolve_designs", "record_warmup",
           "solve_designs", "warmup_needed", "warmup_key"]
