"""Tables as CSV or Parquet, estimates in wide form, and the replay's progress lines.

* the fast CSV writer writes exactly the bytes of ``to_csv(float_format=FLOAT_FORMAT)``;
* wide estimates turn back into the long frame they came from;
* ``--format parquet`` runs give the same bytes for the same seed, the same numbers as CSV, and a
  report, ``compare`` and ``check --baseline`` that read them;
* a replay writes one estimates row per time step and prints one line per segment and observer.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from roadtruth.harness.files import table_io
from roadtruth.harness.files.table_io import (
    WideEstimates,
    estimates_long,
    estimates_wide,
    read_estimates,
    read_table,
    write_csv_table,
)
from roadtruth.harness.report.rundata import FLOAT_FORMAT, RunData

OBSERVERS = ["kf_bicycle", "open_loop_bicycle"]


def awkward_frame(n: int = 257) -> pd.DataFrame:
    rng = np.random.default_rng(7)
    f = pd.DataFrame({
        "t_s": np.arange(n) * 0.001,
        "small": rng.normal(size=n) * 1e-9,
        "large": rng.normal(size=n) * 1e12,
        "count": np.arange(n, dtype=np.int64),
        "flag": rng.integers(0, 2, n).astype(bool),
        "text": rng.choice(["ok", "error: a, b", 'say "hi"', "", "line\nbreak"], n),
    })
    f.loc[::5, "small"] = np.nan
    f.loc[1, "large"], f.loc[2, "large"], f.loc[3, "small"] = np.inf, -np.inf, -0.0
    f["maybe"] = pd.Series(rng.choice(["x", None], n), dtype=object)
    f["mixed"] = pd.Series([1.5 if k % 2 else "a" for k in range(n)], dtype=object)  # left to pandas
    return f


def test_csv_writer_writes_the_bytes_of_pandas_to_csv(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(table_io, "CSV_BLOCK_ROWS", 50)  # several blocks, one of them partial
    f = awkward_frame()
    f["x, \"tiny\""] = np.where(np.arange(len(f)) % 7 == 0, np.nan, 5e-324 * np.arange(len(f)))  # a name to quote
    for cols in (list(f.columns), ["text"], ["small"], ["t_s", "small", "large", "count"],
                 ["t_s", "small", "large", 'x, "tiny"']):  # the last: all floats, one format per block
        write_csv_table(f[cols], tmp_path / "fast.csv")
        f[cols].to_csv(tmp_path / "pandas.csv", index=False, float_format=FLOAT_FORMAT, na_rep="",
                       lineterminator="\n")
        assert (tmp_path / "fast.csv").read_bytes() == (tmp_path / "pandas.csv").read_bytes(), cols
    with table_io.TableWriter(tmp_path, "blocks") as w:  # block by block = the whole frame at once
        for start in range(0, len(f), 100):
            w.write(f.iloc[start:start + 100])
    assert (tmp_path / "blocks.csv").read_bytes() == f.to_csv(index=False, float_format=FLOAT_FORMAT, na_rep="",
                                                             lineterminator="\n").encode()


def long_estimates(n: int = 40) -> pd.DataFrame:
    t = np.arange(n) * 0.01
    rows = []
    for obs, states, bounds in (("kf", ("beta_rad", "vy_mps"), False), ("iv", ("beta_rad",), True)):
        for s in states:
            v = np.sin(t * (3 if s == "beta_rad" else 5)) * (2 if obs == "kf" else 1)
            rows.append(pd.DataFrame({"t_s": t, "observer": obs, "state": s, "value": v,
                                      "lo": v - 0.1 if bounds else np.nan, "hi": v + 0.1 if bounds else np.nan,
                                      "var": np.full(n, 0.01) if not bounds else np.nan}))
    return pd.concat(rows, ignore_index=True)


def test_wide_estimates_are_one_row_per_step_and_read_back_long() -> None:
    long = long_estimates()
    wide = estimates_wide(long)
    assert len(wide) == 40
    assert list(wide.columns) == ["t_s", "kf.beta_rad", "kf.beta_rad_var", "kf.vy_mps", "kf.vy_mps_var",
                                  "iv.beta_rad", "iv.beta_rad_lo", "iv.beta_rad_hi"]
    back = estimates_long(wide)
    pd.testing.assert_frame_equal(back.reset_index(drop=True), long[list(back.columns)].reset_index(drop=True))
    # a replay's accumulator: the observer missing on a segment is NaN there, absent when read back
    acc = WideEstimates()
    acc.add(0, long["t_s"].unique(), long)
    acc.add(3, long["t_s"].unique() + 10.0, long[long.observer == "kf"])
    frame = acc.frame()
    assert len(frame) == 80 and frame["segment"].tolist() == [0] * 40 + [3] * 40
    assert frame["iv.beta_rad"].iloc[40:].isna().all()
    assert len(estimates_long(frame).query("observer == 'iv'")) == 40
    shifted = acc.long("kf", {3: -5.0})
    assert shifted["t_s"].max() == pytest.approx(0.39 + 5.0)


def run(out: Path, fmt: str, seed: int = 5) -> Path:
    from roadtruth.harness.jobs.pipeline import run_suite

    return run_suite(scenarios=["step_steer"], observers=OBSERVERS, seed=seed, out=out, render=False,
                     progress=False, table_format=fmt)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("formats")
    return {"parquet": run(base / "pq", "parquet"), "parquet_again": run(base / "pq2", "parquet"),
            "csv": run(base / "csv", "csv")}


def test_parquet_run_is_byte_identical_for_the_same_seed(runs: dict[str, Path]) -> None:
    a, b = runs["parquet"], runs["parquet_again"]
    tables = sorted(p.relative_to(a) for p in a.rglob("*.parquet"))
    assert [str(t) for t in tables] == ["metrics.parquet", "step_steer/estimates.parquet",
                                        "step_steer/measurements.parquet", "step_steer/truth.parquet"]
    assert not list(a.rglob("*.csv"))
    # Every file but metrics (its us_per_step column is a measured time, as in metrics.csv) is byte-equal.
    for rel in [*tables[1:], Path("run.json"), Path("index.html")]:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    ma, mb = (read_table(d / "metrics.parquet").drop(columns="us_per_step") for d in (a, b))
    pd.testing.assert_frame_equal(ma, mb)
    assert ma.drop(columns="us_per_step", errors="ignore").shape[1] > 10
    assert json.loads((a / "run.json").read_text())["table_format"] == "parquet"


def test_parquet_holds_the_numbers_the_csv_run_rounds(runs: dict[str, Path]) -> None:
    pq, csv = runs["parquet"], runs["csv"]
    m_pq = read_table(pq / "metrics.parquet")
    m_csv = pd.read_csv(csv / "metrics.csv")
    assert list(m_pq.columns) == list(m_csv.columns)
    rmse = m_pq.set_index(["observer", "state"])["rmse"].dropna()
    assert np.allclose(rmse, m_csv.set_index(["observer", "state"])["rmse"].dropna().loc[rmse.index], rtol=1e-9)
    e_pq, e_csv = read_estimates(pq / "step_steer"), read_estimates(csv / "step_steer")
    assert len(e_pq) == len(e_csv) > 0
    assert np.allclose(e_pq["value"], e_csv["value"], rtol=1e-9, equal_nan=True)
    wide = read_table(pq / "step_steer" / "estimates.parquet")
    meas = read_table(pq / "step_steer" / "measurements.parquet")
    assert len(wide) == len(meas)  # one row per time step, not per (step, observer, state)
    assert "kf_bicycle.beta_rad" in wide.columns and "observer" not in wide.columns


def test_report_compare_and_check_read_parquet_folders(runs: dict[str, Path], tmp_path: Path) -> None:
    from roadtruth.harness.jobs.check import load_baseline
    from roadtruth.harness.jobs.compare import compare

    data = RunData.load(runs["parquet"])
    est = data.scenario("step_steer").estimates
    assert set(est["observer"]) == set(OBSERVERS) and "beta_rad" in set(est["state"])
    assert len(data.scenario("step_steer").truth) > 100
    assert "kf_bicycle" in (runs["parquet"] / "index.html").read_text()
    result = compare(runs["csv"], runs["parquet"], tmp_path / "cmp")
    deltas = result.table["rmse_delta"].dropna().abs()
    assert len(deltas) > 0 and (deltas < 1e-8).all()  # the same run: only the rounding of the CSV differs
    assert len(load_baseline(runs["parquet"], ("rmse",))) == len(pd.read_csv(runs["csv"] / "metrics.csv"))


def test_replay_writes_wide_parquet_and_one_progress_line_per_segment_and_observer(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from roadtruth.harness.jobs.replay import replay

    t = np.arange(0.0, 12.0, 0.01)
    vx = np.where((t >= 5.0) & (t < 7.0), 0.0, 20.0)  # a standstill: two run segments
    delta = 0.02 * np.sin(2 * np.pi * 0.3 * t)
    r = vx * delta / (2.4 + 0.002 * vx**2)
    log = pd.DataFrame({"t_s": t, "vx_mps": vx, "beta_rad": -0.3 * delta, "delta_rad": delta,
                        "yaw_rate_radps": r, "ay_mps2": vx * r})
    log.to_csv(tmp_path / "drive.csv", index=False)
    out = replay(tmp_path / "drive.csv", vehicle="ferrari_250lm", observers=OBSERVERS, out=tmp_path / "out",
                 table_format="parquet")
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("[")]
    assert len(lines) == 2 * len(OBSERVERS), err
    assert all(("kf_bicycle" in ln or "open_loop_bicycle" in ln) and "segment" in ln for ln in lines)
    wide = read_table(out / "drive" / "estimates.parquet")
    meas = read_table(out / "drive" / "measurements.parquet")
    assert len(wide) == len(meas) and sorted(wide["segment"].unique()) == sorted(meas["segment"].unique())
    assert {"t_s", "segment", "kf_bicycle.beta_rad"} <= set(wide.columns)
    assert (out / "metrics.parquet").is_file() and not list(out.rglob("*.csv"))
    m = RunData.load(out).metrics
    assert m.set_index(["observer", "state"]).loc[("kf_bicycle", "beta_rad"), "status"] == "ok"
