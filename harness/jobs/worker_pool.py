"""Supervised worker processes: a crash costs one task, never the run, and no worker outlives the run.

Why not ``concurrent.futures.ProcessPoolExecutor``: when one of its workers dies (a segfault in
compiled code, the out-of-memory killer) it marks the whole pool broken and every pending future
fails with ``BrokenProcessPool``; it cannot say which task killed the worker. Here a worker holds at
most one task at a time, so a worker that dies names its task exactly: that task's future fails
with :class:`WorkerCrashed` (``worker crashed (signal 11)``) and a fresh worker takes the next one.
Holding one task at a time costs nothing here: tasks are whole scenarios, renders or sweep cases
(seconds each) against a dispatch round trip of well under a millisecond.

Process lifetime. :func:`exit_with` makes a process end when the run's main process is gone, even
when the main process was killed with ``kill -9`` and had no chance to clean up:

* on Linux, ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` (through ctypes) kills the process the moment its
  parent dies. A worker's parent is the multiprocessing forkserver, which itself exits as soon as
  the main process is gone, so the signal chains down: main → forkserver → workers → their
  observer hosts. The parent-death signal fires when the parent *thread* that started the child
  ends, so it is only armed for children started from a main thread;
* everywhere, a daemon watchdog thread checks twice a second that the original parent pid is still
  the parent and that the main pid is alive (not a zombie), and ends the process if not (this also
  covers a parent that is not the main process and platforms without ``prctl``).

Workers ignore SIGINT: Ctrl-C is the main process's business (it raises ``KeyboardInterrupt`` there,
the pool is killed on the way out and the run stops).

Workers are never plain-forked from the caller: a process that has made an OpenGL (EGL) context,
e.g. a test session that rendered before, hangs its forked children when they render. On Linux they
fork from the multiprocessing forkserver, which before its first fork imports everything a worker
needs and sets numba up (:mod:`roadtruth.harness.jobs.forkserver_preload`: imports, observers, numba's
target context, ``gc.freeze``; 1.5-3 s of CPU paid once per run instead of once per worker). The
forkserver only forks and never renders, so a worker may still make a GL context after its fork.
Elsewhere workers spawn a fresh interpreter.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any, Generic, TypeVar

from roadtruth.harness.jobs.warm_start import one_blas_thread

T = TypeVar("T")
R = TypeVar("R")

#: How often the watchdog looks at the parent [s]; an orphan ends within about this time.
WATCHDOG_PERIOD_S = 0.5
#: How long a worker gets to exit after being asked to, before it is killed [s].
EXIT_GRACE_S = 5.0
_PR_SET_PDEATHSIG = 1


def start_method() -> str:
    """``forkserver`` on Linux, ``spawn`` elsewhere (never ``fork``, see the module docstring)."""
    return "forkserver" if sys.platform.startswith("linux") else "spawn"


#: What the forkserver imports before its first fork: the caller's ``__main__`` (multiprocessing's
#: default) and the module that warms it (:mod:`roadtruth.harness.jobs.forkserver_preload`).
FORKSERVER_PRELOAD: tuple[str, ...] = ("__main__", "roadtruth.harness.jobs.forkserver_preload")
#: The preload when a run's only workers are renderers (:func:`start_forkserver` ``renders_only``).
RENDER_PRELOAD: tuple[str, ...] = ("__main__", "roadtruth.harness.jobs.render_preload")
#: The preload when the server's children are the workers of a Dask ``LocalCluster`` (``stress
#: --dask local``): everything a scenario worker needs, and Dask's own worker code.
DASK_PRELOAD: tuple[str, ...] = (*FORKSERVER_PRELOAD, "distributed")


def _serves(running: tuple[str, ...], wanted: tuple[str, ...]) -> bool:
    """True if a server started with preload ``running`` gives the children ``wanted`` asks for: it
    preloaded at least that, or it is a full preload and a renderer is asked for."""
    return set(wanted) <= set(running) or (wanted == RENDER_PRELOAD and set(FORKSERVER_PRELOAD) <= set(running))


#: Pools of this process that may still have workers (the forkserver is only restarted when none has).
_live_pools = 0
#: The start-up environment the running forkserver was started under (None: not started by a pool).
_forkserver_started_under: tuple[object, ...] | None = None
#: The preload of the running forkserver (None: not started by a pool).
_forkserver_preload: tuple[str, ...] | None = None
_forkserver_lock = threading.Lock()


def worker_context(preload: tuple[str, ...] = FORKSERVER_PRELOAD) -> multiprocessing.context.BaseContext:
    """The multiprocessing context of the pools; on Linux its forkserver preloads ``preload`` when it
    starts here (default :data:`FORKSERVER_PRELOAD`; a server already running keeps its own).

    The forkserver lives as long as the process and imports once, when it starts. If the start-up
    environment has changed since (``PYTHONPATH``, ``NUMBA_*``, ``MUJOCO_GL``, see
    ``warm_start.startup_environment``), its workers would not hold what a fresh interpreter imports
    now; so it is restarted, but only when no pool of this process has workers (they are its
    children and die with it).
    """
    global _forkserver_started_under, _forkserver_preload
    ctx = multiprocessing.get_context(start_method())
    if start_method() != "forkserver":
        return ctx
    from multiprocessing import forkserver

    from roadtruth.harness.jobs.warm_start import startup_environment

    now = startup_environment()
    server = forkserver._forkserver  # the process's one forkserver; _stop is its documented-for-tests stop
    with _forkserver_lock:
        running = server._forkserver_pid is not None
        # The full preload serves every pool; a renderers-only one lacks what scenario workers need.
        lacking = _forkserver_preload is not None and not _serves(_forkserver_preload, preload)
        if running and (_forkserver_started_under not in (None, now) or lacking) and _live_pools == 0:
            server._stop()
            running = False
        if not running:
            _forkserver_started_under, _forkserver_preload = now, preload
            ctx.set_forkserver_preload(list(preload))  # what the server about to start imports
            with _environment(one_blas_thread()):  # the server's children inherit it; this process keeps its own
                forkserver.ensure_running()
    return ctx


@contextlib.contextmanager
def _environment(env: dict[str, str]) -> Iterator[None]:
    """``os.environ`` is ``env`` for the block (a process started in it inherits it), as before after."""
    before = dict(os.environ)
    os.environ.clear()
    os.environ.update(env)
    try:
        yield
    finally:
        os.environ.clear()
        os.environ.update(before)


def start_forkserver(*, renders_only: bool = False, preload: tuple[str, ...] | None = None) -> None:
    """Start the pools' forkserver now (Linux; elsewhere nothing), so its preload (imports, every
    observer, numba's set-up: ~2.5 s of CPU) runs while the caller is still checking its inputs and
    preparing tasks, instead of holding up the first worker. Returns at once; the first pool uses
    the server started here (restarted only if the start-up environment changes meanwhile).

    ``renders_only``: this process's pools will only render (``run`` without ``--jobs``), so the
    server preloads :data:`RENDER_PRELOAD`, not the observers and numba a renderer never uses. A
    scenario worker forked from it later still works; it imports what it needs itself.
    ``preload``: another preload (e.g. :data:`DASK_PRELOAD`).
    """
    if start_method() != "forkserver":
        return
    from multiprocessing import forkserver

    worker_context(preload or (RENDER_PRELOAD if renders_only else FORKSERVER_PRELOAD))
    forkserver.ensure_running()


class WorkerCrashed(Exception):
    """The worker process holding a task died before answering (its exit code says how)."""

    def __init__(self, exitcode: int | None, what: str = "worker") -> None:
        self.exitcode = exitcode
        self.what = what
        super().__init__(f"{what} crashed ({exit_reason(exitcode)})")


def exit_reason(exitcode: int | None) -> str:
    """``signal 11`` for a negative ``Popen``/``Process`` exit code, ``exit code 3`` otherwise."""
    if exitcode is None:
        return "no exit code"
    if exitcode < 0:
        return f"signal {-exitcode}"
    return f"exit code {exitcode}"


class _RemoteTraceback(Exception):
    """Carries a worker's traceback text as the ``__cause__`` of the exception re-raised here."""

    def __init__(self, text: str) -> None:
        super().__init__(text)

    def __str__(self) -> str:
        return "\n" + str(self.args[0])


