"""Observers: citation, certification of the LMI design, and per scenario whether the
run was ok, not applicable (grey) or failed (red) — three separate things."""

from __future__ import annotations

from typing import Any

from roadtruth.harness.report.rundata import RunData
from roadtruth.harness.report.sections.base import Section
from roadtruth.harness.report.verdicts import (
    FAILED,
    NOT_APPLICABLE,
    count_statuses,
    run_verdict,
    status_kind,
    status_label,
)


class ObserversSection(Section):
    template = "observers.html"
    title = "Observers and certification"
    anchor = "observers"

    def context(self, run: RunData, page: Any) -> dict[str, Any]:
        states_of: dict[str, set[str]] = {}  # observer -> the states of its metrics rows
        for r in run.records:
            states_of.setdefault(str(r["observer"]), set()).add(r["state"])
        info = {o.get("name"): o for o in run.run.get("observers", []) if isinstance(o, dict)}
        runs = run.run.get("observer_runs", {})
        rows = []
        for obs in run.observer_names:
            statuses = []
            reasons = []
            for scen in run.scenario_names:
                rows_here = run.row_statuses.get((scen, obs))
                if rows_here:
                    status = run_verdict(run.run_status(scen, obs), rows_here)
                    statuses.append({"scenario": scen, "status": status, "kind": status_kind(status),
                                     "label": status_label(status)})
                r = runs.get(scen, {}).get(obs, {})
                if r.get("design_reason"):
                    reasons.append(str(r["design_reason"]))
            meta = info.get(obs, {})
            rows.append({
                "name": obs, "colour": page.colours.get(obs, "#444"), "swatch": page.swatch(obs),
                "citation": meta.get("citation", ""), "states": meta.get("states") or sorted(states_of.get(obs, ())),
                "design": page.designs.get(obs, "not_applicable"),
                "design_reason": "; ".join(dict.fromkeys(reasons)),
                "statuses": statuses,
                "counts": count_statuses(s["status"] for s in statuses),
                "na_labels": sorted({s["label"] for s in statuses if s["kind"] == NOT_APPLICABLE}),
                "n_failed": sum(1 for s in statuses if s["kind"] == FAILED),
            })
        return {"rows": rows}
