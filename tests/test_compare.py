"""compare_runs: deltas, better/worse judgements, status changes, bad folders."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from synthetic_run import make_run_folder

from roadtruth.harness.errors import InputError
from roadtruth.harness.jobs.compare import compare, compare_runs

REPO = Path(__file__).resolve().parents[1]


def test_deltas_and_verdicts(tmp_path: Path):
    a = make_run_folder(tmp_path / "a")
    b = make_run_folder(tmp_path / "b")
    m = pd.read_csv(b / "metrics.csv")
    lpv = (m.observer == "lpv_interval") & (m.state == "beta_rad")
    m.loc[lpv, "rmse"] = m.loc[lpv, "rmse"] * 0.5
    ekf = (m.observer == "ekf") & (m.scenario == "ice_patch")
    m.loc[ekf, "status"] = "diverged"
    m.to_csv(b / "metrics.csv", index=False)
    ma = pd.read_csv(a / "metrics.csv")

    table = compare_runs(a, b, tmp_path / "cmp")
    assert len(table) == len(ma)
    row = table[(table.observer == "lpv_interval") & (table.state == "beta_rad")].iloc[0]
    assert row.rmse_delta == pytest.approx(-0.5 * row.rmse_a)
    assert row.rmse_change == "better" and row.verdict == "better"
    assert table[(table.observer == "ekf") & (table.scenario == "ice_patch")].verdict.iloc[0] == "worse"
    same = table[(table.observer == "lpv_interval") & (table.state == "yaw_rate_radps")].iloc[0]
    assert same.rmse_delta == 0.0 and same.verdict == "same"
    assert (tmp_path / "cmp" / "compare.csv").is_file()
    assert "roadtruth compare" in (tmp_path / "cmp" / "compare.html").read_text()


def test_missing_folder_is_input_error(tmp_path: Path):
    a = make_run_folder(tmp_path / "a", scenarios=("s",))
    with pytest.raises(InputError):
        compare_runs(a, tmp_path / "missing", None)
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "metrics.csv").write_text("x,y\n1,2\n")
    with pytest.raises(InputError, match="missing column"):
        compare_runs(a, tmp_path / "bad", None)


def _edit_run_json(folder: Path, **changes: object) -> None:
    run = json.loads((folder / "run.json").read_text())
    for key, value in changes.items():
        if key == "mujoco":
            run["versions"]["mujoco"] = value
        else:
            run[key] = value
    (folder / "run.json").write_text(json.dumps(run))


def test_one_sided_scenarios_and_observers_are_listed_not_counted_better_or_worse(tmp_path: Path):
    a = make_run_folder(tmp_path / "a", scenarios=("step_steer", "ice_patch"))
    b = make_run_folder(tmp_path / "b", scenarios=("step_steer", "lane_change"))
    mb = pd.read_csv(b / "metrics.csv")
    extra = mb[mb.observer == "ekf"].assign(observer="ukf_new")
    pd.concat([mb[mb.observer != "ts_uio"], extra]).to_csv(b / "metrics.csv", index=False)

    c = compare(a, b, tmp_path / "cmp")
    assert c.only_a["scenarios"] == ("ice_patch",) and c.only_b["scenarios"] == ("lane_change",)
    assert c.only_a["observers"] == ("ts_uio",) and c.only_b["observers"] == ("ukf_new",)
    t = c.table
    # Nothing present on one side only is judged: today's main called every such row "worse" or "better".
    assert set(t[t.scenario == "ice_patch"].verdict) == {"only in A"}
    assert set(t[t.scenario == "lane_change"].verdict) == {"only in B"}
    assert set(t[t.observer == "ts_uio"].verdict) == {"only in A"}
    assert set(t[t.observer == "ukf_new"].verdict) == {"only in B"}
    both = t[(t.scenario == "step_steer") & t.observer.isin(["lpv_interval", "ekf"])]
    assert set(both.verdict) == {"same"} and c.counts()["worse"] == 0 and c.counts()["better"] == 0
    text = c.terminal()
    assert "only in A (not compared): 1 scenario (ice_patch); 1 observer (ts_uio)" in text
    assert "only in B (not compared): 1 scenario (lane_change); 1 observer (ukf_new)" in text
    assert "3 rows in both runs: 0 worse, 0 better, 3 same" in text
    page = (tmp_path / "cmp" / "compare.html").read_text()
    assert "<td>only in A</td><td>scenario</td><td>ice_patch</td>" in page
    assert "<td>only in B</td><td>observer</td><td>ukf_new</td>" in page


def test_different_settings_are_flagged_at_the_top(tmp_path: Path):
    a = make_run_folder(tmp_path / "a", scenarios=("step_steer",))
    b = make_run_folder(tmp_path / "b", scenarios=("step_steer",))
    same = compare(a, b, tmp_path / "same")
    assert same.settings == ()
    assert "WARNING" not in same.terminal()
    assert "id='settings-same'" in (tmp_path / "same" / "compare.html").read_text()

    _edit_run_json(b, vehicle="suv", friction="0.3", seed=5, faults="gnss:dropout=0.2", mujoco="9.9.9")
    c = compare(a, b, tmp_path / "cmp")
    got = {d.name: (d.a, d.b) for d in c.settings}
    assert got == {"vehicle": ("the scenario's own", "suv"), "friction": ("the scenario's own", "0.3"),
                   "faults": ("the scenario's own", "gnss:dropout=0.2"), "seed": ("the scenario's own", "5"),
                   "MuJoCo version": (np.__version__ and json.loads((a / "run.json").read_text())["versions"]
                                      .get("mujoco") or "not recorded", "9.9.9")}
    lines = c.terminal().splitlines()
    assert lines[2].startswith("WARNING: the runs were made with different settings")
    assert "  vehicle: the scenario's own (A) vs suv (B)" in lines
    page = (tmp_path / "cmp" / "compare.html").read_text()
    main = page[page.index("<main>"):]
    assert main.index("id='settings-warning'") < main.index("<section")
    assert "<b>vehicle</b>: the scenario&#x27;s own (A) vs suv (B)" in main
    # Per-scenario settings (a scenario run with another seed) are flagged too.
    run = json.loads((b / "run.json").read_text())
    run.update(vehicle=None, friction=None, seed=None, faults=None)
    run["versions"] = json.loads((a / "run.json").read_text())["versions"]
    run["scenarios"][0]["seed"] = 999
    (b / "run.json").write_text(json.dumps(run))
    assert [(d.name, d.b) for d in compare(a, b).settings] == [("seed of step_steer", "999")]


def test_terminal_shows_short_table_of_largest_changes_in_degrees(tmp_path: Path):
    a = make_run_folder(tmp_path / "a", scenarios=("s1", "s2", "s3", "s4", "s5"))
    b = make_run_folder(tmp_path / "b", scenarios=("s1", "s2", "s3", "s4", "s5"))
    m = pd.read_csv(b / "metrics.csv")
    factor = {"s1": 3.0, "s2": 1.5, "s3": 1.2, "s4": 0.5, "s5": 1.0}
    beta = m.state == "beta_rad"
    m.loc[beta, "rmse"] = m.loc[beta, "rmse"] * m.loc[beta, "scenario"].map(factor)
    m.loc[(m.scenario == "s5") & (m.observer == "ekf"), "status"] = "diverged"
    m.to_csv(b / "metrics.csv", index=False)
    ma = pd.read_csv(a / "metrics.csv")
    c = compare(a, b)
    text = c.terminal(n=3)
    lines = text.splitlines()
    assert len(lines) < 20  # not a dump of every row
    start = lines.index(next(ln for ln in lines if ln.startswith("largest regressions")))
    assert lines[start] == "largest regressions (3 of 7):"
    first, second = lines[start + 2], lines[start + 3]
    # A status regression comes first, then the largest relative RMSE growth.
    assert first.split()[:3] == ["s5", "ekf", "beta_rad"] and "status ok → diverged" in first
    assert second.split()[:4] == ["s1", "ekf", "beta_rad", "deg"] or second.split()[:4] == ["s1", "lpv_interval",
                                                                                             "beta_rad", "deg"]
    assert second.endswith("+200%")
    # Angles shown in degrees: the A column is the radian RMSE × 180/π.
    rad = float(ma[(ma.scenario == second.split()[0]) & (ma.observer == second.split()[1])
                   & (ma.state == "beta_rad")].rmse.iloc[0])
    assert float(second.split()[4]) == pytest.approx(math.degrees(rad), rel=2e-3)
    imp = lines.index(next(ln for ln in lines if ln.startswith("largest improvements")))
    assert lines[imp + 2].split()[0] == "s4" and lines[imp + 2].endswith("-50%")


def test_malformed_metrics_files_are_one_line_errors_for_compare(tmp_path: Path):
    a = make_run_folder(tmp_path / "a", scenarios=("s",))
    good = pd.read_csv(a / "metrics.csv")
    cases = {
        "dup": (pd.concat([good, good.iloc[:1]]), f"duplicate row s/lpv_interval/beta_rad on lines 2, {len(good) + 2}"),
        "text": (good.assign(rmse=["0.1", "lots", *["0.2"] * (len(good) - 2)]),
                 "rmse: not a number on line 3 (got 'lots')"),
        "nocol": (good.drop(columns="status"), "status: missing column"),
    }
    for name, (frame, message) in cases.items():
        folder = make_run_folder(tmp_path / name, scenarios=("s",))
        frame.to_csv(folder / "metrics.csv", index=False)
        with pytest.raises(InputError, match=re.escape(message)):
            compare(a, folder)
        res = subprocess.run([sys.executable, "-m", "roadtruth.harness.cli", "compare", str(a), str(folder), "--out",
                              str(tmp_path / f"out_{name}")], cwd=REPO, capture_output=True, text=True, timeout=120)
        assert res.returncode == 2, res.stderr
        err = res.stderr.strip().splitlines()
        assert len(err) == 1 and message in err[0] and "metrics.csv" in err[0]
        assert not (tmp_path / f"out_{name}").exists()
