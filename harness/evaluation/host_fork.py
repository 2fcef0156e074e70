"""Starting an observer host by forking the caller, and when that is safe.

A host forked from a warmed process (a scenario worker forked from the preloaded forkserver) inherits
every import, numba's target set-up and the frozen objects, so it is ready in milliseconds instead of
seconds of CPU. :mod:`roadtruth.harness.evaluation.observer_host` decides with :func:`fork_is_safe` and
falls back to a fresh interpreter otherwise.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import re
import signal
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable

import roadtruth
from roadtruth.harness.jobs.warm_start import startup_environment


def name_process(name: str) -> None:
    """Set this process's name as ``ps`` and ``/proc/PID/comm`` show it (Linux; at most 15 bytes)."""
    if not sys.platform.startswith("linux"):
        return
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(15, name.encode()[:15], 0, 0, 0)  # PR_SET_NAME


#: Libraries mapped only once a process has made an OpenGL context (Mesa's DRI/Gallium drivers,
#: NVIDIA's GL core, OSMesa): importing MuJoCo maps libEGL, making a context maps these.
_GL_CONTEXT_LIBRARIES = re.compile(rb"_dri\.so|libgallium|libnvidia-eglcore|libnvidia-glcore|libOSMesa")


#: The start-up environment this process's imports were made under (see ``startup_environment``),
#: as it was when roadtruth was first imported: a caller may change ``PYTHONPATH`` before this
#: module is first imported.
_IMPORTED_UNDER = startup_environment(roadtruth.ENVIRON_AT_IMPORT)


def fork_is_safe() -> bool:
    """True if a host may be forked from this process instead of started as a fresh interpreter.

    Forking inherits the caller's imports, observers, numba set-up and frozen objects, so the host
    is ready in milliseconds instead of seconds of CPU. It is only safe on Linux, from the main
    thread, with every other Python thread a daemon (a non-daemon thread may hold a lock the child
    would wait on forever), and when this process has never made an OpenGL context (its forked
    children hang when they render, and GL drivers keep threads of their own). And only while the
    start-up environment (``PYTHONPATH`` and the like) is the one this process imported under: else
    the child would hold what this process imported, not what a fresh interpreter would now.
    """
    if not sys.platform.startswith("linux") or not hasattr(os, "fork"):
        return False
    if startup_environment() != _IMPORTED_UNDER:  # a fresh interpreter would import something else now
        return False
    if threading.current_thread() is not threading.main_thread():
        return False
    if any(not t.daemon for t in threading.enumerate() if t is not threading.current_thread()):
        return False
    try:
        with open("/proc/self/maps", "rb") as f:
            maps = f.read()
    except OSError:
        return False
    return _GL_CONTEXT_LIBRARIES.search(maps) is None


class ForkedProcess:
    """A forked child, seen by its parent with the ``subprocess.Popen`` methods used here."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:  # reaped by someone else: it is gone, how is unknown
                self.returncode = 255
            else:
                if pid:
                    self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if deadline is not None and time.monotonic() >= deadline:
                raise subprocess.TimeoutExpired(f"forked process {self.pid}", timeout or 0.0)
            time.sleep(0.005)
        return self.returncode  # type: ignore[return-value]

    def kill(self) -> None:
        if self.poll() is None:  # never signal a pid that was reaped (and may be reused)
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)


def fork_child(run: Callable[[], int], keep_fds: tuple[int, ...]) -> ForkedProcess:
    """Fork a child that runs ``run()`` and exits with its return value; the child never returns from here.

    The child keeps only stdout, stderr and ``keep_fds`` (stdin becomes ``/dev/null``): the caller's
    other descriptors (its worker-pool pipe, its other hosts' pipes) must close when the caller
    closes them. It ends with ``os._exit``: the caller's ``atexit`` handlers are the caller's.
    """
    for stream in (sys.stdout, sys.stderr):  # else the child would write the caller's buffered text again
        with contextlib.suppress(Exception):
            stream.flush()
    pid = os.fork()
    if pid:
        return ForkedProcess(pid)
    code = 1
    try:
        devnull = os.open(os.devnull, os.O_RDONLY)
        os.dup2(devnull, 0)
        low = 3
        for fd in sorted(set(keep_fds)):
            os.closerange(low, fd)
            low = fd + 1
        os.closerange(low, 1 << 20)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        code = run()
    except BaseException:  # noqa: BLE001 - whatever happens, the child must not run the caller's code
        with contextlib.suppress(Exception):
            traceback.print_exc()
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(code)
