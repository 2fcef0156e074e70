"""Metrics per (scenario, observer, state): one small function per metric, named by its column.

How an estimate is compared with truth
--------------------------------------
Everything is evaluated on the **truth time base** (the simulation rate when called from the
pipeline). An observer's estimates are held zero-order onto the truth times, starting at its first
output: the value scored at truth time ``t`` is the latest estimate with ``t_est <= t``. Truth rows
before the first output are not scored (there is nothing to compare yet). Errors of angle states
(canonical names ending in ``_rad``) are wrapped into (-pi, pi].

Convergence time
----------------
Observers start from a wrong initial state. ``conv_time_s`` is the time from the start of the
truth record until the error enters its band and **stays** there to the end; NaN if the last
sample is still outside. Bands (:func:`convergence_band`): beta, slip angles and other angles
0.5 deg; lateral and other velocities 0.1 m/s; yaw and other rates 0.01 rad/s; forces 5 % of
the car's weight m*g (axle and wheel forces alike); friction coefficients 0.05; positions 0.5 m;
accelerations 0.2 m/s^2; curvature 1e-3 1/m. A caller may override any band via ``bands``.

Scored window
-------------
Scoring stops where the truth says the car did something no observer can be blamed for: the first
spin-out or roll-over (``roadtruth.harness.truth.truth_events.scoring_end_s``; passed in as ``scored_until_s``).
Truth rows at or after that time are not scored; ``scored_until_s`` in every row says where the
window ends (the last truth time when nothing happened) and ``n_scored`` how many rows it holds.

Usable or not
-------------
An ``ok`` observer whose estimate is not usable over the scored window gets another status (the
precedence is error > diverged > saturated > ok; ``skipped`` is carried as it is):

* ``diverged (no estimate for x % of the time)`` if its value is NaN for more than
  ``MAX_MISSING_FRACTION`` of the scored time (a non-finite estimate already means ``diverged``
  for ``roadtruth.harness.evaluation.estimate``);
* ``saturated (x % of the time)`` if a state sits on one of the observer's declared state bounds
  (``Observer.state_bounds``, e.g. the ±0.5 rad sideslip projection of the EKF/UKF) for more than
  ``MAX_SATURATED_FRACTION`` of the scored time. "On the bound" is ``value <= lo + tol`` or
  ``value >= hi - tol`` with ``tol = BOUND_TOL * max(1, |bound|)``. A bounded estimate can never pass
  ``roadtruth.harness.evaluation.estimate.ABSURD_LIMITS`` when its bound lies inside them; sitting on the bound is its
  way of being absurd, and this is the check that sees it.

* ``unusable (RMS error N× that of assuming zero)`` on the row of a state whose RMS error exceeds
  both the RMS of the true state over the scored window (the error of the trivial estimate 0) and
  its convergence band (``unusable_state_status``; not for poses and distances, which have no
  natural zero). A state whose truth is nearly zero (RMS below a tenth of its band; the curvature of
  a straight road is exactly 0, so any error is "∞×" that of assuming zero) is judged against the band:
  ``unusable (error outside its convergence band x % of the time; …)`` only if its RMS error exceeds
  the band and the error is outside the band for more than half the scored time. This one is per
  state: a radar observer whose range is good but whose lead acceleration is worse than guessing 0
  is ``ok`` on range and ``unusable`` on the acceleration.

Scoring of each observer starts at its first estimate: leading NaN rows (no measurement yet) are
"not started", neither scored nor counted as missing.

Fractions are time-weighted and taken per state; the observer's status uses its worst state and is
written in all its rows.

Intervals and variances
-----------------------
Where an observer gives bounds (``lo``/``hi`` finite), ``coverage`` is the fraction of scored
time with ``lo <= truth <= hi``, ``violation_time_s`` the time outside, ``mean_width``/``max_width``
the width ``hi - lo``. Where it gives a variance (an optional ``var`` column of the long estimates
frame, e.g. a Kalman filter's diagonal covariance), ``nees_mean`` is the normalised estimation error
squared ``e^2 / var`` of that one state (1 degree of freedom) averaged over the N *fresh* estimates
(each observer output counted once, not once per held truth row). For a consistent filter with
independent errors N * nees_mean ~ chi^2(N), so ``nees_in_band`` tests it against the two-sided
95 % band ``chi2.ppf([0.025, 0.975], N) / N`` (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4.2).
Consecutive errors of a real filter are correlated, which makes this band optimistic (too
narrow) for long records: read ``nees_in_band`` as a consistency flag, ``nees_mean`` as the figure.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import pandas as pd

from roadtruth.harness.truth.vehicle import G

#: Key columns of a metrics row, then the metric columns, then what is carried from the run.
KEY_COLUMNS: tuple[str, ...] = ("scenario", "observer", "state")
METRIC_COLUMNS: tuple[str, ...] = (
    "rmse", "mae", "max_abs", "p95_abs", "bias", "conv_time_s",
    "coverage", "mean_width", "max_width", "violation_time_s",
    "nees_mean", "nees_in_band",
)
RUN_COLUMNS: tuple[str, ...] = ("us_per_step", "certified", "status")
EXTRA_COLUMNS: tuple[str, ...] = ("conv_band", "n_scored", "scored_until_s")
COLUMNS: tuple[str, ...] = KEY_COLUMNS + METRIC_COLUMNS + RUN_COLUMNS + EXTRA_COLUMNS

#: Time tolerance when holding estimates onto truth times (float rounding of t = k * dt).
TIME_TOL_S = 1e-9
#: An estimate on a state bound for more than this fraction of the scored time is ``saturated``:
#: a filter held by its constraint 1 step in 20 is reporting the constraint, not the car.
MAX_SATURATED_FRACTION = 0.05
#: An estimate missing (NaN) for more than this fraction of the scored time is not usable either.
MAX_MISSING_FRACTION = 0.05
#: Relative tolerance of "on the bound" (a projected estimate lands on it to rounding, ~1e-16).
BOUND_TOL = 1e-6

DEG = math.pi / 180.0


class ObserverRunLike(Protocol):
    """What scoring reads from ``roadtruth.harness.evaluation.estimate.ObserverRun``."""

    status: str
    us_per_step: float
    certified: bool | None


@dataclass(frozen=True)
class Aligned:
    """One state of one observer on the truth time base (all arrays (n,), n = scored rows).

    ``t_s`` [s] truth times from the observer's first output on; ``truth`` and ``value`` in the
    state's unit; ``error`` = value - truth (wrapped for angles); ``lo``/``hi`` bounds (NaN if none);
    ``var`` variance [unit^2] (NaN if none); ``fresh`` (n,) bool, True on the first truth row at or
    after each estimate output; ``dt_s`` (n,) time each row stands for; ``t0_s`` start of the truth
    record; ``band`` the convergence band.
    """

    t_s: np.ndarray
    truth: np.ndarray
    value: np.ndarray
    error: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    var: np.ndarray
    fresh: np.ndarray
    dt_s: np.ndarray
    t0_s: float
    band: float
    finite_error: np.ndarray | None = None  # ``error`` without its NaNs (computed once, read by five metrics)


# ---- one function per metric ---------------------------------------------------------------

def _finite_error(a: Aligned) -> np.ndarray:
    return a.finite_error if a.finite_error is not None else a.error[np.isfinite(a.error)]


def rmse(a: Aligned) -> float:
    e = _finite_error(a)
    return float(np.sqrt(np.mean(e**2))) if e.size else math.nan


def mae(a: Aligned) -> float:
    e = _finite_error(a)
    return float(np.mean(np.abs(e))) if e.size else math.nan


def max_abs(a: Aligned) -> float:
    e = _finite_error(a)
    return float(np.max(np.abs(e))) if e.size else math.nan


def p95_abs(a: Aligned) -> float:
    e = _finite_error(a)
    return float(np.percentile(np.abs(e), 95.0)) if e.size else math.nan


def bias(a: Aligned) -> float:
    e = _finite_error(a)
    return float(np.mean(e)) if e.size else math.nan


def conv_time_s(a: Aligned) -> float:
    """Time from the start of the record until |error| <= band for good; NaN if never."""
    if a.error.size == 0 or not math.isfinite(a.band):
        return math.nan
    # A non-finite error counts as outside the band.
    outside = ~(np.abs(a.error) <= a.band)
    if not outside.any():
        return float(a.t_s[0] - a.t0_s)
    last = int(np.flatnonzero(outside)[-1])
    if last == a.error.size - 1:
        return math.nan
    return float(a.t_s[last + 1] - a.t0_s)


def _bounded(a: Aligned) -> np.ndarray:
    return np.isfinite(a.lo) & np.isfinite(a.hi) & np.isfinite(a.truth)


def coverage(a: Aligned) -> float:
    m = _bounded(a)
    if not m.any():
        return math.nan
    inside = (a.lo[m] <= a.truth[m]) & (a.truth[m] <= a.hi[m])
    return float(np.sum(a.dt_s[m] * inside) / np.sum(a.dt_s[m]))


def violation_time_s(a: Aligned) -> float:
    m = _bounded(a)
    if not m.any():
        return math.nan
    outside = (a.truth[m] < a.lo[m]) | (a.truth[m] > a.hi[m])
    return float(np.sum(a.dt_s[m] * outside))


def mean_width(a: Aligned) -> float:
    m = _bounded(a)
    return float(np.mean(a.hi[m] - a.lo[m])) if m.any() else math.nan


def max_width(a: Aligned) -> float:
    m = _bounded(a)
    return float(np.max(a.hi[m] - a.lo[m])) if m.any() else math.nan


def _nees_samples(a: Aligned) -> np.ndarray:
    m = a.fresh & np.isfinite(a.var) & (a.var > 0) & np.isfinite(a.error)
    return a.error[m] ** 2 / a.var[m]


def nees_mean(a: Aligned) -> float:
    q = _nees_samples(a)
    return float(np.mean(q)) if q.size else math.nan


def nees_band(n: int) -> tuple[float, float]:
    """Two-sided 95 % band of the mean of n independent chi^2(1) variables.

    The chi^2(n) quantile is 2 P^-1(n/2, q), P the regularised lower incomplete gamma function: what
    ``scipy.stats.chi2.ppf`` computes, to the bit, without importing scipy.stats (1-3 s per process).
    """
    from scipy.special import gammaincinv

    lo, hi = 2.0 * gammaincinv(0.5 * n, np.array([0.025, 0.975])) / n
    return float(lo), float(hi)


def nees_in_band(a: Aligned) -> float:
    """1.0 if the mean NEES lies in its chi^2 95 % band, 0.0 if not, NaN without variances."""
    q = _nees_samples(a)
    if not q.size:
        return math.nan
    lo, hi = nees_band(q.size)
    return float(lo <= float(np.mean(q)) <= hi)


#: The metric generators, keyed by their column in ``metrics.csv`` (order = METRIC_COLUMNS).
METRICS: dict[str, Callable[[Aligned], float]] = {
    "rmse": rmse, "mae": mae, "max_abs": max_abs, "p95_abs": p95_abs, "bias": bias,
    "conv_time_s": conv_time_s, "coverage": coverage, "mean_width": mean_width,
    "max_width": max_width, "violation_time_s": violation_time_s,
    "nees_mean": nees_mean, "nees_in_band": nees_in_band,
}
assert tuple(METRICS) == METRIC_COLUMNS


# ---- bands and alignment -------------------------------------------------------------------

def convergence_band(state: str, *, mass_kg: float | None = None) -> float:
    """Default convergence band of a canonical state, in the state's unit (see module doc)."""
    if state.startswith("mu_"):
        return 0.05
    if state.endswith("_rad"):
        return 0.5 * DEG
    if state.endswith("_radps"):
        return 0.01
    if state.endswith("_mps"):
        return 0.1
    if state.endswith("_N"):
        return 0.05 * mass_kg * G if mass_kg else math.nan
    if state.endswith("_mps2"):
        return 0.2
    if state.endswith("_1pm"):
        return 1e-3
    if state.endswith("_m"):
        return 0.5
    return math.nan


