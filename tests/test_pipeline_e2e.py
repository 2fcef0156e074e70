"""End to end: a tiny suite writes every file of a run folder, well-formed, and the same seed gives the
same bytes whatever the number of worker processes."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from roadtruth.harness.errors import InputError
from roadtruth.harness.evaluation.scoring import COLUMNS
from roadtruth.harness.files.table_io import read_estimates

pytestmark = pytest.mark.slow

SCENARIOS = ["step_steer", "brake_in_turn"]
CONTRACT_METRICS = ["scenario", "observer", "state", "rmse", "mae", "max_abs", "p95_abs", "bias", "conv_time_s",
                    "coverage", "mean_width", "us_per_step", "certified", "status"]


def pick_observers() -> list[str]:
    from roadtruth.observers.registry import available_observers, observer_info

    info = {i["name"]: i for i in observer_info()}
    names = available_observers()
    # Sideslip observers that run on every scenario's sensors (steering, IMU, wheel speeds), so the
    # report's leaderboard and annotation paths are exercised; then any other, at most three.
    preferred = [n for n in ("kf_bicycle", "open_loop_bicycle", "lpv_wang") if n in names]
    beta = [n for n in names if "beta_rad" in info[n].get("states", ()) and n not in preferred]
    return (preferred + beta + [n for n in names if n not in beta and n not in preferred])[:3]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, list[str]]:
    from roadtruth.harness.jobs.pipeline import run_suite

    observers = pick_observers()
    root = tmp_path_factory.mktemp("e2e")
    a = run_suite(scenarios=SCENARIOS, observers=observers, seed=11, out=root / "a", jobs=1, render=True,
                  progress=False)
    b = run_suite(scenarios=SCENARIOS, observers=observers, seed=11, out=root / "b", jobs=2, render=False,
                  progress=False)
    return a, b, observers


def test_every_file_exists_and_is_well_formed(runs: tuple[Path, Path, list[str]]):
    a, _, observers = runs
    assert not [p for p in a.parent.iterdir() if ".partial-" in p.name or ".old-" in p.name]
    run = json.loads((a / "run.json").read_text())
    for key in ("scenarios", "observers", "seed", "versions", "git_revision"):
        assert key in run, key
    for pkg in ("roadtruth", "mujoco", "numpy", "cvxpy"):
        assert pkg in run["versions"]
    assert [s["name"] for s in run["scenarios"]] == SCENARIOS
    assert [o["name"] for o in run["observers"]] == observers
    timings = json.loads((a / "timings.json").read_text())  # times live apart: run.json is reproducible
    assert {"simulate", "sensors", "observers", "scoring", "render", "report"} <= set(timings["stages_s"])
    assert timings["wall_s"] > 0 and "timings_s" not in run and "wall_s" not in run
    # The phases partition the run's wall time (each rounded to 1 ms).
    phases = timings["phases_s"]
    assert set(phases) == {"start", "work", "finish"} and min(phases.values()) >= 0
    assert sum(phases.values()) == pytest.approx(timings["wall_s"], abs=0.004)
    assert phases["work"] >= timings["stages_s"]["simulate"] / 2  # two workers at most share the scenarios
    from numba.core import config as numba_config  # per-step times name the code they timed

    assert timings["kernel_target"] == (numba_config.CPU_NAME or "host")

    m = pd.read_csv(a / "metrics.csv")
    assert list(m.columns) == list(COLUMNS)
    assert set(CONTRACT_METRICS) <= set(m.columns)
    assert set(m.scenario) == set(SCENARIOS) and set(m.observer) == set(observers)
    assert not m.duplicated(["scenario", "observer", "state"]).any()
    assert m.status.notna().all()
    ok = m[m.status == "ok"]
    assert len(ok) > 0 and ok.rmse.notna().all() and (ok.rmse >= 0).all()
    assert (ok.rmse >= ok.mae - 1e-12).all() and (ok.max_abs >= ok.p95_abs - 1e-12).all()

    for s in run["scenarios"]:
        d = a / s["name"]
        truth = pd.read_csv(d / "truth.csv")
        dt = np.diff(truth.t_s.to_numpy())
        assert np.allclose(dt, 0.01, atol=1e-9)  # 100 Hz log rate
        assert {"t_s", "x_m", "y_m", "beta_rad", "vy_mps", "yaw_rate_radps"} <= set(truth.columns)
        meas = pd.read_csv(d / "measurements.csv")
        valid = [c for c in meas.columns if c.endswith("_valid")]
        assert valid and "imu_valid" in valid
        for c in valid:
            assert set(meas[c].unique()) <= {0, 1}
        assert meas.loc[meas.imu_valid == 0, "yaw_rate_radps"].isna().all()  # missing = empty cell
        est = read_estimates(d)  # wide on disk; the long frame
        assert {"t_s", "observer", "state", "value", "lo", "hi"} <= set(est.columns)
        assert set(est.observer) <= set(observers)
        events = json.loads((d / "events.json").read_text())
        assert all({"t_s", "label"} <= set(e) for e in events)
        info = json.loads((d / "scenario.json").read_text())
        assert info["name"] == s["name"] and "friction" in info
        if run["render"]["enabled"]:
            import cv2

            r = s["render"]
            assert r["reason"] is None and len(r["frames"]) >= 3
            for f in r["frames"]:
                img = cv2.imread(str(a / f["file"]))
                assert img is not None and img.shape == (480, 640, 3)
            video = (a / r["video"]).read_bytes()
            assert len(video) > 10_000 and video[4:8] == b"ftyp"
    html = (a / "index.html").read_text(encoding="utf-8")
    assert 'class="leaderboard"' in html and "<img " in html


def without_column(path: Path, column: str) -> list[list[str]]:
    """The CSV's cells as written (strings, not re-parsed numbers), minus one column."""
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    j = rows[0].index(column)
    return [r[:j] + r[j + 1:] for r in rows]


