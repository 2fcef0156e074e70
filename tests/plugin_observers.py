"""Misbehaving plug-in observers for the isolation tests (importable, so an observer host finds them).

Each fails in one way an observer from a third party can: an ``InputError`` at run time, an exception
in its design, ``sys.exit``, a native crash (SIGSEGV) and a hang. They are registered by the tests
(``roadtruth.observers.registry.register``), not on import.
"""

from __future__ import annotations

import os
import signal
import sys
import time

from roadtruth.harness.errors import InputError
from roadtruth.observers.base import ScalarLoopObserver
from roadtruth.observers.lmi import DesignResult


class _YawEcho(ScalarLoopObserver):
    """Echoes the yaw rate; the subclasses break it."""

    name = "plugin_yaw_echo"
    citation = "test plug-in"
    inputs = ("yaw_rate_radps",)
    states = ("yaw_rate_radps",)

    def _initial_state(self) -> list[float]:
        return [0.0]

    def _advance(self, t_s: float, y: list[float]) -> None:
        if y[0] == y[0]:
            self._z[0] = y[0]

    def _values(self) -> list[float]:
        return [self._z[0]]


class RaisesInputErrorInRun(_YawEcho):
    name = "plugin_input_error"

    def _advance(self, t_s: float, y: list[float]) -> None:
        if t_s > 0.5:
            raise InputError("plug-in refused its input at run time", field="plugin")


class RaisesInDesign(_YawEcho):
    name = "plugin_design_error"

    def _compute_design(self) -> DesignResult:
        raise RuntimeError("design exploded")


class CallsSysExit(_YawEcho):
    name = "plugin_sys_exit"

    def _advance(self, t_s: float, y: list[float]) -> None:
        sys.exit(3)


class Segfaults(_YawEcho):
    name = "plugin_segfault"

    def _advance(self, t_s: float, y: list[float]) -> None:
        os.kill(os.getpid(), signal.SIGSEGV)
        time.sleep(10.0)  # the signal is delivered asynchronously


class Hangs(_YawEcho):
    name = "plugin_hang"

    def _advance(self, t_s: float, y: list[float]) -> None:
        while True:
            time.sleep(1.0)


MISBEHAVING = (RaisesInputErrorInRun, RaisesInDesign, CallsSysExit, Segfaults, Hangs)


class ReportsFrozenObjects(_YawEcho):
    """Reports how many objects its process has frozen out of garbage collection (``gc.freeze``)."""

    name = "plugin_gc_probe"

    def _values(self) -> list[float]:
        import gc

        return [float(gc.get_freeze_count())]
