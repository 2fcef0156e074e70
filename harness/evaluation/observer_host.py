"""Observers run in a separate *host* process, so that no observer can stop, hang or crash a run.

An observer is third-party code (plug-ins load through entry points) and often compiled: it can
raise anything, call ``sys.exit``, segfault inside numba/C code or loop forever. Catching exceptions
in the caller handles only the first. So each observer's ``design()`` and ``run()`` execute in a
child process, the *host*; the caller sends ``(observer class, vehicle, options, t, Y)`` as one
pickled message and receives the estimate track, the design's certificate and the loop's timing:

* an exception of any kind, ``SystemExit`` included, is caught in the host and becomes
  ``error: <Type>: <message>``;
* a host that dies (segfault, ``os._exit``, the OOM killer) closes its pipe: ``error: observer
  process crashed (signal 11)``;
* no answer within the time budget: the host is killed, ``error: timed out after N s``.

After a crash or a timeout the next observer gets a fresh host; the others are unaffected.

Why one persistent host rather than a process per observer: starting Python and importing numpy,
numba (compiled kernels loaded from the cache) and cvxpy costs seconds, the observers of a scenario
cost tens of milliseconds each. A host is started once per process that runs observers (the main
process, or each scenario worker) and reused for every observer and scenario; ``prestart`` starts it
in the background while the scenario is being simulated, so its imports overlap useful work. The
only per-observer cost is pickling the inputs and the track (about a millisecond). Timing is
unchanged: ``us_per_step`` is measured in the host around ``run()`` alone.

How a host starts. A fresh interpreter costs 1.5-2 s of CPU in imports plus 0.8-1.2 s of numba's
one-time target set-up; on two cores, with a worker and a host per core, that was most of what
``--jobs 2`` lost. So when :func:`fork_is_safe` (Linux, the main thread, every other thread a
daemon, no OpenGL context ever made here) the host is ``os.fork()``-ed from the caller: a scenario
worker forked from the preloaded forkserver (:mod:`roadtruth.harness.jobs.forkserver_preload`) already
holds every import, numba set up and its imports frozen, so its host is ready in milliseconds. The
forked child keeps only stdout, stderr and its two pipes, never returns into the caller's code and
ends with ``os._exit`` (the caller's ``atexit`` handlers are the caller's). Otherwise the host is
``python -m roadtruth.harness.evaluation.observer_host`` (``subprocess``, not ``multiprocessing``: workers of
a Dask cluster are daemonic, and multiprocessing refuses children of daemonic processes), which
imports every observer and sets numba up *before* it says it is ready, so that cost overlaps the
caller's simulation instead of landing in the first observer's request. Either way the pipes carry
length-prefixed pickles (``multiprocessing.connection.Connection`` framing); stdin is closed and
stdout/stderr are the caller's, so an observer's prints still show but cannot corrupt the protocol,
and the host names itself ``roadtruth-host`` (``/proc/PID/comm``).

The host ignores SIGINT (Ctrl-C raises ``KeyboardInterrupt`` in the caller, which kills the host),
and dies with its parent (``roadtruth.harness.jobs.worker_pool.exit_with``). An observer class that cannot be
imported by name in another process (defined inside a function, or in a ``__main__`` script) runs
in the calling process instead, with exceptions still caught but no crash or time-out protection.
"""

from __future__ import annotations

import atexit
import contextlib
import copy
import importlib
import importlib.util
import math
import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from roadtruth.harness.evaluation.host_fork import ForkedProcess, fork_child, fork_is_safe, name_process
from roadtruth.harness.jobs.warm_start import one_blas_thread
from roadtruth.harness.jobs.worker_pool import exit_reason

#: How long a new host may take to import numpy, numba, cvxpy and the observers [s].
STARTUP_TIMEOUT_S = 300.0