# ---- process lifetime ----------------------------------------------------------------------------

def _gone(pid: int) -> bool:
    """True if process ``pid`` no longer runs (absent, or a zombie waiting to be reaped)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            # the state letter follows the parenthesised command name, which may contain spaces
            return f.read().rsplit(b")", 1)[1].split()[0] == b"Z"
    except (OSError, IndexError):
        return False


def _arm_parent_death_signal() -> bool:
    """Ask Linux to SIGKILL this process when its parent dies; False where that is unavailable."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def exit_with(main_pid: int, parent_pid: int | None = None, *, death_signal: bool = True) -> None:
    """End this process (``os._exit``) as soon as ``main_pid`` is gone or the parent changes.

    Parameters
    ----------
    main_pid : the process whose lifetime bounds this one (the run's main process).
    parent_pid : the expected parent (default: the current parent). If the parent is already not
        this pid, the parent died before we got here and the process exits at once.
    death_signal : arm ``PR_SET_PDEATHSIG`` (only valid if the parent started us from its main thread).
    """
    ppid = os.getppid() if parent_pid is None else int(parent_pid)
    if death_signal:
        _arm_parent_death_signal()
    if os.getppid() != ppid or _gone(main_pid):  # the parent died before the signal was armed
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(WATCHDOG_PERIOD_S)
            if os.getppid() != ppid or _gone(main_pid):
                os._exit(1)

    threading.Thread(target=watch, name="roadtruth-parent-watchdog", daemon=True).start()


