"""Per (scenario, observer, state) metric deltas between two run folders (``roadtruth compare``).

The two ``metrics.csv`` files are read with the validation ``check --baseline`` uses
(:mod:`roadtruth.harness.evaluation.metrics_file`: a malformed file is one error line, never dropped or duplicated rows),
and the two ``run.json`` files for the settings. For each metric the table has ``<m>_a``, ``<m>_b``
and ``<m>_delta`` (= b - a, SI units as in metrics.csv) and, for the headline metrics,
``<m>_change`` in {better, worse, same} judged by the metric's sense (lower error, shorter
convergence, higher coverage, NEES nearer 1) with a relative tolerance ``REL_TOL`` so that float
noise is "same". ``verdict`` summarises a row present in both runs from the RMSE change and the
status change (an observer that stops being ok is "worse"); a row present in one run only is
``only in A`` / ``only in B`` and one where the observer does not apply on a side (``skipped:
missing …``) is ``not comparable``: neither counts as better or worse.

Runs made with different settings (vehicle, friction, sensors, faults, seed, roadtruth or MuJoCo
version) are listed in :attr:`Comparison.settings`, at the top of the terminal text and the page.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.evaluation.metrics_file import read_metrics_file
from roadtruth.harness.files.outdir import atomic_output_dir
from roadtruth.harness.report.rundata import read_run_json, write_csv

KEYS = ["scenario", "observer", "state"]
#: metric -> sense: "low" lower is better, "high" higher is better, "one" nearer 1 is better.
COMPARED: dict[str, str] = {
    "rmse": "low", "mae": "low", "max_abs": "low", "p95_abs": "low", "bias": "abs",
    "conv_time_s": "low", "coverage": "high", "mean_width": "low", "violation_time_s": "low",
    "nees_mean": "one", "us_per_step": "low",
}
HEADLINE = ("rmse", "max_abs", "conv_time_s", "coverage", "nees_mean")
REL_TOL = 0.01
#: Rows of each list (regressions, improvements) the terminal shows.
TERMINAL_ROWS = 8
ONLY_A, ONLY_B, NOT_COMPARABLE = "only in A", "only in B", "not comparable"
#: Run settings that change results: run.json key -> label.
SETTINGS: tuple[tuple[str, str], ...] = (("vehicle", "vehicle"), ("friction", "friction"), ("sensors", "sensors"),
                                         ("faults", "faults"), ("seed", "seed"))
#: Settings recorded per scenario (a run without overrides uses each scenario's own).
SCENARIO_SETTINGS: tuple[str, ...] = ("vehicle", "sensors", "seed")
VERSIONS: tuple[tuple[str, str], ...] = (("roadtruth", "roadtruth version"), ("mujoco", "MuJoCo version"))
_NOT_APPLICABLE = "skipped: missing"


@dataclass(frozen=True)
class SettingDifference:
    """One setting that differs between the runs (values as text; ``default`` = the scenario's own)."""

    name: str
    a: str
    b: str


@dataclass(frozen=True)
class Comparison:
    """Run B against run A: the row table, what only one side has, and differing settings."""

    table: pd.DataFrame
    dir_a: Path
    dir_b: Path
    only_a: dict[str, tuple[str, ...]]
    only_b: dict[str, tuple[str, ...]]
    settings: tuple[SettingDifference, ...]

    def counts(self) -> dict[str, int]:
        """Rows per verdict (better, worse, same, only in A, only in B, not comparable)."""
        vc = self.table["verdict"].value_counts()
        return {k: int(vc.get(k, 0)) for k in ("worse", "better", "same", ONLY_A, ONLY_B, NOT_COMPARABLE)}

    def regressions(self, n: int | None = None) -> pd.DataFrame:
        """Rows judged worse: status regressions first, then by relative RMSE growth (largest first)."""
        return _ranked(self.table[self.table["verdict"] == "worse"], worst_first=True).head(n)

    def improvements(self, n: int | None = None) -> pd.DataFrame:
        """Rows judged better: status recoveries first, then by relative RMSE drop (largest first)."""
        return _ranked(self.table[self.table["verdict"] == "better"], worst_first=False).head(n)

    def terminal(self, n: int = TERMINAL_ROWS) -> str:
        """A short readable summary: settings warnings, one-sided items, counts, top regressions and
        improvements (angles in degrees)."""
        lines = [f"A = {self.dir_a}", f"B = {self.dir_b}"]
        if self.settings:
            lines.append("WARNING: the runs were made with different settings; deltas mix setup and code changes:")
            lines.extend(f"  {d.name}: {d.a} (A) vs {d.b} (B)" for d in self.settings)
        for side, only in (("A", self.only_a), ("B", self.only_b)):
            text = one_sided_text(only)
            if text:
                lines.append(f"only in {side} (not compared): {text}")
        c = self.counts()
        both = c["worse"] + c["better"] + c["same"]
        tail = f", {c[NOT_COMPARABLE]} not comparable (observer not applicable on a side)" if c[NOT_COMPARABLE] else ""
        lines.append(f"{both} rows in both runs: {c['worse']} worse, {c['better']} better, {c['same']} same "
                     f"(RMSE beyond ±{REL_TOL:.0%}, or the status changed){tail}")
        for title, rows in (("largest regressions", self.regressions()), ("largest improvements",
                                                                           self.improvements())):
            if rows.empty:
                lines.append(f"{title}: none")
                continue
            shown = rows.head(n)
            lines.append(f"{title} ({len(shown)} of {len(rows)}):")
            lines.extend("  " + ln for ln in _text_table(shown))
        return "\n".join(lines)


def _ranked(rows: pd.DataFrame, *, worst_first: bool) -> pd.DataFrame:
    ok_a = rows["status_a"].str.startswith("ok")
    ok_b = rows["status_b"].str.startswith("ok")
    status_change = (ok_a != ok_b).astype(int)
    rel = relative_change(rows)
    key = -rel if worst_first else rel
    order = pd.DataFrame({"s": -status_change, "k": key.fillna(np.inf)}, index=rows.index)
    return rows.loc[order.sort_values(["s", "k"], kind="stable").index]


def relative_change(rows: pd.DataFrame) -> pd.Series:
    """(RMSE_B − RMSE_A) / |RMSE_A| (NaN where either is missing or A is 0)."""
    a, b = rows["rmse_a"], rows["rmse_b"]
    return (b - a) / a.abs().where(a != 0)


def display_value(state: str, v: float) -> str:
    """A metric value in the unit the pages show (angles in degrees), or ``—``."""
    from roadtruth.harness.report.figures import display_unit

    if v is None or not math.isfinite(float(v)):
        return "—"
    scale, _ = display_unit(state)
    return f"{float(v) * scale:.3g}"


def display_unit_of(state: str) -> str:
    from roadtruth.harness.report.figures import display_unit

    return display_unit(state)[1]


def _row_cells(d: dict[str, Any]) -> tuple[str, ...]:
    rel = (d["rmse_b"] - d["rmse_a"]) / abs(d["rmse_a"]) if d["rmse_a"] and math.isfinite(d["rmse_a"]) \
        and math.isfinite(d["rmse_b"]) else math.nan
    if str(d["status_a"]) != str(d["status_b"]):
        change = f"status {d['status_a']} → {d['status_b']}"
    else:
        change = f"{rel:+.0%}" if math.isfinite(rel) else "—"
    return (str(d["scenario"]), str(d["observer"]), str(d["state"]) or "-", display_unit_of(str(d["state"])) or "-",
            display_value(d["state"], d["rmse_a"]), display_value(d["state"], d["rmse_b"]), change)


TERMINAL_HEAD = ("scenario", "observer", "state", "unit", "RMSE A", "RMSE B", "change")


def _text_table(rows: pd.DataFrame) -> list[str]:
    body = [_row_cells(d) for d in rows.to_dict("records")]
    widths = [max(len(r[i]) for r in [TERMINAL_HEAD, *body]) for i in range(len(TERMINAL_HEAD))]
    right = {4, 5}
    def fmt(r: tuple[str, ...]) -> str:
        return "  ".join(c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths,
                                                                                                   strict=True)))
    return [fmt(TERMINAL_HEAD).rstrip(), *(fmt(r).rstrip() for r in body)]