def test_same_seed_same_bytes_whatever_the_jobs(runs: tuple[Path, Path, list[str]]):
    a, b, _ = runs
    # us_per_step is the one wall-clock measurement in metrics.csv; every other cell is identical.
    assert without_column(a / "metrics.csv", "us_per_step") == without_column(b / "metrics.csv", "us_per_step")
    for s in SCENARIOS:
        for f in ("truth.csv", "measurements.csv", "estimates.csv", "events.json"):
            assert (a / s / f).read_bytes() == (b / s / f).read_bytes(), f"{s}/{f}"


def test_compare_of_identical_runs_is_all_same(runs: tuple[Path, Path, list[str]]):
    from roadtruth.harness.jobs.compare import compare_runs

    a, b, _ = runs
    table = compare_runs(a, b, None)
    assert (table.verdict == "same").all()
    assert (table.rmse_delta.fillna(0.0) == 0.0).all()


def test_report_rebuild_from_saved_files(runs: tuple[Path, Path, list[str]]):
    from roadtruth.harness.report import build_report

    _, b, _ = runs
    before = (b / "index.html").read_text(encoding="utf-8")
    (b / "index.html").unlink()
    assert build_report(b).read_text(encoding="utf-8") == before


def test_simulate_to_dir_writes_truth_and_measurements(tmp_path: Path):
    from roadtruth.harness.jobs.pipeline import simulate_to_dir

    out = simulate_to_dir("step_steer", tmp_path / "sim", seed=5, log_rate_hz=1000.0)
    truth = pd.read_csv(out / "truth.csv")
    run = json.loads((out / "run.json").read_text())
    assert run["status"] == "ok" and run["sim_steps"] == len(truth)
    assert np.allclose(np.diff(truth.t_s), 0.001, atol=1e-9)
    assert (out / "measurements.csv").is_file() and (out / "events.json").is_file()