def wrap_angle(x: np.ndarray) -> np.ndarray:
    """Wrap angles [rad] into (-pi, pi]."""
    return np.pi - np.mod(np.pi - x, 2.0 * np.pi)


def align(
    t_truth: np.ndarray, truth: np.ndarray, est: pd.DataFrame | Mapping[str, np.ndarray], state: str, band: float,
) -> Aligned:
    """Hold one state's estimates zero-order onto the truth times.

    Parameters
    ----------
    t_truth, truth : (n,) arrays
        Truth times [s] (increasing) and the truth of ``state``.
    est : DataFrame or mapping of (m,) arrays
        One observer's estimates of one state: ``t_s, value`` and optionally ``lo, hi, var`` (the
        long-format rows, or the columns of a track, :func:`state_columns`).
    """
    if isinstance(est, pd.DataFrame):
        cols = {c: est[c].to_numpy(float) for c in ALIGN_COLUMNS if c in est.columns}
    else:
        cols = {c: np.asarray(est[c], dtype=float) for c in ALIGN_COLUMNS if c in est}
    t_est = cols["t_s"]
    if t_est.size > 1 and not bool(np.all(t_est[1:] >= t_est[:-1])):  # observers emit in time order
        order = np.argsort(t_est, kind="stable")
        cols = {c: v[order] for c, v in cols.items()}
    # Scoring starts at the observer's first estimate (rows before it are "not started yet", e.g.
    # a radar observer before the first radar sample), not at its first output row.
    started = np.isfinite(cols["value"]) if "value" in cols else np.ones(t_est.size, bool)
    if started.any() and not started[0]:
        first = int(np.argmax(started))
        cols = {c: v[first:] for c, v in cols.items()}
    t_est = cols["t_s"]
    idx = np.searchsorted(t_est, t_truth + TIME_TOL_S, side="right") - 1
    keep = idx >= 0
    idx = idx[keep]
    t = t_truth[keep]
    tr = truth[keep]

    def column(name: str) -> np.ndarray:
        if name not in cols:
            return np.full(idx.size, np.nan)
        return cols[name][idx]

    value = column("value")
    err = value - tr
    if state.endswith("_rad"):
        err = wrap_angle(err)
    fresh = np.ones(idx.size, bool)
    fresh[1:] = idx[1:] != idx[:-1]
    dt = np.diff(t_truth).mean() if t_truth.size > 1 else 0.0
    dt_s = np.append(np.diff(t), dt) if t.size else np.empty(0)
    return Aligned(
        t_s=t, truth=tr, value=value, error=err, lo=column("lo"), hi=column("hi"), var=column("var"),
        fresh=fresh, dt_s=dt_s, t0_s=float(t_truth[0]) if t_truth.size else 0.0, band=band,
        finite_error=err[np.isfinite(err)],
    )


