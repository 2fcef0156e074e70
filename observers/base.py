"""Observer interface: design -> reset -> step (or run) -> estimates.

An observer is one class. It declares ``name``, ``citation``, ``inputs`` (measurement columns of
ARCHITECTURE "Measurements", in the order ``step`` receives them), ``states`` (canonical names of
``roadtruth.harness.signals``), whether it gives bounds (``has_bounds``) or a covariance (``has_covariance``),
its ``default_options`` and the hard limits it puts on its estimates (``state_bounds``). ``y`` passed
to ``step`` is a float array ordered as ``inputs``; NaN means "no new sample": the observer predicts
with the inputs it holds and does not correct.

:class:`ScalarLoopObserver` is the base of the built-ins: it holds the latest value of every input
(zero-order hold), works on Python floats and runs its loop without per-step allocation.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.vehicle import VehicleParams
from roadtruth.observers.lmi import DesignRequest, DesignResult


@dataclass(frozen=True)
class StepOutput:
    """One step's estimate. x, lo, hi: (k,) arrays in ``states`` order; cov: (k, k) array or None."""

    x: np.ndarray
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    cov: np.ndarray | None = None


@dataclass(frozen=True)
class EstimateTrack:
    """A whole run. t_s: (n,) [s]; x, lo, hi, var: (n, k) arrays in ``states`` order (None if absent)."""

    observer: str
    states: tuple[str, ...]
    t_s: np.ndarray
    x: np.ndarray
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    var: np.ndarray | None = None

    def to_frame(self) -> pd.DataFrame:
        """Long format ``t_s, observer, state, value, lo, hi, var`` (NaN where absent)."""
        n, k = self.x.shape
        nan = np.full((n, k), np.nan)
        lo = self.lo if self.lo is not None else nan
        hi = self.hi if self.hi is not None else nan
        var = self.var if self.var is not None else nan
        return pd.DataFrame({
            "t_s": np.tile(self.t_s, k),
            "observer": self.observer,
            "state": np.repeat(np.array(self.states, dtype=object), n),
            "value": self.x.T.reshape(-1),
            "lo": lo.T.reshape(-1),
            "hi": hi.T.reshape(-1),
            "var": var.T.reshape(-1),
        })


class Observer(ABC):
    """Base of every observer (see module docstring). Subclasses set the class attributes."""

    name: ClassVar[str] = ""
    citation: ClassVar[str] = ""
    inputs: ClassVar[tuple[str, ...]] = ()
    states: ClassVar[tuple[str, ...]] = ()
    has_bounds: ClassVar[bool] = False
    has_covariance: ClassVar[bool] = False
    variant: ClassVar[str] = ""
    default_options: ClassVar[Mapping[str, Any]] = {}
    #: Hard limits the observer imposes on its own estimates (projection, clipping), state ->
    #: (lo, hi) in the state's unit; empty = none. Scoring reports an estimate that sits on one for
    #: more than a small fraction of the time as ``saturated`` (``roadtruth.harness.evaluation.scoring``): declare every
    #: static clip here, or a pinned estimate passes as ``ok``.
    state_bounds: ClassVar[Mapping[str, tuple[float, float]]] = {}
    #: True if the observer returns NaN ("no estimate") where its inputs cannot support one (an
    #: algebraic estimate during a camera gap) instead of predicting. NaN is never a divergence (only
    #: ±inf is); scoring counts it as missing and a long gap makes the status ``diverged (no estimate
    #: for x % of the time)``.
    withholds_estimates: ClassVar[bool] = False

    def __init__(self, vehicle: VehicleParams, **options: Any) -> None:
        unknown = sorted(set(options) - set(self.default_options))
        if unknown:
            known = ", ".join(sorted(self.default_options)) or "none"
            raise InputError(f"unknown option {unknown[0]!r} (known: {known})", field=f"observer {self.name}")
        self.vehicle = vehicle
        self.options: dict[str, Any] = {**self.default_options, **options}
        self._design: DesignResult | None = None

    def design(self) -> DesignResult:
        """Gains and their certificate (cached). Observers without a design return NOT_APPLICABLE."""
        if self._design is None:
            self._design = self._compute_design()
        return self._design

    def design_request(self, model: Any = None) -> DesignRequest:
        """What this observer's LMI design depends on; design modules take this, never the observer."""
        return DesignRequest(self.vehicle, self.variant, self.options, model)

    def _compute_design(self) -> DesignResult:
        return DesignResult.not_applicable(self.variant or self.name, "no LMI design (model-based baseline)")

    @abstractmethod
    def reset(self, t0_s: float, x0: Mapping[str, float] | None = None) -> None:
        """Start at time ``t0_s`` [s] from ``x0`` (state name -> value) or the default initial state."""

    @abstractmethod
    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        """Advance to ``t_s`` [s] with inputs ``y``: (len(inputs),) floats, NaN = no new sample."""

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        """Reset at ``t[0]`` and step through ``t``: (n,) [s], ``Y``: (n, len(inputs))."""
        t = np.asarray(t, dtype=float)
        Y = np.asarray(Y, dtype=float).reshape(len(t), len(self.inputs))
        n, k = len(t), len(self.states)
        x = np.full((n, k), np.nan)
        lo = np.full((n, k), np.nan) if self.has_bounds else None
        hi = np.full((n, k), np.nan) if self.has_bounds else None
        var = np.full((n, k), np.nan) if self.has_covariance else None
        if n:
            self.reset(float(t[0]), x0)
        for i in range(n):
            out = self.step(float(t[i]), Y[i])
            x[i] = out.x
            if lo is not None and out.lo is not None and hi is not None and out.hi is not None:
                lo[i], hi[i] = out.lo, out.hi
            if var is not None and out.cov is not None:
                var[i] = np.diag(out.cov)
        return EstimateTrack(self.name, tuple(self.states), t, x, lo, hi, var)