@dataclass(frozen=True)
class ObserverRequest:
    """One observer to design and run (picklable). ``t``: (n,) [s]; ``Y``: (n, len(inputs))."""

    name: str
    module: str              # the observer class, imported by name in the host
    qualname: str
    module_file: str | None  # fallback when the module is not importable by name there
    vehicle: Any             # roadtruth.harness.truth.vehicle.VehicleParams
    options: dict[str, Any]
    t: np.ndarray
    Y: np.ndarray
    # The caller's context, so a long-lived host behaves as if it were the caller right now
    # (design cache location from the environment, relative paths, modules added to sys.path).
    path: tuple[str, ...] = ()
    env: tuple[tuple[str, str], ...] = ()
    cwd: str = ""


@dataclass(frozen=True)
class ObserverReply:
    """What became of one request. ``error`` is "" when the observer ran, else one line."""

    track: Any | None   # roadtruth.observers.base.EstimateTrack
    seconds: float      # wall time of ``run()`` only [s] (NaN if it did not run)
    certified: bool
    design_reason: str
    design_status: str
    error: str = ""

    @classmethod
    def failed(cls, error: str) -> ObserverReply:
        return cls(None, math.nan, False, "", "", error)


def one_line(exc: BaseException) -> str:
    """``Type: message`` on one line, at most 300 characters."""
    text = f"{type(exc).__name__}: {exc}".strip().splitlines()
    return text[0][:300] if text else type(exc).__name__


# ---- the observer's side (in the host, or in-process as a fallback) -------------------------------

def _adopt_context(req: ObserverRequest) -> None:
    for p in reversed(req.path):
        if p not in sys.path:
            sys.path.insert(0, p)
    env = dict(req.env)
    if env and env != dict(os.environ):
        os.environ.clear()
        os.environ.update(env)
    if req.cwd and req.cwd != os.getcwd():
        os.chdir(req.cwd)


def _load_class(req: ObserverRequest) -> type:
    try:
        module = importlib.import_module(req.module)
    except ModuleNotFoundError:
        if not req.module_file:
            raise
        spec = importlib.util.spec_from_file_location(req.module, req.module_file)
        if spec is None or spec.loader is None:
            raise
        module = importlib.util.module_from_spec(spec)
        sys.modules[req.module] = module
        spec.loader.exec_module(module)
    obj: Any = module
    for part in req.qualname.split("."):
        obj = getattr(obj, part)
    return obj


def _check_track(track: Any, n: int) -> None:
    from roadtruth.observers.base import EstimateTrack

    if not isinstance(track, EstimateTrack):
        raise TypeError(f"run() returned {type(track).__name__}, not an EstimateTrack")
    k = len(track.states)
    for label, a in (("x", track.x), ("lo", track.lo), ("hi", track.hi), ("var", track.var)):
        if a is None and label != "x":
            continue
        if not isinstance(a, np.ndarray) or a.shape != (n, k):
            raise ValueError(f"run() returned {label} of shape {getattr(a, 'shape', None)}, expected {(n, k)}")


#: Steps of the untimed warm-up run (:func:`_load_compiled_code`).
WARMUP_STEPS = 64


def _load_compiled_code(obs: Any, t: np.ndarray, Y: np.ndarray) -> None:
    """Run a copy of the designed observer over the first ``WARMUP_STEPS`` steps, untimed (once per class).

    The first call of a numba kernel in a process loads it from the on-disk cache (and sets up
    numba's target context the first time of all): tens of milliseconds that would be charged to
    whichever observer happens to run first and make its µs/step several times what its loop costs.
    The copy keeps the observer itself untouched (``run()`` resets at ``t[0]`` anyway); anything that
    goes wrong here is left for the timed run to report.
    """
    n = min(len(t), WARMUP_STEPS)
    cls = type(obs)
    if n < 2 or cls in _WARMED:
        return
    try:
        copy.deepcopy(obs).run(np.ascontiguousarray(t[:n]), np.ascontiguousarray(Y[:n]))
    except Exception:  # noqa: BLE001 - the real run reports any failure
        return
    _WARMED.add(cls)


#: Observer classes whose code this process has run once (their kernels are loaded: a long-lived
#: host warms each class once, not once per scenario).
_WARMED: set[type] = set()


