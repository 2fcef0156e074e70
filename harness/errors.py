"""One exception root; each subclass also subclasses the builtin a caller would expect.

``InputError`` and its subclasses are the user's mistakes: the CLI prints their one-line message
and exits 2. ``CheckFailed`` exits 1. Anything else is a crash and keeps its traceback.
"""

from __future__ import annotations


class RoadtruthError(Exception):
    """Root of every roadtruth exception."""


class InputError(RoadtruthError, ValueError):
    """Bad user input. The message is one line naming the file, field and value at fault."""

    def __init__(self, message: str, *, source: str | None = None, field: str | None = None) -> None:
        parts = [p for p in (source, field) if p]
        prefix = ": ".join(parts)
        super().__init__(f"{prefix}: {message}" if prefix else message)
        self.source = source
        self.field = field


class VehicleError(InputError):
    """A vehicle parameter file is missing, malformed or physically implausible."""


class ScenarioError(InputError):
    """A scenario file or a scenario option is invalid."""


class SensorConfigError(InputError):
    """A sensor preset, override or fault specification is invalid."""


class LogError(InputError):
    """A recorded log (replay) is unreadable, incomplete or implausible."""


class SimulationDiverged(RoadtruthError, RuntimeError):
    """The physics blew up (non-finite state, car flipped). Carries the time and the cause."""

    def __init__(self, message: str, *, t_s: float) -> None:
        super().__init__(f"diverged at t={t_s:.3f} s: {message}")
        self.t_s = t_s
        self.cause = message


class CheckFailed(RoadtruthError):
    """A CI gate threshold or regression was breached (exit 1)."""
