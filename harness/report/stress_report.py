"""Summary table and self-contained page of a stress sweep (``summary.csv``, ``index.html``).

The page answers "down to which friction, up to which fault level does each observer hold?":

* **degradation curves** of every observer's RMSE against road μ (uniform frictions) and against the
  level of each swept fault (``gnss:dropout=0.2`` → fault ``gnss:dropout``, level 0.2; ``none`` is
  level 0): the mean over the Monte Carlo seeds and a P5–P95 band;
* the **breaking point** of each observer: the first μ (going down from the highest) or fault level
  (going up from none) where it fails its threshold, with the threshold used. A level fails when the
  mean RMSE over the seeds exceeds the threshold or when any seed ends not ok (diverged, error,
  saturated…). Thresholds: the first ``rmse`` ``max`` rule of the shipped CI thresholds
  (``harness/thresholds/ci.yaml``) matching the (scenario, observer, state), else ``DEFAULT_RMSE_LIMITS``;
* the **truth context**: cases whose car lost control (``truth_status`` says spun out or rolled over,
  or the simulation failed) are left out of the observer statistics and marked on every chart, so no
  observer is blamed for a car going backwards.

``summary.csv`` has one row per (scenario, observer, state, friction, faults) with ``n_cases``,
``n_controlled`` (seeds whose car stayed under control), RMSE statistics over those seeds
(``rmse_mean``, ``rmse_p5``, ``rmse_p95``, ``rmse_max``, SI units), ``coverage_min``, the status
fractions over all seeds (``frac_ok``, ``frac_diverged``, ``frac_error``, ``frac_not_applicable``),
``frac_failed`` over the controlled seeds, ``truth_lost`` (cases that lost control), the distinct
``truth_statuses`` and the truth's peak |β| (``peak_abs_beta_rad_mean``). Angles on the page are in degrees.
"""

from __future__ import annotations

import math
import re
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.report.job_page import esc, finite_or_none, observer_line_styles, page, plot_div, table

GROUP: tuple[str, ...] = ("scenario", "observer", "state", "friction", "faults")
#: States charted and judged (the headline states of the harness).
CHART_STATES: tuple[str, ...] = ("beta_rad", "vy_mps", "yaw_rate_radps")
#: RMSE limits when the shipped CI thresholds have no rule for a (scenario, observer, state):
#: an estimate off by more than this on average is not usable for stability control (SI units).
DEFAULT_RMSE_LIMITS: dict[str, float] = {"beta_rad": math.radians(1.0), "vy_mps": 0.3,
                                         "yaw_rate_radps": math.radians(1.0)}
#: Truth events after which the car is not under control (the truth's own list when available).
try:
    from roadtruth.harness.truth.truth_events import ENDS_SCORING as _LOST
except ImportError:  # pragma: no cover - older trees without truth events
    _LOST = frozenset({"spun out", "rolled over"})
LOST_CONTROL: tuple[str, ...] = tuple(sorted(_LOST))
_FAULT = re.compile(r"^\s*([A-Za-z_][\w]*:[A-Za-z_][\w]*)\s*=\s*([-+]?[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*$")
NO_FAULTS = "none"


# ---- per-case classification ---------------------------------------------------------------------

def lost_control(truth_status: pd.Series) -> pd.Series:
    """True where the truth says the car was not under control: spun out, rolled over, or the
    simulation itself failed (no truth to judge against)."""
    s = truth_status.fillna("ok").astype(str)
    spun = s.map(lambda v: any(k in v for k in LOST_CONTROL))
    failed = s.str.startswith(("diverged", "error"))
    return spun | failed


def _observer_failed(status: pd.Series) -> pd.Series:
    """An observer status that is a failure (not ok and not 'not applicable')."""
    s = status.astype(str)
    return ~s.str.startswith("ok") & ~s.str.startswith("skipped")


def _is_observer_failure(status: str) -> bool:
    """:func:`_observer_failed` of one status."""
    return not status.startswith("ok") and not status.startswith("skipped")


#: Stands for a NaN group label (NaN equals nothing, itself included).
_NAN_KEY = object()


def _missing(x: Any) -> bool:
    return x is None or x is pd.NA or (isinstance(x, float) and x != x)


def _fraction(values: list[str], test: Any) -> float:
    """Share of ``values`` passing ``test`` (NaN for none), as a mean of booleans gives it."""
    return sum(1 for v in values if test(v)) / len(values) if values else math.nan