def run_request(req: ObserverRequest, *, in_process: bool = False) -> ObserverReply:
    """Create, design and run one observer; every failure becomes ``ObserverReply.error``.

    ``in_process``: running in the caller's process, where Ctrl-C must still stop the run.
    """
    certified, reason, status = False, "", ""
    try:
        if not in_process:
            _adopt_context(req)
        obs = _load_class(req)(req.vehicle, **req.options)
        d = obs.design()
        certified, reason, status = bool(d.certified), str(d.reason), str(d.status.value)
        _load_compiled_code(obs, req.t, req.Y)
        t0 = time.perf_counter()
        track = obs.run(req.t, req.Y)
        seconds = time.perf_counter() - t0
        _check_track(track, len(req.t))
    except KeyboardInterrupt:
        if in_process:
            raise
        return ObserverReply(None, math.nan, certified, reason, status, "KeyboardInterrupt")
    except BaseException as exc:  # noqa: BLE001 - SystemExit too: one observer never ends the run
        return ObserverReply(None, math.nan, certified, reason, status, one_line(exc))
    return ObserverReply(track, seconds, certified, reason, status)


#: The name a host process goes by (``/proc/PID/comm``, ``ps -o comm``), whichever way it started.
HOST_PROCESS_NAME = "roadtruth-host"


def serve(requests: Connection, replies: Connection, parent_pid: int, death_signal: bool, *, forked: bool) -> int:
    """The host's life: get ready, then answer requests until the caller closes the request pipe.

    ``forked``: this process was forked from the caller (which may have imported and warmed
    everything already) rather than started as a fresh interpreter.
    """
    from roadtruth.harness.jobs.warm_start import (
        collection_paused,
        import_observers,
        load_numba_blas,
        set_up_numba,
    )
    from roadtruth.harness.jobs.worker_pool import exit_with

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the caller's: it kills this process
    name_process(HOST_PROCESS_NAME)
    exit_with(parent_pid, parent_pid, death_signal=death_signal)
    load_numba_blas()
    # The imports leave some 150 000-200 000 tracked objects that every full garbage collection would walk
    # again: 0.2-0.7 s, charged to whichever observer's timed run() it happens to fall in (a
    # 5 µs/step loop measured 262 µs/step). Made with collection paused and frozen, they are never
    # walked (a forked host has the caller's frozen already, and nothing else to walk).
    with collection_paused(freeze=True):
        import_observers()  # numpy, numba kernels and every observer, imported once (if not yet)
        # numba's one-time target set-up (0.8-1.2 s) now, before "ready", while the caller still
        # simulates: otherwise it lands in the first observer's request.
        set_up_numba()
    try:
        replies.send(("ready", os.getpid()))
        while True:
            try:
                req = requests.recv()
            except (EOFError, OSError):
                return 0
            reply = run_request(req)
            try:
                replies.send(reply)
            except (BrokenPipeError, ConnectionResetError):
                raise
            except Exception as exc:  # noqa: BLE001 - an unpicklable track is that observer's error
                replies.send(ObserverReply.failed(f"estimates could not be sent back: {one_line(exc)}"))
    except (BrokenPipeError, ConnectionResetError):
        return 0  # the caller is gone (e.g. it stopped on bad input before its first observer)


def main(argv: Sequence[str]) -> int:
    """Host process: ``python -m roadtruth.harness.evaluation.observer_host REQUEST_FD REPLY_FD PARENT_PID DEATH_SIGNAL``."""
    request_fd, reply_fd, parent_pid, death_signal = (int(a) for a in argv)
    return serve(Connection(request_fd, writable=False), Connection(reply_fd, readable=False), parent_pid,
                 bool(death_signal), forked=False)


# ---- the caller's side -------------------------------------------------------------------------

class HostDied(Exception):
    def __init__(self, exitcode: int | None) -> None:
        self.exitcode = exitcode
        super().__init__(exit_reason(exitcode))


class HostTimeout(Exception):
    pass


