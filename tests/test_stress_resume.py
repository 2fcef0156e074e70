"""Sweeps resume: every finished case is cached under a key of everything that determines it, so a
rerun computes nothing, a wider sweep computes only its new cases, a sweep stopped half-way resumes,
and the files are the same bytes whether a case was computed or loaded. ``--fresh`` recomputes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from roadtruth.harness.files.disk_cache import CACHE_ENV
from roadtruth.harness.jobs.stress import run_stress
from roadtruth.harness.jobs.stress_cache import CACHE_KIND

OBSERVERS = ["kf_bicycle"]  # no LMI design: the cost of a case is the simulation
FRICTIONS = ["1.0", "0.5"]
# Files of a sweep that must not depend on whether its cases were computed or loaded.
RESULT_FILES = ("stress.csv", "summary.csv", "run.json", "index.html")


@pytest.fixture
def tiny(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A 1.5 s step steer (the shipped one, shortened) and a private cache."""
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    src = (Path(__file__).parents[1] / "harness" / "scenarios" / "step_steer.yaml").read_text()
    text = (src.replace("name: step_steer", "name: tiny_step").replace("duration_s: 5.0", "duration_s: 1.5")
            .replace("t_start_s: 1.0, amplitude", "t_start_s: 0.3, amplitude").replace("{t_s: 1.0,", "{t_s: 0.3,"))
    assert text.count("tiny_step") == 1 and "duration_s: 1.5" in text
    path = tmp_path / "tiny_step.yaml"
    path.write_text(text)
    return path


def _sweep(scenario: Path, out: Path, **kw: object) -> Path:
    args: dict[str, object] = {"scenarios": [str(scenario)], "observers": OBSERVERS, "frictions": FRICTIONS,
                               "faults": None, "seeds": 2, "base_seed": 3, "progress": False, "jobs": 1}
    args.update(kw)
    return run_stress(out=out, **args)  # type: ignore[arg-type]


def _timings(folder: Path) -> dict:
    return json.loads((folder / "timings.json").read_text())


def _rows(folder: Path) -> pd.DataFrame:
    return pd.read_csv(folder / "stress.csv", keep_default_na=False, na_values=[""])


def test_rerun_loads_every_case_and_writes_the_same_bytes(tiny: Path, tmp_path: Path) -> None:
    first = _sweep(tiny, tmp_path / "a")
    assert (_timings(first)["n_computed"], _timings(first)["n_cached"]) == (4, 0)
    assert len(list((tmp_path / "cache" / CACHE_KIND).glob("*.json"))) == 4
    again = _sweep(tiny, tmp_path / "b")
    assert (_timings(again)["n_computed"], _timings(again)["n_cached"]) == (0, 4)
    # The phases partition each sweep's wall time; a sweep served from the cache runs no case.
    for t in (_timings(first), _timings(again)):
        assert sum(t["phases_s"].values()) == pytest.approx(t["wall_s"], abs=0.004)
    assert _timings(first)["phases_s"]["work"] > 0 and _timings(again)["phases_s"]["work"] == 0
    for name in RESULT_FILES:  # us_per_step included: a loaded case keeps the measurement it was made with
        assert (first / name).read_bytes() == (again / name).read_bytes(), name
    # --fresh recomputes everything; only the time measurements may differ
    fresh = _sweep(tiny, tmp_path / "c", fresh=True)
    assert _timings(fresh)["n_computed"] == 4
    pd.testing.assert_frame_equal(_rows(first).drop(columns="us_per_step"),
                                  _rows(fresh).drop(columns="us_per_step"), check_exact=True)
    assert (first / "summary.csv").read_bytes() == (fresh / "summary.csv").read_bytes()


def test_a_wider_sweep_computes_only_its_new_cases(tiny: Path, tmp_path: Path) -> None:
    narrow = _sweep(tiny, tmp_path / "narrow")
    wide = _sweep(tiny, tmp_path / "wide", seeds=3, frictions=[*FRICTIONS, "0.3"])
    t = _timings(wide)
    assert (t["n_cases"], t["n_cached"], t["n_computed"]) == (9, 4, 5)  # 2 x 2 shared of 3 x 3
    a, b = _rows(narrow), _rows(wide)
    assert list(b["case"].drop_duplicates()) == list(range(9))  # positions of the wide sweep
    key = ["friction", "seed", "observer", "state"]
    shared = b.merge(a, on=key, suffixes=("", "_narrow"))
    assert len(shared) == len(a)
    for col in a.columns:
        if col not in key and col != "case":
            left, right = shared[col], shared[f"{col}_narrow"]
            same = (left == right) | (left.isna() & right.isna())
            assert same.all(), col
    # the seed index of a shared case is its index in the wide sweep (seed k does not depend on n)
    assert (shared["seed_index"] == shared["seed_index_narrow"]).all()


def test_a_stopped_sweep_resumes_where_it_stopped(tiny: Path, tmp_path: Path) -> None:
    """A sweep killed after some cases left exactly those cases in the cache: a subset sweep stands
    for it; the full sweep then computes only the rest and equals an uninterrupted one."""
    _sweep(tiny, tmp_path / "half", frictions=["1.0"])  # 2 of the 4 cases finished
    full = _sweep(tiny, tmp_path / "full")
    t = _timings(full)
    assert (t["n_cached"], t["n_computed"]) == (2, 2)
    whole = _sweep(tiny, tmp_path / "whole", fresh=True)
    pd.testing.assert_frame_equal(_rows(full).drop(columns="us_per_step"),
                                  _rows(whole).drop(columns="us_per_step"), check_exact=True)