def _q(v: np.ndarray, q: float) -> float:
    v = v[np.isfinite(v)]
    return float(np.percentile(v, q)) if v.size else math.nan


def _stat(v: np.ndarray, f: Any) -> float:
    v = v[np.isfinite(v)]
    return float(f(v)) if v.size else math.nan


def summarize(rows: pd.DataFrame) -> pd.DataFrame:
    """Aggregate ``stress.csv`` rows over seeds.

    Parameters
    ----------
    rows : DataFrame
        The ``stress.csv`` frame (columns of ``roadtruth.harness.jobs.stress.CASE_COLUMNS`` + ``roadtruth.harness.evaluation.scoring.COLUMNS``).

    Returns
    -------
    DataFrame
        One row per ``GROUP`` key in first-appearance order. RMSE statistics use the seeds whose car
        stayed under control and whose observer ran (NaN metrics ignored); status fractions use all seeds.
    """
    # One pass over plain columns: a pandas filter per group cost ~4 ms a group (0.3 s per 96 cases).
    n = len(rows)
    truth = (rows["truth_status"].tolist() if "truth_status" in rows else ["ok"] * n)
    truth = ["ok" if _missing(t) else str(t) for t in truth]
    lost_all = lost_control(pd.Series(truth, dtype=object)).tolist()
    status_all = [str(v) for v in rows["status"].tolist()]
    case_all = rows["case"].tolist()
    mu_all = rows["mu"].tolist()
    rmse_all = rows["rmse"].to_numpy(float)
    coverage_all = rows["coverage"].to_numpy(float)
    beta_all = rows["peak_abs_beta_rad"].to_numpy(float) if "peak_abs_beta_rad" in rows else None
    groups: dict[tuple[Any, ...], list[int]] = {}
    keys: dict[tuple[Any, ...], tuple[Any, ...]] = {}
    for i, key in enumerate(zip(*(rows[c].tolist() for c in GROUP), strict=True)):
        # NaN labels form one group, as in groupby(dropna=False)
        norm = tuple(_NAN_KEY if _missing(k) else k for k in key)
        if norm not in groups:
            groups[norm], keys[norm] = [], key
        groups[norm].append(i)
    out = []
    for norm, idx in groups.items():
        ctl = [i for i in idx if not lost_all[i]]
        lost = [i for i in idx if lost_all[i]]
        status = [status_all[i] for i in idx]
        rmse = rmse_all[ctl]
        out.append({
            **dict(zip(GROUP, keys[norm], strict=True)),
            "mu": mu_all[idx[0]], "n_cases": len({case_all[i] for i in idx}),
            "n_controlled": len({case_all[i] for i in ctl}),
            "rmse_mean": _stat(rmse, np.mean), "rmse_p5": _q(rmse, 5), "rmse_p95": _q(rmse, 95),
            "rmse_max": _stat(rmse, np.max), "coverage_min": _stat(coverage_all[ctl], np.min),
            "frac_ok": _fraction(status, lambda v: v.startswith("ok")),
            "frac_diverged": _fraction(status, lambda v: "diverged" in v),
            "frac_error": _fraction(status, lambda v: v.startswith("error")),
            "frac_not_applicable": _fraction(status, lambda v: v.startswith("skipped: missing")),
            "frac_failed": (_fraction([status_all[i] for i in ctl], _is_observer_failure) if ctl else math.nan),
            "truth_lost": len({case_all[i] for i in lost}),
            "truth_statuses": "; ".join(sorted({truth[i] for i in idx if truth[i] != "ok"})),
            "peak_abs_beta_rad_mean": _stat(beta_all[idx] if beta_all is not None else np.array([]), np.mean),
        })
    return pd.DataFrame(out, columns=[*GROUP, "mu", "n_cases", "n_controlled", "rmse_mean", "rmse_p5", "rmse_p95",
                                      "rmse_max", "coverage_min", "frac_ok", "frac_diverged", "frac_error",
                                      "frac_not_applicable", "frac_failed", "truth_lost", "truth_statuses",
                                      "peak_abs_beta_rad_mean"])


# ---- thresholds and breaking points --------------------------------------------------------------