def _child_pythonpath() -> str:
    """The caller's ``sys.path`` (``''`` = the working folder), so the host imports the same modules."""
    entries = [os.path.abspath(p) if p else os.getcwd() for p in sys.path]
    old = os.environ.get("PYTHONPATH", "")
    return os.pathsep.join(list(dict.fromkeys(entries)) + ([old] if old else []))


class ObserverHost:
    """One host process and its two pipes (caller's side).

    ``forked``: the host was forked from this process (:func:`fork_is_safe`), else it is a fresh
    interpreter. ``process`` has the ``subprocess.Popen`` methods used here either way.
    """

    def __init__(self) -> None:
        req_r, req_w = os.pipe()
        rep_r, rep_w = os.pipe()
        # The parent-death signal fires when the creating *thread* ends: arm it only from a main thread.
        death = int(threading.current_thread() is threading.main_thread())
        parent = os.getpid()
        self.forked = fork_is_safe()
        try:
            if self.forked:
                self.process: subprocess.Popen | ForkedProcess = fork_child(
                    lambda: serve(Connection(req_r, writable=False), Connection(rep_w, readable=False), parent,
                                  bool(death), forked=True), keep_fds=(req_r, rep_w))
            else:
                env = {**one_blas_thread(), "PYTHONPATH": _child_pythonpath()}
                self.process = subprocess.Popen(
                    [sys.executable, "-m", "roadtruth.harness.evaluation.observer_host", str(req_r), str(rep_w),
                     str(os.getpid()), str(death)],
                    stdin=subprocess.DEVNULL, pass_fds=(req_r, rep_w), env=env, close_fds=True)
        finally:
            os.close(req_r)
            os.close(rep_w)
        self.owner = os.getpid()
        self.requests = Connection(req_w, readable=False)
        self.replies = Connection(rep_r, writable=False)
        self.ready = False
        self.killed = False

    def alive(self) -> bool:
        return self.process.poll() is None

    def _receive(self, deadline: float) -> Any:
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise HostTimeout
            try:
                if self.replies.poll(min(remaining, 1.0)):
                    return self.replies.recv()
            except (EOFError, OSError):
                pass
            else:
                if self.process.poll() is None:
                    continue
                if self.replies.poll(0):  # it answered, then exited
                    continue
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.process.wait(timeout=5.0)
            raise HostDied(self.process.returncode)

    def wait_ready(self, timeout_s: float) -> None:
        if not self.ready:
            self._receive(time.monotonic() + timeout_s)
            self.ready = True

    def run(self, payload: bytes, timeout_s: float) -> ObserverReply:
        """Send a pickled ``ObserverRequest`` and wait at most ``timeout_s`` [s] for the reply."""
        deadline = time.monotonic() + timeout_s
        self.requests.send_bytes(payload)
        reply = self._receive(deadline)
        if not isinstance(reply, ObserverReply):
            raise HostDied(None)
        return reply

    def kill(self) -> None:
        self.killed = True
        with contextlib.suppress(OSError):
            self.process.kill()
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.process.wait(timeout=5.0)
        self.close_pipes()

    def close(self) -> None:
        """Let an idle host exit (end of input), killing it if it lingers."""
        self.close_pipes()
        try:
            self.process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self.kill()

    def close_pipes(self) -> None:
        for c in (self.requests, self.replies):
            with contextlib.suppress(OSError):
                c.close()


_idle: list[ObserverHost] = []
_busy = 0  # hosts of this process running a request now (they are idle again when it returns)
_lock = threading.Lock()


def _acquire() -> ObserverHost:
    global _busy
    with _lock:
        _busy += 1
        while _idle:
            host = _idle.pop()
            if host.owner == os.getpid() and host.alive():
                return host
            if host.owner == os.getpid():
                host.kill()
    return ObserverHost()


def _release(host: ObserverHost) -> None:
    with _lock:
        _idle.append(host)


def prestart(count: int = 1) -> None:
    """Start hosts in the background until this process has ``count`` (idle or running a request),
    so their imports overlap other work (``count`` > 1: one per thread that will run observers at
    the same time; started here, from the calling thread, so a main thread arms their parent-death
    signal)."""
    with _lock:
        have = _busy + sum(1 for h in _idle if h.owner == os.getpid() and h.alive())
    for _ in range(max(0, count - have)):
        _release(ObserverHost())


