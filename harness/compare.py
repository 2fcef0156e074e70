"""Per (scenario, observer, state) metric deltas between two run folders (``roadtruth compare``).

Only the saved ``metrics.csv`` files are read. For each metric the table has ``<m>_a``, ``<m>_b``
and ``<m>_delta`` (= b - a) and, for the headline metrics, ``<m>_change`` in {better, worse, same}
judged by the metric's sense (lower error, shorter convergence, higher coverage, NEES nearer 1) with
a relative tolerance ``REL_TOL`` so that float noise is "same". ``verdict`` summarises the row from
the RMSE change and the status change (an observer that stops being ok is always "worse").
"""

from __future__ import annotations

import html
import math
from pathlib import Path

import numpy as np
import pandas as pd

from harness.outdir import atomic_output_dir
from harness.report.rundata import read_metrics, write_csv

KEYS = ["scenario", "observer", "state"]
#: metric -> sense: "low" lower is better, "high" higher is better, "one" nearer 1 is better.
COMPARED: dict[str, str] = {
    "rmse": "low", "mae": "low", "max_abs": "low", "p95_abs": "low", "bias": "abs",
    "conv_time_s": "low", "coverage": "high", "mean_width": "low", "violation_time_s": "low",
    "nees_mean": "one", "us_per_step": "low",
}
HEADLINE = ("rmse", "max_abs", "conv_time_s", "coverage", "nees_mean")
REL_TOL = 0.01


def _goodness(x: pd.Series, sense: str) -> pd.Series:
    """A 'lower is better' transform of a metric."""
    if sense == "high":
        return -x
    if sense == "one":
        return np.abs(np.log(x.where(x > 0)))
    if sense == "abs":
        return x.abs()
    return x


def _change(a: pd.Series, b: pd.Series, sense: str) -> pd.Series:
    ga, gb = _goodness(a, sense), _goodness(b, sense)
    scale = np.maximum(np.abs(ga), np.abs(gb))
    tol = REL_TOL * scale.where(scale > 0, 1.0)
    out = pd.Series("same", index=a.index, dtype=object)
    out[gb < ga - tol] = "better"
    out[gb > ga + tol] = "worse"
    # A metric that appears or disappears (NaN on one side), e.g. convergence lost.
    out[a.notna() & b.isna()] = "worse" if sense == "low" else "lost"
    out[a.isna() & b.notna()] = "better" if sense == "low" else "new"
    out[a.isna() & b.isna()] = ""
    return out


def compare_runs(dir_a: Path, dir_b: Path, out: Path | None = None) -> pd.DataFrame:
    """Metric deltas of run B against run A.

    Parameters
    ----------
    dir_a, dir_b : run folders (each with ``metrics.csv``); a missing or invalid folder raises
        ``RunFolderError`` (an InputError).
    out : optional folder for ``compare.csv`` and ``compare.html`` (written atomically).

    Returns
    -------
    DataFrame
        One row per (scenario, observer, state) present in either run, with ``status_a``,
        ``status_b``, ``<metric>_a/_b/_delta``, ``<metric>_change`` for the headline metrics,
        and ``verdict``.
    """
    a = read_metrics(Path(dir_a))
    b = read_metrics(Path(dir_b))
    metrics = [m for m in COMPARED if m in a.columns or m in b.columns]
    cols = KEYS + ["status"] + metrics
    a = a.reindex(columns=cols)
    b = b.reindex(columns=cols)
    j = a.merge(b, on=KEYS, how="outer", suffixes=("_a", "_b"), sort=False)
    table = j[KEYS].copy()
    table["status_a"] = j["status_a"].fillna("absent")
    table["status_b"] = j["status_b"].fillna("absent")
    for m in metrics:
        ma, mb = pd.to_numeric(j[f"{m}_a"], errors="coerce"), pd.to_numeric(j[f"{m}_b"], errors="coerce")
        table[f"{m}_a"], table[f"{m}_b"], table[f"{m}_delta"] = ma, mb, mb - ma
        if m in HEADLINE:
            table[f"{m}_change"] = _change(ma, mb, COMPARED[m])
    ok_a = table["status_a"].str.startswith("ok")
    ok_b = table["status_b"].str.startswith("ok")
    verdict = table["rmse_change"].replace({"": "same"}) if "rmse_change" in table else "same"
    table["verdict"] = verdict
    table.loc[ok_a & ~ok_b, "verdict"] = "worse"
    table.loc[~ok_a & ok_b, "verdict"] = "better"
    table = table.sort_values(KEYS, kind="stable").reset_index(drop=True)
    if out is not None:
        with atomic_output_dir(out, command="compare", inputs=[dir_a, dir_b]) as tmp:
            write_csv(table, tmp / "compare.csv")
            (tmp / "compare.html").write_text(_html(table, Path(dir_a), Path(dir_b)), encoding="utf-8")
    return table


def _fmt(v: float) -> str:
    return "—" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.4g}"


def _html(table: pd.DataFrame, dir_a: Path, dir_b: Path) -> str:
    counts = table["verdict"].value_counts().to_dict()
    rows = []
    for r in table.itertuples(index=False):
        d = r._asdict()
        cls = {"better": "better", "worse": "worse"}.get(d["verdict"], "")
        rows.append(
            f"<tr class='{cls}'><td>{html.escape(str(d['scenario']))}</td><td>{html.escape(str(d['observer']))}</td>"
            f"<td><code>{html.escape(str(d['state']))}</code></td>"
            f"<td>{html.escape(str(d['status_a']))}</td><td>{html.escape(str(d['status_b']))}</td>"
            f"<td class=n>{_fmt(d.get('rmse_a'))}</td><td class=n>{_fmt(d.get('rmse_b'))}</td>"
            f"<td class=n>{_fmt(d.get('rmse_delta'))}</td>"
            f"<td class=n>{_fmt(d.get('conv_time_s_a'))} → {_fmt(d.get('conv_time_s_b'))}</td>"
            f"<td class=n>{_fmt(d.get('coverage_a'))} → {_fmt(d.get('coverage_b'))}</td>"
            f"<td>{html.escape(str(d['verdict']))}</td></tr>")
    summary = ", ".join(f"{html.escape(str(k))}: {v}" for k, v in sorted(counts.items()))
    return f"""<!doctype html><html lang="en"><head><meta charset="utf-8"><title>roadtruth compare</title>
<style>body{{font:14px system-ui,sans-serif;margin:24px;color:#1d2430}}table{{border-collapse:collapse}}
td,th{{padding:4px 9px;border-bottom:1px solid #e4e7ec;text-align:left}}td.n{{text-align:right;font-variant-numeric:tabular-nums}}
tr.better td{{background:#e3f4e8}}tr.worse td{{background:#fde7e4}}th{{background:#14213d;color:#fff;font-weight:500}}</style>
</head><body><h1>roadtruth compare</h1><p>A = <code>{html.escape(str(dir_a))}</code>, B = <code>{html.escape(str(dir_b))}</code>.
Deltas are B − A; "better"/"worse" judge the RMSE (±{REL_TOL:.0%}) and status changes. {summary}</p>
<table><thead><tr><th>scenario</th><th>observer</th><th>state</th><th>status A</th><th>status B</th><th>RMSE A</th>
<th>RMSE B</th><th>Δ RMSE</th><th>convergence [s]</th><th>coverage</th><th>verdict</th></tr></thead>
<tbody>{''.join(rows)}</tbody></table></body></html>
"""
