"""Ranks of observers per scenario and their mean over scenarios — the one computation behind both
the leaderboard tables and the summary's "best observer" cards.

Rules (each one a claim the page makes):

* Only **scored** cells are ranked: status ``ok`` and a finite value of the chosen metric. Skipped,
  failed and empty cells get no rank and do not count in the mean.
* **Ties share the minimum rank** ("1, 1, 3": standard competition ranking). Two values are tied
  when they are equal to 3 significant digits, the precision the table shows: a rank never reflects
  a difference the reader cannot see. Never an alphabetical tie-break.
* The mean rank of an observer is over the scenarios where it was ranked, and is always given with
  that count ("2.3 over 5 of 7 scenarios").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pandas as pd

from roadtruth.harness.report.verdicts import OK, status_kind

#: How each switchable metric is ordered: "low" = smaller |v| is better, "high" = larger is better,
#: "one" = closer to 1 is better (NEES of a consistent filter).
SENSES = ("low", "high", "one")

SHOWN_DIGITS = 3


def badness(value: float, sense: str) -> float:
    """Sort key, lower is better; the value first rounded to the precision the page shows."""
    v = float(f"{value:.{SHOWN_DIGITS}g}")
    if sense == "high":
        return -v
    if sense == "one":
        return abs(math.log(max(v, 1e-12)))
    if sense == "low":
        return abs(v)
    raise ValueError(f"unknown sense {sense!r}")


def competition_ranks(scores: dict[str, float]) -> dict[str, int]:
    """Rank 1 = lowest score; equal scores share the lowest rank of their group (1, 1, 3)."""
    ordered = sorted(scores.values())
    return {k: 1 + ordered.index(v) for k, v in scores.items()}


@dataclass(frozen=True)
class MeanRank:
    """An observer's mean rank on one state and metric."""

    observer: str
    mean: float | None        # None when it was ranked nowhere
    n_ranked: int             # scenarios where it had a scored cell
    n_scenarios: int          # scenario columns of the table
    ranks: dict[str, int]     # scenario -> rank (only ranked scenarios)

    @property
    def coverage_text(self) -> str:
        if self.mean is None:
            return f"not ranked in any of {self.n_scenarios} scenarios"
        return f"{self.mean:.1f} over {self.n_ranked} of {self.n_scenarios} scenario{'s' if self.n_scenarios != 1 else ''}"


def rank_state(metrics: pd.DataFrame | Sequence[Mapping[str, Any]], state: str, column: str, sense: str,
               scenarios: Sequence[str], observers: Sequence[str] | None = None,
               scale: float = 1.0) -> dict[str, MeanRank]:
    """Per-scenario competition ranks of every observer on ``state`` by ``column`` and their means.

    ``metrics`` has the ``metrics.csv`` columns (``scenario, observer, state, status, <column>``),
    as a frame or as its rows (dicts, e.g. ``RunData.records``). ``observers`` fixes the rows
    (default: every observer with a row for this state). ``scale`` converts the SI value to the unit
    the table shows it in (e.g. rad -> deg), so that ties are judged on the digits the reader sees.
    """
    if isinstance(metrics, pd.DataFrame):
        metrics = metrics.to_dict("records")
    sm = [r for r in metrics if str(r.get("state")) == state]
    if observers is None:
        observers = list(dict.fromkeys(str(r.get("observer")) for r in sm))
    per_obs: dict[str, dict[str, int]] = {o: {} for o in observers}
    by_scenario: dict[str, dict[str, float]] = {}
    for r in sm:
        obs = str(r.get("observer"))
        if obs not in per_obs or column not in r or status_kind(str(r.get("status"))) != OK:
            continue
        v = number(r[column])
        if math.isfinite(v):
            by_scenario.setdefault(str(r.get("scenario")), {})[obs] = badness(v * scale, sense)
    for scen in scenarios:
        for obs, rank in competition_ranks(by_scenario.get(scen, {})).items():
            per_obs[obs][scen] = rank
    out = {}
    for obs, ranks in per_obs.items():
        mean = sum(ranks.values()) / len(ranks) if ranks else None
        out[obs] = MeanRank(observer=obs, mean=mean, n_ranked=len(ranks), n_scenarios=len(scenarios), ranks=ranks)
    return out


def number(v: Any) -> float:
    """A cell as a float, NaN when it holds none (what ``pd.to_numeric(errors="coerce")`` gives)."""
    if v is None:
        return math.nan
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def leaders(ranks: dict[str, MeanRank]) -> list[MeanRank]:
    """The best observers of one table: lowest mean rank among those ranked in the most scenarios
    (an observer ranked once, at 1, does not beat one ranked first in six of seven); all tied ones."""
    ranked = [r for r in ranks.values() if r.mean is not None]
    if not ranked:
        return []
    most = max(r.n_ranked for r in ranked)
    pool = [r for r in ranked if r.n_ranked == most]
    best = min(round(r.mean, 9) for r in pool if r.mean is not None)
    return sorted((r for r in pool if r.mean is not None and round(r.mean, 9) == best), key=lambda r: r.observer)

