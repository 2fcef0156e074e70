"""Per scenario: the path over the friction map, truth vs estimates with bounds, errors, events,
rendered frames and the video."""

from __future__ import annotations

import math
import re
from typing import Any

import pandas as pd

from roadtruth.harness.report.figures import TRUTH_EVENTS, state_figure, trajectory_figure
from roadtruth.harness.report.plot_data import PIXEL_COLUMNS, STEPS_PER_SPAN
from roadtruth.harness.report.ranking import number
from roadtruth.harness.report.rundata import RunData
from roadtruth.harness.report.sections.base import Section


def slug(text: str) -> str:
    return re.sub(r"[^a-zA-Z0-9_-]+", "-", text).strip("-") or "x"


def truth_events(entry: dict[str, Any], events: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """What the car did that no observer is to blame for (spun out, left the road, …), with times:
    run.json's ``truth_events`` when the run wrote them, else those events of ``events.json``."""
    listed = entry.get("truth_events")
    if isinstance(listed, list):
        out = [e for e in listed if isinstance(e, dict) and isinstance(e.get("t_s"), int | float)]
    else:
        out = [e for e in events if str(e.get("label", "")).split(" (")[0] in TRUTH_EVENTS or e.get("kind") == "truth"]
    return sorted(out, key=lambda e: float(e["t_s"]))


def truth_summary(entry: dict[str, Any], events: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The truth's status for the scenario header: ``{"text", "bad"}``, or None when the run folder
    does not say (older runs)."""
    evs = truth_events(entry, events)
    status = entry.get("truth_status")
    if evs:
        text = "; ".join(f"{e.get('label', '')} at {float(e['t_s']):.3g} s" for e in evs)
        return {"text": text, "bad": True}
    if isinstance(status, str) and status:
        return {"text": status, "bad": status != "ok"}
    return None


def scored_until(metrics: pd.DataFrame | list[dict[str, Any]]) -> float | None:
    """Where scoring of a scenario stopped (``scored_until_s`` column, earliest finite value), or
    None when the column is absent or every row was scored to the end. ``metrics``: the scenario's
    metrics rows, as a frame or as dicts (``RunData.records``)."""
    if isinstance(metrics, pd.DataFrame):
        if "scored_until_s" not in metrics.columns:
            return None
        metrics = metrics.to_dict("records")
    v = [x for x in (number(r.get("scored_until_s")) for r in metrics) if math.isfinite(x)]
    return min(v) if v else None


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
            truth, events = files.truth, files.events
            figures = []
            if not truth.empty and {"x_m", "y_m"} <= set(truth.columns):
                figures.append({"id": f"fig-{slug(name)}-path", "spec": trajectory_figure(truth, info, events),
                                "wide": False})
            rows = [r for r in run.records if r["scenario"] == name]
            scored = {r["state"] for r in rows if str(r["status"]).startswith("ok") and not pd.isna(r["rmse"])}
            states = [s for s in run.scored_states if s in scored]
            until = scored_until(rows)
            t_end = float(truth["t_s"].iloc[-1]) if "t_s" in truth.columns and len(truth) else None
            if until is not None and t_end is not None and until >= t_end - 1e-9:
                until = None
            tevs = truth_events(entry, events)
            reason = next((str(e.get("label", "")) for e in reversed(tevs)
                           if until is not None and float(e["t_s"]) <= until + 1e-6), "")
            for state in states:
                est = files.series_of(state)  # one state's columns at a time, never the whole table
                if truth.empty and not est:
                    continue
                figures.append({"id": f"fig-{slug(name)}-{slug(state)}",
                                "spec": state_figure(state, truth, est, page.styles, events, until, reason),
                                "wide": False})
                del est  # a long log's one state is tens of MB: never hold two states' arrays at once
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
                "truth": truth_summary(entry, events),
                "scored_until_s": until,
                "unscored_reason": reason,
                "duration_s": entry.get("duration_s") or info.get("duration_s"),
                "vehicle": entry.get("vehicle") or info.get("vehicle"),
                "seed": entry.get("seed"),
                "events": events,
                "figures": figures,
                "frames": frames,
                "video": video,
                "render_reason": render.get("reason"),
            })
            del files, truth  # this scenario's tables, before the next one's are read
        return {"scenarios": items, "plot_columns": PIXEL_COLUMNS, "plot_steps": STEPS_PER_SPAN}
