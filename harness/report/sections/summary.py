"""Summary: what was run, what failed (and, apart from it, what could not run),
what the truth did, and whether frames could be rendered."""

from __future__ import annotations

from typing import Any

import pandas as pd

from roadtruth.harness.report.figures import display_unit, state_label
from roadtruth.harness.report.ranking import leaders as best_of
from roadtruth.harness.report.rundata import RunData
from roadtruth.harness.report.sections.base import Section
from roadtruth.harness.report.sections.leaderboard import state_ranks
from roadtruth.harness.report.sections.scenarios import slug, truth_summary
from roadtruth.harness.report.verdicts import (
    FAILED,
    NOT_APPLICABLE,
    count_statuses,
    run_verdict,
    status_kind,
    status_label,
)


def observer_run_statuses(run: RunData) -> list[dict[str, str]]:
    """One entry per (scenario, observer) run: its status as counted, kind and short label."""
    out = []
    for (scen, obs), rows in run.row_statuses.items():
        status = run_verdict(run.run_status(scen, obs), rows)
        out.append({"scenario": str(scen), "observer": str(obs), "status": status,
                    "kind": status_kind(status), "label": status_label(status)})
    return out


class SummarySection(Section):
    template = "summary.html"
    title = "Summary"
    anchor = "summary"

    def context(self, run: RunData, page: Any) -> dict[str, Any]:
        runs = observer_run_statuses(run)
        counts = count_statuses(r["status"] for r in runs)
        failures = [r for r in runs if r["kind"] == FAILED]
        # Not applicable, grouped by reason: "hgo_radar_multi, hgo_radar_standard on 6 scenarios".
        na_groups: dict[str, dict[str, set[str]]] = {}
        for r in runs:
            if r["kind"] == NOT_APPLICABLE:
                g = na_groups.setdefault(r["label"], {"observers": set(), "scenarios": set()})
                g["observers"].add(r["observer"])
                g["scenarios"].add(r["scenario"])
        not_applicable = [{"label": k, "observers": sorted(v["observers"]), "n_scenarios": len(v["scenarios"])}
                          for k, v in sorted(na_groups.items())]
        scen_status = []
        for name in run.scenario_names:
            entry = run.scenario_entry(name)
            scen_status.append({"name": name, "anchor": f"scenario-{slug(name)}",
                                "status": entry.get("status", "ok"),
                                "truth": truth_summary(entry, run.scenario(name).events),
                                "duration_s": entry.get("duration_s")})
        render = run.run.get("render", {})
        if not render:  # e.g. a replay: the scenarios say why there are no frames
            reasons = [run.scenario_entry(n).get("render", {}).get("reason") for n in run.scenario_names]
            render = {"enabled": False, "reason": next((r for r in reasons if r), None)}
        return {
            "suite": run.run.get("suite", ""),
            "n_scenarios": len(run.scenario_names),
            "n_observers": len(run.observer_names),
            "n_rows": len(run.metrics),
            "n_runs": counts.total,
            "counts": counts,
            "failures": failures,
            "not_applicable": not_applicable,
            "scenarios": scen_status,
            "render_enabled": render.get("enabled", False),
            "render_reason": render.get("reason"),
            "seed": run.run.get("seed"),
            "leaders": leaders(run, page),
        }


def leaders(run: RunData, page: Any) -> list[dict[str, Any]]:
    """Per state, the observer(s) with the best mean RMSE rank among those scored in the most
    scenarios — from ``state_ranks``, the same function the leaderboard's rank column uses."""
    out = []
    for state in run.scored_states:
        ranks = state_ranks(run, state, "rmse")
        best = best_of(ranks)
        if not best:
            continue
        scale, unit = display_unit(state)
        names = [b.observer for b in best]
        chosen = set(names)
        rmse = pd.Series([r["rmse"] for r in run.records if r["state"] == state and r["observer"] in chosen
                          and status_kind(r["status"]) == "ok"], dtype=float).dropna()
        out.append({"state": state, "label": state_label(state), "observers": names,
                    "swatches": [page.swatch(n) for n in names], "mean_rank": best[0].mean,
                    "n_ranked": best[0].n_ranked, "n_scenarios": best[0].n_scenarios,
                    "n_observers": sum(1 for r in ranks.values() if r.mean is not None),
                    "median_rmse": float(rmse.median()) * scale if len(rmse) else None, "unit": unit})
    return out
