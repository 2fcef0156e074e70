"""Plotly figure specifications as plain dicts (drawn by the plotly.js inlined once in the page).

Building the dicts by hand keeps report generation fast (no plotly Python object validation) and
lets the page draw each figure only when it scrolls into view. What a figure carries is decided in
``plot_data``: traces longer than four samples per pixel column are reduced to their per-column
envelope (every peak, spike and step kept), values are written on a grid finer than the axis can
show, and arrays are written compactly (an error on the truth's time grid is drawn in the page as
estimate minus truth). Angles are shown in degrees; the tables stay in SI units, and the metrics
are computed from the tables at their full rate, never from a figure.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.report.plot_data import (
    ArrayPool,
    compact_values,
    envelope_indices,
    grid_exponent,
    largest_magnitude,
)
from roadtruth.harness.report.rundata import ObserverSeries, observer_series
from roadtruth.harness.report.styles import (  # noqa: F401 - re-exported: other pages import styles from here
    PALETTE,
    TRUTH_COLOUR,
    LineStyle,
    observer_style,
    observer_styles,
    swatch_svg,
)

#: From this many points on, plotly draws a scatter trace as lines alone by default.
_LINES_ONLY = 20

#: Smallest span an axis is focused on, per display unit (so a near-constant truth does not zoom
#: the axis onto sensor noise).
_MIN_SPAN = {"deg": 1.0, "deg/s": 2.0, "m/s": 0.2, "m/s²": 0.5, "kN": 0.5, "m": 0.5, "1/m": 1e-3}
#: The focused axis extends at most this many truth spans beyond the truth's own range.
FOCUS_SPANS = 1.5
#: Robust quantiles of each estimate that the focused axis tries to contain.
FOCUS_QUANTILES = (0.01, 0.99)

#: Truth events that mean the car did something no observer is to blame for (drawn in red).
TRUTH_EVENTS = ("spun out", "left the road", "wheel lift", "rolled over", "stopped")


def display_unit(state: str) -> tuple[float, str]:
    """Scale factor and unit used to show a canonical state (angles in deg, forces in kN)."""
    if state.endswith("_radps2"):
        return 180.0 / math.pi, "deg/s²"
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


def _event_marks(events: list[dict[str, Any]], t_span: tuple[float, float]) -> tuple[list[dict], list[dict]]:
    """A dotted line per event and a small number above the plot (the full label on hover and in
    the scenario's event list), staggered in two rows where events are close, so labels never
    overprint whatever the width of the screen. Truth events (a spin-out…) are red."""
    shapes, notes = [], []
    width = max(t_span[1] - t_span[0], 1e-9)
    last_t = -math.inf
    row = 1
    for k, e in enumerate(events, start=1):
        t = float(e["t_s"])
        label = str(e.get("label", ""))
        truth_event = label.split(" (")[0] in TRUTH_EVENTS or e.get("kind") == "truth"
        colour = "#b42318" if truth_event else "#667085"
        shapes.append({"type": "line", "xref": "x", "yref": "paper", "x0": t, "x1": t, "y0": 0, "y1": 1,
                       "line": {"color": colour, "width": 1.2 if truth_event else 1, "dash": "dot"}})
        row = 1 - row if (t - last_t) / width < 0.05 else 0
        last_t = t
        # The keys every event number shares are the figure's ``note_defaults`` (EVENT_NOTE).
        notes.append({"x": t, "y": 1.0 + 0.055 * row, "text": f"<b>{k}</b>", "hovertext": f"{t:g} s — {label}",
                      "font": {"size": 10, "color": colour}, "bordercolor": colour})
    return shapes, notes


#: What every event number above a time plot shares (written once per figure as ``note_defaults``).
EVENT_NOTE: dict[str, Any] = {"xref": "x", "yref": "paper", "yanchor": "bottom", "showarrow": False,
                              "bgcolor": "rgba(255,255,255,0.85)", "borderwidth": 1, "borderpad": 1}


def _quantiles(v: np.ndarray, qs: Sequence[float]) -> np.ndarray:
    """``np.quantile(v, qs)`` (its default linear interpolation) of a non-empty finite ``v`` from one
    sort: the same numbers at a fraction of its per-call cost, which two thousand traces felt."""
    return _sorted_quantiles(np.sort(v), qs)


def _sorted_quantiles(s: np.ndarray, qs: Sequence[float]) -> np.ndarray:
    pos = np.asarray(qs, dtype=float) * (s.size - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, s.size - 1)
    return s[lo] + (s[hi] - s[lo]) * (pos - lo)


def _spread(e: np.ndarray) -> tuple[np.ndarray, float, float] | None:
    """The sorted finite values of ``e`` and its smallest and largest value ±inf included (what
    ``nanmin``/``nanmax`` give), from one sort; None when no value is finite."""
    s = np.sort(e[~np.isnan(e)])
    a, b = int(np.searchsorted(s, -np.inf, side="right")), int(np.searchsorted(s, np.inf, side="left"))
    if b <= a:
        return None
    return s[a:b], float(s[0]), float(s[-1])


def focus_range(truth: np.ndarray, estimates: list[np.ndarray], unit: str) -> tuple[list[float], bool]:
    """A y range a person can read: the truth's range, widened to hold the 1-99 % quantiles of each
    estimate but never more than ``FOCUS_SPANS`` truth spans beyond the truth (a start-up interval
    bound of ±100° or one drifting observer does not flatten every other line). Returns the range
    and whether some estimate lies outside it (the page then offers "show all")."""
    tv = truth[np.isfinite(truth)]
    spreads = [sp for sp in map(_spread, estimates) if sp is not None]
    qs = [_sorted_quantiles(sp[0], FOCUS_QUANTILES) for sp in spreads]
    if tv.size:
        lo, hi = float(tv.min()), float(tv.max())
    elif qs:
        lo, hi = float(min(q[0] for q in qs)), float(max(q[1] for q in qs))
    else:
        return [-1.0, 1.0], False
    span = max(hi - lo, _MIN_SPAN.get(unit, 0.0), 0.1 * max(abs(lo), abs(hi)), 1e-12)
    cap_lo, cap_hi = lo - FOCUS_SPANS * span, hi + FOCUS_SPANS * span
    for q in qs:
        lo, hi = min(lo, max(float(q[0]), cap_lo)), max(hi, min(float(q[1]), cap_hi))
    pad = 0.06 * max(hi - lo, span)
    lo, hi = lo - pad, hi + pad
    clipped = any(sp[1] < lo or sp[2] > hi for sp in spreads)
    return [lo, hi], clipped


def _error_range(errors: list[np.ndarray], truth_span: float, unit: str) -> tuple[list[float], bool]:
    """Symmetric error axis: the largest 99 % quantile of |error|, capped at the focus span."""
    spreads = [sp for sp in (_spread(np.abs(x)) for x in errors) if sp is not None]
    q = [float(_sorted_quantiles(sp[0], FOCUS_QUANTILES[1:])[0]) for sp in spreads]
    if not q:
        return [-1.0, 1.0], False
    cap = FOCUS_SPANS * max(truth_span, _MIN_SPAN.get(unit, 0.0), 1e-12)
    e = 1.1 * max(min(max(q), cap), 1e-12)
    clipped = any(sp[2] > e for sp in spreads)
    return [-e, e], clipped


def state_figure(
    state: str, truth: pd.DataFrame, estimates: pd.DataFrame | Sequence[ObserverSeries], styles: dict[str, Any],
    events: list[dict[str, Any]], scored_until_s: float | None = None, unscored_reason: str = "",
) -> dict[str, Any]:
    """Truth and every observer's estimate (with bounds as a band) on top, the errors below.

    ``estimates`` is a long estimates frame or each observer's series of ``state`` (``ScenarioFiles.series_of``).
    ``styles`` maps observer -> ``LineStyle`` (see ``observer_style``). Axes are focused on the
    truth (``focus_range``) with buttons to show everything. After ``scored_until_s`` (a spin-out,
    a roll-over) the plot is shaded: that part is drawn but not scored.
    """
    scale, unit = display_unit(state)
    if state in truth.columns:
        t_truth = truth["t_s"].to_numpy(float)
        y_truth = truth[state].to_numpy(float)
    else:
        t_truth = y_truth = np.empty(0)
    series = observer_series(estimates, state) if isinstance(estimates, pd.DataFrame) else estimates
    # Errors at every estimate sample against the truth held at that time (full rate: the ranges
    # and the drawn envelope come from all samples).
    errors: list[np.ndarray] = []
    for one in series:
        err = np.empty(0)
        if t_truth.size:
            if one.t_s.size == t_truth.size and np.array_equal(one.t_s, t_truth):
                err = one.value - y_truth
            else:
                j = np.clip(np.searchsorted(t_truth, one.t_s + 1e-9, side="right") - 1, 0, t_truth.size - 1)
                err = one.value - y_truth[j]
            if state.endswith("_rad"):
                err = np.pi - np.mod(np.pi - err, 2 * np.pi)
            err = err * scale
        errors.append(err)
    t_ends = ([float(t_truth[-1])] if t_truth.size else []) + [float(o.t_s[-1]) for o in series if o.t_s.size]
    t0 = float(t_truth[0]) if t_truth.size else 0.0
    t_span = (t0, max(t_ends) if t_ends else t0 + 1.0)
    values = [o.value * scale for o in series]
    y_range, clipped = focus_range(y_truth * scale, values, unit)
    tv = y_truth[np.isfinite(y_truth)] * scale
    e_range, e_clipped = _error_range([e for e in errors if e.size], float(tv.max() - tv.min()) if tv.size else 0.0, unit)
    # One value grid for the truth, the estimates and their bounds, fine enough for both panels, so
    # that an estimate minus the truth is exact on it; explicit errors get their own panel's grid.
    # (The largest magnitude taken array by array: one array of every observer's values and bounds
    # was the figure's peak memory on a long log.)
    peak = max([largest_magnitude(tv), *map(largest_magnitude, values),
                *(largest_magnitude(o.lo * scale) for o in series), *(largest_magnitude(o.hi * scale) for o in series)])
    exp = grid_exponent(min(y_range[1] - y_range[0], e_range[1] - e_range[0]), np.array([peak]))
    exp_err = grid_exponent(e_range[1] - e_range[0])
    pool = ArrayPool()
    traces: list[dict[str, Any]] = []
    truth_whole = False
    if t_truth.size:
        idx = envelope_indices(t_truth, y_truth)
        truth_whole = idx.size == t_truth.size
        traces.append({"mode": "lines", "name": "truth", "legendgroup": "truth", **pool.times(t_truth, idx),
                       "y": compact_values(y_truth[idx] * scale, exp), "line": {"color": TRUTH_COLOUR, "width": 2.2}})
    wrap = 360.0 if state.endswith("_rad") else None
    for one, err in zip(series, errors, strict=True):
        obs, t, v, lo, hi = one.observer, one.t_s, one.value, one.lo, one.hi
        style = styles.get(obs) or observer_style(obs)
        idx = envelope_indices(t, v)
        if np.isfinite(lo).any() and np.isfinite(hi).any():
            # The band as two lines, the upper one filled down to the lower ("tonexty": the trace
            # before it on the same axes), each its own envelope.
            common = {"legendgroup": str(obs), "showlegend": False, "hoverinfo": "skip", "mode": "lines",
                      "line": {"width": 0}}
            half = _half_width(v, lo, hi) if idx.size == t.size else None
            if half is not None:
                # value ± half width (a variance's ±2σ): the half width is written once, the page
                # adds it to the estimate drawn two traces on.
                j = len(pool.arrays)
                pool.arrays.append(compact_values(half * scale, exp))
                band = len(traces) + 2
                ylo, yhi = {"around": [band, j], "side": -1}, {"around": [band, j], "side": 1}
                xlo = xhi = pool.times(t)
            else:
                ilo, ihi = envelope_indices(t, lo), envelope_indices(t, hi)
                ylo, yhi = compact_values(lo[ilo] * scale, exp), compact_values(hi[ihi] * scale, exp)
                xlo, xhi = pool.times(t, ilo), pool.times(t, ihi)
            traces.append({**common, "name": f"{obs} lower bound", **xlo, "y": ylo})
            traces.append({**common, "name": f"{obs} bounds", **xhi, "y": yhi, "fill": "tonexty",
                           "fillcolor": _alpha(style.colour, 0.13)})
        traces.append({"mode": "lines", "name": str(obs), "legendgroup": str(obs), **pool.times(t, idx),
                       "y": compact_values(v[idx] * scale, exp), "line": _line(style, 1.4)})
        if not err.size:
            continue
        error = {"mode": "lines", "name": f"{obs} error", "legendgroup": str(obs), "showlegend": False,
                 "line": _line(style, 1.1), "yaxis": "y2"}
        if truth_whole and idx.size == t.size and np.array_equal(t, t_truth):
            # Same time grid as the truth and nothing left out: the page draws estimate − truth.
            value_trace = len(traces) - 1
            traces.append({**error, **pool.times(t), "y": {"minus": [value_trace, 0], **({"wrap": wrap} if wrap else {})}})
        else:
            ie = envelope_indices(t, err)
            traces.append({**error, **pool.times(t, ie), "y": compact_values(err[ie], exp_err)})
    if t_truth.size >= _LINES_ONLY and all(o.t_s.size >= _LINES_ONLY for o in series):
        for tr in traces:  # plotly draws lines alone from 20 points on: "mode" is its default
            del tr["mode"]
    shapes, notes = _event_marks(events, t_span)
    if scored_until_s is not None and math.isfinite(scored_until_s) and scored_until_s < t_span[1]:
        shapes.append({"type": "rect", "xref": "x", "yref": "paper", "x0": scored_until_s, "x1": t_span[1],
                       "y0": 0, "y1": 1, "fillcolor": "rgba(120,120,120,0.16)", "line": {"width": 0},
                       "layer": "below"})
        notes.append({"x": scored_until_s, "xref": "x", "y": 0.99, "yref": "paper", "xanchor": "left",
                      "yanchor": "top", "showarrow": False, "font": {"size": 10, "color": "#475467"},
                      "bgcolor": "rgba(0,0,0,0)", "borderwidth": 0,
                      "text": "not scored" + (f" ({unscored_reason})" if unscored_reason else ""),
                      "hovertext": f"from {scored_until_s:g} s on: drawn, not scored"})
    label = state_label(state)
    layout = {
        "height": 450, "margin": {"l": 56, "r": 8, "t": 58, "b": 40},
        "title": {"text": f"{label} [{unit}]", "font": {"size": 14}, "x": 0.01, "y": 0.985, "yanchor": "top"},
        "xaxis": {"anchor": "y2", "title": {"text": "t [s]"}, "zeroline": False},
        "yaxis": {"domain": [0.38, 1.0], "title": {"text": f"{unit}"}, "zeroline": False, "range": y_range},
        "yaxis2": {"domain": [0.0, 0.28], "title": {"text": f"error [{unit}]"}, "zeroline": True,
                   "zerolinecolor": "#bbb", "range": e_range},
        "legend": {"orientation": "h", "y": -0.22, "font": {"size": 11}},
        "shapes": shapes, "annotations": notes, "hovermode": "x",
        "plot_bgcolor": "#fff", "paper_bgcolor": "#fff",
        "updatemenus": [{
            "type": "buttons", "direction": "left", "showactive": True, "active": 0,
            # In the gap between the two panels, clear of the title, event numbers and tool bar.
            "x": 1.0, "xanchor": "right", "y": 0.33, "yanchor": "middle", "pad": {"t": 0, "b": 0},
            "font": {"size": 10}, "bgcolor": "#f6f7f9", "bordercolor": "#d0d5dd",
            "buttons": [
                {"label": "focus", "method": "relayout",
                 "args": [{"yaxis.range": y_range, "yaxis2.range": e_range}]},
                {"label": "show all" + (" ⚠" if clipped or e_clipped else ""), "method": "relayout",
                 "args": [{"yaxis.autorange": True, "yaxis2.autorange": True}]},
            ]}],
    }
    spec: dict[str, Any] = {"data": traces, "layout": layout, "arrays": pool.arrays, "note_defaults": EVENT_NOTE,
                            "meta": {"clipped": bool(clipped or e_clipped)}}
    if t_truth.size:
        grid = {k: v for k, v in pool.times(t_truth).items() if k in ("x0", "dx")}
        if grid:  # the truth's time grid: what a trace without its own x is drawn on
            spec["grid"] = grid
            for tr in traces:
                if tr.get("x0") == grid["x0"] and tr.get("dx") == grid["dx"]:
                    del tr["x0"], tr["dx"]
    return spec


def _half_width(v: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray | None:
    """The half width of a band centred on the estimate (``lo = v - h``, ``hi = v + h`` to rounding,
    missing together), NaN where the band is missing; None for any other band."""
    finite = np.isfinite(lo)
    if not np.array_equal(finite, np.isfinite(hi)) or not np.isfinite(v[finite]).all():
        return None
    h = np.where(finite, (hi - lo) / 2, np.nan)
    scale = np.maximum(np.abs(v), np.abs(h))
    if np.any(np.abs((hi - v) - h)[finite] > 1e-9 * scale[finite] + 1e-300):
        return None
    return h


def _line(style: LineStyle, width: float) -> dict[str, Any]:
    """A plotly line of ``style`` (solid, plotly's default dash, is left out)."""
    line = style.plotly_line(width)
    if line.get("dash") == "solid":
        del line["dash"]
    return line


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
        road_trace = {"mode": "lines", "name": "road centre", "x": rx, "y": ry,
                      "line": {"color": "#999", "width": 1, "dash": "dash"}, "hoverinfo": "skip"}
        traces.append(road_trace)
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
    # Positions on a grid of a ten-thousandth of the wider axis span (plenty for a 360 px plot).
    exp = grid_exponent(float(np.max(hi - lo)), allp)
    for tr in traces:
        tr["x"], tr["y"] = compact_values(tr["x"], exp), compact_values(tr["y"], exp)
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
        traces.append({"mode": "text", "showlegend": False, "hoverinfo": "text",
                       "x": [float(np.clip(c[0], lo[0], hi[0]))], "y": [float(np.clip(c[1], lo[1], hi[1]))],
                       "text": [f"{p.get('surface') or p.get('name', '')} μ={float(p.get('mu', 1.0)):.2f}{when}"],
                       "textfont": {"size": 11, "color": "#234"}})
    if x.size:
        # A path is no function of x: its envelope is taken along the samples, in both coordinates.
        i = np.arange(x.size, dtype=float)
        idx = np.union1d(envelope_indices(i, x), envelope_indices(i, y))
        traces.append({"mode": "lines", "name": "CG path", "x": compact_values(x[idx], exp),
                       "y": compact_values(y[idx], exp), "line": {"color": "#c0392b", "width": 2.5}})
        t = truth["t_s"].to_numpy(float)
        ev_t = [float(e["t_s"]) for e in events]
        if ev_t:
            j = np.clip(np.searchsorted(t, ev_t), 0, t.size - 1)
            traces.append({"mode": "markers+text", "name": "events",
                           "x": compact_values(x[j], exp), "y": compact_values(y[j], exp),
                           # Numbers as in the time plots and the event list; full labels on hover.
                           "text": [str(k) for k in range(1, len(events) + 1)],
                           "hovertext": [f"{float(e['t_s']):g} s — {e.get('label', '')}" for e in events],
                           "hoverinfo": "text", "textposition": "top center", "textfont": {"size": 10},
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
