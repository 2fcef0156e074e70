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
