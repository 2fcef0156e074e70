"""What a process that runs scenarios or observers pays once, done ahead so its children inherit it.

A worker or observer host started from a fresh interpreter imports numpy, pandas, MuJoCo, numba,
every observer and the harness (1.5-2 s of CPU), and the first numba kernel it calls sets up numba's
target context (another 0.8-1.2 s, even when every kernel comes from the on-disk cache). On two
cores, with a worker and an observer host per core, that start-up is most of what ``--jobs 2`` loses.
So it is paid once, in a process that only forks children:

* the multiprocessing forkserver of the worker pools imports :mod:`roadtruth.harness.jobs.forkserver_preload`
  (which calls :func:`warm_process`) before it forks any worker, so workers start with all of it done;
* an observer host is forked from the process that asks for it when that is safe (see
  :func:`roadtruth.harness.evaluation.host_fork.fork_is_safe`), so a worker's host inherits the same.

Nothing here creates an OpenGL context (a process that made one hangs its forked children when they
render): MuJoCo is imported, never rendered with.
"""

from __future__ import annotations

import gc
import importlib
import os
import sys
import warnings
from collections.abc import Mapping

#: Modules a scenario or sweep worker and an observer host import (the costly part of their start-up).
#: Not cvxpy (1.1 s): observers import it only to solve a design, which the design cache makes rare.
HEAVY_MODULES: tuple[str, ...] = (
    "numpy", "pandas", "mujoco", "numba",
    "roadtruth.harness.jobs.pipeline", "roadtruth.harness.jobs.stress",
    "roadtruth.harness.truth.simulate", "roadtruth.harness.sensors",
    "roadtruth.harness.evaluation.estimate", "roadtruth.harness.evaluation.scoring",
    "roadtruth.harness.evaluation.observer_host", "roadtruth.observers.registry",
)


#: Environment variables read while a process starts or imports (the site module, numba, MuJoCo).
_STARTUP_PREFIXES = ("PYTHON", "NUMBA_", "MUJOCO_")


def startup_environment(environ: Mapping[str, str] | None = None) -> tuple[object, ...]:
    """What a fresh interpreter's imports depend on besides the files: the interpreter and the
    ``PYTHON*``, ``NUMBA_*``, ``MUJOCO_*`` variables (e.g. a ``PYTHONPATH`` with a ``sitecustomize``).

    A process warmed under one start-up environment and forked after it changed would give its child
    what it imported then, not what a fresh interpreter would import now; callers compare this.
    """
    env = os.environ if environ is None else environ
    return (sys.executable, tuple(sorted((k, v) for k, v in env.items() if k.startswith(_STARTUP_PREFIXES))))


def _one_more(x: float) -> float:
    return x + 1.0


#: ``_one_more`` compiled (on first use: importing this module must not import numba).
_compiled: list = []


def set_up_numba() -> None:
    """Call one tiny cached kernel: numba sets up its target context (the registries of every
    supported numpy function, 0.8-1.2 s) on the first call of any kernel in a process, cached or not."""
    if not _compiled:
        from numba import njit

        _compiled.append(njit(cache=True)(_one_more))
    _compiled[0](1.0)


def import_observers() -> None:
    """Import every observer, plug-ins included (the caller reports any plug-in that fails to load)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from roadtruth.observers.registry import available_observers

        available_observers()


def warm_process(*, freeze: bool = True) -> None:
    """Import :data:`HEAVY_MODULES` and every observer, set numba up, then (``freeze``) move what the
    imports left out of garbage collection's reach (``gc.freeze``: children inherit it, and a full
    collection, 0.2-0.7 s over those millions of objects, never walks them again).

    A module that fails to import is skipped: the worker that needs it imports it again and reports
    the failure where it belongs, with its task.
    """
    _import_and_freeze(HEAVY_MODULES, freeze=False)
    try:
        import_observers()
    except Exception:  # noqa: BLE001 - the observer's own request reports it
        pass
    set_up_numba()
    if freeze:
        gc.collect()
        gc.freeze()


def _import_and_freeze(modules: tuple[str, ...], *, freeze: bool) -> None:
    """Import ``modules`` (one that fails is skipped: the task that needs it imports it again and
    reports the failure where it belongs), then (``freeze``) ``gc.collect`` and ``gc.freeze``."""
    for name in modules:
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001, S112 - reported by the task that needs the module
            continue
    if freeze:
        gc.collect()
        gc.freeze()


#: What a render worker imports (:func:`roadtruth.harness.jobs.pipeline.render_job`).
RENDER_MODULES: tuple[str, ...] = ("numpy", "pandas", "mujoco", "cv2", "imageio_ffmpeg",
                                   "roadtruth.harness.report.render", "roadtruth.harness.jobs.pipeline")


def warm_renderer(*, freeze: bool = True) -> None:
    """Import :data:`RENDER_MODULES` (a module that fails is left for the render to report), then
    (``freeze``) ``gc.freeze`` as :func:`warm_process` does. No GL context is made."""
    _import_and_freeze(RENDER_MODULES, freeze=freeze)