def shutdown() -> None:
    """Let every idle host of this process exit (run at interpreter exit)."""
    with _lock:
        hosts = [h for h in _idle if h.owner == os.getpid()]
        _idle.clear()
    for h in hosts:
        h.close()


def _forget_after_fork() -> None:
    # A forked child must not talk to its parent's hosts: the pipes belong to the parent.
    global _lock, _busy
    _lock = threading.Lock()
    _busy = 0
    for h in _idle:
        h.close_pipes()
    _idle.clear()


atexit.register(shutdown)
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_after_fork)


def isolatable(cls: type) -> bool:
    """True if ``cls`` can be imported by name (or file) in another process."""
    module = sys.modules.get(cls.__module__)
    return (os.name == "posix" and cls.__module__ != "__main__" and "<locals>" not in cls.__qualname__ and module is not None
            and getattr(module, "__spec__", None) is not None)


def request_for(cls: type, vehicle: Any, options: Mapping[str, Any], t: np.ndarray, Y: np.ndarray) -> ObserverRequest:
    module = sys.modules.get(cls.__module__)
    return ObserverRequest(name=str(getattr(cls, "name", cls.__qualname__)), module=cls.__module__,
                           qualname=cls.__qualname__, module_file=getattr(module, "__file__", None),
                           vehicle=vehicle, options=dict(options), t=t, Y=Y,
                           path=tuple(os.path.abspath(p) if p else os.getcwd() for p in sys.path),
                           env=tuple(os.environ.items()), cwd=os.getcwd())


def run_isolated(cls: type, vehicle: Any, options: Mapping[str, Any], t: np.ndarray, Y: np.ndarray,
                 timeout_s: float) -> ObserverReply:
    """Design and run observer class ``cls`` on ``(t, Y)`` in a host process within ``timeout_s`` [s].

    Never raises for anything the observer does; ``KeyboardInterrupt`` (Ctrl-C) kills the host and
    propagates.
    """
    req = request_for(cls, vehicle, options, t, Y)
    if not isolatable(cls):
        return run_request(req, in_process=True)
    try:
        payload = pickle.dumps(req, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:  # noqa: BLE001 - e.g. an option holding a lambda: it cannot travel, run it here
        return run_request(req, in_process=True)
    for attempt in (1, 2):
        host = _acquire()
        try:
            try:
                host.wait_ready(STARTUP_TIMEOUT_S)
            except HostDied as died:
                host.kill()
                return ObserverReply.failed(f"observer process failed to start ({died})")
            except HostTimeout:
                host.kill()
                return ObserverReply.failed(f"observer process did not start within {STARTUP_TIMEOUT_S:g} s")
            try:
                reply = host.run(payload, timeout_s)
            except (BrokenPipeError, ConnectionResetError):
                host.kill()  # the host was gone before it took the request: not this observer's doing
                if attempt == 1:
                    continue
                return ObserverReply.failed("observer process crashed before taking the request")
            except HostDied as died:
                host.kill()
                return ObserverReply.failed(f"observer process crashed ({died})")
            except HostTimeout:
                host.kill()
                return ObserverReply.failed(f"timed out after {timeout_s:g} s")
        except BaseException:  # Ctrl-C (or anything else here): the host must not outlive the run
            host.kill()
            raise
        finally:
            _done_with(host)
        return reply
    raise AssertionError("unreachable")


def _done_with(host: ObserverHost) -> None:
    """The request on ``host`` is over: idle again if it lives, forgotten if it was killed."""
    global _busy
    with _lock:
        _busy -= 1
        if not host.killed and host.alive():
            _idle.append(host)


if __name__ == "__main__":
    # Run from the importable module, not ``__main__``: replies must pickle as
    # ``roadtruth.harness.evaluation.observer_host.ObserverReply`` for the caller to read them.
    from roadtruth.harness.evaluation.observer_host import main as _host_main

    sys.exit(_host_main(sys.argv[1:]))
