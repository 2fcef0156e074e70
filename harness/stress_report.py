"""Summary table and self-contained HTML page of a stress sweep (``summary.csv``, ``index.html``).

``summary.csv`` has one row per (scenario, observer, state, friction, faults) with, over the Monte
Carlo seeds: ``n_cases``, ``rmse_mean``, ``rmse_p95``, ``rmse_max``, ``coverage_min`` (worst case),
``frac_ok``, ``frac_diverged`` (observer or simulation diverged), ``frac_error``. The page shows the
table and one inline-SVG chart per scenario of the mean β RMSE against μ (uniform frictions only),
one line per observer. No script, no CDN.
"""

from __future__ import annotations

import html
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

GROUP: tuple[str, ...] = ("scenario", "observer", "state", "friction", "faults")
#: Line colours of the chart (colour-blind-safe Okabe–Ito palette).
PALETTE = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442", "#000000")


def _p95(x: pd.Series) -> float:
    v = x.to_numpy(float)
    v = v[np.isfinite(v)]
    return float(np.percentile(v, 95)) if v.size else math.nan


def _nan_stat(x: pd.Series, f: Any) -> float:
    v = x.to_numpy(float)
    v = v[np.isfinite(v)]
    return float(f(v)) if v.size else math.nan


def summarize(rows: pd.DataFrame) -> pd.DataFrame:
    """Aggregate ``stress.csv`` rows over seeds.

    Parameters
    ----------
    rows : DataFrame
        The ``stress.csv`` frame (columns of ``harness.stress.CASE_COLUMNS`` + ``harness.scoring.COLUMNS``).

    Returns
    -------
    DataFrame
        One row per ``GROUP`` key in first-appearance order; statistics ignore NaN metrics
        (a failed case counts in ``n_cases`` and in the status fractions only).
    """
    out = []
    for key, g in rows.groupby(list(GROUP), sort=False, dropna=False):
        status = g["status"].astype(str)
        diverged = status.str.contains("diverged")
        out.append({
            **dict(zip(GROUP, key, strict=True)),
            "mu": g["mu"].iloc[0], "n_cases": int(g["case"].nunique()),
            "rmse_mean": _nan_stat(g["rmse"], np.mean), "rmse_p95": _p95(g["rmse"]),
            "rmse_max": _nan_stat(g["rmse"], np.max), "coverage_min": _nan_stat(g["coverage"], np.min),
            "frac_ok": float(status.str.startswith("ok").mean()), "frac_diverged": float(diverged.mean()),
            "frac_error": float(status.str.startswith("error").mean()),
        })
    return pd.DataFrame(out, columns=[*GROUP, "mu", "n_cases", "rmse_mean", "rmse_p95", "rmse_max",
                                      "coverage_min", "frac_ok", "frac_diverged", "frac_error"])


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.4g}"
    return str(v)