# ---- the scorer ----------------------------------------------------------------------------

def bound_fraction(a: Aligned, bounds: tuple[float, float]) -> float:
    """Fraction of the scored time ``a`` sits on (or past) ``bounds = (lo, hi)``; NaN if nothing is scored."""
    total = float(np.sum(a.dt_s))
    if not total > 0.0:
        return math.nan
    lo, hi = float(bounds[0]), float(bounds[1])
    finite = [abs(b) for b in (lo, hi) if math.isfinite(b)]
    tol = BOUND_TOL * max([1.0, *finite])
    with np.errstate(invalid="ignore"):
        on = (a.value <= lo + tol) | (a.value >= hi - tol)
    return float(np.sum(a.dt_s * on)) / total


def missing_fraction(a: Aligned) -> float:
    """Fraction of the scored time without a (finite) estimate; NaN if nothing is scored.

    Only where the truth itself is defined: a car at rest has no sideslip (NaN in the truth), and an
    observer that says nothing there has not failed.
    """
    defined = np.isfinite(a.truth)
    total = float(np.sum(a.dt_s * defined))
    if not total > 0.0:
        return math.nan
    return float(np.sum(a.dt_s * (defined & ~np.isfinite(a.value)))) / total


def _percent(fraction: float) -> str:
    p = 100.0 * fraction
    return f"{p:.1f}" if p < 10.0 else f"{p:.0f}"