class ScalarLoopObserver(Observer):
    """Observer on Python floats with held inputs; subclasses implement the hooks below.

    Hooks: ``_setup()`` (after option parsing), ``_initial_state() -> list`` (internal state ``_z``),
    ``_reset_extra()``, ``_advance(t_s, y_list)`` (use ``_tick`` to latch inputs and get the step),
    ``_values() -> list`` (estimates in ``states`` order), and if given ``_bounds() -> (lo, hi)``,
    ``_variances() -> list`` and ``_covariance() -> (k, k) array``.
    """

    def __init__(self, vehicle: VehicleParams, **options: Any) -> None:
        super().__init__(vehicle, **options)
        self._setup()
        self.reset(0.0)

    def _setup(self) -> None:
        return None

    @abstractmethod
    def _initial_state(self) -> list[float]: ...

    def _reset_extra(self) -> None:
        return None

    def _internal_from_x0(self, z: list[float], x0: Mapping[str, float]) -> list[float]:
        """Default: the internal state is ``states[:len(z)]``; other names are rejected."""
        names = self.states[: len(z)]
        for key, value in x0.items():
            if key not in names:
                raise InputError(f"cannot initialise state {key!r} (settable: {', '.join(names)})",
                                 field=f"observer {self.name} x0")
            z[names.index(key)] = float(value)
        return z

    def reset(self, t0_s: float, x0: Mapping[str, float] | None = None) -> None:
        n = len(self.inputs)
        self._t = float(t0_s)
        self._u = [math.nan] * n          # latest sample of each input (zero-order hold)
        self._fresh = [False] * n          # a new sample arrived at this step
        self._t_last = [-math.inf] * n     # arrival time of the latest sample [s]
        z = list(self._initial_state())
        self._z = self._internal_from_x0(z, x0) if x0 else z
        self._reset_extra()

    def _tick(self, t_s: float, y: list[float]) -> float:
        """Latch the new samples of ``y`` and return the step since the last call [s] (0 if none)."""
        u, fresh, tl = self._u, self._fresh, self._t_last
        for i, v in enumerate(y):
            if v == v:
                u[i] = v
                fresh[i] = True
                tl[i] = t_s
            else:
                fresh[i] = False
        h = t_s - self._t
        if h > 0.0:
            self._t = t_s
            return h
        return 0.0

    @abstractmethod
    def _advance(self, t_s: float, y: list[float]) -> None: ...

    @abstractmethod
    def _values(self) -> list[float]: ...

    def _bounds(self) -> tuple[list[float], list[float]] | None:
        return None

    def _variances(self) -> list[float] | None:
        return None

    def _covariance(self) -> np.ndarray | None:
        v = self._variances()
        return None if v is None else np.diag(v)

    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        self._advance(float(t_s), np.asarray(y, dtype=float).tolist())
        b = self._bounds()
        return StepOutput(np.array(self._values()), None if b is None else np.array(b[0]),
                          None if b is None else np.array(b[1]), self._covariance())

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        t = np.asarray(t, dtype=float)
        Y = np.asarray(Y, dtype=float).reshape(len(t), len(self.inputs))
        tl, rows = t.tolist(), Y.tolist()
        xs: list[list[float]] = []
        los: list[list[float]] = []
        his: list[list[float]] = []
        vs: list[list[float]] = []
        if tl:
            self.reset(tl[0], x0)
        advance, values = self._advance, self._values
        bounds = self._bounds if self.has_bounds else None
        variances = self._variances if self.has_covariance else None
        for ti, yi in zip(tl, rows, strict=True):
            advance(ti, yi)
            xs.append(values())
            if bounds is not None:
                b = bounds()
                if b is not None:
                    los.append(b[0])
                    his.append(b[1])
            if variances is not None:
                v = variances()
                if v is not None:
                    vs.append(v)
        k = len(self.states)

        def arr(rows_: list[list[float]]) -> np.ndarray:
            return np.array(rows_, dtype=float).reshape(len(rows_), k)

        n = len(tl)
        return EstimateTrack(self.name, tuple(self.states), t, arr(xs),
                             arr(los) if bounds is not None and len(los) == n else None,
                             arr(his) if bounds is not None and len(his) == n else None,
                             arr(vs) if variances is not None and len(vs) == n else None)