def svg_lines(series: dict[str, list[tuple[float, float]]], title: str, x_label: str, y_label: str,
              width: int = 560, height: int = 300) -> str:
    """A line chart as inline SVG: one polyline with markers per series of (x, y) points."""
    pts = [(x, y) for s in series.values() for x, y in s if math.isfinite(x) and math.isfinite(y)]
    left, right, top, bottom = 60, 140, 28, 40
    if not pts:
        return f"<p>{html.escape(title)}: nothing to plot.</p>"
    x0, x1 = min(p[0] for p in pts), max(p[0] for p in pts)
    y1 = max(p[1] for p in pts)
    x0, x1 = (x0 - 0.05, x1 + 0.05) if x1 - x0 < 1e-9 else (x0, x1)
    y0, y1 = 0.0, (y1 * 1.1 if y1 > 0 else 1.0)
    pw, ph = width - left - right, height - top - bottom

    def sx(x: float) -> float:
        return left + (x - x0) / (x1 - x0) * pw

    def sy(y: float) -> float:
        return top + ph - (y - y0) / (y1 - y0) * ph

    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
             f'role="img" aria-label="{html.escape(title)}" font-family="sans-serif" font-size="11">',
             f'<text x="{left}" y="16" font-size="13">{html.escape(title)}</text>',
             f'<rect x="{left}" y="{top}" width="{pw}" height="{ph}" fill="none" stroke="#888"/>']
    for i in range(5):
        yv = y0 + (y1 - y0) * i / 4
        parts.append(f'<text x="{left - 6}" y="{sy(yv) + 4:.1f}" text-anchor="end">{yv:.3g}</text>')
        parts.append(f'<line x1="{left}" x2="{left + pw}" y1="{sy(yv):.1f}" y2="{sy(yv):.1f}" stroke="#eee"/>')
    for xv in sorted({p[0] for p in pts}):
        parts.append(f'<text x="{sx(xv):.1f}" y="{top + ph + 16}" text-anchor="middle">{xv:.3g}</text>')
    parts.append(f'<text x="{left + pw / 2}" y="{height - 6}" text-anchor="middle">{html.escape(x_label)}</text>')
    parts.append(f'<text x="14" y="{top + ph / 2}" transform="rotate(-90 14 {top + ph / 2})" '
                 f'text-anchor="middle">{html.escape(y_label)}</text>')
    for i, (name, s) in enumerate(series.items()):
        colour = PALETTE[i % len(PALETTE)]
        good = sorted((x, y) for x, y in s if math.isfinite(x) and math.isfinite(y))
        if good:
            path = " ".join(f"{sx(x):.1f},{sy(y):.1f}" for x, y in good)
            parts.append(f'<polyline points="{path}" fill="none" stroke="{colour}" stroke-width="2"/>')
            parts.extend(f'<circle cx="{sx(x):.1f}" cy="{sy(y):.1f}" r="3" fill="{colour}"/>' for x, y in good)
        ly = top + 12 + 16 * i
        parts.append(f'<line x1="{left + pw + 10}" x2="{left + pw + 28}" y1="{ly - 4}" y2="{ly - 4}" '
                     f'stroke="{colour}" stroke-width="2"/>')
        parts.append(f'<text x="{left + pw + 32}" y="{ly}">{html.escape(name)}</text>')
    parts.append("</svg>")
    return "\n".join(parts)


def _charts(summary: pd.DataFrame) -> str:
    beta = summary[(summary["state"] == "beta_rad") & summary["mu"].notna()]
    if beta.empty:
        return "<p>No β rows with a uniform μ to chart (give --friction numbers or surfaces).</p>"
    faults = str(beta["faults"].iloc[0])
    beta = beta[beta["faults"] == faults]
    charts = []
    for sc, g in beta.groupby("scenario", sort=False):
        series = {str(o): [(float(m), float(r) * 180.0 / math.pi) for m, r in zip(go["mu"], go["rmse_mean"],
                                                                                 strict=True)]
                  for o, go in g.groupby("observer", sort=False)}
        charts.append(svg_lines(series, f"{sc}: mean β RMSE vs μ (faults: {faults})", "road μ", "β RMSE [deg]"))
    return "\n".join(charts)


def write_index(folder: Path, summary: pd.DataFrame, run: dict[str, Any]) -> Path:
    """Write ``folder/index.html``: what was run, the β charts, and the summary table."""
    head = "".join(f"<th>{html.escape(c)}</th>" for c in summary.columns)
    body = "\n".join("<tr>" + "".join(f"<td>{html.escape(_fmt(v))}</td>" for v in r) + "</tr>"
                     for r in summary.itertuples(index=False))
    facts = [("scenarios", ", ".join(run["scenarios"])), ("observers", ", ".join(run["observers"])),
             ("frictions", ", ".join(run["frictions"])), ("faults", " ; ".join(run["faults"])),
             ("seeds", f"{run['seeds']} (base seed {run['base_seed']})"), ("cases", str(run["n_cases"])),
             ("executor", str(run["executor"])), ("wall time", f"{run.get('wall_s', math.nan):.1f} s")]
    facts_html = "".join(f"<tr><th>{k}</th><td>{html.escape(v)}</td></tr>" for k, v in facts)
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>roadtruth stress</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; color: #222; }}
table {{ border-collapse: collapse; font-size: 12px; }}
th, td {{ border: 1px solid #ccc; padding: 2px 6px; text-align: right; }}
th {{ background: #f3f3f3; }}
td:nth-child(-n+5) {{ text-align: left; }}
</style></head><body>
<h1>roadtruth stress sweep</h1>
<table>{facts_html}</table>
<h2>β RMSE against road friction</h2>
{_charts(summary)}
<h2>Summary over seeds</h2>
<p>Per scenario × observer × state × friction × faults; RMSE statistics over seeds (failed cases excluded),
worst-case interval coverage, fractions of cases ok / diverged / in error. Full rows: <code>stress.csv</code>.</p>
<table><thead><tr>{head}</tr></thead><tbody>
{body}
</tbody></table>
</body></html>
"""
    path = folder / "index.html"
    path.write_text(page)
    return path
