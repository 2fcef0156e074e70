"""The CI gate (``roadtruth check``): run a suite, then judge its metrics against thresholds and a baseline.

Three kinds of checks, each giving one ``CheckOutcome`` per (scenario, observer, state) it judges:

* **simulation** — every scenario's simulation status must be ``ok`` (a diverged or crashed
  simulation fails the gate whatever the thresholds file says);
* **threshold** — the ``rules`` of a thresholds YAML (``max``/``min``/``equals`` on one
  ``metrics.csv`` column, glob patterns on scenario/observer/state). A rule that matches no row is
  itself an outcome: *skipped* when it names something known that this run did not select (e.g. a
  scenario outside ``--scenario``), *failed* when it matches nothing known at all (a typo);
* **regression** — against a baseline ``metrics.csv``: a metric may not get worse by more than
  ``rel_tol * |baseline| + abs_tol[state]`` (in the metric's own sense: lower error, higher
  coverage, NEES nearer 1), a finite baseline value may not become NaN, and an ``ok`` status may
  not become anything else.

The file format, defaults and the JUnit mapping are documented in ``docs/CHECK.md``. The thresholds
file is parsed by ``roadtruth.harness.jobs.check_rules``; the JUnit writer is ``roadtruth.harness.jobs.check_junit``.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.files.outdir import write_atomic
from roadtruth.harness.jobs.check_rules import (
    DEFAULT_THRESHOLDS,
    KEYS,
    SENSE,
    CheckOutcome,
    RegressionSpec,
    Rule,
    Thresholds,
    load_baseline,
    load_thresholds,
    metric_kind,
)

__all__ = ["CheckOutcome", "CheckResult", "RegressionSpec", "Rule", "Thresholds", "evaluate", "known_universe",
           "load_baseline", "load_thresholds", "reason_of", "run_check", "simulation_outcomes"]

#: Most failure lines ``CheckResult.summary`` prints before "… and N more".
SUMMARY_ROWS = 40


# ---- evaluation (pure) ----------------------------------------------------------------------------

def _fmt(v: Any) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "NaN"
    if isinstance(v, bool | np.bool_):
        return "true" if v else "false"
    if isinstance(v, float | np.floating):
        return f"{float(v):.4g}"
    return str(v)


def _as_flag(v: Any) -> bool | None:
    """A ``certified``/``nees_in_band`` cell as a bool (CSV gives True/False, 1.0/0.0 or empty)."""
    if isinstance(v, bool | np.bool_):
        return bool(v)
    if isinstance(v, int | float | np.integer | np.floating):
        return None if math.isnan(float(v)) else bool(v)
    if isinstance(v, str):
        return {"true": True, "1": True, "1.0": True, "false": False, "0": False, "0.0": False}.get(v.strip().lower())
    return None


def _as_number(v: Any) -> float:
    if isinstance(v, bool | np.bool_):
        return float(v)
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _matches(patterns: tuple[str, ...], values: pd.Series) -> pd.Series:
    return values.astype(str).map(lambda v: any(fnmatchcase(v, p) for p in patterns)).astype(bool)


def _judge(rule: Rule, value: Any) -> tuple[str, str]:
    """(verdict, reason) of one rule on one cell."""
    kind = metric_kind(rule.metric)
    if kind == "text":
        v = None if value is None or (isinstance(value, float) and math.isnan(value)) else str(value)
    elif kind == "flag":
        v = _as_flag(value)
    else:
        v = _as_number(value)
        v = None if math.isnan(v) else v
    if v is None:
        if rule.if_missing == "skip":
            return "skip", f"{rule.metric} is missing (if_missing: skip)"
        return "fail", f"{rule.metric} is missing (NaN)"
    if rule.equals is not None:
        ok = (v == rule.equals) if kind != "number" else (float(v) == float(rule.equals))
        return ("pass", "") if ok else ("fail", f"{rule.metric} = {_fmt(v)}, expected {_fmt(rule.equals)}")
    if rule.max is not None and v > rule.max:
        return "fail", f"{rule.metric} = {_fmt(v)} > max {_fmt(rule.max)}"
    if rule.min is not None and v < rule.min:
        return "fail", f"{rule.metric} = {_fmt(v)} < min {_fmt(rule.min)}"
    return "pass", ""


#: Observer statuses that mean "not applicable to this scenario", which no threshold judges.
NOT_APPLICABLE = "skipped: missing"


def _threshold_outcomes(metrics: pd.DataFrame, rule: Rule, known: pd.DataFrame | None) -> list[CheckOutcome]:
    sel = (_matches(rule.scenario, metrics["scenario"]) & _matches(rule.observer, metrics["observer"])
           & _matches(rule.state, metrics["state"])) if len(metrics) else pd.Series(dtype=bool)
    rows = metrics[sel]
    if rows.empty:
        where = f"scenario {'|'.join(rule.scenario)}, observer {'|'.join(rule.observer)}, state {'|'.join(rule.state)}"
        hit_known = known is not None and bool(
            (_matches(rule.scenario, known["scenario"]) & _matches(rule.observer, known["observer"])
             & _matches(rule.state, known["state"])).any())
        if hit_known:
            return [CheckOutcome("rule", "", "", "", rule.metric, rule.label, None, "skip",
                                 f"{rule.where}: matches no row of this run ({where} not selected)", rule.where)]
        return [CheckOutcome("rule", "", "", "", rule.metric, rule.label, None, "fail",
                             f"{rule.where}: matches no metrics row ({where}; a typo?)", rule.where)]
    out = []
    has_col = rule.metric in metrics.columns
    for d in rows.to_dict("records"):
        if str(d.get("status", "")).startswith(NOT_APPLICABLE):
            # The scenario lacks a sensor the observer needs (e.g. no radar target): nothing to judge,
            # and the reason is kept so that JUnit and the page say why it was skipped.
            out.append(CheckOutcome("threshold", str(d["scenario"]), str(d["observer"]), str(d["state"]),
                                    rule.metric, rule.label, d.get("status"), "skip",
                                    f"{d['scenario']} {d['observer']} {d['state'] or '-'}: not applicable "
                                    f"({d.get('status')}) ({rule.where})", rule.where))
            continue
        value = d.get(rule.metric) if has_col else None
        verdict, reason = _judge(rule, value)
        if not has_col:
            reason = f"metrics have no column {rule.metric!r}"
            verdict = "skip" if rule.if_missing == "skip" else "fail"
        msg = f"{d['scenario']} {d['observer']} {d['state'] or '-'}: {reason} ({rule.where})" if reason else ""
        out.append(CheckOutcome("threshold", str(d["scenario"]), str(d["observer"]), str(d["state"]), rule.metric,
                                rule.label, value, verdict, msg, rule.where))
    return out


def _goodness(x: float, sense: str) -> float:
    """A 'lower is better' version of a metric value (sense from ``roadtruth.harness.jobs.compare.COMPARED``)."""
    return {"low": x, "high": -x, "abs": abs(x), "one": abs(x - 1.0)}[sense]


def _regression_outcomes(metrics: pd.DataFrame, baseline: pd.DataFrame, spec: RegressionSpec) -> list[CheckOutcome]:
    # Only scenarios and observers that this run computed can regress; a baseline for a wider suite is fine.
    base = baseline[baseline["scenario"].isin(set(metrics["scenario"])) & baseline["observer"].isin(set(metrics["observer"]))]
    cur = metrics.set_index(KEYS)
    cur = cur[~cur.index.duplicated()]
    out: list[CheckOutcome] = []
    for d in base.to_dict("records"):
        key = (str(d["scenario"]), str(d["observer"]), str(d["state"]))
        head = f"{key[0]} {key[1]} {key[2] or '-'}"
        if key not in cur.index:
            out.append(CheckOutcome("regression", *key, "status", "present as in baseline", None, "fail",
                                    f"{head}: in the baseline but missing from this run", "regression"))
            continue
        now = cur.loc[key]
        if str(now["status"]).startswith(NOT_APPLICABLE) and not str(d["status"]).startswith("ok"):
            # Not applicable in this run nor in the baseline: a skip with its reason (an observer
            # that was ok in the baseline and is skipped now still fails the status check below).
            out.append(CheckOutcome("regression", *key, "status", "no worse than baseline", now["status"], "skip",
                                    f"{head}: not applicable ({now['status']})", "regression"))
            continue
        was_ok, is_ok = str(d["status"]).startswith("ok"), str(now["status"]).startswith("ok")
        if was_ok:
            verdict = "pass" if is_ok else "fail"
            msg = "" if is_ok else f"{head}: status regressed from ok to {now['status']!r}"
            out.append(CheckOutcome("regression", *key, "status", "status stays ok", now["status"], verdict, msg,
                                    "regression"))
        for m in spec.metrics:
            a = _as_number(d.get(m))
            bval = _as_number(now[m]) if m in now.index else math.nan
            label = f"{m} no worse than baseline"
            if math.isnan(a):
                out.append(CheckOutcome("regression", *key, m, label, bval, "skip",
                                        f"{head}: no baseline value of {m}", "regression"))
                continue
            if math.isnan(bval):
                out.append(CheckOutcome("regression", *key, m, label, bval, "fail",
                                        f"{head}: {m} was {_fmt(a)} in the baseline, now missing (NaN)", "regression"))
                continue
            ga, gb = _goodness(a, SENSE[m]), _goodness(bval, SENSE[m])
            tol = spec.rel_tol * abs(ga) + spec.abs_tol_for(key[2])
            if gb > ga + tol:
                rel = f" ({(bval - a) / abs(a):+.1%})" if a != 0 else ""
                out.append(CheckOutcome("regression", *key, m, label, bval, "fail",
                                        f"{head}: {m} = {_fmt(bval)} vs baseline {_fmt(a)}{rel}, "
                                        f"beyond tolerance {_fmt(tol)}", "regression"))
            else:
                out.append(CheckOutcome("regression", *key, m, label, bval, "pass", "", "regression"))
    return out


def evaluate(metrics: pd.DataFrame, rules: Thresholds | list[Rule] | tuple[Rule, ...],
             baseline: pd.DataFrame | None = None, tolerance: RegressionSpec | None = None, *,
             known: pd.DataFrame | None = None) -> list[CheckOutcome]:
    """Judge a metrics frame against threshold rules and (optionally) a baseline.

    Parameters
    ----------
    metrics : DataFrame
        ``metrics.csv`` rows (``scenario, observer, state, status`` and metric columns).
    rules : Thresholds or sequence of Rule
        Threshold rules; a ``Thresholds`` also supplies the regression tolerance when ``tolerance``
        is None.
    baseline : DataFrame, optional
        A previous ``metrics.csv`` (see ``load_baseline``); None = no regression checks.
    tolerance : RegressionSpec, optional
        Which metrics are compared with the baseline and how much worse they may get (default
        ``RegressionSpec()``: rmse and p95_abs, 10 %, no absolute slack).
    known : DataFrame, optional
        Every (scenario, observer, state) that could exist (all shipped scenarios × registered
        observers' states, see ``known_universe``). A rule matching no row of ``metrics`` but some
        known triple is skipped; one matching nothing known fails. None = every unmatched rule fails.

    Returns
    -------
    list of CheckOutcome
        Threshold outcomes in rule order, then regression outcomes in baseline row order.
    """
    if isinstance(rules, Thresholds):
        tolerance = tolerance if tolerance is not None else rules.regression
        rules = rules.rules
    metrics = metrics.copy()
    metrics["state"] = metrics["state"].fillna("").astype(str)
    out: list[CheckOutcome] = []
    for rule in rules:
        out.extend(_threshold_outcomes(metrics, rule, known))
    if baseline is not None:
        base = baseline.copy()
        base["state"] = base["state"].fillna("").astype(str)
        out.extend(_regression_outcomes(metrics, base, tolerance or RegressionSpec()))
    return out


def simulation_outcomes(scenarios: list[dict[str, Any]]) -> list[CheckOutcome]:
    """One outcome per scenario entry of ``run.json``: the simulation status must be ``ok``."""
    out = []
    for e in scenarios:
        status = str(e.get("status", "missing"))
        ok = status == "ok"
        out.append(CheckOutcome("simulation", str(e.get("name", "?")), "", "", "status", "simulation status == ok",
                                status, "pass" if ok else "fail",
                                "" if ok else f"{e.get('name', '?')}: scenario status {status!r} (expected ok)",
                                "simulation"))
    return out


def known_universe() -> pd.DataFrame:
    """Every (scenario, observer, state) that could appear: shipped scenarios × registered observers' states."""
    from roadtruth.harness.truth.scenario import available_scenarios
    from roadtruth.observers.registry import observer_info

    pairs = [(i["name"], s) for i in observer_info() for s in (i.get("states") or [""])]
    rows = [(sc, o, s) for sc in available_scenarios() for o, s in pairs]
    return pd.DataFrame(rows, columns=KEYS)


# ---- result -----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class CheckResult:
    """What ``run_check`` found. ``n_checks`` counts judged outcomes (passed + failed, not skipped)."""

    passed: bool
    n_checks: int
    n_failed: int
    n_skipped: int
    out: Path
    failures: tuple[str, ...]
    outcomes: tuple[CheckOutcome, ...] = ()

    @classmethod
    def from_outcomes(cls, outcomes: list[CheckOutcome], out: Path) -> CheckResult:
        failed = [o for o in outcomes if o.verdict == "fail"]
        skipped = sum(o.verdict == "skip" for o in outcomes)
        return cls(passed=not failed, n_checks=len(outcomes) - skipped, n_failed=len(failed), n_skipped=skipped,
                   out=Path(out), failures=tuple(o.message for o in failed), outcomes=tuple(outcomes))

    @property
    def n_rules(self) -> int:
        """How many sources of checks were applied (each thresholds rule, the regression, the simulation)."""
        return len({o.source for o in self.outcomes})

    @property
    def failed_rules(self) -> list[str]:
        """Sources with at least one failed check, in order of appearance."""
        return list(dict.fromkeys(o.source for o in self.outcomes if o.verdict == "fail"))

    def verdict_line(self) -> str:
        """``check passed: …`` / ``check FAILED: …`` with the counts of checks and rules."""
        verdict = "passed" if self.passed else "FAILED"
        n_bad = len(self.failed_rules)
        return (f"check {verdict}: {self.n_failed} of {self.n_checks} checks failed ({n_bad} of {self.n_rules} rules "
                f"broken), {self.n_skipped} skipped")

    def summary(self) -> str:
        """A compact table of the failures (at most ``SUMMARY_ROWS``, with the reason of each) and the verdict."""
        failed = [o for o in self.outcomes if o.verdict == "fail"]
        lines: list[str] = []
        if failed:
            head = ("kind", "scenario", "observer", "state", "check", "value", "reason")
            rows = [(o.kind, o.scenario or "-", o.observer or "-", o.state or "-", o.check, _fmt(o.value),
                     reason_of(o)) for o in failed[:SUMMARY_ROWS]]
            widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
            lines.append("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)).rstrip())
            lines.extend("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in rows)
            if len(failed) > SUMMARY_ROWS:
                lines.append(f"… and {len(failed) - SUMMARY_ROWS} more (see {self.out / 'check.csv'})")
        lines.append(f"{self.verdict_line()} (see {self.out / 'check.html'})")
        return "\n".join(lines)


def reason_of(o: CheckOutcome) -> str:
    """Why a check failed or was skipped, without the scenario/observer/state the row already names."""
    msg = o.message
    for head in (f"{o.scenario} {o.observer} {o.state or '-'}: ", f"{o.source}: ", f"{o.scenario}: "):
        if head.strip(": -") and msg.startswith(head):
            return msg[len(head):]
    return msg


# ---- files ------------------------------------------------------------------------------------------

def outcomes_frame(outcomes: list[CheckOutcome] | tuple[CheckOutcome, ...]) -> pd.DataFrame:
    """The outcomes as a table (the ``check.csv`` written next to ``metrics.csv``)."""
    cols = ["kind", "scenario", "observer", "state", "metric", "check", "value", "verdict", "message", "source"]
    return pd.DataFrame([{**o.__dict__, "value": _fmt(o.value) if o.value is not None else ""} for o in outcomes],
                        columns=cols)


def _scenario_seconds(run_dir: Path) -> dict[str, float]:
    """Seconds per scenario for JUnit, from the run's ``timings.json`` (empty when it is unreadable)."""
    try:
        data = json.loads((run_dir / "timings.json").read_text(encoding="utf-8"))
        return {str(name): float(sum(t.values())) for name, t in data["scenarios_s"].items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}


def run_check(*, thresholds: Path | None, baseline: Path | None, junit: Path | None, suite_name: str = "ci",
              scenarios: list[str] | None = None, observers: list[str] | None = None, seed: int | None = None,
              jobs: int = 1, out: Path = Path("reports/check"),
              observer_timeout_s: float | None = None, observer_options: dict[str, dict[str, Any]] | None = None,
              table_format: str = "csv") -> CheckResult:
    """Run a suite (no rendering) into ``out`` and judge it; ``roadtruth check``.

    Parameters
    ----------
    thresholds : thresholds YAML (None = the shipped ``harness/thresholds/ci.yaml``).
    baseline : a previous ``metrics.csv`` (or a run folder holding one); None = no regression checks.
    junit : where to write a JUnit XML report (None = none).
    suite_name, scenarios, observers, seed, jobs, observer_timeout_s, observer_options, table_format :
        as ``roadtruth run`` (``roadtruth.harness.jobs.pipeline.run_suite``).
    out : the run folder (``run_suite`` output plus ``check.csv``, every outcome; ``check.parquet``
        with ``table_format="parquet"``).

    Returns
    -------
    CheckResult
        ``passed`` is False when any outcome failed (the CLI exits 1).

    Raises
    ------
    InputError
        Bad thresholds or baseline file, unknown scenario/observer, a JUnit path that is a folder;
        raised before anything is simulated or written.
    """
    from roadtruth.harness.evaluation.metrics_file import read_metrics_file
    from roadtruth.harness.files.outdir import check_output_dir, check_writable, claim
    from roadtruth.harness.files.table_io import check_format, table_file, write_parquet_table
    from roadtruth.harness.jobs.check_junit import junit_xml
    from roadtruth.harness.jobs.pipeline import run_suite
    from roadtruth.harness.report.check_page import check_page
    from roadtruth.harness.report.rundata import read_run_json, write_csv

    check_format(table_format)

    spec = load_thresholds(Path(thresholds) if thresholds is not None else DEFAULT_THRESHOLDS)
    base = load_baseline(Path(baseline), spec.regression.metrics) if baseline is not None else None
    # Every output location is checked before anything is simulated (the run itself re-checks --out).
    check_output_dir(out, inputs=[thresholds, baseline, *(scenarios or [])])
    if junit is not None:
        check_writable(junit, what="--junit", folder=False)
    run_dir = run_suite(scenarios=scenarios, suite_name=suite_name, observers=observers, seed=seed, jobs=jobs,
                        out=Path(out), render=False, progress=None, observer_timeout_s=observer_timeout_s,
                        observer_options=observer_options, table_format=table_format)
    metrics = read_metrics_file(run_dir)  # the validation a baseline gets, too
    run_json = read_run_json(run_dir)
    outcomes = simulation_outcomes(run_json.get("scenarios", []))
    outcomes += evaluate(metrics, spec, base, spec.regression, known=known_universe())
    result = CheckResult.from_outcomes(outcomes, run_dir)

    name = table_file(run_dir, "check", table_format).name
    tmp = run_dir / f".{name}.partial"
    (write_parquet_table if table_format == "parquet" else write_csv)(outcomes_frame(outcomes), tmp)
    os.replace(tmp, run_dir / name)
    if name != "check.csv":
        claim(run_dir, [name])  # ours: a later check may replace the folder with it
    write_atomic(run_dir / "check.json", json.dumps({
        "thresholds": str(spec.source), "baseline": str(baseline) if baseline is not None else None,
        "passed": result.passed, "n_checks": result.n_checks, "n_failed": result.n_failed,
        "n_skipped": result.n_skipped, "n_rules": result.n_rules, "failed_rules": result.failed_rules},
        indent=2) + "\n")
    write_atomic(run_dir / "check.html", check_page(
        result, thresholds=spec.source, baseline=Path(baseline) if baseline is not None else None,
        run_report="index.html" if (run_dir / "index.html").is_file() else None))
    if junit is not None:
        times = _scenario_seconds(run_dir)
        write_atomic(Path(junit), junit_xml(outcomes, times=times,
                                            properties={"thresholds": str(spec.source),
                                                        "baseline": str(baseline or ""),
                                                        "run_folder": str(run_dir)}))
        if Path(junit).resolve().parent == run_dir:
            claim(run_dir, [Path(junit).name])  # ours: a later check may replace the folder with it
    return result
