"""Module-level task functions for the worker-pool tests (importable by worker processes)."""

from __future__ import annotations

import os
import signal
import time


def square_or_fail(x: object) -> int:
    """``x * x``; ``"segv"`` kills the worker with SIGSEGV, ``"raise"`` raises ValueError."""
    if x == "segv":
        os.kill(os.getpid(), signal.SIGSEGV)
        time.sleep(10.0)
    if x == "raise":
        raise ValueError("task refused")
    assert isinstance(x, int)
    return x * x


def process_state(_: object) -> dict[str, object]:
    """What a worker had done before its first task: heavy modules imported, numba set up, objects frozen."""
    import gc
    import sys

    state: dict[str, object] = {"modules": sorted(m for m in ("mujoco", "pandas", "roadtruth.observers.registry",
                                                                 "roadtruth.harness.jobs.pipeline") if m in sys.modules),
                                "frozen": gc.get_freeze_count(), "numba_registries": 0}
    if "numba" in sys.modules:
        from numba.core.registry import cpu_target

        # numba's target context, set up by the first kernel call of a process (0.8-1.2 s)
        state["numba_registries"] = len(cpu_target.target_context._registries)
    return state


def blas_environment(_: object) -> dict[str, object]:
    """``OPENBLAS_NUM_THREADS`` as this worker and its parent (the pools' forkserver, which loaded
    NumPy's and SciPy's OpenBLAS before forking it) started with; None where it is not set."""
    def variable(environ: bytes) -> str | None:
        for item in environ.split(b"\0"):
            if item.startswith(b"OPENBLAS_NUM_THREADS="):
                return item.split(b"=", 1)[1].decode()
        return None

    with open(f"/proc/{os.getppid()}/environ", "rb") as f:
        server = variable(f.read())
    with open("/proc/self/environ", "rb") as f:
        worker = variable(f.read())
    return {"worker": worker, "server": server, "server_pid": os.getppid()}