def one_sided_text(only: dict[str, tuple[str, ...]]) -> str:
    """``scenarios ice_patch; observers ts_uio`` (empty when nothing is one-sided)."""
    parts = []
    for kind in ("scenarios", "observers", "rows"):
        items = only.get(kind, ())
        if items:
            parts.append(f"{len(items)} {kind[:-1] if len(items) == 1 else kind} ({', '.join(items[:6])}"
                         f"{' …' if len(items) > 6 else ''})")
    return "; ".join(parts)


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


def _text(v: Any, none: str = "the scenario's own") -> str:
    """A setting as text; None (no override on the command line) is each scenario's own value."""
    if v is None:
        return none
    if isinstance(v, dict | list):
        import json

        return json.dumps(v, sort_keys=True)
    return str(v)


def settings_differences(run_a: dict[str, Any], run_b: dict[str, Any]) -> tuple[SettingDifference, ...]:
    """Settings that differ between two ``run.json`` contents (empty dict = run.json missing)."""
    if not run_a or not run_b:
        return (SettingDifference("run.json", "present" if run_a else "missing (settings unknown)",
                                  "present" if run_b else "missing (settings unknown)"),) if run_a or run_b else \
            (SettingDifference("run.json", "missing (settings unknown)", "missing (settings unknown)"),)
    out: list[SettingDifference] = []
    top_differs = set()
    for key, label in SETTINGS:
        a, b = _text(run_a.get(key)), _text(run_b.get(key))
        if a != b:
            out.append(SettingDifference(label, a, b))
            top_differs.add(key)
    sc_a = {str(e.get("name")): e for e in run_a.get("scenarios", []) if isinstance(e, dict)}
    sc_b = {str(e.get("name")): e for e in run_b.get("scenarios", []) if isinstance(e, dict)}
    for key in SCENARIO_SETTINGS:
        if key in top_differs:
            continue
        names = [n for n in sc_a if n in sc_b and _text(sc_a[n].get(key)) != _text(sc_b[n].get(key))]
        out.extend(SettingDifference(f"{key} of {n}", _text(sc_a[n].get(key)), _text(sc_b[n].get(key)))
                   for n in names)
    va, vb = run_a.get("versions") or {}, run_b.get("versions") or {}
    for key, label in VERSIONS:
        if _text(va.get(key)) != _text(vb.get(key)):
            out.append(SettingDifference(label, _text(va.get(key), "not recorded"), _text(vb.get(key), "not recorded")))
    return tuple(out)


