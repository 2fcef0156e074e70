"""Run observers over a measurement frame and isolate their failures.

One observer that raises, exits, crashes, hangs, diverges or lacks an input never stops the others:
it gets a status (``ok``, ``diverged``, ``error: <msg>``, ``skipped: <reason>``) and the run carries
on. Each observer is designed and run in a host process (:mod:`roadtruth.harness.evaluation.observer_host`) with a time
budget (:func:`default_observer_timeout`). Bad requests (an unknown observer, options for an observer
not being run, an option it does not accept) raise ``InputError`` before any observer runs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.vehicle import VehicleParams

if TYPE_CHECKING:
    from roadtruth.observers.base import EstimateTrack

ESTIMATE_COLUMNS = ("t_s", "observer", "state", "value", "lo", "hi", "var")

#: |estimate| above which a state is absurd; sustained for ``ABSURD_DURATION_S`` -> "diverged".
ABSURD_LIMITS: dict[str, float] = {
    "beta_rad": 1.0, "alpha_f_rad": 1.0, "alpha_r_rad": 1.0, "vy_mps": 30.0, "yaw_rate_radps": 5.0,
    "vx_mps": 150.0, "fy_f_N": 1e5, "fy_r_N": 1e5,
}
ABSURD_DURATION_S = 1.0

#: Default time budget of one observer (design + run) [s]: this many seconds per simulated second ...
OBSERVER_TIMEOUT_PER_SIM_S = 20.0
#: ... and never less than this [s] (a cold LMI design with cvxpy takes seconds, not minutes).
OBSERVER_TIMEOUT_MIN_S = 60.0


def default_observer_timeout(duration_s: float) -> float:
    """Time budget of one observer over ``duration_s`` simulated seconds: max(60 s, 20 × duration) [s]."""
    d = float(duration_s) if math.isfinite(duration_s) and duration_s > 0 else 0.0
    return max(OBSERVER_TIMEOUT_MIN_S, OBSERVER_TIMEOUT_PER_SIM_S * d)


def check_observer_timeout(timeout_s: float | None) -> None:
    """``--observer-timeout``: None (the default budget) or a finite number of seconds > 0."""
    if timeout_s is not None and not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s)
                                      and timeout_s > 0):
        raise InputError(f"must be a number of seconds > 0 (got {timeout_s!r})", field="--observer-timeout")


@dataclass(frozen=True)
class ObserverRun:
    """Outcome of one observer over one measurement frame."""

    status: str             # ok | diverged | error: <msg> | skipped: <reason>
    us_per_step: float      # wall time of the estimation loop per step [us] (NaN if not run)
    certified: bool         # the design carries a valid certificate (False for baselines)
    design_reason: str
    n_steps: int
    design_status: str = ""  # DesignStatus value of the observer's design
    detail: str = ""         # why it diverged, where it did


def _diverged(track_x: np.ndarray, t: np.ndarray, states: tuple[str, ...], withholds: bool = False) -> str | None:
    """A reason if the estimates are non-finite or absurd for a long stretch, else None.

    ±inf is divergence. NaN is "no estimate": before an observer's first measurement (a radar
    observer before the first radar sample; scoring starts at its first estimate) or, for an observer
    that withholds estimates without input (``Observer.withholds_estimates``), during a gap; scoring
    counts it as missing (``diverged (no estimate for x % of the time)`` past a small fraction).
    For any other observer a NaN after its first estimate is a numerical failure: divergence.
    """
    if np.isinf(track_x).any():
        bad = int(np.argmax(np.isinf(track_x).any(axis=1)))
        return f"infinite estimate at t={t[bad]:.3f} s"
    finite_rows = np.all(np.isfinite(track_x), axis=1)
    if track_x.size and not finite_rows.any():
        return "no finite estimate at all"
    start = int(np.argmax(finite_rows)) if track_x.size else 0
    if not withholds and not np.all(finite_rows[start:]):
        bad = start + int(np.argmax(~finite_rows[start:]))
        return f"non-finite estimate at t={t[bad]:.3f} s"
    for j, s in enumerate(states):
        lim = ABSURD_LIMITS.get(s)
        if lim is None:
            continue
        over = np.abs(track_x[:, j]) > lim
        if not over.any():
            continue
        # longest run of consecutive absurd samples, measured in time
        edges = np.diff(np.concatenate([[0], over.astype(np.int8), [0]]))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
        longest = float(np.max(t[ends] - t[starts]))
        if longest >= ABSURD_DURATION_S:
            return f"|{s}| > {lim:g} for {longest:.2f} s"
    return None


def run_observers(measurements: pd.DataFrame, vehicle: VehicleParams, names: list[str], *,
                  options: Mapping[str, Mapping[str, Any]] | None = None,
                  timeout_s: float | None = None,
                  ) -> tuple[pd.DataFrame, dict[str, ObserverRun]]:
    """Run each observer of ``names`` over ``measurements``; the estimates as one long frame.

    The same as :func:`run_observer_tracks` with its tracks joined by :func:`long_estimates`.

    Parameters
    ----------
    measurements : DataFrame
        ``t_s`` [s] plus measurement columns (ARCHITECTURE "Measurements"); NaN = no new sample.
    vehicle : VehicleParams
        The vehicle the observers are built and designed for.
    names : list of str
        Registered observer names; an unknown name raises ``InputError`` before anything runs.
    options : mapping name -> options, optional
        Per-observer options passed to the observer's constructor (checked before anything runs).
    timeout_s : float, optional
        Wall-time budget of each observer's design + run [s]; default
        :func:`default_observer_timeout` of the frame's duration. Over budget: ``error: timed out after N s``.

    Returns
    -------
    estimates : DataFrame
        Long format ``t_s, observer, state, value, lo, hi, var`` (lo/hi NaN without bounds, var NaN
        without covariance). A diverged observer's estimates are kept (for plots); failed ones are absent.
    runs : dict name -> ObserverRun
    """
    tracks, runs = run_observer_tracks(measurements, vehicle, names, options=options, timeout_s=timeout_s)
    return long_estimates(tracks), runs


def long_estimates(tracks: Mapping[str, EstimateTrack]) -> pd.DataFrame:
    """Tracks as the long frame ``t_s, observer, state, value, lo, hi, var`` (observers in order)."""
    frames = [track.to_frame() for track in tracks.values()]
    if frames:
        est = pd.concat(frames, ignore_index=True)
    else:
        est = pd.DataFrame({c: pd.Series(dtype=object if c in ("observer", "state") else float)
                            for c in ESTIMATE_COLUMNS})
    return est[list(ESTIMATE_COLUMNS)]


def measurement_times(measurements: pd.DataFrame) -> np.ndarray:
    """The ``t_s`` column as the (N,) float array every observer is run on [s]."""
    return measurements["t_s"].to_numpy(dtype=float)


def observer_inputs(measurements: pd.DataFrame, inputs: Sequence[str]) -> np.ndarray:
    """The (N, len(inputs)) float array of an observer's input columns, in its order.

    This and :func:`measurement_times` are the one place observer inputs are made: a numba kernel
    is compiled per memory layout and per writeable flag of its arguments (a column of a frame is a
    read-only view), so the design warm-up (:mod:`roadtruth.harness.jobs.design_warmup`) makes its
    two-sample inputs here to compile what the real run will call.
    """
    return measurements[list(inputs)].to_numpy(dtype=float)


def run_observer_tracks(measurements: pd.DataFrame, vehicle: VehicleParams, names: list[str], *,
                        options: Mapping[str, Mapping[str, Any]] | None = None,
                        timeout_s: float | None = None,
                        ) -> tuple[dict[str, EstimateTrack], dict[str, ObserverRun]]:
    """Run each observer of ``names`` over ``measurements``; the estimates as arrays.

    Parameters as :func:`run_observers`. Returns ``tracks``: name -> ``EstimateTrack`` ((n, k)
    arrays on the frame's times, in the order of ``names``; a diverged observer's track is kept for
    plots, a failed or skipped one is absent) and ``runs``: name -> ``ObserverRun``. Scoring
    (``roadtruth.harness.evaluation.scoring.score``) and the wide table writer take the tracks as
    they are, without the long frame's copies.
    """
    from roadtruth.harness.evaluation.observer_host import run_isolated
    from roadtruth.observers.registry import observer_class

    options = dict(options or {})
    unknown = sorted(set(options) - set(names))
    if unknown:
        raise InputError(f"options given for observer {unknown[0]!r}, which is not being run", field="options")
    if "t_s" not in measurements.columns:
        raise InputError("measurement frame has no t_s column", field="t_s")
    check_observer_timeout(timeout_s)
    for n in names:
        cls = observer_class(n)  # unknown names fail here, before any work
        if options.get(n):
            # The caller's options are checked here (unknown keys, bad values raise InputError, which
            # is the caller's mistake); running the observer happens in the host.
            cls(vehicle, **dict(options[n]))
    t = measurement_times(measurements)
    budget = default_observer_timeout(float(t[-1] - t[0]) if len(t) else 0.0) if timeout_s is None else float(timeout_s)
    tracks: dict[str, EstimateTrack] = {}
    runs: dict[str, ObserverRun] = {}
    for name in names:
        cls = observer_class(name)
        missing = [c for c in cls.inputs if c not in measurements.columns
                   or not np.isfinite(measurements[c].to_numpy(dtype=float)).any()]
        if missing:
            runs[name] = ObserverRun(f"skipped: missing {missing[0]}", math.nan, False, "", 0)
            continue
        Y = observer_inputs(measurements, cls.inputs)
        reply = run_isolated(cls, vehicle, options.get(name, {}), t, Y, budget)
        if reply.error:
            runs[name] = ObserverRun(f"error: {reply.error}", math.nan, reply.certified, reply.design_reason, 0,
                                     reply.design_status)
            continue
        track = reply.track
        n = len(t)
        why = _diverged(track.x, t, track.states, bool(getattr(cls, "withholds_estimates", False)))
        status = "diverged" if why else "ok"
        runs[name] = ObserverRun(status, reply.seconds / max(n, 1) * 1e6, reply.certified, reply.design_reason, n,
                                 reply.design_status, why or "")
        tracks[name] = track
    return tracks, runs
