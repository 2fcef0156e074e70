"""The files of a ``roadtruth falsify`` folder: ``cases.csv``, the worst and the smallest breaking
case as ready scenarios (``worst.yaml``, ``smallest.yaml`` + ``.txt`` run lines), ``run.json`` and
``index.html`` (search progress and the worst case's truth against its bounds)."""

from __future__ import annotations

import math
import shlex
from pathlib import Path
from typing import Any

import pandas as pd
import yaml

from roadtruth.harness.report.job_page import esc, finite_or_none, page, plot_div, table

_UNITS = {"patch_start_m": "m", "patch_length_m": "m", "patch_t_start_s": "s", "speed_mps": "m/s",
          "steer_amplitude_deg": "deg", "steer_frequency_hz": "Hz", "steer_dwell_s": "s", "cg_shift_m": "m"}


def describe(point: dict[str, Any], prop_phrase: str) -> str:
    """The finding in words, e.g. ``inclusion lost for a μ 0.55 patch over 12 m from 30 m at 22 m/s``."""
    parts = []
    if "patch_mu" in point:
        txt = f"a μ {point['patch_mu']:.3g} patch"
        if "patch_length_m" in point:
            txt += f" over {point['patch_length_m']:.3g} m"
        side = point.get("patch_side", "both")
        if side != "both":
            txt += f" on the {side} half"
        if "patch_start_m" in point:
            txt += f" from {point['patch_start_m']:.3g} m"
        if "patch_t_start_s" in point:
            txt += f" from t = {point['patch_t_start_s']:.3g} s"
        parts.append(txt)
    if "speed_mps" in point:
        parts.append(f"at {point['speed_mps']:.3g} m/s")
    for key, label in (("steer_amplitude_deg", "steer amplitude"), ("steer_frequency_hz", "steer frequency"),
                       ("steer_dwell_s", "dwell")):
        if key in point:
            parts.append(f"{label} {point[key]:.3g} {_UNITS[key]}")
    if "mass_scale" in point:
        parts.append(f"mass ×{point['mass_scale']:.3g}")
    if "cg_shift_m" in point:
        parts.append(f"CG {point['cg_shift_m'] * 100:+.2g} cm forward")
    if "cornering_stiffness_scale" in point:
        parts.append(f"cornering stiffness ×{point['cornering_stiffness_scale']:.3g}")
    faults = [f"{k[6:]}={v:.3g}" for k, v in point.items() if k.startswith("fault:")]
    if faults:
        parts.append("with " + ", ".join(faults))
    return f"{prop_phrase} for " + ", ".join(parts) if parts else prop_phrase


def _write_case(tmp: Path, stem: str, task: Any, info: dict[str, Any]) -> str:
    """``STEM.yaml`` (+ ``STEM_vehicle.yaml``) and ``STEM.txt``; returns the run line."""
    sc = dict(task.scenario)
    sc["name"] = stem
    sc["description"] = f"falsify: {info['observer']} / {info['property']} (case {task.index})"
    if task.vehicle is not None:
        (tmp / f"{stem}_vehicle.yaml").write_text(yaml.safe_dump(task.vehicle, sort_keys=False), encoding="utf-8")
        sc["vehicle"] = f"{stem}_vehicle.yaml"
    (tmp / f"{stem}.yaml").write_text(yaml.safe_dump(sc, sort_keys=False, allow_unicode=True), encoding="utf-8")
    cmd = ["roadtruth", "run", "--scenario", f"{stem}.yaml", "--observer", info["observer"]]
    if task.faults:
        cmd += ["--faults", task.faults]
    line = " ".join(shlex.quote(c) for c in cmd)
    (tmp / f"{stem}.txt").write_text(line + "\n", encoding="utf-8")
    return line


def cases_frame(s: Any) -> pd.DataFrame:
    """One row per evaluated candidate, in evaluation order."""
    rows = []
    for t in s.tasks:
        r = s.results[t.index]
        row = {"case": t.index, "phase": t.phase, "robustness": r.robustness, "violated": r.violated,
               "counted": r.counted, "observer_status": r.observer_status, "truth_status": r.truth_status,
               "distance": s.space.distance(t.point), "faults": t.faults or ""}
        row.update({p.name: t.point.get(p.name) for p in s.space.parameters})
        rows.append(row)
    return pd.DataFrame(rows)


def _progress_figure(cases: pd.DataFrame) -> dict[str, Any]:
    x = cases["case"].tolist()
    y = [finite_or_none(v) for v in cases["robustness"]]
    best, run = [], math.inf
    for v, c in zip(cases["robustness"], cases["counted"], strict=True):
        if c and math.isfinite(v):
            run = min(run, v)
        best.append(finite_or_none(run))
    colours = ["#c0392b" if v else ("#999999" if not c else "#2c7fb8")
               for v, c in zip(cases["violated"], cases["counted"], strict=True)]
    return {"data": [{"type": "scatter", "mode": "markers", "x": x, "y": y, "name": "case",
                      "marker": {"color": colours, "size": 7}},
                     {"type": "scatter", "mode": "lines", "x": x, "y": best, "name": "worst so far",
                      "line": {"color": "#333333", "shape": "hv"}}],
            "layout": {"title": {"text": "Robustness per evaluation (red: violated, grey: not counted)"},
                       "xaxis": {"title": {"text": "evaluation"}}, "yaxis": {"title": {"text": "robustness"}},
                       "shapes": [{"type": "line", "xref": "paper", "x0": 0, "x1": 1, "y0": 0, "y1": 0,
                                   "line": {"color": "#c0392b", "dash": "dot", "width": 1}}]}}