#: States whose value has no natural zero (a pose in the world, a distance): "worse than assuming
#: zero" says nothing about them, so ``unusable_state_status`` leaves them alone.
NO_ZERO_BASELINE = frozenset({"x_m", "y_m", "psi_rad", "s_m", "range_m"})
#: An estimate whose RMS error exceeds both the state's own RMS over the scored window (the error of
#: the estimate 0) and its convergence band is not usable: ``unusable (…)``.
UNUSABLE_RATIO = 1.0
#: A truth whose RMS over the scored window is below this fraction of its convergence band is
#: "nearly zero" (e.g. the curvature of a straight road, identically 0): then "N× the error of
#: assuming zero" has no scale (any transient is "∞×", and the ratio exceeds 1/NEARLY_ZERO_FRACTION
#: as soon as the RMS error exceeds the band), so the estimate is judged against its band instead.
NEARLY_ZERO_FRACTION = 0.1
#: On a nearly-zero truth an estimate is unusable only if, besides an RMS error above the band, its
#: error is outside the band for more than this fraction of the scored time (it does not settle).
MAX_OUTSIDE_BAND_FRACTION = 0.5


def unusable_state_status(state: str, status: str, rmse_value: float, truth: np.ndarray, band: float,
                          error: np.ndarray | None = None, dt_s: np.ndarray | None = None) -> str:
    """``unusable (…)`` for a state whose estimate is worse than the trivial estimate 0 (and than its
    convergence band); otherwise ``status`` unchanged.

    Only ``ok`` is overridden. A kinematic integrator that drifted to 20° on a car whose sideslip
    stays within 2°, or a certified high-gain observer that turns range noise into 50 m/s² of
    acceleration error, is reported as such, not as ``ok`` with a number among numbers.

    Parameters
    ----------
    state, status : the canonical state name and the observer's status so far.
    rmse_value : RMS error of the estimate over the scored window [state unit].
    truth : (n,) true values over the scored window [state unit].
    band : convergence band [state unit] (NaN = none).
    error, dt_s : (n,) estimate - truth [state unit] and the time each row stands for [s]. Used
        when the truth is nearly zero (RMS(truth) < ``NEARLY_ZERO_FRACTION`` × band): then the
        estimate is unusable
        only if its error is also outside the band more than ``MAX_OUTSIDE_BAND_FRACTION`` of the
        time (a transient that settles back into the band is not unusable). Without them, an RMS
        error above the band is enough, as for any other state.
    """
    if not status.startswith("ok") or state in NO_ZERO_BASELINE or not math.isfinite(rmse_value):
        return status
    finite = truth[np.isfinite(truth)]
    if not finite.size:
        return status
    zero_error = float(np.sqrt(np.mean(finite ** 2)))
    floor = band if math.isfinite(band) else 0.0
    if rmse_value <= max(UNUSABLE_RATIO * zero_error, floor):
        return status
    if floor > 0.0 and zero_error < NEARLY_ZERO_FRACTION * floor:
        # A (nearly) zero truth: judge the estimate against the band, not against 0.
        if error is None:
            return f"unusable (RMS error {rmse_value / floor:.2g}× its convergence band; truth nearly 0)"
        weight = np.ones(error.shape) if dt_s is None else np.asarray(dt_s, float)
        scored = np.isfinite(truth)
        total = float(np.sum(weight * scored))
        outside = float(np.sum(weight * (scored & ~(np.abs(error) <= floor)))) / total if total > 0 else math.nan
        if not outside > MAX_OUTSIDE_BAND_FRACTION:
            return status
        return f"unusable (error outside its convergence band {_percent(outside)} % of the time; truth nearly 0)"
    ratio = rmse_value / zero_error
    what = f"{ratio:.2f}×" if ratio < 10 else f"{ratio:.0f}×"
    return f"unusable (RMS error {what} that of assuming zero)"


