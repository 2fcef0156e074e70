"""The CI gate: rules, regressions, unmatched rules, input errors, JUnit, and one end-to-end CLI run."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from roadtruth.harness.errors import InputError
from roadtruth.harness.evaluation import scoring
from roadtruth.harness.jobs.check import CheckResult, evaluate
from roadtruth.harness.jobs.check_junit import junit_xml
from roadtruth.harness.jobs.check_rules import (
    DEFAULT_THRESHOLDS,
    BaselineError,
    RegressionSpec,
    Rule,
    ThresholdsError,
    load_baseline,
    load_thresholds,
    propose_rules,
    round_up,
)

REPO = Path(__file__).resolve().parents[1]


def metrics_frame() -> pd.DataFrame:
    """Two scenarios × (obs_a: beta_rad, vy_mps with bounds; obs_b: beta_rad, certified)."""
    rows = []
    for k, sc in enumerate(("s1", "s2")):
        rows += [
            dict(scenario=sc, observer="obs_a", state="beta_rad", rmse=0.010 + 0.001 * k, p95_abs=0.02,
                 coverage=0.95, certified=False, status="ok"),
            dict(scenario=sc, observer="obs_a", state="vy_mps", rmse=0.10, p95_abs=0.2, coverage=0.97,
                 certified=False, status="ok"),
            dict(scenario=sc, observer="obs_b", state="beta_rad", rmse=0.004, p95_abs=0.008, coverage=math.nan,
                 certified=True, status="ok"),
        ]
    return pd.DataFrame(rows)


def verdicts(outcomes: list) -> dict[tuple[str, str, str], str]:
    return {(o.scenario, o.observer, o.state): o.verdict for o in outcomes}


# ---- thresholds ---------------------------------------------------------------------------------------

def test_max_min_equals_breaches_caught():
    m = metrics_frame()
    m.loc[(m.scenario == "s2") & (m.observer == "obs_a") & (m.state == "beta_rad"), "rmse"] = 0.05
    m.loc[(m.scenario == "s1") & (m.state == "vy_mps"), "coverage"] = 0.85
    m.loc[(m.scenario == "s2") & (m.observer == "obs_b"), ["status", "rmse"]] = ["diverged", math.nan]
    rules = [Rule(metric="rmse", observer=("obs_*",), state=("beta_rad",), max=0.02, where="rules[0]"),
             Rule(metric="coverage", observer=("obs_a",), min=0.9, where="rules[1]"),
             Rule(metric="status", equals="ok", where="rules[2]"),
             Rule(metric="certified", observer=("obs_b",), equals=True, where="rules[3]")]
    out = evaluate(m, rules)
    by_rule = {r.where: [o for o in out if o.source == r.where] for r in rules}

    rmse = verdicts(by_rule["rules[0]"])
    assert rmse == {("s1", "obs_a", "beta_rad"): "pass", ("s2", "obs_a", "beta_rad"): "fail",
                    ("s1", "obs_b", "beta_rad"): "pass", ("s2", "obs_b", "beta_rad"): "fail"}
    msg = next(o.message for o in by_rule["rules[0]"] if o.observer == "obs_a" and o.verdict == "fail")
    assert "rmse = 0.05 > max 0.02" in msg and "rules[0]" in msg
    nan_msg = next(o.message for o in by_rule["rules[0]"] if o.observer == "obs_b" and o.verdict == "fail")
    assert "missing" in nan_msg  # a diverged observer has no rmse: that fails, never passes silently

    cov = verdicts(by_rule["rules[1]"])
    assert cov[("s1", "obs_a", "vy_mps")] == "fail" and cov[("s2", "obs_a", "vy_mps")] == "pass"
    assert sum(v == "fail" for v in cov.values()) == 1

    status = verdicts(by_rule["rules[2]"])
    assert [k for k, v in status.items() if v == "fail"] == [("s2", "obs_b", "beta_rad")]
    assert all(o.verdict == "pass" for o in by_rule["rules[3]"])
    assert len(by_rule["rules[3]"]) == 2


def test_nan_metric_fails_unless_if_missing_skip():
    m = metrics_frame()
    strict = evaluate(m, [Rule(metric="coverage", min=0.9)])
    lenient = evaluate(m, [Rule(metric="coverage", min=0.9, if_missing="skip")])
    # obs_b gives no bounds (coverage NaN) in both scenarios.
    assert sum(o.verdict == "fail" for o in strict) == 2
    assert sum(o.verdict == "skip" for o in lenient) == 2 and not any(o.verdict == "fail" for o in lenient)


def test_rule_matching_nothing_is_reported():
    m = metrics_frame()
    typo = Rule(metric="rmse", observer=("obs_aa",), max=1.0, where="rules[0]")
    [o] = evaluate(m, [typo])
    assert o.verdict == "fail" and o.kind == "rule" and "typo" in o.message and "obs_aa" in o.message
    # Named in the universe of known observers but not selected in this run: skipped, not failed.
    known = pd.DataFrame([("s1", "obs_c", "beta_rad"), ("s3", "obs_a", "beta_rad")],
                         columns=["scenario", "observer", "state"])
    [o] = evaluate(m, [Rule(metric="rmse", observer=("obs_c",), max=1.0)], known=known)
    assert o.verdict == "skip"
    [o] = evaluate(m, [Rule(metric="rmse", scenario=("s3",), max=1.0)], known=known)
    assert o.verdict == "skip"
    [o] = evaluate(m, [typo], known=known)
    assert o.verdict == "fail"


# ---- regressions ---------------------------------------------------------------------------------------

def test_regression_beyond_tolerance_caught_within_passed():
    base = metrics_frame()
    cur = base.copy()
    spec = RegressionSpec(metrics=("rmse", "coverage"), rel_tol=0.10, abs_tol=(("beta_rad", 0.0005),))
    sel = (cur.scenario == "s1") & (cur.observer == "obs_a")
    # beta: 0.010 -> 0.0114 is within 0.010 * 1.1 + 0.0005 = 0.0115; vy: 0.10 -> 0.111 is beyond 0.11.
    cur.loc[sel & (cur.state == "beta_rad"), "rmse"] = 0.0114
    cur.loc[sel & (cur.state == "vy_mps"), "rmse"] = 0.111
    # coverage is "higher is better": 0.97 -> 0.86 is worse than 0.97 - 0.097.
    cur.loc[(cur.scenario == "s2") & (cur.state == "vy_mps"), "coverage"] = 0.86
    out = [o for o in evaluate(cur, [], base, spec) if o.verdict == "fail"]
    keys = sorted((o.scenario, o.observer, o.state, o.metric) for o in out)
    assert keys == [("s1", "obs_a", "vy_mps", "rmse"), ("s2", "obs_a", "vy_mps", "coverage")]
    assert "0.111 vs baseline 0.1 (+11.0%)" in next(o.message for o in out if o.metric == "rmse")
    # Improvements never fail; identical runs pass everything they judge.
    better = base.assign(rmse=base.rmse / 2, coverage=1.0)
    assert not any(o.verdict == "fail" for o in evaluate(better, [], base, spec))
    assert not any(o.verdict == "fail" for o in evaluate(base, [], base, spec))


def test_regression_status_nan_and_missing_rows():
    base = metrics_frame()
    cur = base.copy()
    lost = (cur.scenario == "s1") & (cur.observer == "obs_b")
    cur.loc[lost, ["status", "rmse"]] = ["diverged", math.nan]
    cur = cur[~((cur.scenario == "s2") & (cur.state == "vy_mps"))]
    wider = pd.concat([base, base.assign(scenario="s9")])  # a baseline of a wider suite
    out = evaluate(cur, [], wider, RegressionSpec(metrics=("rmse",)))
    failed = {(o.scenario, o.observer, o.state, o.metric) for o in out if o.verdict == "fail"}
    assert failed == {("s1", "obs_b", "beta_rad", "status"), ("s1", "obs_b", "beta_rad", "rmse"),
                      ("s2", "obs_a", "vy_mps", "status")}
    assert not any(o.scenario == "s9" for o in out)


# ---- input files ---------------------------------------------------------------------------------------

@pytest.mark.parametrize(("text", "field"), [
    ("rules:\n  - {observer: '*', metric: rmsee, max: 1}\n", "rules[0].metric"),
    ("rules:\n  - {observer: '*', metric: rmse, max: 1, colour: red}\n", "rules[0].colour"),
    ("rules:\n  - {metric: rmse, max: 1}\n  - {metric: rmse, min: 1, equals: 2}\n", "rules[1].equals"),
    ("rules:\n  - {metric: status, max: 1}\n", "rules[0].max"),
    ("rules:\n  - {metric: certified, equals: yes please}\n", "rules[0].equals"),
    ("rules:\n  - {metric: rmse}\n", "rules[0].max"),
    ("rules:\n  - {metric: rmse, min: 2, max: 1}\n", "rules[0].min"),
    ("rules:\n  - {metric: rmse, state: beta, max: 1}\n", "rules[0].state"),
    ("rules: []\nregression: {metric: status}\n", "regression.metric"),
    ("rules: []\nregression: {rel_tol: -0.1}\n", "regression.rel_tol"),
    ("rules: []\nregression: {abs_tol: {beta: 0.1}}\n", "regression.abs_tol.beta"),
    ("rules: []\n", "rules"),
    ("rulez: []\n", "rulez"),
])
def test_bad_thresholds_file_names_field(tmp_path: Path, text: str, field: str):
    path = tmp_path / "gate.yaml"
    path.write_text(text)
    with pytest.raises(ThresholdsError) as e:
        load_thresholds(path)
    assert isinstance(e.value, InputError)
    assert str(path) in str(e.value) and f"{field}:" in str(e.value)


def test_bad_baseline_file_names_column(tmp_path: Path):
    good = metrics_frame()
    cases = {"nocol.csv": good.drop(columns="p95_abs"), "text.csv": good.assign(rmse=["0.1", "x", *["0.2"] * 4]),
             "dup.csv": pd.concat([good, good.iloc[:1]])}
    for name, frame in cases.items():
        frame.to_csv(tmp_path / name, index=False)
    with pytest.raises(BaselineError, match=r"nocol\.csv: p95_abs: missing column"):
        load_baseline(tmp_path / "nocol.csv", ("rmse", "p95_abs"))
    with pytest.raises(BaselineError, match=r"text\.csv: rmse: not a number on line 3 \(got 'x'\)"):
        load_baseline(tmp_path / "text.csv", ("rmse",))
    with pytest.raises(BaselineError, match="duplicate row s1/obs_a/beta_rad"):
        load_baseline(tmp_path / "dup.csv", ("rmse",))
    with pytest.raises(BaselineError, match="file not found"):
        load_baseline(tmp_path / "missing.csv", ("rmse",))


def test_shipped_thresholds_parse_and_name_known_metrics():
    spec = load_thresholds(DEFAULT_THRESHOLDS)
    assert spec.rules and spec.regression.metrics == ("rmse", "p95_abs")
    # Status is gated per scenario on the pairs measured ok (not "*": some are honestly unusable).
    status = [r for r in spec.rules if r.metric == "status"]
    assert all(r.equals == "ok" and r.observer != ("*",) for r in status)
    assert {sc for r in status for sc in r.scenario} == {"step_steer", "brake_in_turn", "split_mu_braking"}


# ---- JUnit, summary, proposals ---------------------------------------------------------------------------

def test_junit_xml_structure_and_counts():
    m = metrics_frame()
    m.loc[0, "rmse"] = 0.5
    outcomes = evaluate(m, [Rule(metric="rmse", state=("beta_rad",), max=0.02, where="rules[0]"),
                            Rule(metric="rmse", observer=("nope",), max=1.0, where="rules[1]")])
    root = ET.fromstring(junit_xml(outcomes, times={"s1": 1.5}, properties={"thresholds": "x.yaml"}))
    assert root.tag == "testsuites"
    suites = {s.get("name"): s for s in root.findall("testsuite")}
    assert list(suites) == ["s1", "s2", "thresholds"]
    for s in suites.values():
        cases = s.findall("testcase")
        assert int(s.get("tests")) == len(cases)
        assert int(s.get("failures")) == sum(c.find("failure") is not None for c in cases)
        assert s.find("properties/property").get("value") == "x.yaml"
    assert int(root.get("tests")) == len(outcomes) == 5 and root.get("failures") == "2"
    assert suites["s1"].get("time") == "1.500"
    [bad] = [c for c in suites["s1"].findall("testcase") if c.find("failure") is not None]
    assert bad.get("classname") == "s1.obs_a" and bad.get("name") == "beta_rad: rmse <= 0.02"
    assert "rmse = 0.5 > max 0.02" in bad.find("failure").get("message")
    assert suites["thresholds"].find("testcase/failure").get("type") == "rule"


def test_summary_lists_failures_and_total(tmp_path: Path):
    m = metrics_frame()
    m.loc[0, "rmse"] = 0.5
    result = CheckResult.from_outcomes(evaluate(m, [Rule(metric="rmse", max=0.3)]), tmp_path)
    assert not result.passed and result.n_failed == 1 and result.n_checks == len(m)
    lines = result.summary().splitlines()
    assert lines[0].split() == ["kind", "scenario", "observer", "state", "check", "value", "reason"]
    assert lines[1].split()[:4] == ["threshold", "s1", "obs_a", "beta_rad"]
    # The reason column says why, without repeating the scenario/observer/state of the row.
    assert lines[1].split("  ")[-1] == "rmse = 0.5 > max 0.3 (rules[?])" and " 0.5 " in lines[1]
    assert lines[-1].startswith(f"check FAILED: 1 of {len(m)} checks failed (1 of 1 rules broken), 0 skipped")


def test_proposed_rules_pass_their_runs_and_catch_doubled_error(tmp_path: Path):
    runs = [metrics_frame(), metrics_frame().assign(rmse=lambda f: f.rmse * 1.2)]
    assert round_up(0.01201) == 0.013 and round_up(1.0e-5 * 1.5) == 1.5e-05
    text = "rules:\n" + "\n".join(propose_rules(runs, states=("beta_rad", "vy_mps"), margin=1.5)) + "\n"
    (tmp_path / "p.yaml").write_text(text)
    spec = load_thresholds(tmp_path / "p.yaml")
    assert len([r for r in spec.rules if r.metric == "rmse"]) == 6
    assert [r.observer for r in spec.rules if r.metric == "certified"] == [("obs_b",)]
    assert not any(o.verdict == "fail" for r in runs for o in evaluate(r, spec))
    worse = runs[1].assign(rmse=runs[1].rmse * 2)
    assert sum(o.verdict == "fail" for o in evaluate(worse, spec)) == 6
    # Coverage (higher is better): floors 0.10 under the worst run, only where an observer gives bounds.
    lines = propose_rules(runs, metric="coverage", states=("beta_rad", "vy_mps"), slack=0.10, certified=False)
    (tmp_path / "c.yaml").write_text("rules:\n" + "\n".join(lines) + "\n")
    rules = load_thresholds(tmp_path / "c.yaml").rules
    assert sorted(r.min for r in rules) == [0.85, 0.85, 0.87, 0.87] and {r.observer for r in rules} == {("obs_a",)}
    assert not any(o.verdict == "fail" for o in evaluate(runs[0], rules))
    assert sum(o.verdict == "fail" for o in evaluate(runs[0].assign(coverage=runs[0].coverage - 0.2), rules)) == 4


def test_simulation_status_other_than_ok_fails():
    from roadtruth.harness.jobs.check import simulation_outcomes

    out = simulation_outcomes([{"name": "a", "status": "ok"}, {"name": "b", "status": "diverged: car flipped"}])
    assert [o.verdict for o in out] == ["pass", "fail"]
    assert "diverged: car flipped" in out[1].message and out[1].scenario == "b"
    root = ET.fromstring(junit_xml(out))
    [case] = root.findall("testsuite[@name='b']/testcase")
    assert case.get("name") == "simulation: status == ok" and case.find("failure").get("type") == "simulation"


# ---- end to end -------------------------------------------------------------------------------------------

def _cli(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": "egl"}
    return subprocess.run([sys.executable, "-m", "roadtruth.harness.cli", "check", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=300)


def test_cli_check_passes_then_fails_with_strict_thresholds(tmp_path: Path):
    common = ["--scenario", "step_steer", "--observer", "kf_bicycle,lpv_wang"]
    ok = _cli(*common, "--out", str(tmp_path / "ok"))
    assert ok.returncode == 0, ok.stderr
    assert "check passed: 0 of" in ok.stdout
    table = pd.read_csv(tmp_path / "ok" / "check.csv")
    assert set(table.verdict) <= {"pass", "skip"} and (table.verdict == "pass").sum() > 10

    strict = tmp_path / "strict.yaml"
    strict.write_text("rules:\n"
                      "  - {observer: kf_bicycle, state: beta_rad, metric: rmse, max: 1.0e-6}\n"
                      "  - {observer: kf_bicycel, metric: status, equals: ok}\n"
                      "regression: {metric: rmse, rel_tol: 0.0}\n")
    junit = tmp_path / "junit" / "check.xml"
    bad = _cli(*common, "--out", str(tmp_path / "bad"), "--thresholds", str(strict),
               "--baseline", str(tmp_path / "ok" / "metrics.csv"), "--junit", str(junit))
    assert bad.returncode == 1, bad.stderr
    assert "check failed: 2 of" in bad.stderr
    root = ET.parse(junit).getroot()
    assert root.get("failures") == "2"
    failures = {(c.get("classname"), c.get("name")): c.find("failure").get("message")
                for c in root.iter("testcase") if c.find("failure") is not None}
    assert "rmse" in failures[("step_steer.kf_bicycle", "beta_rad: rmse <= 1e-06")]
    assert "kf_bicycel" in failures[("thresholds", "rules[1]: status == ok")]
    # stdout: one row per failure with its reason, then the verdict; check.html opens with the verdict.
    out_lines = bad.stdout.splitlines()
    assert out_lines[0].split()[-1] == "reason"
    assert any(ln.startswith("rule ") and ln.endswith("matches no metrics row (scenario *, observer kf_bicycel, "
                                                     "state *; a typo?)") for ln in out_lines)
    assert out_lines[-1].startswith("check FAILED: 2 of") and "2 of 4 rules broken" in out_lines[-1]  # 2 rules, the regression, the simulation
    page = (tmp_path / "bad" / "check.html").read_text()
    main = page[page.index("<main>"):]
    assert re.match(r"<main>\s*<div class='verdict fail' id='verdict'><div class='big'>FAIL</div>", main)
    assert "2 of 4 rules broken" in main[:600] and "rmse = " in main[:2000]
    assert "<div class='big'>PASS</div>" in (tmp_path / "ok" / "check.html").read_text()
    # Same seeds -> identical metrics: every regression check against the first run passes at rel_tol 0.
    regress = [c for c in root.iter("testcase") if "baseline" in c.get("name")]
    assert regress and all(c.find("failure") is None for c in regress)

    broken = tmp_path / "broken.yaml"
    broken.write_text("rules:\n  - {metric: rmse, mx: 0.1}\n")
    err = _cli(*common, "--out", str(tmp_path / "never"), "--thresholds", str(broken))
    assert err.returncode == 2
    assert "broken.yaml: rules[0].mx: unknown field" in err.stderr
    assert not (tmp_path / "never").exists()



def test_observer_not_applicable_to_a_scenario_is_skipped_not_failed():
    m = metrics_frame()
    m.loc[(m.scenario == "s2") & (m.observer == "obs_b"), "status"] = "skipped: missing range_m"
    m.loc[(m.scenario == "s2") & (m.observer == "obs_b"), "rmse"] = math.nan
    rules = [Rule(metric="status", equals="ok"), Rule(metric="rmse", max=0.05)]
    v = verdicts(evaluate(m, rules))
    assert v[("s2", "obs_b", "beta_rad")] == "skip"
    assert v[("s1", "obs_b", "beta_rad")] == "pass"
    m.loc[(m.scenario == "s1") & (m.observer == "obs_a"), "status"] = "diverged"
    assert "fail" in {o.verdict for o in evaluate(m, rules) if o.scenario == "s1" and o.observer == "obs_a"}


def test_not_applicable_checks_are_junit_skipped_with_their_reason():
    m = metrics_frame()
    na = (m.scenario == "s2") & (m.observer == "obs_b")
    m.loc[na, ["status", "rmse"]] = ["skipped: missing range_m", math.nan]
    base = m.copy()
    outcomes = evaluate(m, [Rule(metric="rmse", state=("beta_rad",), max=0.05, where="rules[0]")], base, RegressionSpec())
    root = ET.fromstring(junit_xml(outcomes))
    [case] = [c for c in root.iter("testcase") if c.get("classname") == "s2.obs_b" and "rules[0]" not in c.get("name")
              and c.find("skipped") is not None and c.get("name").startswith("beta_rad: rmse")]
    assert case.find("failure") is None
    assert case.find("skipped").get("message") == ("s2 obs_b beta_rad: not applicable (skipped: missing range_m) "
                                                   "(rules[0])")
    # The regression against a baseline where it was not applicable either: skipped with the reason too.
    reg = [c for c in root.iter("testcase") if c.get("classname") == "s2.obs_b" and "baseline" in c.get("name")]
    assert reg and all(c.find("skipped") is not None and "not applicable" in c.find("skipped").get("message")
                       for c in reg)
    assert root.get("failures") == "0" and int(root.get("skipped")) == 2
    # Every skipped element carries a message.
    assert all(s.get("message") for s in root.iter("skipped"))


def test_check_page_opens_with_the_verdict_and_the_failed_rules(tmp_path: Path):
    from roadtruth.harness.report.check_page import check_page

    m = metrics_frame()
    m.loc[0, "rmse"] = 0.5
    rules = [Rule(metric="rmse", max=0.3, where="rules[0]"), Rule(metric="status", equals="ok", where="rules[1]")]
    result = CheckResult.from_outcomes(evaluate(m, rules), tmp_path)
    html = check_page(result, thresholds=DEFAULT_THRESHOLDS, baseline=None, run_report="index.html")
    main = html[html.index("<main>"):]
    assert re.match(r"<main>\s*<div class='verdict fail' id='verdict'><div class='big'>FAIL</div>", main)
    banner = main[:main.index("</div>", main.index("class='big'") + 40) + 6]
    assert "1 of 12 checks failed; 1 of 2 rules broken" in banner
    assert "rmse = 0.5 &gt; max 0.3 (rules[0])" in banner
    assert "the shipped CI thresholds" in html and "href='index.html'" in html
    ok = CheckResult.from_outcomes(evaluate(metrics_frame(), rules), tmp_path)
    page_ok = check_page(ok, thresholds=tmp_path / "t.yaml", baseline=None, run_report=None)
    assert "<div class='verdict pass' id='verdict'><div class='big'>PASS</div>" in page_ok
    assert "0 of 12 checks failed; 0 of 2 rules broken" in page_ok


# ---- malformed metrics files: the same validation as compare ---------------------------------------------

def test_baseline_validation_covers_every_numeric_flag_and_key_column(tmp_path: Path):
    good = metrics_frame()
    cases = {
        "cov.csv": (good.assign(coverage=["0.9", "abc", *["0.9"] * 4]), r"cov\.csv: coverage: not a number on line 3 "
                                                                       r"\(got 'abc'\)"),
        "flag.csv": (good.assign(certified=["maybe", *["true"] * 5]), r"flag\.csv: certified: not true/false on line 2"),
        "obs.csv": (good.assign(observer=["obs_a", "", *["obs_b"] * 4]), r"obs\.csv: observer: empty cell on line 3"),
        "dupstate.csv": (pd.concat([good, good.iloc[[2]]]), r"duplicate row s1/obs_b/beta_rad on lines 4, 8"),
        "inf.csv": (good.assign(rmse=["inf", *["0.1"] * 5]), r"inf\.csv: rmse: infinite value on line 2"),
    }
    for name, (frame, _) in cases.items():
        frame.to_csv(tmp_path / name, index=False)
    (tmp_path / "empty.csv").write_text("scenario,observer,state,status,rmse,p95_abs\n")
    for name, (_, pattern) in cases.items():
        with pytest.raises(BaselineError, match=pattern):
            load_baseline(tmp_path / name, ("rmse", "p95_abs"))
    with pytest.raises(BaselineError, match=r"empty\.csv: no rows"):
        load_baseline(tmp_path / "empty.csv", ("rmse",))
    # A well-formed file comes back typed: numbers as floats, flags as booleans.
    good.to_csv(tmp_path / "good.csv", index=False)
    back = load_baseline(tmp_path / "good.csv", ("rmse", "p95_abs"))
    assert back["rmse"].dtype == float and list(back["certified"]) == [False, False, True] * 2


def test_cli_check_with_a_malformed_baseline_exits_2_with_one_line_before_any_work(tmp_path: Path):
    frame = metrics_frame()
    bad = pd.concat([frame, frame.iloc[:1]])
    bad.to_csv(tmp_path / "base.csv", index=False)
    res = _cli("--scenario", "step_steer", "--observer", "kf_bicycle", "--baseline", str(tmp_path / "base.csv"),
               "--out", str(tmp_path / "never"))
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "base.csv" in lines[0] and "duplicate row s1/obs_a/beta_rad on lines 2, 8" in lines[0]
    assert "Traceback" not in res.stderr and not (tmp_path / "never").exists()


# ---- the "unusable" verdict on a state whose truth is zero -------------------------------------------------

def _score_rho(truth_rho: np.ndarray, est_rho: np.ndarray, t: np.ndarray) -> str:
    """Status of one curvature estimate scored by ``roadtruth.harness.evaluation.scoring.score`` (band 1e-3 1/m)."""
    truth = pd.DataFrame({"t_s": t, "rho_1pm": truth_rho})
    est = pd.DataFrame({"t_s": t, "observer": "o", "state": "rho_1pm", "value": est_rho})
    run = SimpleNamespace(status="ok", us_per_step=1.0, certified=False, design_reason="", n_steps=t.size)
    m = scoring.score(truth, est, scenario="s", runs={"o": run})
    [status] = m["status"]
    return str(status)


def test_zero_truth_transient_that_settles_in_the_band_is_not_unusable():
    """Straight road (curvature exactly 0): a 4.5e-3 1/m transient for 1.2 s of 5 s (RMS 2.2x the
    1e-3 band), then 2e-5 for good, is an estimate that settles in its band, not one "∞× worse
    than assuming zero"; the same estimate wandering 0.05 1/m all the time is unusable."""
    t = np.round(np.arange(0.0, 5.0, 0.01), 9)
    zero = np.zeros_like(t)
    settles = np.where((t > 1.0) & (t < 2.2), 4.5e-3, 2e-5)
    assert np.sqrt(np.mean(settles**2)) > 2e-3  # above the band: the old rule said "unusable (∞×)"
    assert _score_rho(zero, settles, t) == "ok"
    wanders = 0.05 * np.sin(3.0 * t)
    status = _score_rho(zero, wanders, t)
    assert status.startswith("unusable (error outside its convergence band 9") and "∞" not in status, status
    # Inside the band all the time: ok whatever its ratio to the zero truth.
    assert _score_rho(zero, np.full_like(t, 5e-4), t) == "ok"


