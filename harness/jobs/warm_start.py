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

import contextlib
import gc
import importlib
import os
import sys
import warnings
from collections.abc import Iterator, Mapping

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


def leave_without_teardown() -> None:
    """Make this process (a workers' forkserver) end at interpreter shutdown without the teardown.

    A forkserver exits when the command that started it has exited, and then spends about 0.1 s
    freeing the modules it imported one by one (numba, llvmlite, pandas, MuJoCo). It holds the
    command's stdout and stderr, so anything reading them to the end (a pipe into ``tee``, a
    caller capturing the output) waits that long after the command is done. The exit handler
    registered here runs before the modules are torn down; it flushes stdout and stderr and leaves
    with the exit status 0 the forkserver ends with. Only in this process: the children it forks
    inherit the handler but leave with ``os._exit`` themselves, and the handler checks the pid.
    """
    import atexit

    pid = os.getpid()

    def leave() -> None:
        if os.getpid() != pid:
            return
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(0)

    atexit.register(leave)


#: The variables OpenBLAS (bundled with NumPy's and SciPy's wheels, one copy each) reads its thread
#: count from when it loads, in the order it reads them.
BLAS_THREAD_VARIABLES: tuple[str, ...] = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")


def one_blas_thread(environ: dict[str, str] | None = None) -> dict[str, str]:
    """``environ`` (default: a copy of ``os.environ``) with ``OPENBLAS_NUM_THREADS=1`` unless one of
    :data:`BLAS_THREAD_VARIABLES` is set already (the user's choice is kept).

    The processes of a run work in parallel already, one per core: a scenario or sweep worker and its
    observer host each, and each loads two OpenBLAS copies (NumPy's and SciPy's, the one numba calls).
    With their default, each copy keeps a thread per extra core that spins for a while after every
    call, on the cores the other workers need; the matrices here are a few rows, far below the size
    where a second BLAS thread pays. Read when OpenBLAS loads: set it before NumPy is imported.
    """
    env = dict(os.environ if environ is None else environ)
    if not any(env.get(name, "").strip() for name in BLAS_THREAD_VARIABLES):
        env[BLAS_THREAD_VARIABLES[0]] = "1"
    return env


#: The BLAS and LAPACK modules numba binds its linear algebra to (imported when numba starts).
NUMBA_BLAS_MODULES: tuple[str, ...] = ("scipy.linalg.cython_blas", "scipy.linalg.cython_lapack")


def load_numba_blas() -> None:
    """Load the two SciPy extension modules numba takes BLAS and LAPACK from, without the rest of
    ``scipy.linalg``.

    Numba imports ``scipy.linalg.cython_blas`` when it starts (to know whether ``np.dot`` can
    work), and Python runs ``scipy/linalg/__init__.py`` first: all of ``scipy.linalg`` and SciPy's
    array-API layer, 0.15-0.24 s, for two modules that need none of it (they link BLAS directly).
    Loaded here from their own files, numba finds them imported; a later ``import scipy.linalg``
    still runs the package as usual and finds the same two modules. Call before numba is imported;
    a no-op once ``scipy.linalg`` is imported, and wherever SciPy is laid out otherwise (numba then
    imports what it always did).
    """
    import importlib.machinery
    import importlib.util

    if "scipy.linalg" in sys.modules or all(name in sys.modules for name in NUMBA_BLAS_MODULES):
        return
    try:
        package = importlib.util.find_spec("scipy.linalg")
        places = package.submodule_search_locations if package is not None else None
        if not places:
            return
        for name in NUMBA_BLAS_MODULES:
            if name in sys.modules:
                continue
            spec = importlib.machinery.PathFinder.find_spec(name, list(places))
            if spec is None or spec.loader is None:
                return
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            try:
                spec.loader.exec_module(module)
            except BaseException:
                del sys.modules[name]
                raise
    except Exception:  # noqa: BLE001 - numba's own import then loads them the usual way
        return


def set_up_numba() -> None:
    """Call one tiny cached kernel: numba sets up its target context (the registries of every
    supported numpy function, 0.8-1.2 s) on the first call of any kernel in a process, cached or not."""
    from roadtruth.harness.jobs.target_kernel import one_more

    one_more(1.0)


def import_observers() -> None:
    """Import every observer, plug-ins included (the caller reports any plug-in that fails to load)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from roadtruth.observers.registry import available_observers

        available_observers()


def warm_process(*, freeze: bool = True) -> None:
    """Import :data:`HEAVY_MODULES` and every observer, set numba up, then (``freeze``) move what the
    imports left out of garbage collection's reach (``gc.freeze``: children inherit it, and a full
    collection, 0.1-0.7 s over those 150 000-200 000 tracked objects, never walks them again).

    A module that fails to import is skipped: the worker that needs it imports it again and reports
    the failure where it belongs, with its task.
    """
    with collection_paused(freeze=freeze):
        _import_and_freeze(HEAVY_MODULES, freeze=False)  # numba's BLAS first, then the imports
        try:
            import_observers()
        except Exception:  # noqa: BLE001 - the observer's own request reports it
            pass
        set_up_numba()


@contextlib.contextmanager
def collection_paused(*, freeze: bool = False) -> Iterator[None]:
    """Garbage collection off for the block (as it was before, after it), then (``freeze``) what the
    block made moved out of its reach (``gc.freeze``, before collection resumes: the first collection
    after a pause would otherwise walk everything the block made).

    Imports make objects that live as long as the process: collecting while they are made only walks
    them again and again (three full collections, 0.15-0.25 s, over a worker's imports). Nor are
    they collected before the freeze: after a worker's imports, its observers and numba's set-up, a
    full collection (0.1 s) finds about 10 unreachable objects among 176 000.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if freeze:
            gc.freeze()
        if was_enabled:
            gc.enable()


def _import_and_freeze(modules: tuple[str, ...], *, freeze: bool) -> None:
    """Import ``modules`` (one that fails is skipped: the task that needs it imports it again and
    reports the failure where it belongs) with garbage collection paused, then (``freeze``) ``gc.freeze``."""
    load_numba_blas()
    with collection_paused(freeze=freeze):
        for name in modules:
            try:
                importlib.import_module(name)
            except Exception:  # noqa: BLE001, S112 - reported by the task that needs the module
                continue


#: What a render worker imports (:func:`roadtruth.harness.jobs.pipeline.render_job`).
RENDER_MODULES: tuple[str, ...] = ("numpy", "pandas", "mujoco", "cv2", "imageio_ffmpeg",
                                   "roadtruth.harness.report.render", "roadtruth.harness.jobs.pipeline")


def warm_renderer(*, freeze: bool = True) -> None:
    """Import :data:`RENDER_MODULES` (a module that fails is left for the render to report), then
    (``freeze``) ``gc.freeze`` as :func:`warm_process` does. No GL context is made."""
    _import_and_freeze(RENDER_MODULES, freeze=freeze)