def test_anything_that_changes_a_case_changes_its_key(tiny: Path, tmp_path: Path) -> None:
    _sweep(tiny, tmp_path / "a", seeds=1)
    assert _timings(_sweep(tiny, tmp_path / "seed", seeds=1, base_seed=4))["n_computed"] == 2
    assert _timings(_sweep(tiny, tmp_path / "faults", seeds=1, faults=["gnss:dropout=0.5"]))["n_computed"] == 2
    assert _timings(_sweep(tiny, tmp_path / "obs", seeds=1, observers=["kinematic_vy"]))["n_computed"] == 2
    tiny.write_text(tiny.read_text().replace("initial_speed_mps: 20.0", "initial_speed_mps: 19.0"))
    changed = _sweep(tiny, tmp_path / "content", seeds=1)  # same file name, other content
    assert _timings(changed)["n_computed"] == 2


def test_a_tampered_case_entry_is_recomputed(tiny: Path, tmp_path: Path) -> None:
    first = _sweep(tiny, tmp_path / "a", seeds=1)
    entries = sorted((tmp_path / "cache" / CACHE_KIND).glob("*.json"))
    assert len(entries) == 2
    data = json.loads(entries[0].read_text())
    rmse = next(c for c in data["columns"] if c["name"] == "rmse")
    rmse["values"] = [0.0 for _ in rmse["values"]]  # a perfect observer, written by hand
    entries[0].write_text(json.dumps(data))
    again = _sweep(tiny, tmp_path / "b", seeds=1)
    assert _timings(again)["n_computed"] == 1
    assert np.all(_rows(again)["rmse"].dropna() > 0)
    pd.testing.assert_frame_equal(_rows(first).drop(columns="us_per_step"),
                                  _rows(again).drop(columns="us_per_step"), check_exact=True)


def test_failed_cases_are_not_cached(tiny: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import roadtruth.harness.sensors as sensors

    real = sensors.emulate

    def emulate_failing_on_ice(frame: pd.DataFrame, *args: object, **kw: object) -> object:
        # on ice (mu = 0.1) |a_y| stays below 0.1 g * grip * 1.15; the dry case reaches ~4 m/s^2
        if np.nanmax(np.abs(frame["ay_mps2"].to_numpy())) < 0.15 * 9.80665:
            raise RuntimeError("sensor rig on fire")
        return real(frame, *args, **kw)

    monkeypatch.setattr(sensors, "emulate", emulate_failing_on_ice)
    broken = _sweep(tiny, tmp_path / "broken", seeds=1, frictions=["1.0", "ice"])
    rows = _rows(broken)
    assert rows.loc[rows["friction"] == "ice", "status"].str.startswith("error").all()
    assert rows.loc[rows["friction"] == "1.0", "status"].str.startswith("ok").all()
    monkeypatch.setattr(sensors, "emulate", real)
    healed = _sweep(tiny, tmp_path / "healed", seeds=1, frictions=["1.0", "ice"])
    assert (_timings(healed)["n_cached"], _timings(healed)["n_computed"]) == (1, 1)  # the error is retried
    # retried and run: no error left (on ice the KF's sideslip may honestly be "unusable")
    assert not _rows(healed)["status"].str.startswith("error").any()
    assert _rows(healed).loc[lambda r: r["friction"] == "1.0", "status"].str.startswith("ok").all()


def test_worker_processes_store_their_own_cases(tiny: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With ``--jobs 2`` each worker stores the cases it ran as soon as they are scored; the sweep's
    own process, which shares the two cores with them, stores none (and a rerun loads them all)."""
    import roadtruth.harness.jobs.stress_cache as stress_cache

    def not_here(*args: object) -> None:
        raise AssertionError("the sweep's process stored a case its worker had stored")

    monkeypatch.setattr(stress_cache, "store_finished", not_here)  # this process only: workers are fresh
    first = _sweep(tiny, tmp_path / "a", jobs=2)
    assert (_timings(first)["n_computed"], _timings(first)["n_cached"]) == (4, 0)
    assert len(list((tmp_path / "cache" / CACHE_KIND).glob("*.json"))) == 4
    again = _sweep(tiny, tmp_path / "b", jobs=2)
    assert (_timings(again)["n_computed"], _timings(again)["n_cached"]) == (0, 4)
    # The phases partition each sweep's wall time; a sweep served from the cache runs no case.
    for t in (_timings(first), _timings(again)):
        assert sum(t["phases_s"].values()) == pytest.approx(t["wall_s"], abs=0.004)
    assert _timings(first)["phases_s"]["work"] > 0 and _timings(again)["phases_s"]["work"] == 0
    for name in RESULT_FILES:
        assert (first / name).read_bytes() == (again / name).read_bytes(), name


def test_a_serial_sweep_does_the_page_s_one_time_work_beside_its_cases(tiny: Path, tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """Without workers the page's one-time work runs in a thread beside the cases and is finished
    before the page is written; a sweep served from the case cache does it in line."""
    import threading

    from roadtruth.harness.report import stress_report

    calls: list[str] = []
    real_warm, real_page = stress_report.warm_up, stress_report.stress_page
    monkeypatch.setattr(stress_report, "warm_up", lambda: (calls.append(threading.current_thread().name), real_warm()))
    monkeypatch.setattr(stress_report, "stress_page",
                        lambda *a, **k: (calls.append("page"), real_page(*a, **k))[1])
    _sweep(tiny, tmp_path / "a")
    assert calls == ["roadtruth-page-warm-up", "page"]
    calls.clear()
    _sweep(tiny, tmp_path / "b")  # every case from the cache: nothing to overlap
    assert calls == ["page"]