def compare(dir_a: Path, dir_b: Path, out: Path | None = None) -> Comparison:
    """Compare run B against run A.

    Parameters
    ----------
    dir_a, dir_b : run folders (each with ``metrics.csv``; ``run.json`` for the settings). A missing
        folder or a malformed metrics file raises ``MetricsFileError`` (an InputError).
    out : optional folder for ``compare.csv`` and ``compare.html`` (written atomically).
    """
    a = read_metrics_file(Path(dir_a))  # a run folder (metrics.csv or metrics.parquet) or the file
    b = read_metrics_file(Path(dir_b))
    run_a = read_run_json(Path(dir_a)) if Path(dir_a).is_dir() else {}
    run_b = read_run_json(Path(dir_b)) if Path(dir_b).is_dir() else {}
    metrics = [m for m in COMPARED if m in a.columns or m in b.columns]
    cols = KEYS + ["status"] + metrics
    j = a.reindex(columns=cols).merge(b.reindex(columns=cols), on=KEYS, how="outer", suffixes=("_a", "_b"),
                                      sort=False, indicator=True)
    table = j[KEYS].copy()
    table["status_a"] = j["status_a"].fillna("absent").astype(str)
    table["status_b"] = j["status_b"].fillna("absent").astype(str)
    for m in metrics:
        ma, mb = j[f"{m}_a"].astype(float), j[f"{m}_b"].astype(float)
        table[f"{m}_a"], table[f"{m}_b"], table[f"{m}_delta"] = ma, mb, mb - ma
        if m in HEADLINE:
            table[f"{m}_change"] = _change(ma, mb, COMPARED[m])
    if "rmse_a" not in table:
        table["rmse_a"] = table["rmse_b"] = math.nan
    ok_a = table["status_a"].str.startswith("ok")
    ok_b = table["status_b"].str.startswith("ok")
    verdict = table["rmse_change"].replace({"": "same"}) if "rmse_change" in table else \
        pd.Series("same", index=table.index)
    verdict = verdict.astype(object)
    verdict[ok_a & ~ok_b] = "worse"
    verdict[~ok_a & ok_b] = "better"
    na = table["status_a"].str.startswith(_NOT_APPLICABLE) | table["status_b"].str.startswith(_NOT_APPLICABLE)
    verdict[na] = NOT_COMPARABLE
    verdict[(j["_merge"] == "left_only").to_numpy()] = ONLY_A
    verdict[(j["_merge"] == "right_only").to_numpy()] = ONLY_B
    table["verdict"] = verdict
    table = table.sort_values(KEYS, kind="stable").reset_index(drop=True)

    def only(x: pd.DataFrame, y: pd.DataFrame, verdict_name: str) -> dict[str, tuple[str, ...]]:
        scen = tuple(s for s in dict.fromkeys(x["scenario"]) if s not in set(y["scenario"]))
        obs = tuple(o for o in dict.fromkeys(x["observer"]) if o not in set(y["observer"]))
        rows = table[(table["verdict"] == verdict_name) & ~table["scenario"].isin(scen) & ~table["observer"].isin(obs)]
        return {"scenarios": scen, "observers": obs,
                "rows": tuple(f"{r.scenario}/{r.observer}/{r.state or '-'}" for r in rows.itertuples())}

    result = Comparison(table=table, dir_a=Path(dir_a), dir_b=Path(dir_b), only_a=only(a, b, ONLY_A),
                        only_b=only(b, a, ONLY_B), settings=settings_differences(run_a, run_b))
    if out is not None:
        from roadtruth.harness.report.compare_page import compare_page

        with atomic_output_dir(out, command="compare", inputs=[dir_a, dir_b]) as tmp:
            write_csv(table, tmp / "compare.csv")
            (tmp / "compare.html").write_text(compare_page(result), encoding="utf-8")
    return result


def compare_runs(dir_a: Path, dir_b: Path, out: Path | None = None) -> pd.DataFrame:
    """The row table of :func:`compare` (one row per (scenario, observer, state) of either run)."""
    return compare(dir_a, dir_b, out).table