def rmse_threshold(scenario: str, observer: str, state: str, rules: Any = None) -> tuple[float, str]:
    """(limit [SI], where it comes from) for one (scenario, observer, state); NaN when there is none.

    ``rules``: the rules of a thresholds file (default: the shipped CI thresholds).
    """
    if rules is None:
        rules = _shipped_rules()
    for r in rules:
        if r.metric != "rmse" or r.max is None:
            continue
        if (any(fnmatchcase(scenario, p) for p in r.scenario) and any(fnmatchcase(observer, p) for p in r.observer)
                and any(fnmatchcase(state, p) for p in r.state)):
            return float(r.max), f"ci.yaml {r.where}"
    if state in DEFAULT_RMSE_LIMITS:
        return DEFAULT_RMSE_LIMITS[state], "default"
    return math.nan, "none"


def _shipped_rules() -> tuple[Any, ...]:
    from roadtruth.harness.jobs.check_rules import DEFAULT_THRESHOLDS, load_thresholds

    return load_thresholds(DEFAULT_THRESHOLDS).rules


def fault_level(spec: str) -> tuple[str, float] | None:
    """(fault, level) of a one-fault spec (``gnss:dropout=0.2`` → ``("gnss:dropout", 0.2)``); None otherwise."""
    m = _FAULT.match(str(spec))
    return (m.group(1), float(m.group(2))) if m else None


def _mu_faults(summary: pd.DataFrame) -> str:
    """The fault spec the μ curves are drawn at: no faults when swept, else the first spec."""
    faults = list(dict.fromkeys(summary["faults"].astype(str)))
    return NO_FAULTS if NO_FAULTS in faults else faults[0]


def _fault_axes(summary: pd.DataFrame) -> dict[str, list[tuple[float, str]]]:
    """fault -> [(level, spec)] ascending, with ``none`` as level 0 when it was swept."""
    specs = list(dict.fromkeys(summary["faults"].astype(str)))
    axes: dict[str, list[tuple[float, str]]] = {}
    for s in specs:
        fl = fault_level(s)
        if fl is not None:
            axes.setdefault(fl[0], []).append((fl[1], s))
    for name, levels in axes.items():
        if NO_FAULTS in specs:
            levels.append((0.0, NO_FAULTS))
        levels.sort()
        axes[name] = list(dict.fromkeys(levels))
    return axes


def _curve_rows(summary: pd.DataFrame, axis: str) -> tuple[pd.DataFrame, str]:
    """Summary rows of one axis with an ``x`` column (μ, or a fault's level) and what is held fixed."""
    if axis == "mu":
        fixed = _mu_faults(summary)
        g = summary[(summary["faults"].astype(str) == fixed) & summary["mu"].notna()].copy()
        g["x"] = g["mu"].astype(float)
        return g, f"faults: {fixed}"
    levels = dict((s, lv) for lv, s in _fault_axes(summary)[axis])
    friction = str(summary["friction"].iloc[0])
    g = summary[(summary["friction"].astype(str) == friction) & summary["faults"].astype(str).isin(levels)].copy()
    g["x"] = g["faults"].astype(str).map(levels)
    return g, f"friction: {friction}"


def breaking_points(summary: pd.DataFrame, rules: Any = None) -> pd.DataFrame:
    """The breaking point of every (scenario, observer, state) on every axis (μ and each fault).

    Returns
    -------
    DataFrame
        ``scenario, observer, state, axis, threshold, threshold_source, breaks_at, verdict, reason``:
        ``breaks_at`` is the first level (μ going down, fault levels going up) that fails, NaN when
        none does; ``verdict`` is ``breaks``, ``holds`` (no tested level fails), ``not applicable``
        or ``no threshold``. Levels where every seed lost control are not judged.
    """
    axes = (["mu"] if summary["mu"].notna().any() else []) + list(_fault_axes(summary))
    out = []
    for axis in axes:
        rows, _ = _curve_rows(summary, axis)
        rows = rows[rows["state"].isin(CHART_STATES)]
        for (sc, obs, st), g in rows.groupby(["scenario", "observer", "state"], sort=False):
            limit, source = rmse_threshold(str(sc), str(obs), str(st), rules)
            g = g.sort_values("x", ascending=(axis != "mu"))
            base = {"scenario": sc, "observer": obs, "state": st, "axis": "μ" if axis == "mu" else axis,
                    "threshold": limit, "threshold_source": source, "breaks_at": math.nan}
            if (g["frac_not_applicable"] >= 1.0).all():
                out.append({**base, "verdict": "not applicable", "reason": "the scenario lacks a sensor it needs"})
                continue
            verdict, reason, judged, unjudged = "holds", "", [], []
            for r in g.itertuples():
                if r.n_controlled == 0:
                    unjudged.append(f"{r.x:g}")  # every seed lost control: the truth failed here, not the observer
                    continue
                judged.append(r.x)
                if r.frac_failed > 0:
                    verdict, reason = "breaks", f"{r.frac_failed:.0%} of the seeds not ok"
                elif math.isfinite(limit) and math.isfinite(r.rmse_mean) and r.rmse_mean > limit:
                    verdict, reason = "breaks", (f"mean RMSE {_fmt_limit(str(st), r.rmse_mean)} > "
                                                 f"{_fmt_limit(str(st), limit)}")
                else:
                    continue
                base["breaks_at"] = float(r.x)
                break
            if verdict == "holds":
                reason = (f"no judged level fails ({'down' if axis == 'mu' else 'up'} to {judged[-1]:g})"
                          if judged else "no level could be judged")
                if unjudged:
                    reason += f"; not judged where every seed lost control: {', '.join(unjudged)}"
            if verdict == "holds" and not math.isfinite(limit):
                verdict, reason = "no threshold", "no rule and no default for this state"
            out.append({**base, "verdict": verdict, "reason": reason})
    return pd.DataFrame(out, columns=["scenario", "observer", "state", "axis", "threshold", "threshold_source",
                                      "breaks_at", "verdict", "reason"])


