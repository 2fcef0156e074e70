"""Leaderboard: one table per state, observers × scenarios, coloured and sortable in the page.

Cells say one of three things: a number (scored), a grey "n/a — needs radar" (not applicable), or
a red status (failed: the estimate is not usable). Ranks come from ``roadtruth.harness.report.ranking``,
computed here for every switchable metric; the page only shows them."""

from __future__ import annotations

import math
from typing import Any

import pandas as pd

from roadtruth.harness.report.figures import display_unit, state_label
from roadtruth.harness.report.ranking import MeanRank, rank_state
from roadtruth.harness.report.rundata import RunData
from roadtruth.harness.report.sections.base import Section
from roadtruth.harness.report.verdicts import ABSENT, FAILED, NOT_APPLICABLE, OK, status_kind, status_label

#: Metrics the page can switch between: (column, label, scaled by the state's display unit?, sense).
#: sense: "low" = lower is better, "high" = higher is better, "one" = closer to 1 is better.
SWITCHABLE: tuple[tuple[str, str, bool, str], ...] = (
    ("rmse", "RMSE", True, "low"),
    ("max_abs", "max |e|", True, "low"),
    ("p95_abs", "p95 |e|", True, "low"),
    ("bias", "bias", True, "low"),
    ("conv_time_s", "convergence [s]", False, "low"),
    ("coverage", "coverage", False, "high"),
    ("mean_width", "mean width", True, "low"),
    ("nees_mean", "NEES", False, "one"),
)


def short_status(status: str) -> str:
    """'error: LMI infeasible' -> 'error'; 'ok' -> 'ok'."""
    return status.split(":", 1)[0].strip() or "ok"


def certification_of(rows: pd.DataFrame | list[dict[str, Any]]) -> str:
    """'certified' if every design was certified, 'not certified' if any was not, else 'n/a'.
    ``rows``: metrics rows, as a frame or as dicts (``RunData.records``)."""
    cells = (rows.get("certified", pd.Series(dtype=object)).tolist() if isinstance(rows, pd.DataFrame)
             else [r.get("certified") for r in rows])
    vals = [v for v in cells if _truthy(v) is not None]
    if not vals:
        return "n/a"
    return "certified" if all(_truthy(v) for v in vals) else "not certified"


def _truthy(v: Any) -> bool | None:
    if isinstance(v, bool):
        return v
    if isinstance(v, float) and math.isnan(v):
        return None
    s = str(v).strip().lower()
    if s in ("true", "1", "1.0", "yes"):
        return True
    if s in ("false", "0", "0.0", "no"):
        return False
    return None


def _num(v: Any, scale: float = 1.0) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f * scale if math.isfinite(f) else None


def state_ranks(run: RunData, state: str, column: str = "rmse",
                scenarios: list[str] | None = None) -> dict[str, MeanRank]:
    """Mean ranks of every observer on one state and metric: the one function behind the
    leaderboard's rank column and the summary's best-observer cards."""
    scenarios = scenarios if scenarios is not None else table_scenarios(run, state)
    key = ("state_ranks", state, column, tuple(scenarios))
    if key in run.memo:  # the summary's cards and the leaderboard rank the same rows
        return run.memo[key]
    sense = next((sense for col, _, _, sense in SWITCHABLE if col == column), "low")
    scaled = next((sc for col, _, sc, _ in SWITCHABLE if col == column), False)
    scale = display_unit(state)[0] if scaled else 1.0
    run.memo[key] = rank_state(state_rows(run, state), state, column, sense, scenarios, scale=scale)
    return run.memo[key]


def state_rows(run: RunData, state: str) -> list[dict[str, Any]]:
    """The metrics rows of one state (as ``RunData.records``), plus the run-level rows (empty state:
    the observer errored before giving any estimate) of observers that declare this state in
    run.json, so that a crashed observer shows as failed in the table of each state it estimates
    instead of vanishing. Rows of the state first, in file order, then those run-level ones."""
    key = ("state_rows", state)
    if key in run.memo:
        return run.memo[key]
    declared = {str(o.get("name")) for o in run.run.get("observers", [])
                if isinstance(o, dict) and state in (o.get("states") or [])}
    rows = [r for r in run.records if r["state"] == state]
    have = {(str(r["observer"]), str(r["scenario"])) for r in rows}
    extra = [{**r, "state": state} for r in run.records
             if r["state"] == "" and str(r["observer"]) in declared
             and (str(r["observer"]), str(r["scenario"])) not in have]
    run.memo[key] = rows + extra
    return run.memo[key]


def table_scenarios(run: RunData, state: str) -> list[str]:
    """Scenario columns of a state's table: those where some observer ran (ok or failed). A column
    where every observer was not applicable (no radar, say) would only say "n/a" in each row."""
    used = {str(r["scenario"]) for r in state_rows(run, state) if status_kind(str(r["status"])) != NOT_APPLICABLE}
    return [s for s in run.scenario_names if s in used]


class LeaderboardSection(Section):
    template = "leaderboard.html"
    title = "Leaderboard"
    anchor = "leaderboard"

    def context(self, run: RunData, page: Any) -> dict[str, Any]:
        tables = []
        for state in run.scored_states:
            scale, unit = display_unit(state)
            scenarios = table_scenarios(run, state)
            sm = state_rows(run, state)
            observers = list(dict.fromkeys(str(r["observer"]) for r in sm))
            ranks = {col: state_ranks(run, state, col, scenarios) for col, _, _, _ in SWITCHABLE}
            # One pass over the rows (first row per observer × scenario), not a filter per cell.
            by_cell = {(str(r["observer"]), str(r["scenario"])): r for r in reversed(sm)}
            rows = []
            for obs in observers:
                cells = []
                for scen in scenarios:
                    r0 = by_cell.get((obs, scen))
                    if r0 is None:
                        cells.append({"present": False, "kind": ABSENT})
                        continue
                    status = str(r0["status"])
                    values = {col: _num(r0.get(col), scale if scaled else 1.0)
                              for col, _, scaled, _ in SWITCHABLE}
                    cell_ranks = {col: ranks[col][obs].ranks.get(scen) for col in ranks}
                    cells.append({"present": True, "status": status, "kind": status_kind(status),
                                  "label": status_label(status), "short": short_status(status),
                                  "ok": status_kind(status) == OK, "values": values, "ranks": cell_ranks,
                                  "certified": _truthy(r0.get("certified"))})
                mean_ranks = {col: {"mean": ranks[col][obs].mean, "n": ranks[col][obs].n_ranked,
                                    "of": ranks[col][obs].n_scenarios} for col in ranks}
                rows.append({"observer": obs, "colour": page.colours.get(obs, "#444"),
                             "swatch": page.swatch(obs),
                             "design": page.designs.get(obs, "not_applicable"), "cells": cells,
                             "mean_ranks": mean_ranks, "rmse_rank": ranks["rmse"][obs],
                             "failures": sum(1 for c in cells if c["kind"] == FAILED)})
            tables.append({"state": state, "label": state_label(state), "unit": unit, "rows": rows,
                           "scenarios": scenarios})
        metrics = [{"col": c, "label": lab, "sense": sense, "scaled": sc} for c, lab, sc, sense in SWITCHABLE]
        unscored = [s for s in run.states if s not in run.scored_states]
        return {"tables": tables, "metrics": metrics, "unscored": unscored}
