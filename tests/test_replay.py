"""``roadtruth replay`` end to end: the real Revs log, skipped segments, bad logs through the CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from roadtruth.harness.cli import main
from roadtruth.harness.errors import LogError
from roadtruth.harness.files.table_io import read_estimates
from roadtruth.harness.jobs.replay import prepare_log, replay

REVS_NAME = "revs_250lm_2014-02-22"
DEG = math.pi / 180.0


@pytest.fixture(scope="module")
def revs_run(tmp_path_factory: pytest.TempPathFactory, revs_log: Path) -> Path:
    """The whole Revs log (55,001 rows) replayed with the linear KF and two other observers."""
    out = tmp_path_factory.mktemp("replay") / "revs"
    return replay(revs_log, vehicle="ferrari_250lm", columns="revs_250lm",
                  observers=["kf_bicycle", "open_loop_bicycle", "lpv_wang"], out=out)


def test_revs_replay_writes_the_files_of_a_run(revs_run: Path) -> None:
    for f in ("metrics.csv", "run.json", "index.html", f"{REVS_NAME}/truth.csv", f"{REVS_NAME}/measurements.csv",
              f"{REVS_NAME}/estimates.csv", f"{REVS_NAME}/segments.csv"):
        assert (revs_run / f).is_file(), f
    assert not (revs_run / "frames").exists()  # a recorded log has nothing to render
    assert not list(revs_run.parent.glob(".revs.partial-*"))
    run = json.loads((revs_run / "run.json").read_text())
    assert run["command"] == "replay" and run["vehicle"] == "ferrari_250lm"
    # a clean log: one segment over all 55,001 rows, nothing skipped, and the report says so
    assert run["skipped_segments"] == []
    [seg] = run["scenarios"][0]["segments"]
    assert (seg["status"], seg["n_samples"], seg["t_start_s"], seg["t_end_s"]) == ("run", 55001, 149.99, 699.99)
    assert "nothing skipped" in (revs_run / "index.html").read_text()


def test_revs_reference_obeys_the_kinematic_identity(revs_run: Path) -> None:
    truth = pd.read_csv(revs_run / REVS_NAME / "truth.csv")
    assert len(truth) == 55001 and list(truth.columns) == ["t_s", "beta_rad", "vy_mps", "vx_mps", "segment"]
    # beta = atan(vy / vx) of the INS reference, to the CSV's 10 significant digits
    np.testing.assert_allclose(truth.beta_rad, np.arctan2(truth.vy_mps, truth.vx_mps), atol=1e-7)
    assert (truth.vx_mps > 16.0).all()  # racing: never near the standstill threshold


def test_linear_kf_beta_error_on_the_revs_log(revs_run: Path) -> None:
    m = pd.read_csv(revs_run / "metrics.csv")
    assert set(m.scenario) == {REVS_NAME}
    kf = m[(m.observer == "kf_bicycle") & (m.state == "beta_rad")].iloc[0]
    assert kf.status == "ok" and kf.n_scored == 55001
    # the linear single-track KF tracks the INS sideslip (range -5.5..4.4 deg) to well under 2 deg RMS
    assert 0.1 * DEG < kf.rmse < 2.0 * DEG
    assert abs(kf.bias) < kf.rmse and kf.max_abs < 10 * DEG
    # the metric is the RMS of estimate - reference over the log: recompute it from the files
    est = read_estimates(revs_run / REVS_NAME)
    truth = pd.read_csv(revs_run / REVS_NAME / "truth.csv")
    b = est[(est.observer == "kf_bicycle") & (est.state == "beta_rad")]
    np.testing.assert_array_equal(b.t_s.to_numpy(), truth.t_s.to_numpy())
    rmse = np.sqrt(np.mean((b.value.to_numpy() - truth.beta_rad.to_numpy()) ** 2))
    assert kf.rmse == pytest.approx(rmse, rel=1e-6)
    # vy = vx tan(beta): the vy error is the beta error scaled by the speed (~32 m/s on average)
    kf_vy = m[(m.observer == "kf_bicycle") & (m.state == "vy_mps")].iloc[0]
    assert 10.0 < kf_vy.rmse / kf.rmse < 60.0


def test_every_beta_observer_run_is_scored(revs_run: Path) -> None:
    m = pd.read_csv(revs_run / "metrics.csv")
    beta = m[m.state == "beta_rad"].set_index("observer")
    assert set(beta.index) == {"kf_bicycle", "open_loop_bicycle", "lpv_wang"}
    assert (beta.status == "ok").all() and np.isfinite(beta.rmse).all()
    # states the log has no reference for are reported, not silently dropped
    alpha = m[(m.observer == "lpv_wang") & (m.state == "alpha_f_rad")].iloc[0]
    assert alpha.status.startswith("skipped: truth has no alpha_f_rad")


# ---- a log with gaps, standstill and irregular timestamps ----------------------------------------

def stop_and_go_log(rng: np.random.Generator) -> pd.DataFrame:
    """Three driving stretches of a linear-bicycle car: a stop (10-14 s), a 3 s logger gap, jittered time."""
    t = np.concatenate([np.arange(0.0, 20.0, 0.01), np.arange(23.0, 30.0, 0.01)])
    t = t + np.where(t > 23.0, rng.uniform(-0.003, 0.003, t.size), 0.0)  # irregular after the gap
    vx = np.where((t >= 10.0) & (t < 14.0), 0.0, 25.0)
    delta = 0.02 * np.sin(2 * np.pi * 0.3 * t)
    r = vx * delta / (2.4 + 0.002 * vx**2)
    beta = -0.3 * delta
    return pd.DataFrame({"t_s": t, "vx_mps": vx, "beta_rad": beta, "vy_mps": vx * np.tan(beta),
                         "delta_rad": delta, "yaw_rate_radps": r, "ay_mps2": vx * r})


def test_skipped_segments_are_reported_and_never_scored(tmp_path: Path) -> None:
    log = stop_and_go_log(np.random.default_rng(3))
    src = tmp_path / "stopgo.parquet"
    log.to_parquet(src)
    out = replay(src, vehicle="ferrari_250lm", observers=["kf_bicycle"], out=tmp_path / "out")
    segs = pd.read_csv(out / "stopgo" / "segments.csv")
    assert segs.status.tolist() == ["run", "skipped", "run", "skipped", "run"]
    assert segs.reason[1].startswith("standstill") and segs.reason[3].startswith("gap of 3")
    assert segs.resampled.tolist() == [False, False, False, False, True]
    run = json.loads((out / "run.json").read_text())
    assert [s["reason"].split(" ")[0] for s in run["skipped_segments"]] == ["standstill", "gap"]
    html = (out / "index.html").read_text()
    assert "2 skipped" in html and "standstill" in html
    est = read_estimates(out / "stopgo")
    t = est.t_s.to_numpy()
    assert not ((t >= 10.0) & (t < 14.0)).any()  # nothing estimated at standstill …
    assert not ((t > 20.0) & (t < 22.99)).any()  # … nor inside the gap
    assert sorted(est.segment.unique().tolist()) == [0, 2, 4]
    m = pd.read_csv(out / "metrics.csv")
    kf = m[(m.observer == "kf_bicycle") & (m.state == "beta_rad")].iloc[0]
    truth = pd.read_csv(out / "stopgo" / "truth.csv")
    # only rows of run segments are scored, each against the latest estimate of its own segment
    assert kf.n_scored == (truth.segment >= 0).sum() < len(truth)
    b = est[(est.observer == "kf_bicycle") & (est.state == "beta_rad")]
    errors = []
    for seg, rows in truth[truth.segment >= 0].groupby("segment"):
        e = b[b.segment == seg]
        j = np.searchsorted(e.t_s.to_numpy(), rows.t_s.to_numpy() + 1e-9, side="right") - 1
        assert (j >= 0).all()  # every segment's first row has an estimate at its own time
        errors.append(e.value.to_numpy()[j] - rows.beta_rad.to_numpy())
    assert kf.rmse == pytest.approx(np.sqrt(np.mean(np.concatenate(errors) ** 2)), rel=1e-6)


def test_observers_are_reset_at_each_segment_start(tmp_path: Path) -> None:
    log = stop_and_go_log(np.random.default_rng(4))
    whole, part = tmp_path / "whole.csv", tmp_path / "part.csv"
    log.to_csv(whole, index=False)
    log[log.t_s >= 14.0].iloc[:600].to_csv(part, index=False)  # the second driving stretch alone
    a = replay(whole, vehicle="ferrari_250lm", observers=["kf_bicycle"], out=tmp_path / "a")
    b = replay(part, vehicle="ferrari_250lm", observers=["kf_bicycle"], out=tmp_path / "b")
    ea = read_estimates(a / "whole")
    eb = read_estimates(b / "part")
    ea = ea[(ea.segment == 2) & (ea.t_s <= eb.t_s.max())].reset_index(drop=True)
    eb = eb.reset_index(drop=True)
    # the same estimates as a fresh run on that stretch: nothing carried over from before the stop
    pd.testing.assert_frame_equal(ea[["t_s", "state", "value"]], eb[["t_s", "state", "value"]])


# ---- bad logs through the CLI: exit 2, one line, nothing written -----------------------------------

@pytest.mark.parametrize(("content", "columns", "message"), [
    (b"", None, "empty file"),
    (b"t_s,vx_mps,delta_rad,yaw_rate_radps\n0,20,0.01,0.1\n0.01,20,0.01,0.1\n0.005,20,0.01,0.1\n", None,
     "time column 't_s' goes backwards at row 3"),
    (b"t_s,vx_mps,delta_rad,yaw_rate_radps\n0,20,0.01,12\n0.01,20,0.01,14\n0.02,20,0.01,15\n", None,
     "yaw_rate_radps: 100.0 % of samples exceed |3| rad/s"),
    (b"t_s,vx_mps,delta_rad\n0,20,0.01\n0.01,20,0.01\n", "revs_250lm",
     "missing required column 'yaw_rate_radps' (mapped to yaw_rate_radps"),
    (b"t_s,vx_mps,delta_rad\n" + b"".join(b"%g,1.0,0.0\n" % (i / 100) for i in range(300)), None,
     "no segment the observers can run on (every stretch skipped: standstill"),
])
def test_bad_log_exits_2_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes,
                                       columns: str | None, message: str) -> None:
    src = tmp_path / "bad.csv"
    src.write_bytes(content)
    out = tmp_path / "out"
    argv = ["replay", str(src), "--vehicle", "ferrari_250lm", "--out", str(out), "--observer", "kf_bicycle"]
    assert main([*argv, *(["--columns", columns] if columns else [])]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bad.csv" in err and message in err
    assert not out.exists() and not list(tmp_path.glob(".out.*"))


def test_prepare_log_rejects_unknown_map_name(revs_log: Path) -> None:
    with pytest.raises(LogError, match="unknown column map 'revs'"):
        prepare_log(revs_log, "revs")