def _bounds_figure(plot: dict[str, Any], observer: str) -> dict[str, Any]:
    from roadtruth.harness.report.figures import observer_style

    line = observer_style(observer).plotly_line(width=1.4)
    state = plot["state"][0]
    t = plot["t_s"]
    data = [{"type": "scatter", "mode": "lines", "x": t, "y": plot["hi"], "name": "upper bound",
             "line": {**line, "width": 0.8}},
            {"type": "scatter", "mode": "lines", "x": t, "y": plot["lo"], "name": "lower bound", "fill": "tonexty",
             "line": {**line, "width": 0.8}},
            {"type": "scatter", "mode": "lines", "x": t, "y": plot["value"], "name": f"{observer} estimate",
             "line": line},
            {"type": "scatter", "mode": "lines", "x": t, "y": plot["truth"], "name": "truth",
             "line": {"color": "#000000", "width": 1.6}}]
    shapes = []
    until = plot.get("scored_until_s", [None])[0]
    if until is not None:
        shapes.append({"type": "line", "yref": "paper", "x0": until, "x1": until, "y0": 0, "y1": 1,
                       "line": {"color": "#999999", "dash": "dash"}})
    return {"data": data, "layout": {"title": {"text": f"Worst case: {state}, truth and bounds"},
                                     "xaxis": {"title": {"text": "t [s]"}}, "yaxis": {"title": {"text": state}},
                                     "shapes": shapes}}


def write_outputs(tmp: Path, s: Any, info: dict[str, Any]) -> None:
    """Write every file of the folder from the finished search ``s`` (a ``roadtruth.harness.jobs.falsify._Search``)."""
    from roadtruth.harness.report.rundata import git_revision, versions, write_csv, write_json

    cases = cases_frame(s)
    write_csv(cases, tmp / "cases.csv")
    counted = [t for t in s.tasks if s.results[t.index].counted and math.isfinite(s.results[t.index].robustness)]
    worst = min(counted, key=lambda t: (s.results[t.index].robustness, t.index)) if counted else None
    bad = [t for t in s.tasks if s.results[t.index].violated]
    smallest = min(bad, key=lambda t: (s.space.distance(t.point), t.index)) if bad else None
    phrase = s.prop.phrase()
    entry: dict[str, Any] = {"command": "falsify", **info, "space": s.space.to_dict(), "n_cases": len(s.tasks),
                             "n_violated": len(bad),
                             "n_not_counted": sum(not s.results[t.index].counted for t in s.tasks)}
    if worst is not None:
        r = s.results[worst.index]
        entry["worst"] = {"case": worst.index, "robustness": r.robustness, "violated": r.violated,
                          "point": worst.point, "faults": worst.faults, "run": _write_case(tmp, "worst", worst, info)}
    if smallest is not None:
        entry["smallest"] = {"case": smallest.index, "distance": s.space.distance(smallest.point),
                             "robustness": s.results[smallest.index].robustness, "point": smallest.point,
                             "finding": describe(smallest.point, phrase),
                             "run": _write_case(tmp, "smallest", smallest, info)}
    entry["versions"] = versions()
    entry["git_revision"] = git_revision()
    write_json(entry, tmp / "run.json")
    (tmp / "index.html").write_text(_page(cases, s, entry, worst), encoding="utf-8")


def _page(cases: pd.DataFrame, s: Any, entry: dict[str, Any], worst: Any) -> str:
    obs, prop = entry["observer"], entry["property"]
    if "smallest" in entry:
        verdict = (f"<div class='verdict fail'><div class='big'>BROKEN</div><p>{esc(entry['smallest']['finding'])} "
                   f"(case {entry['smallest']['case']}, distance {entry['smallest']['distance']:.3g} from the nominal)."
                   f" {entry['n_violated']} of {entry['n_cases']} cases violate it.</p></div>")
    else:
        verdict = (f"<div class='verdict pass'><div class='big'>NOT BROKEN</div><p>No counted case of "
                   f"{entry['n_cases']} violates {esc(prop)}: the search found no violation, which is not a "
                   f"proof that none exists.</p></div>")
    sections = [("progress", "Search progress", plot_div("falsify-progress", _progress_figure(cases)))]
    if worst is not None and s.results[worst.index].plot:
        w = entry["worst"]
        sections.append(("worst", "Worst case",
                         f"<p>Case {w['case']}, robustness {w['robustness']:.4g}. Reproduce: "
                         f"<code>{esc(w['run'])}</code> (files <code>worst.yaml</code>, <code>worst.txt</code>).</p>"
                         + plot_div("falsify-worst", _bounds_figure(s.results[worst.index].plot, obs))))
    head = ["case", "phase", "robustness", "verdict", "truth", "observer", "distance",
            *[p.name for p in s.space.searched]]
    rows = []
    for _, r in cases.iterrows():
        verdict_txt = "violated" if r["violated"] else ("not counted" if not r["counted"] else "holds")
        rows.append([str(r["case"]), r["phase"], f"{r['robustness']:.4g}", verdict_txt, r["truth_status"],
                     r["observer_status"], f"{r['distance']:.3g}",
                     *[f"{v:.4g}" if isinstance(v, float) else str(v) for v in (r[p.name] for p in s.space.searched)]])
    sections.append(("cases", "Every case", "<p>Not counted: the car spun out, rolled over or left the road, or "
                     "the observer did not run; no observer is blamed for those.</p>"
                     + table(head, rows, numeric=[0, 2, 6])))
    return page(f"roadtruth falsify — {obs}, {prop}", sections, top=verdict, charts=True)


__all__ = ["cases_frame", "describe", "write_outputs"]
