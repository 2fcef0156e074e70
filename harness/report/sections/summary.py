"""Summary: what was run, how long it took, what failed, and whether frames could be rendered."""

from __future__ import annotations

from typing import Any

from harness.report.figures import display_unit, state_label
from harness.report.rundata import RunData
from harness.report.sections.base import Section
from harness.report.sections.leaderboard import short_status
from harness.report.sections.scenarios import slug


class SummarySection(Section):
    template = "summary.html"
    title = "Summary"
    anchor = "summary"

    def context(self, run: RunData, page: Any) -> dict[str, Any]:
        m = run.metrics
        failures = []
        for r in m.drop_duplicates(["scenario", "observer"]).itertuples():
            status = run.run_status(str(r.scenario), str(r.observer))
            if short_status(status) != "ok":
                failures.append({"scenario": r.scenario, "observer": r.observer, "status": status})
        scen_status = []
        for name in run.scenario_names:
            entry = run.scenario_entry(name)
            scen_status.append({"name": name, "anchor": f"scenario-{slug(name)}",
                                "status": entry.get("status", "ok"),
                                "duration_s": entry.get("duration_s")})
        render = run.run.get("render", {})
        if not render:  # e.g. a replay: the scenarios say why there are no frames
            reasons = [run.scenario_entry(n).get("render", {}).get("reason") for n in run.scenario_names]
            render = {"enabled": False, "reason": next((r for r in reasons if r), None)}
        timings = run.run.get("timings_s", {})
        return {
            "suite": run.run.get("suite", ""),
            "n_scenarios": len(run.scenario_names),
            "n_observers": len(run.observer_names),
            "n_rows": len(m),
            "n_runs": len(m.drop_duplicates(["scenario", "observer"])),
            "wall_s": run.run.get("wall_s"),
            "timings": timings,
            "failures": failures,
            "scenarios": scen_status,
            "render_enabled": render.get("enabled", False),
            "render_reason": render.get("reason"),
            "seed": run.run.get("seed"),
            "leaders": leaders(run, page),
        }


def leaders(run: RunData, page: Any) -> list[dict[str, Any]]:
    """Per state, the observer with the best mean RMSE rank over the scenarios (a failure ranks last)."""
    out = []
    m = run.metrics
    for state in run.scored_states:
        sm = m[m["state"] == state]
        observers = sorted(set(sm["observer"]))
        if not observers:
            continue
        ranks: dict[str, list[float]] = {o: [] for o in observers}
        for _, g in sm.groupby("scenario"):
            ok = g["status"].astype(str).str.startswith("ok") & g["rmse"].notna()
            order = g[ok].sort_values(["rmse", "observer"])["observer"].tolist()
            for o in observers:
                ranks[o].append(order.index(o) + 1 if o in order else len(observers))
        mean = {o: sum(r) / len(r) for o, r in ranks.items() if r}
        best = min(mean, key=lambda o: (mean[o], o))
        rmse = sm[(sm["observer"] == best) & sm["status"].astype(str).str.startswith("ok")]["rmse"]
        scale, unit = display_unit(state)
        out.append({"state": state, "label": state_label(state), "observer": best,
                    "colour": page.colours.get(best, "#444"), "mean_rank": mean[best],
                    "median_rmse": float(rmse.median()) * scale if len(rmse) else None, "unit": unit,
                    "n": len(observers)})
    return out
