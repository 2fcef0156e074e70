"""Properties that ``roadtruth falsify`` tries to break, and their robustness on one evaluated case.

Robustness is a signed number: positive = the property holds with that margin, negative = violated
by that much. The search minimises it.

=============================== ================================================================
``--property``                  robustness
=============================== ================================================================
``coverage:STATE``              min over the scored time of ``min(truth − lo, hi − truth)`` [state
                                unit]: the worst signed distance of the truth outside the bounds
``coverage``                    the same for every bounded state, each divided by that state's mean
                                interval width; the minimum [interval widths]
``rmse:STATE<=X`` (also         ``X − metric`` [state unit], the metric of ``metrics.csv``
``max_abs``, ``p95_abs``,
``mae``, ``bias``)
``nees[:STATE]``                ``min(ln(m / lo), ln(hi / m))`` with m the mean NEES and [lo, hi] its
                                two-sided 95 % χ² band (``roadtruth.harness.evaluation.scoring.nees_band``) [1]
``check:RULES.yaml``            the least margin over the file's rules that match the observer: a
                                numeric rule ``(max − v) / |max|`` or ``(v − min) / |min|``; a flag or
                                status rule ±1 [1]
=============================== ================================================================

Only the scored window counts (up to a spin-out or roll-over, ``roadtruth.harness.truth.truth_events``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.errors import InputError

ERROR_METRICS = ("rmse", "max_abs", "p95_abs", "mae", "bias")
PROPERTY_KINDS = ("coverage", *ERROR_METRICS, "nees", "check")
_ERROR_RE = re.compile(r"^(?P<metric>[a-z0-9_]+):(?P<state>[A-Za-z0-9_]+)\s*<=?\s*(?P<x>[-+0-9.eE]+)$")


class PropertyError(InputError):
    """``--property`` is malformed or does not fit the observer."""


@dataclass(frozen=True)
class Property:
    """A parsed ``--property``: kind, state (None = every applicable state), threshold, rules file."""

    kind: str
    state: str | None = None
    threshold: float = math.nan
    rules: str | None = None
    text: str = ""

    def phrase(self) -> str:
        """What a violation means, in words (the start of the finding sentence)."""
        on = f" of {self.state}" if self.state else ""
        if self.kind == "coverage":
            return f"inclusion{on} lost"
        if self.kind in ERROR_METRICS:
            return f"{self.kind}{on} above {self.threshold:g}"
        if self.kind == "nees":
            return f"NEES{on} outside its 95 % chi-square band"
        return f"check rules of {Path(self.rules or '').name} failed"


def parse_property(text: str) -> Property:
    """Parse ``--property`` (see the module doc). Raises :class:`PropertyError`."""
    t = str(text).strip()
    head, _, rest = t.partition(":")
    if head == "coverage" or head == "nees":
        state = rest.strip() or None
        if state is not None and not state.isidentifier():
            raise PropertyError(f"not a state name (got {state!r})", field="--property")
        return Property(head, state=state, text=t)
    if head == "check":
        path = rest.strip()
        if not path:
            raise PropertyError("check needs a thresholds file: check:RULES.yaml", field="--property")
        from roadtruth.harness.jobs.check_rules import load_thresholds

        load_thresholds(Path(path))  # bad rules fail now, before any work
        return Property("check", rules=path, text=t)
    m = _ERROR_RE.match(t)
    if m and m["metric"] in ERROR_METRICS:
        try:
            x = float(m["x"])
        except ValueError:
            m = None
        else:
            return Property(m["metric"], state=m["state"], threshold=x, text=t)
    raise PropertyError(f"must be coverage[:STATE], nees[:STATE], METRIC:STATE<=X (METRIC one of "
                        f"{', '.join(ERROR_METRICS)}) or check:RULES.yaml (got {t!r})", field="--property")


def check_fits(prop: Property, observer: str) -> None:
    """Refuse a property the observer cannot have (no bounds, no covariance, a state it lacks)."""
    from roadtruth.observers.registry import observer_class

    cls = observer_class(observer)
    if prop.state is not None and prop.state not in cls.states:
        raise PropertyError(f"observer {observer!r} does not estimate {prop.state!r} (it estimates "
                            f"{', '.join(cls.states)})", field="--property")
    if prop.kind == "coverage" and not cls.has_bounds:
        raise PropertyError(f"observer {observer!r} gives no bounds, so it promises no inclusion",
                            field="--property")
    if prop.kind == "nees" and not cls.has_covariance:
        raise PropertyError(f"observer {observer!r} gives no variance, so it has no NEES", field="--property")


def _aligned(truth: pd.DataFrame, est: pd.DataFrame, state: str, until: float | None) -> Any:
    from roadtruth.harness.evaluation.scoring import align

    t = truth["t_s"].to_numpy(float)
    keep = t < until if until is not None else np.ones(t.size, bool)
    rows = est[est["state"] == state]
    return align(t[keep], truth[state].to_numpy(float)[keep], rows, state, math.nan)


def _states(prop: Property, est: pd.DataFrame, column: str) -> list[str]:
    if prop.state is not None:
        return [prop.state]
    have = est.dropna(subset=[column]) if column in est else est.iloc[0:0]
    return sorted(set(have["state"]))


def _coverage(prop: Property, truth: pd.DataFrame, est: pd.DataFrame, until: float | None) -> float:
    worst = math.inf
    states = _states(prop, est, "lo")
    for s in states:
        if s not in truth:
            continue
        a = _aligned(truth, est, s, until)
        m = np.isfinite(a.lo) & np.isfinite(a.hi) & np.isfinite(a.truth)
        if not m.any():
            continue
        d = float(np.min(np.minimum(a.truth[m] - a.lo[m], a.hi[m] - a.truth[m])))
        if prop.state is None:  # several units: measured in interval widths
            width = float(np.mean(a.hi[m] - a.lo[m]))
            d = d / width if width > 0 else (-math.inf if d < 0 else math.inf)
        worst = min(worst, d)
    return worst if math.isfinite(worst) else math.nan


def _nees(prop: Property, truth: pd.DataFrame, est: pd.DataFrame, until: float | None) -> float:
    from roadtruth.harness.evaluation.scoring import _nees_samples, nees_band

    worst = math.inf
    for s in _states(prop, est, "var"):
        if s not in truth:
            continue
        q = _nees_samples(_aligned(truth, est, s, until))
        if q.size < 2:
            continue
        lo, hi = nees_band(q.size)
        m = float(np.mean(q))
        worst = min(worst, math.log(max(m, 1e-300) / lo), math.log(hi / max(m, 1e-300)))
    return worst if math.isfinite(worst) else math.nan


def _check(prop: Property, metrics: pd.DataFrame, observer: str) -> float:
    from fnmatch import fnmatchcase

    from roadtruth.harness.jobs.check import evaluate
    from roadtruth.harness.jobs.check_rules import load_thresholds, metric_kind

    worst = math.inf
    rows = metrics[metrics["observer"] == observer]
    for rule in load_thresholds(Path(prop.rules or "")).rules:
        if not any(fnmatchcase(observer, p) for p in rule.observer):
            continue
        numeric = metric_kind(rule.metric) == "number" and rule.equals is None
        for o in evaluate(rows, [rule]):
            if o.verdict == "skip" or o.kind == "rule":
                continue
            v = o.value
            finite = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(float(v))
            if numeric and finite:
                margins = [(rule.max - float(v)) / max(abs(rule.max), 1e-12)] if rule.max is not None else []
                if rule.min is not None:
                    margins.append((float(v) - rule.min) / max(abs(rule.min), 1e-12))
                worst = min(worst, *margins) if margins else worst
            else:
                worst = min(worst, 1.0 if o.verdict == "pass" else -1.0)
    return worst if math.isfinite(worst) else math.nan


def robustness(prop: Property, truth: pd.DataFrame, est: pd.DataFrame, metrics: pd.DataFrame, observer: str,
               until: float | None) -> float:
    """The property's robustness on one case (NaN when it cannot be judged, e.g. no bounded rows).

    ``truth``: the truth frame; ``est``: the observer's long estimates; ``metrics``: its scored rows
    (``roadtruth.harness.evaluation.scoring.score``); ``until``: end of the scored window [s] or None.
    """
    est = est[est["observer"] == observer]
    if prop.kind == "coverage":
        return _coverage(prop, truth, est, until)
    if prop.kind == "nees":
        return _nees(prop, truth, est, until)
    if prop.kind == "check":
        return _check(prop, metrics, observer)
    row = metrics[(metrics["observer"] == observer) & (metrics["state"] == prop.state)]
    if row.empty or not np.isfinite(float(row[prop.kind].iloc[0])):
        return math.nan
    value = float(row[prop.kind].iloc[0])
    return prop.threshold - (abs(value) if prop.kind == "bias" else value)


__all__ = ["ERROR_METRICS", "PROPERTY_KINDS", "Property", "PropertyError", "check_fits", "parse_property",
           "robustness"]