def test_bad_input_raises_before_any_output(tmp_path: Path):
    from roadtruth.harness.jobs.pipeline import run_suite

    with pytest.raises(InputError):
        run_suite(scenarios=["no_such_scenario"], out=tmp_path / "x", progress=False)
    with pytest.raises(InputError, match="observer"):
        run_suite(scenarios=["step_steer"], observers=["no_such_observer"], out=tmp_path / "x", progress=False)
    with pytest.raises(InputError, match="log rate"):
        run_suite(scenarios=["step_steer"], log_rate_hz=300.0, out=tmp_path / "x", progress=False)
    assert not (tmp_path / "x").exists()
    assert list(tmp_path.iterdir()) == []


def test_without_gl_the_report_says_so_and_is_otherwise_complete(tmp_path: Path):
    # A fresh interpreter whose only GL back-end (GLFW without a display) cannot make a context.
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["MUJOCO_GL"] = "glfw"
    code = ("from pathlib import Path; from roadtruth.harness.jobs.pipeline import run_suite; "
            f"run_suite(scenarios=['step_steer'], observers={pick_observers()[:1]!r}, "
            f"out=Path({str(tmp_path / 'nogl')!r}), progress=False)")
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    run = json.loads((tmp_path / "nogl" / "run.json").read_text())
    assert run["render"]["enabled"] is False and "OpenGL" in run["render"]["reason"]
    html = (tmp_path / "nogl" / "index.html").read_text(encoding="utf-8")
    assert "Frames and videos were not rendered" in html and 'class="leaderboard"' in html
    assert (tmp_path / "nogl" / "step_steer" / "estimates.csv").is_file()


def test_a_diverged_or_crashed_scenario_is_reported_and_the_suite_goes_on(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch):
    import dataclasses

    import roadtruth.harness.truth.simulate
    from roadtruth.harness.jobs.pipeline import run_suite

    real = roadtruth.harness.truth.simulate.simulate

    def flaky(scenario, vehicle=None, seed=None, **kw):
        if scenario.name == "step_steer":
            raise RuntimeError("solver exploded")
        truth = real(scenario, vehicle, seed, **kw)
        n = len(truth.frame) // 2
        return dataclasses.replace(truth, frame=truth.frame.iloc[:n], qpos=truth.qpos[:n],
                                   status="diverged: test at t=3 s")

    monkeypatch.setattr(roadtruth.harness.truth.simulate, "simulate", flaky)
    observers = pick_observers()[:2]
    out = run_suite(scenarios=["step_steer", "brake_in_turn"], observers=observers, out=tmp_path / "r",
                    render=False, progress=False)
    run = json.loads((out / "run.json").read_text())
    status = {s["name"]: s["status"] for s in run["scenarios"]}
    assert status["step_steer"] == "error: RuntimeError: solver exploded"
    assert "Traceback" in run["scenarios"][0]["traceback"]
    assert status["brake_in_turn"] == "diverged: test at t=3 s"
    m = pd.read_csv(out / "metrics.csv")
    assert set(m.scenario) == {"step_steer", "brake_in_turn"} and set(m.observer) == set(observers)
    assert m.status.str.startswith("skipped: simulation").all()
    assert m.rmse.isna().all()
    html = (out / "index.html").read_text(encoding="utf-8")
    assert "solver exploded" in html and "diverged: test at t=3 s" in html


def test_workers_take_the_longest_scenarios_first(tmp_path: Path) -> None:
    """With several workers the longest simulated durations go first (ties and unknowns keep their
    order, unknowns last); the e2e runs above show the files do not depend on the order."""
    from roadtruth.harness.jobs.pipeline import ScenarioTask, longest_first

    durations = {"a": 6.0, "b": 10.0, "c": float("nan"), "d": 10.0, "e": 8.0, "f": 5.0}
    tasks = [ScenarioTask(name=n, run_dir=tmp_path, observers=(), seed=None, vehicle=None, friction=None,
                          sensors=None, faults=None, log_rate_hz=100.0, render=False, duration_s=d)
             for n, d in durations.items()]
    assert [t.name for t in longest_first(tasks)] == ["b", "d", "e", "a", "f", "c"]
