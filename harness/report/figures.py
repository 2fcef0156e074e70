"""Plotly figure specifications as plain dicts (drawn by the plotly.js inlined once in the page).

Building the dicts by hand keeps report generation fast (no plotly Python object validation) and
lets the page draw each figure only when it scrolls into view. Traces are decimated to at most
``MAX_POINTS`` points and rounded to 5 significant digits to keep the page light.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

MAX_POINTS = 500

#: One colour per observer, in order of first appearance (colour-blind-safe Okabe-Ito, then Tableau).
PALETTE: tuple[str, ...] = (
    "#0072B2", "#E69F00", "#009E73", "#CC79A7", "#D55E00", "#56B4E9", "#8c564b", "#7f7f7f",
    "#bcbd22", "#17becf", "#9467bd", "#F0E442",
)
TRUTH_COLOUR = "#111111"


def display_unit(state: str) -> tuple[float, str]:
    """Scale factor and unit used to show a canonical state (angles in deg, forces in kN)."""
    if state.endswith("_radps"):
        return 180.0 / math.pi, "deg/s"
    if state.endswith("_rad"):
        return 180.0 / math.pi, "deg"
    if state.endswith("_N"):
        return 1e-3, "kN"
    for suffix, unit in (("_mps2", "m/s²"), ("_mps", "m/s"), ("_1pm", "1/m"), ("_m", "m")):
        if state.endswith(suffix):
            return 1.0, unit
    return 1.0, ""


def state_label(state: str) -> str:
    labels = {
        "beta_rad": "sideslip β", "vy_mps": "lateral velocity vy", "vx_mps": "longitudinal velocity vx",
        "yaw_rate_radps": "yaw rate r", "alpha_f_rad": "front slip angle αf",
        "alpha_r_rad": "rear slip angle αr", "fy_f_N": "front lateral force Fyf",
        "fy_r_N": "rear lateral force Fyr", "roll_rad": "roll angle φ",
    }
    return labels.get(state, state)


def _round(values: np.ndarray) -> list[float | None]:
    out: list[float | None] = []
    for v in values.tolist():
        out.append(float(f"{v:.5g}") if math.isfinite(v) else None)
    return out


def _decimate(n: int) -> np.ndarray:
    step = max(1, math.ceil(n / MAX_POINTS))
    return np.arange(0, n, step)


def _event_shapes(events: list[dict[str, Any]]) -> tuple[list[dict], list[dict]]:
    shapes, notes = [], []
    for e in events:
        t = float(e["t_s"])
        shapes.append({"type": "line", "xref": "x", "yref": "paper", "x0": t, "x1": t, "y0": 0, "y1": 1,
                       "line": {"color": "#888", "width": 1, "dash": "dot"}})
        notes.append({"x": t, "xref": "x", "y": 1.0, "yref": "paper", "yanchor": "bottom",
                      "text": str(e.get("label", "")), "showarrow": False,
                      "font": {"size": 10, "color": "#555"}, "textangle": 0})
    return shapes, notes


def state_figure(
    state: str, truth: pd.DataFrame, estimates: pd.DataFrame, colours: dict[str, str],
    events: list[dict[str, Any]],
) -> dict[str, Any]:
    """Truth and every observer's estimate (with bounds as a band) on top, the errors below."""
    scale, unit = display_unit(state)
    traces: list[dict[str, Any]] = []
    if state in truth.columns:
        idx = _decimate(len(truth))
        t_truth = truth["t_s"].to_numpy(float)
        y_truth = truth[state].to_numpy(float)
        traces.append({"type": "scatter", "mode": "lines", "name": "truth", "legendgroup": "truth",
                       "x": _round(t_truth[idx]), "y": _round(y_truth[idx] * scale),
                       "line": {"color": TRUTH_COLOUR, "width": 2.2}, "xaxis": "x", "yaxis": "y"})
    else:
        t_truth = y_truth = np.empty(0)
    rows = estimates[estimates["state"] == state] if len(estimates) else estimates
    for obs, g in rows.groupby("observer", sort=False):
        colour = colours.get(str(obs), "#444")
        t = g["t_s"].to_numpy(float)
        v = g["value"].to_numpy(float)
        idx = _decimate(t.size)
        lo = g["lo"].to_numpy(float) if "lo" in g else np.full(t.size, np.nan)
        hi = g["hi"].to_numpy(float) if "hi" in g else np.full(t.size, np.nan)
        if np.isfinite(lo).any() and np.isfinite(hi).any():
            band_x = np.concatenate([t[idx], t[idx][::-1]])
            band_y = np.concatenate([hi[idx], lo[idx][::-1]]) * scale
            traces.append({"type": "scatter", "mode": "lines", "name": f"{obs} bounds",
                           "legendgroup": str(obs), "showlegend": False, "hoverinfo": "skip",
                           "x": _round(band_x), "y": _round(band_y), "fill": "toself",
                           "fillcolor": _alpha(colour, 0.15), "line": {"width": 0}, "xaxis": "x", "yaxis": "y"})
        traces.append({"type": "scatter", "mode": "lines", "name": str(obs), "legendgroup": str(obs),
                       "x": _round(t[idx]), "y": _round(v[idx] * scale),
                       "line": {"color": colour, "width": 1.4}, "xaxis": "x", "yaxis": "y"})
        if t_truth.size:
            # Error on the estimate's own times against the truth held at those times.
            j = np.clip(np.searchsorted(t_truth, t[idx] + 1e-9, side="right") - 1, 0, t_truth.size - 1)
            err = v[idx] - y_truth[j]
            if state.endswith("_rad"):
                err = np.pi - np.mod(np.pi - err, 2 * np.pi)
            traces.append({"type": "scatter", "mode": "lines", "name": f"{obs} error",
                           "legendgroup": str(obs), "showlegend": False,
                           "x": _round(t[idx]), "y": _round(err * scale),
                           "line": {"color": colour, "width": 1.1}, "xaxis": "x", "yaxis": "y2"})
    shapes, notes = _event_shapes(events)
    label = state_label(state)
    layout = {
        "height": 450, "margin": {"l": 60, "r": 10, "t": 36, "b": 40},
        "title": {"text": f"{label} [{unit}]", "font": {"size": 14}, "x": 0.01},
        "xaxis": {"anchor": "y2", "title": {"text": "t [s]"}, "zeroline": False},
        "yaxis": {"domain": [0.38, 1.0], "title": {"text": f"{unit}"}, "zeroline": False},
        "yaxis2": {"domain": [0.0, 0.28], "title": {"text": "error"}, "zeroline": True,
                   "zerolinecolor": "#bbb"},
        "legend": {"orientation": "h", "y": -0.22, "font": {"size": 11}},
        "shapes": shapes, "annotations": notes, "hovermode": "x",
        "plot_bgcolor": "#fff", "paper_bgcolor": "#fff",
    }
    return {"data": traces, "layout": layout}