def usability_status(status: str, missing: float, saturated: float) -> str:
    """The status of an observer given the worst missing and on-bound fractions of its states.

    Only ``ok`` is overridden (error, diverged and skipped stay); missing estimates come before
    saturation (a gap is worse than a pinned value). NaN fractions (nothing scored) change nothing.
    """
    # A missing or pinned estimate is the more specific verdict than "unusable" (which it causes).
    if not (status.startswith("ok") or status.startswith("unusable")):
        return status
    if missing > MAX_MISSING_FRACTION:
        return f"diverged (no estimate for {_percent(missing)} % of the time)"
    if saturated > MAX_SATURATED_FRACTION:
        return f"saturated ({_percent(saturated)} % of the time)"
    return status


def _nan_metrics() -> dict[str, float]:
    return dict.fromkeys(METRIC_COLUMNS, math.nan)


def _run_fields(run: ObserverRunLike | None) -> dict[str, Any]:
    if run is None:
        return {"us_per_step": math.nan, "certified": None, "status": "ok"}
    return {"us_per_step": float(run.us_per_step) if run.us_per_step is not None else math.nan,
            "certified": run.certified, "status": str(run.status)}


def _declared_states(observer: str) -> tuple[str, ...]:
    """States an observer declares, from the registry (used when it produced no estimates)."""
    try:
        from roadtruth.observers.registry import observer_info
    except ImportError:
        return ()
    try:
        info = observer_info()
    except Exception:  # a broken plugin must not stop scoring of the others
        return ()
    entry = info.get(observer) if isinstance(info, Mapping) else None
    if entry is None and isinstance(info, list | tuple):
        entry = next((i for i in info if _get(i, "name") == observer), None)
    states = _get(entry, "states") if entry is not None else None
    return tuple(states or ())