# ---- the page ---------------------------------------------------------------------------------------

def _rgba(hex_colour: str, alpha: float) -> str:
    h = hex_colour.lstrip("#")
    r, g, b = (int(h[i:i + 2], 16) for i in (0, 2, 4))
    return f"rgba({r},{g},{b},{alpha})"


def _figure(rows: pd.DataFrame, state: str, axis: str, styles: dict[str, dict[str, str]],
            breaks: pd.DataFrame, title: str) -> dict[str, Any]:
    from roadtruth.harness.report.figures import display_unit, state_label

    scale, unit = display_unit(state)
    traces: list[dict[str, Any]] = []
    for obs, g in rows.groupby("observer", sort=False):
        g = g.sort_values("x")
        if not np.isfinite(g["rmse_mean"].to_numpy(float)).any():
            continue
        st = styles[str(obs)]
        x = [finite_or_none(v) for v in g["x"]]
        lo = [finite_or_none(v * scale) for v in g["rmse_p5"]]
        hi = [finite_or_none(v * scale) for v in g["rmse_p95"]]
        traces.append({"type": "scatter", "mode": "lines", "x": x, "y": hi, "line": {"width": 0},
                       "legendgroup": obs, "showlegend": False, "hoverinfo": "skip"})
        traces.append({"type": "scatter", "mode": "lines", "x": x, "y": lo, "line": {"width": 0}, "fill": "tonexty",
                       "fillcolor": _rgba(st["color"], 0.14), "legendgroup": obs, "showlegend": False,
                       "name": f"{obs} P5–P95", "hoverinfo": "skip"})
        traces.append({"type": "scatter", "mode": "lines+markers", "name": str(obs), "legendgroup": obs, "x": x,
                       "y": [finite_or_none(v * scale) for v in g["rmse_mean"]],
                       "line": {"color": st["color"], "dash": st["dash"], "width": 2}, "marker": {"size": 6},
                       "hovertemplate": f"{obs}<br>%{{x}}: mean %{{y:.3g}} {unit}<extra></extra>"})
        b = breaks[(breaks["observer"] == obs) & (breaks["verdict"] == "breaks")]
        if len(b) and math.isfinite(float(b["breaks_at"].iloc[0])):
            xb = float(b["breaks_at"].iloc[0])
            yb = g.loc[np.isclose(g["x"].astype(float), xb), "rmse_mean"]
            traces.append({"type": "scatter", "mode": "markers", "x": [xb],
                           "y": [finite_or_none(float(yb.iloc[0]) * scale) if len(yb) else None],
                           "marker": {"symbol": "x", "size": 13, "color": st["color"], "line": {"width": 2}},
                           "legendgroup": obs, "showlegend": False,
                           "hovertemplate": f"{obs} breaks here<extra></extra>"})
    shapes, notes = [], []
    lost = rows.groupby("x", sort=True).agg(lost=("truth_lost", "max"), n=("n_cases", "max"))
    xs = sorted(rows["x"].astype(float).unique())
    half = (min(np.diff(xs)) / 2) if len(xs) > 1 else 0.05
    for xv, r in lost.iterrows():
        if r["lost"] > 0:
            shapes.append({"type": "rect", "xref": "x", "yref": "paper", "x0": xv - half, "x1": xv + half, "y0": 0,
                           "y1": 1, "fillcolor": "rgba(180,35,24,0.08)", "line": {"width": 0}, "layer": "below"})
            notes.append({"x": xv, "y": 1.0, "xref": "x", "yref": "paper", "yanchor": "bottom", "showarrow": False,
                          "text": f"{int(r['lost'])}/{int(r['n'])} lost control", "font": {"size": 9,
                                                                                                "color": "#b42318"}})
    limits = breaks["threshold"].dropna().unique()
    if len(limits) == 1:
        shapes.append({"type": "line", "xref": "paper", "x0": 0, "x1": 1, "yref": "y", "y0": limits[0] * scale,
                       "y1": limits[0] * scale, "line": {"color": "#b42318", "width": 1, "dash": "dash"}})
        notes.append({"xref": "paper", "x": 1, "y": limits[0] * scale, "yref": "y", "xanchor": "right",
                      "yanchor": "bottom", "showarrow": False, "text": "threshold", "font": {"size": 10,
                                                                                           "color": "#b42318"}})
    x_title = "road friction μ" if axis == "mu" else f"{axis} level"
    layout = {"title": {"text": title, "font": {"size": 13}}, "height": 400, "margin": {"l": 56, "r": 12, "t": 48,
                                                                                           "b": 40},
              "xaxis": {"title": {"text": x_title}, "autorange": "reversed" if axis == "mu" else True},
              "yaxis": {"title": {"text": f"{state_label(state)} RMSE [{unit}]"}, "rangemode": "tozero"},
              "legend": {"orientation": "h", "y": -0.2, "font": {"size": 10}}, "shapes": shapes,
              "annotations": notes, "hovermode": "closest"}
    return {"data": traces, "layout": layout}