def test_nonzero_truth_keeps_the_worse_than_assuming_zero_rule():
    """A moving truth (RMS 0.01 1/m, ten bands) is judged as before: an estimate with 2.5x the RMS of
    the estimate 0 is unusable with that ratio, one at half of it is ok."""
    t = np.round(np.arange(0.0, 5.0, 0.01), 9)
    truth = np.full_like(t, 0.01)
    assert _score_rho(truth, truth + 0.025, t) == "unusable (RMS error 2.50× that of assuming zero)"
    assert _score_rho(truth, truth + 0.005, t) == "ok"
    # Small but not nearly zero (RMS half the band): a transient above the band still counts against 0.
    small = np.full_like(t, 5e-4)
    settles = small + np.where((t > 1.0) & (t < 2.2), 4.5e-3, 2e-5)
    assert _score_rho(small, settles, t) == "unusable (RMS error 4.39× that of assuming zero)"


# ---- the shipped gate on the current code ----------------------------------------------------------------

#: Observers whose rules broke when the truth physics changed (NEES, coverage, the "∞×" curvature
#: verdict) and one that is honestly unusable on some states (not gated there).
SUBSET_OBSERVERS = "ekf_bicycle,ukf_bicycle,interval_wang_printed,ts_yacine,hgo_gnss_kinematic"