def _declared_bounds(observer: str) -> Mapping[str, tuple[float, float]]:
    """``state_bounds`` of a registered observer class ({} when unknown or undeclared)."""
    try:
        from roadtruth.observers.registry import observer_class

        return dict(getattr(observer_class(observer), "state_bounds", {}) or {})
    except Exception:  # an unknown name (a synthetic or replayed run) or a broken plugin: no bounds
        return {}


ALIGN_COLUMNS: tuple[str, ...] = ("t_s", "value", "lo", "hi", "var")


def state_columns(track: Any, j: int) -> dict[str, np.ndarray]:
    """State ``j`` of an ``EstimateTrack`` as :func:`align` reads it: ``t_s, value`` and the bound and
    variance columns the track has (views, no copies)."""
    cols = {"t_s": track.t_s, "value": track.x[:, j]}
    for key, arr in (("lo", track.lo), ("hi", track.hi), ("var", track.var)):
        if arr is not None:
            cols[key] = arr[:, j]
    return cols


def _estimate_groups(estimates: Any) -> tuple[list[str], dict[tuple[str, str], Any]]:
    """Observers in order and (observer, state) -> that state's estimates, from the long frame or
    from a mapping observer -> ``EstimateTrack``."""
    if estimates is None:
        return [], {}
    if isinstance(estimates, pd.DataFrame):
        if not len(estimates):
            return [], {}
        groups = {k: g for k, g in estimates.groupby(["observer", "state"], sort=False)}
        return estimates["observer"].unique().tolist(), groups
    groups = {}
    for name, track in estimates.items():
        for j, state in enumerate(track.states):
            groups[(str(name), str(state))] = state_columns(track, j)
    return [str(n) for n in estimates], groups


def _get(obj: Any, key: str) -> Any:
    return obj.get(key) if isinstance(obj, Mapping) else getattr(obj, key, None)


