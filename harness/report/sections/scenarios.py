"""Per scenario: the path over the friction map, truth vs estimates with bounds, errors, events,
rendered frames and the video."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from roadtruth.harness.report.figures import (
    TRUTH_EVENTS,
    LineStyle,
    observer_styles,
    state_figure,
    trajectory_figure,
)
from roadtruth.harness.report.plot_data import PIXEL_COLUMNS, STEPS_PER_SPAN
from roadtruth.harness.report.ranking import number
from roadtruth.harness.report.rundata import FLOAT_FORMAT, RunData, ScenarioFiles, state_order
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


@dataclass(frozen=True)
class FigurePlan:
    """Everything a scenario's figures depend on besides the scenario's own files.

    The same plan over the same files gives the same figures (:func:`scenario_figures`). That is
    what lets ``roadtruth run`` draw a scenario's figures in the worker that wrote its files, while
    the other scenarios still run, and the page use them only where its own plan is equal.
    """

    name: str
    #: the page's observers, in page order
    observers: tuple[str, ...]
    #: each of ``observers``' line style on the page (they follow the observers registered in the
    #: process that draws: a worker without an observer the page's process registered would colour
    #: the lines unlike the page's legends)
    styles: tuple[LineStyle, ...]
    #: the scored states, in page order: one figure each
    states: tuple[str, ...]
    scored_until_s: float | None
    unscored_reason: str


def figure_plan(name: str, rows: Sequence[Mapping[str, Any]], entry: Mapping[str, Any],
                events: list[dict[str, Any]], truth: pd.DataFrame, observers: Sequence[str],
                styles: Mapping[str, LineStyle] | None = None) -> FigurePlan:
    """The plan of scenario ``name``'s figures from its metrics ``rows`` (dicts), its run.json
    ``entry``, its events and truth table, the page's ``observers`` and their line ``styles``
    (default: ``observer_styles(observers)`` of this process)."""
    scored = {r["state"] for r in rows if isinstance(r["state"], str) and r["state"]
              and str(r["status"]).startswith("ok") and not pd.isna(r["rmse"])}
    until = scored_until(list(rows))
    t_end = float(truth["t_s"].iloc[-1]) if "t_s" in truth.columns and len(truth) else None
    if until is not None and t_end is not None and until >= t_end - 1e-9:
        until = None
    tevs = truth_events(dict(entry), events)
    reason = next((str(e.get("label", "")) for e in reversed(tevs)
                   if until is not None and float(e["t_s"]) <= until + 1e-6), "")
    observers = tuple(observers)
    styles = observer_styles(observers) if styles is None else styles
    return FigurePlan(name=name, observers=observers, styles=tuple(styles[o] for o in observers),
                      states=tuple(sorted(scored, key=state_order)), scored_until_s=until, unscored_reason=reason)


def scenario_figures(files: ScenarioFiles, plan: FigurePlan) -> list[dict[str, Any]]:
    """The scenario's figures: its path over the friction map, then truth against the estimates of
    each state of ``plan``, in the plan's line styles."""
    truth, events, info = files.truth, files.events, files.info
    styles = dict(zip(plan.observers, plan.styles, strict=True))
    figures = []
    if not truth.empty and {"x_m", "y_m"} <= set(truth.columns):
        figures.append({"id": f"fig-{slug(plan.name)}-path", "spec": trajectory_figure(truth, info, events),
                        "wide": False})
    for state in plan.states:
        est = files.series_of(state)  # one state's columns at a time, never the whole table
        if truth.empty and not est:
            continue
        figures.append({"id": f"fig-{slug(plan.name)}-{slug(state)}",
                        "spec": state_figure(state, truth, est, styles, events, plan.scored_until_s,
                                             plan.unscored_reason),
                        "wide": False})
        del est  # a long log's one state is tens of MB: never hold two states' arrays at once
    return figures


def drawn_figures(run_dir: Path, name: str, metrics: pd.DataFrame,
                  entry: Mapping[str, Any]) -> dict[FigurePlan, list[dict[str, Any]]]:
    """A scenario's figures drawn as soon as its files are written (``roadtruth run``), under the
    plan the page will have if every scenario has the observers of this one, in the same order.

    ``metrics``: the scenario's rows as scored (full precision); their ``scored_until_s`` is taken
    as the page reads it back from ``metrics.csv`` (:data:`FLOAT_FORMAT`), so the plans agree.
    """
    rows = metrics.to_dict("records")
    for r in rows:
        v = number(r.get("scored_until_s"))
        r["scored_until_s"] = float(FLOAT_FORMAT % v) if math.isfinite(v) else v
    observers = list(dict.fromkeys(metrics["observer"].astype(str).tolist())) if len(metrics) else []
    files = ScenarioFiles(name=name, folder=Path(run_dir) / name, root=Path(run_dir).resolve())
    plan = figure_plan(name, rows, entry, files.events, files.truth, observers)
    return {plan: scenario_figures(files, plan)}


class ScenariosSection(Section):
    template = "scenarios.html"
    title = "Scenarios"
    anchor = "scenarios"

    def context(self, run: RunData, page: Any) -> dict[str, Any]:
        drawn: Mapping[FigurePlan, list[dict[str, Any]]] = getattr(page, "figures", {})
        items = []
        for name in run.scenario_names:
            files = run.scenario(name)
            entry = run.scenario_entry(name)
            info = files.info
            events = files.events
            rows = [r for r in run.records if r["scenario"] == name]
            plan = figure_plan(name, rows, entry, events, files.truth, run.observer_names, page.styles)
            figures = drawn.get(plan)
            if figures is None:
                figures = scenario_figures(files, plan)
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
                "scored_until_s": plan.scored_until_s,
                "unscored_reason": plan.unscored_reason,
                "duration_s": entry.get("duration_s") or info.get("duration_s"),
                "vehicle": entry.get("vehicle") or info.get("vehicle"),
                "seed": entry.get("seed"),
                "events": events,
                "figures": figures,
                "frames": frames,
                "video": video,
                "render_reason": render.get("reason"),
            })
            del files  # this scenario's tables, before the next one's are read
        return {"scenarios": items, "plot_columns": PIXEL_COLUMNS, "plot_steps": STEPS_PER_SPAN}