def _fmt_level(axis: str, v: float) -> str:
    return "—" if not math.isfinite(v) else (f"μ = {v:g}" if axis == "μ" else f"{v:g}")


def _fmt_limit(state: str, v: float) -> str:
    from roadtruth.harness.report.figures import display_unit

    scale, unit = display_unit(state)
    return "—" if not math.isfinite(v) else f"{v * scale:.3g} {unit}"


def stress_page(summary: pd.DataFrame, run: dict[str, Any], rules: Any = None) -> str:
    """The whole stress page (curves, breaking points, truth context, summary)."""
    from roadtruth.harness.report.figures import display_unit, state_label

    breaks = breaking_points(summary, rules)
    styles = observer_line_styles(summary["observer"].astype(str))
    facts = [("scenarios", ", ".join(run.get("scenarios", []))), ("observers", ", ".join(run.get("observers", []))),
             ("frictions", ", ".join(run.get("frictions", []))), ("faults", " ; ".join(run.get("faults", []))),
             ("seeds", f"{run.get('seeds')} per case (base seed {run.get('base_seed')})"),
             ("cases", str(run.get("n_cases"))), ("executor", str(run.get("executor")))]
    n_lost = summary.drop_duplicates(["scenario", "friction", "faults"])["truth_lost"].sum()
    n_break = int((breaks["verdict"] == "breaks").sum())
    top = ("<div class='verdict warn' id='verdict'>" if n_break else "<div class='verdict pass' id='verdict'>") + (
        f"<div class='big'>{n_break} breaking points</div><p>{n_break} of {len(breaks)} observer × state × axis "
        f"curves fail their threshold somewhere in the sweep; {int(n_lost)} cases lost control (spun out, rolled over "
        "or the simulation failed) and are not counted against any observer.</p></div>")

    sections: list[tuple[str, str, str]] = []
    bp_rows = []
    for r in breaks.itertuples():
        cls = {"breaks": "worse", "holds": "better"}.get(r.verdict, "na")
        bp_rows.append([esc(r.scenario), esc(r.observer), f"<code>{esc(r.state)}</code>", esc(r.axis),
                        f"<span class='{cls}'>{esc(r.verdict)}</span>", esc(_fmt_level(r.axis, r.breaks_at)),
                        esc(_fmt_limit(r.state, r.threshold)), esc(r.threshold_source), esc(r.reason)])
    defaults = ", ".join(f"{state_label(s)} {_fmt_limit(s, v)}" for s, v in DEFAULT_RMSE_LIMITS.items())
    sections.append(("breaking", "Breaking points",
                     "<p class='muted'>The first μ (from the highest down) or fault level (from none up) where an "
                     "observer's mean RMSE over the seeds exceeds its threshold, or a seed ends not ok. Threshold: "
                     "the first matching <code>rmse</code> rule of the shipped CI thresholds, else the default "
                     f"({esc(defaults)}). Levels where every seed lost control are not judged.</p>"
                     + table(("scenario", "observer", "state", "axis", "verdict", "breaks at", "threshold", "from",
                              "why"), bp_rows, raw=True)))

    axes = (["mu"] if summary["mu"].notna().any() else []) + list(_fault_axes(summary))
    plots, n = [], 0
    for axis in axes:
        rows, fixed = _curve_rows(summary, axis)
        for (sc, st), g in rows[rows["state"].isin(CHART_STATES)].groupby(["scenario", "state"], sort=False):
            b = breaks[(breaks["scenario"] == sc) & (breaks["state"] == st)
                       & (breaks["axis"] == ("μ" if axis == "mu" else axis))]
            what = "μ" if axis == "mu" else axis
            title = f"{sc}: {state_label(str(st))} RMSE vs {what} ({fixed})"
            plots.append(plot_div(f"stress-{n}", _figure(g, str(st), axis, styles, b, title)))
            n += 1
    sections.append(("curves", "Degradation curves",
                     "<p class='muted'>Mean over the seeds (line) and P5–P95 band; × marks the breaking point; red "
                     "bands mark levels where the car lost control in some seeds (those seeds are left out). "
                     "Angles in degrees.</p>"
                     + (f"<div class='plots'>{''.join(plots)}</div>" if plots else
                        "<p>No uniform μ and no numeric fault levels to chart (give --friction numbers or "
                        "surfaces, --faults like gnss:dropout=0.2).</p>")))

    scale, _ = display_unit("beta_rad")
    truth_rows = []
    for r in summary.drop_duplicates(["scenario", "friction", "faults"]).itertuples():
        truth_rows.append((str(r.scenario), str(r.friction), "" if not math.isfinite(r.mu) else f"{r.mu:g}",
                           str(r.faults), f"{r.n_cases - r.truth_lost} of {r.n_cases}",
                           f"{r.peak_abs_beta_rad_mean * scale:.3g}" if math.isfinite(r.peak_abs_beta_rad_mean) else "—",
                           r.truth_statuses or "ok"))
    sections.append(("truth", "Truth context",
                     "<p class='muted'>What the car did in each case group: seeds that stayed under control, the "
                     "truth's peak sideslip |β| (mean over seeds, degrees) and the truth events.</p>"
                     + table(("scenario", "friction", "μ", "faults", "under control", "peak |β| [deg]",
                              "truth events"), truth_rows, numeric=(5,))))

    head = ("scenario", "observer", "state", "friction", "faults", "seeds", "RMSE mean", "P5", "P95", "unit", "ok",
            "lost control")
    srows = []
    for r in summary.itertuples():
        sc_, unit = display_unit(str(r.state))
        srows.append((str(r.scenario), str(r.observer), str(r.state), str(r.friction), str(r.faults),
                      f"{r.n_controlled}/{r.n_cases}", *(f"{v * sc_:.3g}" if math.isfinite(v) else "—"
                                                          for v in (r.rmse_mean, r.rmse_p5, r.rmse_p95)),
                      unit, f"{r.frac_ok:.0%}", str(r.truth_lost)))
    sections.append(("summary", "Summary over seeds",
                     "<details><summary>show every row</summary>" + table(head, srows, numeric=(6, 7, 8)) +
                     "</details><p class='muted small'>SI units and every column: <code>summary.csv</code>; one row "
                     "per case: <code>stress.csv</code>.</p>"))
    sections.append(("sweep", "Sweep", table(("", ""), facts, cls="plain compact")))
    return page("roadtruth stress — breaking points", sections, top=top, charts=bool(plots))


def warm_up() -> None:
    """Do the page's one-time work now (the shipped thresholds parsed, the page's modules imported,
    plotly.js read): a sweep waiting for its workers to start takes it off the end of the sweep."""
    from roadtruth.harness.report import builder, figures  # noqa: F401 - imported for later

    _shipped_rules()
    builder.plotly_js()


def write_index(folder: Path, summary: pd.DataFrame, run: dict[str, Any]) -> Path:
    """Write ``folder/index.html`` (see :func:`stress_page`). No timings: the page is reproducible."""
    path = Path(folder) / "index.html"
    path.write_text(stress_page(summary, run), encoding="utf-8")
    return path