def _mass_from_truth(truth_frame: pd.DataFrame) -> float | None:
    """Weight m*g from the summed normal loads at the start (the car is at rest vertically)."""
    cols = [f"fz_{w}_N" for w in ("fl", "fr", "rl", "rr")]
    if not all(c in truth_frame.columns for c in cols) or truth_frame.empty:
        return None
    total = truth_frame[cols].iloc[: max(1, len(truth_frame) // 20)].sum(axis=1).median()
    return float(total) / G if np.isfinite(total) and total > 0 else None


def score(
    truth_frame: pd.DataFrame,
    estimates_long: pd.DataFrame | Mapping[str, Any] | None,
    *,
    scenario: Any,
    runs: Mapping[str, ObserverRunLike],
    bands: Mapping[str, float] | None = None,
    mass_kg: float | None = None,
    scored_until_s: float | None = None,
    state_bounds: Mapping[str, Mapping[str, tuple[float, float]]] | None = None,
) -> pd.DataFrame:
    """Score every observer on every state it estimates.

    Parameters
    ----------
    truth_frame : DataFrame
        Truth with ``t_s`` and the canonical state columns (any rate; the simulation rate is best).
    estimates_long : DataFrame or mapping observer -> EstimateTrack
        ``t_s, observer, state, value, lo, hi`` (+ optional ``var``), as from
        ``roadtruth.harness.evaluation.estimate.run_observers``, or the tracks of
        ``run_observer_tracks`` (the same rows, without the long frame).
    scenario : str or Scenario
        Scenario name (or an object with ``.name``) written in every row.
    runs : {observer: ObserverRun}
        Status, cost and certification per observer. An observer in ``runs`` whose status is not
        ``ok`` still gets rows (metrics NaN, status carried); so does one without estimates.
    bands : {state: band}, optional
        Overrides of the convergence bands (state unit).
    mass_kg : float, optional
        Vehicle mass for the force bands; taken from the truth's normal loads if not given.
    scored_until_s : float, optional
        End of the scored window [s] (truth rows at or after it are not scored), e.g. the truth's
        first spin-out; None scores the whole record.
    state_bounds : {observer: {state: (lo, hi)}}, optional
        Each observer's declared state bounds for the saturation check; by default the
        ``state_bounds`` of its registered class.

    Returns
    -------
    DataFrame
        One row per (scenario, observer, state), columns ``COLUMNS``.
    """
    name = scenario if isinstance(scenario, str) else str(scenario.name)
    bands = dict(bands or {})
    mass = mass_kg if mass_kg is not None else _mass_from_truth(truth_frame)
    t_truth = truth_frame["t_s"].to_numpy(float) if "t_s" in truth_frame else np.empty(0)
    window = np.ones(t_truth.size, bool) if scored_until_s is None else t_truth < float(scored_until_s) - TIME_TOL_S
    t_scored = t_truth[window]
    until = float(t_truth[-1]) if t_truth.size else math.nan
    if scored_until_s is not None and t_truth.size:
        until = min(float(scored_until_s), until)
    estimated, groups = _estimate_groups(estimates_long)
    observers = list(dict.fromkeys([*runs.keys(), *estimated]))

    rows: list[dict[str, Any]] = []
    for obs in observers:
        run = runs.get(obs)
        carried = _run_fields(run)
        states = [s for (o, s) in groups if o == obs] or list(_declared_states(obs)) or [""]
        declared = (state_bounds.get(obs, {}) if state_bounds is not None else _declared_bounds(obs))
        obs_rows: list[dict[str, Any]] = []
        missing, saturated = [], []
        for state in states:
            band = bands.get(state, convergence_band(state, mass_kg=mass))
            row: dict[str, Any] = {"scenario": name, "observer": obs, "state": state,
                                   **_nan_metrics(), **carried, "conv_band": band, "n_scored": 0,
                                   "scored_until_s": until}
            g = groups.get((obs, state))
            healthy = carried["status"].startswith("ok")
            if healthy and state and g is not None:
                if state not in truth_frame.columns:
                    row["status"] = f"skipped: truth has no {state}"
                else:
                    truth_values = truth_frame[state].to_numpy(float)[window]
                    a = align(t_scored, truth_values, g, state, band)
                    row.update({k: f(a) for k, f in METRICS.items()})
                    row["n_scored"] = int(a.t_s.size)
                    row["status"] = unusable_state_status(state, str(row["status"]), row["rmse"],
                                                          a.truth, band, a.error, a.dt_s)
                    missing.append(missing_fraction(a))
                    if state in declared:
                        saturated.append(bound_fraction(a, declared[state]))
            elif healthy and state:
                row["status"] = "skipped: no estimates"
            obs_rows.append(row)
        worst_missing = max((f for f in missing if math.isfinite(f)), default=math.nan)
        worst_saturated = max((f for f in saturated if math.isfinite(f)), default=math.nan)
        for row in obs_rows:
            row["status"] = usability_status(str(row["status"]), worst_missing, worst_saturated)
        rows.extend(obs_rows)
    return pd.DataFrame(rows, columns=list(COLUMNS))
