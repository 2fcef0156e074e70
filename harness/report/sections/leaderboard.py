"""Leaderboard: one table per state, observers × scenarios, coloured and sortable in the page."""

from __future__ import annotations

import math
from typing import Any

import pandas as pd

from harness.report.figures import display_unit, state_label
from harness.report.rundata import RunData
from harness.report.sections.base import Section

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


def certification_of(rows: pd.DataFrame) -> str:
    """'certified' if every design was certified, 'not certified' if any was not, else 'n/a'."""
    vals = [v for v in rows.get("certified", pd.Series(dtype=object)).tolist() if _truthy(v) is not None]
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


class LeaderboardSection(Section):
    template = "leaderboard.html"
    title = "Leaderboard"
    anchor = "leaderboard"

    def context(self, run: RunData, page: Any) -> dict[str, Any]:
        m = run.metrics
        scenarios = run.scenario_names
        tables = []
        for state in run.scored_states:
            scale, unit = display_unit(state)
            sm = m[m["state"] == state]
            observers = list(dict.fromkeys(sm["observer"].astype(str)))
            rows = []
            for obs in observers:
                om = sm[sm["observer"] == obs]
                cells = []
                for scen in scenarios:
                    r = om[om["scenario"] == scen]
                    if r.empty:
                        cells.append({"present": False})
                        continue
                    r0 = r.iloc[0]
                    status = str(r0["status"])
                    values = {col: _num(r0.get(col), scale if scaled else 1.0)
                              for col, _, scaled, _ in SWITCHABLE}
                    cells.append({"present": True, "status": status, "short": short_status(status),
                                  "ok": short_status(status) == "ok", "values": values,
                                  "certified": _truthy(r0.get("certified"))})
                rows.append({"observer": obs, "colour": page.colours.get(obs, "#444"),
                             "design": page.designs.get(obs, "not_applicable"), "cells": cells,
                             "failures": sum(1 for c in cells if c.get("present") and not c["ok"])})
            tables.append({"state": state, "label": state_label(state), "unit": unit, "rows": rows})
        metrics = [{"col": c, "label": lab, "sense": sense, "scaled": sc} for c, lab, sc, sense in SWITCHABLE]
        unscored = [s for s in run.states if s not in run.scored_states]
        return {"tables": tables, "scenarios": scenarios, "metrics": metrics, "unscored": unscored}