# ---- the pool ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Call:
    """A task that runs ``fn(arg)`` instead of the pool's function (see :meth:`WorkerPool.submit_call`)."""

    fn: Callable[[Any], Any]
    arg: Any


def _serve(conn: Connection, fn: Callable[[Any], Any], main_pid: int, environ: dict[str, str]) -> None:
    """Worker process: answer ``(True, result, "")`` or ``(False, exception, traceback)`` per task.

    ``environ`` is the caller's environment when the worker was started. A forkserver child inherits
    the environment the *forkserver* had when it started (the first pool of the process), so without
    this a variable set later (``--cache-dir`` sets ``ROADTRUTH_CACHE``) would not reach the worker.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is handled by the main process
    exit_with(main_pid, death_signal=True)  # a worker's main thread runs this
    if environ != dict(os.environ):
        os.environ.clear()
        os.environ.update(environ)
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        try:
            result = task.fn(task.arg) if isinstance(task, _Call) else fn(task)
            reply: tuple[bool, Any, str] = (True, result, "")
        except Exception as exc:  # noqa: BLE001 - re-raised in the caller, like ProcessPoolExecutor
            reply = (False, exc, traceback.format_exc())
        try:
            conn.send(reply)
        except Exception as exc:  # noqa: BLE001 - an unpicklable result must still be answered
            conn.send((False, RuntimeError(f"the worker's answer could not be sent back: {exc!r}"),
                       traceback.format_exc()))


class _Worker:
    def __init__(self, process: multiprocessing.process.BaseProcess, conn: Connection) -> None:
        self.process = process
        self.conn = conn
        self.job: tuple[Future, Any] | None = None


class WorkerPool(Generic[T, R]):
    """``workers`` processes running ``fn(task)``; ``submit`` returns a ``Future``.

    A future fails with the task's own exception (its traceback text attached as ``__cause__``) or
    with :class:`WorkerCrashed` if the worker died holding it; the dead worker is replaced. ``fn``
    and the tasks must be picklable (``fn`` a module-level function). Use as a context manager: a
    normal exit waits for the submitted tasks, an exception (Ctrl-C included) kills the workers.
    """

    def __init__(self, fn: Callable[[T], R], workers: int, *, what: str = "worker",
                 preload: tuple[str, ...] = FORKSERVER_PRELOAD) -> None:
        if workers < 1:
            raise ValueError(f"workers must be >= 1 (got {workers})")
        self._fn = fn
        self._size = int(workers)
        self._what = what
        global _live_pools
        self._ctx = worker_context(preload)
        with _forkserver_lock:
            _live_pools += 1
        self._counted = True
        self._lock = threading.Lock()
        self._queue: deque[tuple[Future, Any]] = deque()
        self._workers: list[_Worker] = []
        self._closing = False
        self._aborted = False
        self._wake_r, self._wake_w = multiprocessing.Pipe(duplex=False)
        self._thread = threading.Thread(target=self._loop, name="roadtruth-worker-pool", daemon=True)
        self._thread.start()

    # -- public ----------------------------------------------------------------------------------
    def submit(self, task: T) -> Future[R]:
        fut: Future[R] = Future()
        with self._lock:
            if self._closing:
                raise RuntimeError("submit on a closed WorkerPool")
            self._queue.append((fut, task))
            self._wake()
        return fut

    def submit_call(self, fn: Callable[[Any], Any], arg: Any) -> Future[Any]:
        """Run ``fn(arg)`` (a module-level function) in a worker instead of the pool's function,
        e.g. to fill a cache in a worker before the pool's own tasks are submitted."""
        return self.submit(_Call(fn, arg))  # type: ignore[arg-type]

    def start_workers(self) -> None:
        """Start every worker now rather than when tasks arrive, so their start-up (imports) runs
        while the caller is still preparing the tasks."""
        with self._lock:
            while len(self._workers) < self._size and not self._closing:
                self._start()

    def close(self) -> None:
        """Wait for every submitted task, then let the workers exit."""
        with self._lock:
            self._closing = True
            self._wake()
        try:
            self._thread.join()
            for w in list(self._workers):
                self._retire(w)
        except BaseException:  # Ctrl-C while waiting: the workers must not outlive the run
            self.kill()
            raise
        self._uncount()

    def kill(self) -> None:
        """Stop now: kill the workers, cancel what has not started."""
        with self._lock:
            self._closing = self._aborted = True
            workers = list(self._workers)
            queued = list(self._queue)
            self._queue.clear()
            self._wake()
        for w in workers:
            _stop(w.process, grace_s=0.0)
        for fut, _ in queued:
            fut.cancel()
        self._thread.join(timeout=EXIT_GRACE_S)
        self._uncount()

    def _uncount(self) -> None:
        global _live_pools
        with _forkserver_lock:
            if self._counted:
                self._counted = False
                _live_pools -= 1

    def __enter__(self) -> WorkerPool[T, R]:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self.kill()

    # -- the dispatch thread -------------------------------------------------------------------------
    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            self._wake_w.send_bytes(b"")

    def _loop(self) -> None:
        try:
            while True:
                self._dispatch()
                with self._lock:
                    busy = [w for w in self._workers if w.job is not None]
                    if self._aborted or (self._closing and not self._queue and not busy):
                        return
                ready = wait([self._wake_r] + [w.conn for w in busy] + [w.process.sentinel for w in busy])
                while self._wake_r.poll():
                    self._wake_r.recv_bytes()
                for w in busy:
                    if w.conn in ready or w.process.sentinel in ready:
                        self._collect(w)
        except BaseException as exc:  # noqa: BLE001 - never leave a caller waiting on a dead pool
            with self._lock:
                pending = [w.job for w in self._workers if w.job is not None] + list(self._queue)
                self._queue.clear()
            for fut, _ in pending:
                if not fut.done():
                    fut.set_exception(RuntimeError(f"worker pool failed: {exc!r}"))

    def _dispatch(self) -> None:
        while True:
            with self._lock:
                if not self._queue or self._aborted:
                    return
                worker = next((w for w in self._workers if w.job is None), None)
                if worker is not None and not worker.process.is_alive():
                    self._drop(worker)  # died while idle: not any task's fault
                    continue
                if worker is None:
                    if len(self._workers) >= self._size:
                        return
                    worker = self._start()
                fut, task = self._queue.popleft()
            if not fut.running() and not fut.set_running_or_notify_cancel():
                continue  # cancelled while queued
            try:
                worker.conn.send(task)
            except (OSError, EOFError):  # the worker is gone before taking the task: retry elsewhere
                with self._lock:
                    self._drop(worker)
                    self._queue.appendleft((fut, task))
                continue
            except Exception as exc:  # noqa: BLE001 - an unpicklable task fails alone
                fut.set_exception(exc)
                continue
            worker.job = (fut, task)

    def _start(self) -> _Worker:
        parent_end, child_end = self._ctx.Pipe(duplex=True)
        p = self._ctx.Process(target=_serve, args=(child_end, self._fn, os.getpid(), dict(os.environ)), daemon=True,
                              name=f"roadtruth-{self._what}")
        p.start()
        child_end.close()
        w = _Worker(p, parent_end)
        self._workers.append(w)
        return w

    def _drop(self, w: _Worker) -> None:
        _stop(w.process, grace_s=0.0)
        w.conn.close()
        if w in self._workers:
            self._workers.remove(w)

    def _collect(self, w: _Worker) -> None:
        assert w.job is not None
        fut, _ = w.job
        try:
            if w.conn.poll():
                ok, value, tb = w.conn.recv()
                w.job = None
                if ok:
                    fut.set_result(value)
                else:
                    if isinstance(value, BaseException):
                        value.__cause__ = _RemoteTraceback(tb)
                    fut.set_exception(value)
                return
        except (EOFError, OSError):
            pass
        except Exception as exc:  # noqa: BLE001 - an answer that cannot be unpickled fails its task
            w.job = None
            fut.set_exception(exc)
            return
        # No answer and the worker is gone (or its pipe is): it died holding this task.
        w.process.join(timeout=EXIT_GRACE_S)
        code = w.process.exitcode
        w.job = None
        with self._lock:
            self._drop(w)
        fut.set_exception(WorkerCrashed(code, self._what))

    def _retire(self, w: _Worker) -> None:
        with contextlib.suppress(OSError, EOFError):
            w.conn.send(None)
        w.process.join(timeout=EXIT_GRACE_S)
        with self._lock:
            self._drop(w)


def _stop(p: multiprocessing.process.BaseProcess, grace_s: float) -> None:
    """Terminate ``p`` (SIGTERM, then SIGKILL after ``grace_s``) and reap it."""
    if p.exitcode is None:
        with contextlib.suppress(OSError, ValueError):
            p.terminate()
        p.join(timeout=grace_s if grace_s > 0 else 1.0)
        if p.exitcode is None:
            with contextlib.suppress(OSError, ValueError):
                p.kill()
            p.join(timeout=EXIT_GRACE_S)
