"""A Dask worker preload: the start-up a ``roadtruth stress --dask`` worker pays once, paid when
the worker starts instead of inside its first task.

``stress --dask local`` starts its ``LocalCluster`` with this module as the workers' preload; for a
cluster of your own, start each worker with it::

    dask worker tcp://scheduler:8786 --nthreads 1 --preload roadtruth.harness.jobs.dask_setup

Why: a task runs on one of the worker's threads, and a process with threads of its own must not
fork (a lock held by another thread at the fork stays held in the child for ever), so every
observer host a task asks for would be a fresh interpreter that imports and sets numba up again
(~1.3 s of CPU each, more than ten 5-second cases). When Dask runs this module's
:func:`dask_setup`, the worker's main thread is still the only one that is not a daemon, so the host
can be forked there (``roadtruth.harness.evaluation.host_fork.fork_is_safe`` decides); the tasks
then reuse it, and only a host that crashed is replaced by a fresh interpreter.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import Any


def dask_setup(worker: Any = None) -> None:
    """Warm this worker process (imports, every observer, numba's set-up; nearly free in a worker
    forked from a preloaded server) and start one idle observer host, forked when that is safe."""
    from roadtruth.harness.evaluation import observer_host
    from roadtruth.harness.jobs.warm_start import warm_process

    warm_process()
    observer_host.prestart()


def worker_hash_seed() -> str:
    """The ``PYTHONHASHSEED`` a Dask nanny sets for its workers (so that they hash alike): the
    configured one, else the fixed seed distributed itself uses."""
    import dask

    env = {**(dask.config.get("distributed.nanny.pre-spawn-environ", None) or {}),
           **(dask.config.get("distributed.nanny.environ", None) or {})}
    seed = env.get("PYTHONHASHSEED")
    return "6640" if seed in (None, "0", 0) else str(seed)  # distributed.nanny's own choice


@contextlib.contextmanager
def _environment(**values: str) -> Iterator[None]:
    """Set environment variables for the duration of the block (what a child started in it inherits)."""
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def start_local_cluster_server() -> None:
    """Start the forkserver a ``LocalCluster``'s workers fork from (``stress --dask local``), with
    the heavy imports and Dask's worker code preloaded, under the hash seed Dask gives its workers:
    a worker forked from it is what a fresh one would be, so it may fork its observer host.

    Returns at once (the preload runs meanwhile); nothing happens where there is no forkserver.
    Without the ``distributed`` package it does nothing either (the sweep then says what is missing).
    """
    from roadtruth.harness.jobs.worker_pool import DASK_PRELOAD, start_forkserver

    try:
        seed = worker_hash_seed()
    except ImportError:
        return
    with _environment(PYTHONHASHSEED=seed):
        start_forkserver(preload=DASK_PRELOAD)


def local_cluster(n_workers: int) -> Any:
    """A ``distributed.LocalCluster`` of ``n_workers`` one-thread worker processes on loopback, set up
    as ``stress --dask local`` runs it.

    The workers fork from this process's preloaded server (:func:`start_local_cluster_server`)
    instead of starting as fresh interpreters, and each forks its observer host while it is still
    single-threaded (:func:`dask_setup`, the workers' preload). No dashboard is served, so the
    workers' profiler, whose samples only the dashboard shows, is off.
    """
    import dask
    from distributed import LocalCluster

    from roadtruth.harness.jobs.worker_pool import start_method

    start_local_cluster_server()
    settings: dict[str, Any] = {"distributed.worker.profile.enabled": False}
    if start_method() == "forkserver":
        settings["distributed.worker.multiprocessing-method"] = "forkserver"
    with dask.config.set(settings):
        return LocalCluster(n_workers=max(1, n_workers), threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address=None, preload=[__name__])
