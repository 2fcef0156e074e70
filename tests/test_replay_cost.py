"""What makes a long replay cheap, without changing what it writes (no timing assertions here;
``benchmarks/bench_replay_cost.py`` measures the cost):

* the wide estimates are written from their arrays with the bytes of the frame they form, and the
  observers' frames are stored column by column exactly as ``estimates_wide`` would;
* the long frame of one state (categorical labels) holds the same rows as the whole long frame;
* the report never turns the whole estimates table long: one state at a time, one figure's rows;
* observers run two at a time give the same files as one at a time;
* ``--jobs`` is checked.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from roadtruth.harness.cli import main as cli_main
from roadtruth.harness.errors import InputError
from roadtruth.harness.files import table_io
from roadtruth.harness.files.table_io import (
    WideEstimates,
    estimates_long,
    estimates_wide,
    read_table,
    write_table,
)
from roadtruth.harness.jobs.replay import check_jobs, replay
from roadtruth.harness.report import build_report, rundata

OBSERVERS = ["kf_bicycle", "open_loop_bicycle"]


def observer_frame(name: str, t: np.ndarray, states: list[str], kind: str, seed: int) -> pd.DataFrame:
    """A long frame as ``roadtruth.harness.evaluation.estimate.run_observers`` returns it: one block of rows per state;
    ``kind`` "var" (a filter), "bounds" (an interval observer) or "none"."""
    rng = np.random.default_rng(seed)
    n = len(t)
    parts = []
    for s in states:
        value = rng.normal(size=n)
        value[:3] = np.nan  # not started yet
        lo = value - 0.1 if kind == "bounds" else np.full(n, np.nan)
        hi = value + 0.1 if kind == "bounds" else np.full(n, np.nan)
        var = rng.random(n) if kind == "var" else np.full(n, np.nan)
        parts.append(pd.DataFrame({"t_s": t, "observer": name, "state": s, "value": value, "lo": lo, "hi": hi,
                                   "var": var}))
    return pd.concat(parts, ignore_index=True)


def test_stored_columns_equal_estimates_wide_and_write_the_frame_bytes(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    t0, t1 = np.arange(50) * 0.01, 10.0 + np.arange(30) * 0.01
    kf = observer_frame("kf", t0, ["beta_rad", "vy_mps"], "var", 1)
    iv = observer_frame("iv", t0, ["beta_rad"], "bounds", 2)
    ol = observer_frame("ol", t0, ["beta_rad"], "none", 3)
    acc = WideEstimates()
    for f in (kf, iv, ol):  # one observer at a time, as the replay adds them
        acc.add(0, t0, f)
    acc.add(4, t1, observer_frame("kf", t1, ["beta_rad", "vy_mps"], "var", 4))  # iv, ol did not run here
    frame = acc.frame()
    expected = estimates_wide(pd.concat([kf, iv, ol], ignore_index=True))
    seg0 = frame.iloc[:50].drop(columns="segment").reset_index(drop=True)
    pd.testing.assert_frame_equal(seg0, expected)  # same columns, order and values as the long route
    assert "ol.beta_rad_lo" not in frame.columns and "kf.beta_rad_lo" not in frame.columns
    assert frame["iv.beta_rad"].iloc[50:].isna().all() and frame["segment"].tolist() == [0] * 50 + [4] * 30
    monkeypatch.setattr(table_io, "CSV_BLOCK_CELLS", 100)  # several row blocks
    for fmt in ("csv", "parquet"):
        a_dir, b_dir, c_dir = (tmp_path / f"{fmt}-{k}" for k in "abc")
        for d in (a_dir, b_dir, c_dir):
            d.mkdir()
        a = acc.write(a_dir, "estimates", fmt)
        b = write_table(frame, b_dir, "estimates", fmt)
        if fmt == "csv":
            assert a.read_bytes() == b.read_bytes()  # the bytes of the frame, written from the arrays
        else:
            pd.testing.assert_frame_equal(read_table(a), read_table(b))
            assert acc.write(c_dir, "estimates", fmt).read_bytes() == a.read_bytes()  # same input, same bytes


def test_one_state_long_frame_holds_the_rows_of_the_whole_long_frame() -> None:
    t = np.arange(40) * 0.01
    wide = estimates_wide(pd.concat([observer_frame("kf", t, ["beta_rad", "vy_mps"], "var", 5),
                                     observer_frame("iv", t, ["beta_rad"], "bounds", 6)], ignore_index=True))
    full = estimates_long(wide)
    for state in ("beta_rad", "vy_mps"):
        one = estimates_long(wide, states=[state], categorical=True)
        assert isinstance(one["observer"].dtype, pd.CategoricalDtype)
        ref = full[full["state"] == state].reset_index(drop=True)
        assert len(one) == len(ref) > 0
        assert one["observer"].astype(str).tolist() == ref["observer"].astype(str).tolist()
        assert set(one["state"].astype(str)) == {state}
        for c in ("t_s", "value", "lo", "hi", "var"):
            np.testing.assert_array_equal(one[c].to_numpy(float), ref[c].to_numpy(float))
    # the scoring frame of one observer (categorical) equals its rows of the whole long frame
    acc = WideEstimates()
    acc.add(0, t, estimates_long(wide))
    kf = acc.long("kf")
    ref = full[full["observer"] == "kf"].reset_index(drop=True)
    assert kf["state"].astype(str).tolist() == ref["state"].astype(str).tolist()
    np.testing.assert_array_equal(kf["value"].to_numpy(float), ref["value"].to_numpy(float))


def drive_log(path: Path) -> Path:
    """A 12 s canonical log with a standstill in the middle: two run segments."""
    t = np.arange(0.0, 12.0, 0.01)
    vx = np.where((t >= 5.0) & (t < 7.0), 0.0, 20.0)
    delta = 0.02 * np.sin(2 * np.pi * 0.3 * t)
    r = vx * delta / (2.4 + 0.002 * vx**2)
    vy = -0.3 * delta * vx
    pd.DataFrame({"t_s": t, "vx_mps": vx, "vy_mps": vy, "beta_rad": np.arctan2(vy, np.maximum(vx, 1e-9)),
                  "delta_rad": delta, "yaw_rate_radps": r, "ay_mps2": vx * r}).to_csv(path, index=False)
    return path


@pytest.fixture(scope="module")
def replays(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("cost")
    log = drive_log(base / "drive.csv")
    return {f"{fmt}-{jobs}": replay(log, vehicle="ferrari_250lm", observers=OBSERVERS, out=base / f"{fmt}-{jobs}",
                                   table_format=fmt, jobs=jobs, progress=lambda _m: None)
            for fmt, jobs in (("csv", 1), ("csv", 2), ("parquet", 2))}


def test_two_jobs_write_the_files_of_one(replays: dict[str, Path]) -> None:
    one, two = replays["csv-1"], replays["csv-2"]
    for rel in ("drive/estimates.csv", "drive/truth.csv", "drive/measurements.csv", "drive/segments.csv",
                "drive/events.json", "drive/scenario.json"):
        assert (one / rel).read_bytes() == (two / rel).read_bytes(), rel
    m1, m2 = (pd.read_csv(d / "metrics.csv").drop(columns="us_per_step") for d in (one, two))
    pd.testing.assert_frame_equal(m1, m2)  # everything but the measured cost per step
    assert set(m1["observer"]) == set(OBSERVERS) and (m1["status"] == "ok").any()


@pytest.mark.parametrize("key", ["csv-1", "parquet-2"])
def test_report_turns_only_one_state_long_at_a_time(replays: dict[str, Path], monkeypatch: pytest.MonkeyPatch,
                                                     key: str) -> None:
    run = replays[key]
    n_rows = len(read_table(table_io.table_path(run / "drive", "estimates")))
    calls: list[tuple[str, int]] = []
    real = rundata.ScenarioFiles.series_of

    def spy(self: rundata.ScenarioFiles, state: str) -> list[rundata.ObserverSeries]:
        out = real(self, state)
        calls.append((state, len(out)))
        for s in out:  # one state's samples of one observer: at most one per step
            assert len(s.t_s) <= n_rows
        return out

    def whole(_self: object) -> pd.DataFrame:
        raise AssertionError("the report read the whole estimates table in long form")

    monkeypatch.setattr(rundata.ScenarioFiles, "series_of", spy)
    monkeypatch.setattr(rundata.ScenarioFiles, "estimates", property(whole))
    build_report(run)
    monkeypatch.undo()
    assert calls, "no figure of an estimated state"
    plotted = [state for state, _ in calls]
    assert "beta_rad" in plotted and len(set(plotted)) == len(plotted)  # each state read once
    assert all(n >= 1 for _, n in calls)
    html = (run / "index.html").read_text()
    assert "kf_bicycle" in html and "open_loop_bicycle" in html


def test_jobs_is_checked(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert check_jobs(None) in (1, 2) and check_jobs(3) == 3
    for bad in (0, -1, 1.5, True):
        with pytest.raises(InputError, match="--jobs"):
            check_jobs(bad)  # type: ignore[arg-type]
    log = drive_log(tmp_path / "drive.csv")
    with pytest.raises(SystemExit) as exit_:
        cli_main(["replay", str(log), "--vehicle", "ferrari_250lm", "--jobs", "0", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and len(err.strip().splitlines()) == 1 and "--jobs" in err
    assert not (tmp_path / "o").exists()