def mu_colour(mu: float) -> str:
    """Low friction blue, high friction warm grey (ice → snow → wet → dry)."""
    stops = [(0.1, (120, 180, 255)), (0.3, (200, 225, 250)), (0.6, (110, 140, 190)), (1.0, (205, 200, 190))]
    mu = min(max(mu, stops[0][0]), stops[-1][0])
    for (m0, c0), (m1, c1) in zip(stops, stops[1:], strict=False):
        if mu <= m1:
            w = (mu - m0) / (m1 - m0)
            r, g, b = (round(a + w * (b_ - a)) for a, b_ in zip(c0, c1, strict=True))
            return f"#{r:02x}{g:02x}{b:02x}"
    return "#cdc8be"


def _alpha(hex_colour: str, a: float) -> str:
    h = hex_colour.lstrip("#")
    r, g, b = int(h[0:2], 16), int(h[2:4], 16), int(h[4:6], 16)
    return f"rgba({r},{g},{b},{a})"


def trajectory_figure(truth: pd.DataFrame, info: dict[str, Any], events: list[dict[str, Any]]) -> dict[str, Any]:
    """The CG path drawn over the friction map (patches filled by μ) and the road centre line."""
    traces: list[dict[str, Any]] = []
    shapes: list[dict[str, Any]] = []
    x = truth["x_m"].to_numpy(float) if "x_m" in truth else np.empty(0)
    y = truth["y_m"].to_numpy(float) if "y_m" in truth else np.empty(0)
    pts = [np.column_stack([x, y])] if x.size else []
    road = info.get("road") or {}
    if road.get("x_m"):
        rx, ry = np.asarray(road["x_m"], float), np.asarray(road["y_m"], float)
        traces.append({"type": "scatter", "mode": "lines", "name": "road centre", "x": _round(rx),
                       "y": _round(ry), "line": {"color": "#999", "width": 1, "dash": "dash"},
                       "hoverinfo": "skip"})
        pts.append(np.column_stack([rx, ry]))
    if pts:
        allp = np.vstack(pts)
        allp = allp[np.isfinite(allp).all(axis=1)]
    else:
        allp = np.zeros((1, 2))
    if not allp.size:
        allp = np.zeros((1, 2))
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.08 * max(float(np.max(hi - lo)), 10.0)
    lo, hi = lo - pad, hi + pad
    for p in info.get("friction", {}).get("patches", []):
        verts = np.asarray(p.get("vertices", []), float)
        if verts.ndim != 2 or len(verts) < 3:
            continue
        verts = np.clip(verts, lo - 1e3, hi + 1e3)  # a 'whole plane' patch stays drawable
        path = "M " + " L ".join(f"{vx:.3f},{vy:.3f}" for vx, vy in verts) + " Z"
        shapes.append({"type": "path", "path": path, "layer": "below", "line": {"width": 0.5, "color": "#888"},
                       "fillcolor": _alpha(mu_colour(float(p.get("mu", 1.0))), 0.55)})
        c = verts.mean(axis=0)
        when = ""
        if _is_finite(p.get("t_start_s")) and float(p["t_start_s"]) > 0 or _is_finite(p.get("t_end_s")):
            when = f" t∈[{_fmt(p.get('t_start_s'))}, {_fmt(p.get('t_end_s'))}] s"
        traces.append({"type": "scatter", "mode": "text", "showlegend": False, "hoverinfo": "text",
                       "x": [float(np.clip(c[0], lo[0], hi[0]))], "y": [float(np.clip(c[1], lo[1], hi[1]))],
                       "text": [f"{p.get('surface') or p.get('name', '')} μ={float(p.get('mu', 1.0)):.2f}{when}"],
                       "textfont": {"size": 11, "color": "#234"}})
    if x.size:
        idx = _decimate(x.size)
        traces.append({"type": "scatter", "mode": "lines", "name": "CG path", "x": _round(x[idx]),
                       "y": _round(y[idx]), "line": {"color": "#c0392b", "width": 2.5}})
        t = truth["t_s"].to_numpy(float)
        ev_t = [float(e["t_s"]) for e in events]
        if ev_t:
            j = np.clip(np.searchsorted(t, ev_t), 0, t.size - 1)
            traces.append({"type": "scatter", "mode": "markers+text", "name": "events",
                           "x": _round(x[j]), "y": _round(y[j]), "text": [str(e.get("label", "")) for e in events],
                           "textposition": "top center", "textfont": {"size": 10},
                           "marker": {"size": 7, "color": "#333", "symbol": "diamond"}})
    mu0 = info.get("friction", {}).get("mu_default")
    layout = {
        "height": 360, "margin": {"l": 50, "r": 10, "t": 30, "b": 40},
        "title": {"text": "path over the friction map" + (f" (μ elsewhere = {mu0:g})" if _is_finite(mu0) else ""),
                  "font": {"size": 14}, "x": 0.01},
        "xaxis": {"title": {"text": "x [m]"}, "range": [float(lo[0]), float(hi[0])], "zeroline": False},
        "yaxis": {"title": {"text": "y [m]"}, "range": [float(lo[1]), float(hi[1])], "scaleanchor": "x",
                  "zeroline": False},
        "shapes": shapes, "showlegend": True, "legend": {"orientation": "h", "y": -0.2},
        "plot_bgcolor": mu_colour(float(mu0)) if _is_finite(mu0) else "#fff", "paper_bgcolor": "#fff",
    }
    return {"data": traces, "layout": layout}


def _is_finite(v: Any) -> bool:
    return isinstance(v, int | float) and math.isfinite(v)


def _fmt(v: Any) -> str:
    return f"{float(v):g}" if _is_finite(v) else "∞"
