"""Per scenario: the path over the friction map, truth vs estimates with bounds, errors, events,
rendered frames and the video."""

from __future__ import annotations

import re
from typing import Any

from harness.report.figures import state_figure, trajectory_figure
from harness.report.rundata import RunData
from harness.report.sections.base import Section


def slug(text: str) -> str:
    return re.sub(r"[^a-zA-Z0-9_-]+", "-", text).strip("-") or "x"


class ScenariosSection(Section):
    template = "scenarios.html"
    title = "Scenarios"
    anchor = "scenarios"

    def context(self, run: RunData, page: Any) -> dict[str, Any]:
        items = []
        for name in run.scenario_names:
            files = run.scenario(name)
            entry = run.scenario_entry(name)
            info = files.info
            truth, est, events = files.truth, files.estimates, files.events
            figures = []
            if not truth.empty and {"x_m", "y_m"} <= set(truth.columns):
                figures.append({"id": f"fig-{slug(name)}-path", "spec": trajectory_figure(truth, info, events),
                                "wide": False})
            sm = run.metrics[run.metrics["scenario"] == name]
            ok = sm["status"].astype(str).str.startswith("ok") & sm["rmse"].notna()
            states = [s for s in run.scored_states if s in set(sm.loc[ok, "state"])]
            for state in states:
                if truth.empty and est.empty:
                    break
                figures.append({"id": f"fig-{slug(name)}-{slug(state)}",
                                "spec": state_figure(state, truth, est, page.colours, events), "wide": False})
            render = entry.get("render", {}) or {}
            frames = [f for f in render.get("frames", []) if (run.folder / f.get("file", "")).is_file()]
            video = render.get("video")
            if video and not (run.folder / video).is_file():
                video = None
            items.append({
                "name": name, "anchor": f"scenario-{slug(name)}",
                "description": entry.get("description") or info.get("description", ""),
                "tags": entry.get("tags") or info.get("tags", []),
                "status": entry.get("status", "ok"),
                "duration_s": entry.get("duration_s") or info.get("duration_s"),
                "vehicle": entry.get("vehicle") or info.get("vehicle"),
                "seed": entry.get("seed"),
                "events": events,
                "figures": figures,
                "frames": frames,
                "video": video,
                "render_reason": render.get("reason"),
            })
        return {"scenarios": items}
