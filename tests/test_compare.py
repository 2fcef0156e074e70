"""compare_runs: deltas, better/worse judgements, status changes, bad folders."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from synthetic_run import make_run_folder

from harness.compare import compare_runs
from harness.errors import InputError


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
    with pytest.raises(InputError, match="missing columns"):
        compare_runs(a, tmp_path / "bad", None)