def test_shipped_gate_passes_on_a_representative_subset(tmp_path: Path):
    res = _cli("--scenario", "step_steer,brake_in_turn", "--observer", SUBSET_OBSERVERS, "--out", str(tmp_path / "c"))
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr
    table = pd.read_csv(tmp_path / "c" / "check.csv", keep_default_na=False)
    judged = table[table.kind == "threshold"]
    assert set(judged.verdict) == {"pass"}, judged[judged.verdict != "pass"]

    def passed(scenario: str, observer: str, state: str, metric: str) -> bool:
        row = judged[(judged.scenario == scenario) & (judged.observer == observer) & (judged.state == state)
                     & (judged.metric == metric)]
        return len(row) >= 1 and set(row.verdict) == {"pass"}

    assert passed("step_steer", "ekf_bicycle", "beta_rad", "nees_mean")
    assert passed("brake_in_turn", "interval_wang_printed", "beta_rad", "coverage")
    assert passed("brake_in_turn", "ts_yacine", "rho_1pm", "status") and passed("brake_in_turn", "ts_yacine",
                                                                                "rho_1pm", "rmse")
    assert passed("brake_in_turn", "hgo_gnss_kinematic", "x_m", "rmse")
    # Honestly unusable there: the gate does not demand ok of it, and says so in a comment.
    assert judged[(judged.observer == "hgo_gnss_kinematic") & (judged.state == "vx_mps")
                  & judged.metric.isin(["status", "rmse"])].empty
    metrics = pd.read_csv(tmp_path / "c" / "metrics.csv")
    assert metrics.loc[(metrics.observer == "hgo_gnss_kinematic") & (metrics.state == "vx_mps"),
                       "status"].str.startswith("unusable").all()
    # Straight road: the curvature transient of the steer step settles in its band (ok, not "∞×"); it
    # is not gated because under another seed it stays outside the band (unusable), see ci.yaml.
    rho = (metrics.scenario == "step_steer") & (metrics.observer == "ts_yacine") & (metrics.state == "rho_1pm")
    assert list(metrics.loc[rho, "status"]) == ["ok"]
    # The gate trips when a gated estimate breaks: ten times the RMSE, or a status that is not ok.
    from roadtruth.harness.jobs.check_rules import load_thresholds

    spec = load_thresholds(DEFAULT_THRESHOLDS)
    worse = metrics.assign(rmse=metrics.rmse * 10.0)
    rmse_fails = [o for o in evaluate(worse, spec) if o.kind == "threshold" and o.metric == "rmse"
                  and o.verdict == "fail"]
    assert len(rmse_fails) == (judged.metric == "rmse").sum() > 20
    broken = metrics.copy()
    broken.loc[(broken.observer == "ts_yacine") & (broken.scenario == "step_steer"), "status"] = "diverged"
    assert any(o.metric == "status" and o.observer == "ts_yacine" and o.verdict == "fail"
               for o in evaluate(broken, spec))


def test_shipped_gate_covers_every_registered_observer():
    """Each registered observer is gated on some ci scenario (status and rmse) or named in a comment
    saying why not (not applicable, unusable, diverged)."""
    from roadtruth.observers.registry import observer_info

    spec = load_thresholds(DEFAULT_THRESHOLDS)
    text = DEFAULT_THRESHOLDS.read_text()
    gated = {metric: {o for r in spec.rules if r.metric == metric for o in r.observer} for metric in ("status", "rmse")}
    for info in observer_info():
        name = info["name"]
        if name in gated["status"]:
            assert name in gated["rmse"], name
        else:
            assert re.search(rf"# {re.escape(name)}[ :].*(not applicable|not gated)", text), name
    assert len(gated["status"]) > 30 and len(gated["rmse"]) == len(gated["status"])


@pytest.mark.slow
def test_shipped_gate_passes_on_the_full_ci_suite(tmp_path: Path):
    res = _cli("--out", str(tmp_path / "full"))
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr
    assert "check passed: 0 of" in res.stdout
