"""Observers: citation, certification of the LMI design, cost per step, statuses per scenario."""

from __future__ import annotations

from typing import Any

from harness.report.rundata import RunData
from harness.report.sections.base import Section
from harness.report.sections.leaderboard import short_status


class ObserversSection(Section):
    template = "observers.html"
    title = "Observers and certification"
    anchor = "observers"

    def context(self, run: RunData, page: Any) -> dict[str, Any]:
        m = run.metrics
        info = {o.get("name"): o for o in run.run.get("observers", []) if isinstance(o, dict)}
        runs = run.run.get("observer_runs", {})
        rows = []
        for obs in run.observer_names:
            om = m[m["observer"] == obs]
            us = om["us_per_step"].dropna() if "us_per_step" in om else om.iloc[0:0]
            statuses = []
            reasons = []
            for scen in run.scenario_names:
                if not om[om["scenario"] == scen].empty:
                    status = run.run_status(scen, obs)
                    statuses.append({"scenario": scen, "status": status, "short": short_status(status)})
                r = runs.get(scen, {}).get(obs, {})
                if r.get("design_reason"):
                    reasons.append(str(r["design_reason"]))
            meta = info.get(obs, {})
            rows.append({
                "name": obs, "colour": page.colours.get(obs, "#444"),
                "citation": meta.get("citation", ""), "states": meta.get("states") or sorted(set(om["state"])),
                "design": page.designs.get(obs, "not_applicable"),
                "design_reason": "; ".join(dict.fromkeys(reasons)),
                "us_per_step": float(us.median()) if len(us) else None,
                "statuses": statuses,
                "n_failed": sum(1 for s in statuses if s["short"] != "ok"),
            })
        return {"rows": rows}
