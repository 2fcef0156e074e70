"""``roadtruth falsify`` finds a known breaking point, its worst case reproduces, and it is seeded and resumable.

The observer is ``tests/falsify_observers.py``'s ``mu_promise``: its interval for μ under the
front-left wheel assumes μ ≥ 0.6, so on a patch of μ below 0.6 under that wheel its inclusion is lost
by exactly ``0.6 − μ``, and never on a patch on the right half of the lane only.
"""

from __future__ import annotations

import json
from pathlib import Path

import falsify_observers
import pandas as pd
import pytest

from roadtruth.harness.cli import main
from roadtruth.harness.jobs.falsify import run_falsify
from roadtruth.harness.jobs.pipeline import run_suite
from roadtruth.observers import registry

SCENARIO = """\
name: short_straight
description: "2.5 s nearly straight at 15 m/s"
vehicle: sedan
duration_s: 2.5
initial_speed_mps: 15.0
seed: 3
driver:
  steer: {type: constant, t_start_s: 0.0, amplitude_deg: 0.5}
  speed: {type: hold}
sensors: {preset: automotive}
"""
SPACE = """\
parameters:
  patch_mu: {low: 0.1, high: 1.0, nominal: 1.0}
  patch_side: {choices: [both, left, right], nominal: both}
  patch_start_m: 12.0
  patch_length_m: 15.0
"""
BUDGET = 24
#: How close to the true breaking point (μ = 0.6) the smallest breaking case must be, within BUDGET.
MU_TOLERANCE = 0.03


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("falsify_inputs")
    (d / "short_straight.yaml").write_text(SCENARIO)
    (d / "space.yaml").write_text(SPACE)
    return d / "short_straight.yaml", d / "space.yaml"


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory):
    mp = pytest.MonkeyPatch()
    mp.setenv("ROADTRUTH_CACHE", str(tmp_path_factory.mktemp("falsify_cache")))
    registry.register(falsify_observers.MuPromise)
    yield
    registry.unregister(falsify_observers.MuPromise.name)
    mp.undo()


def _falsify(inputs: tuple[Path, Path], out: Path, jobs: int = 1) -> Path:
    return run_falsify(observer="mu_promise", prop="coverage:mu_fl", scenario=str(inputs[0]), space=str(inputs[1]),
                       budget=BUDGET, jobs=jobs, seed=7, out=out, progress=False)


@pytest.fixture(scope="module")
def first(inputs, cache, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _falsify(inputs, tmp_path_factory.mktemp("falsify") / "first")


def test_the_search_finds_the_known_breaking_point(first: Path):
    cases = pd.read_csv(first / "cases.csv")
    assert len(cases) == BUDGET and (cases["observer_status"] == "ok").all() and cases["counted"].all()
    under = cases[cases["patch_side"] != "right"]
    # The truth under the front-left wheel is the patch's μ: robustness is μ − 0.6 to rounding.
    assert (under["robustness"] - (under["patch_mu"] - falsify_observers.BREAKING_MU)).abs().max() < 1e-6
    right = cases[cases["patch_side"] == "right"]
    assert (right["robustness"] > 0.3).all() and not right["violated"].any()  # that wheel never touches it
    assert (cases["violated"] == (cases["robustness"] < 0)).all()
    run = json.loads((first / "run.json").read_text())
    small = run["smallest"]["point"]
    assert falsify_observers.BREAKING_MU - MU_TOLERANCE <= small["patch_mu"] < falsify_observers.BREAKING_MU
    assert small["patch_side"] != "right"
    assert run["smallest"]["finding"].startswith("inclusion of mu_fl lost for a μ 0.")
    worst = run["worst"]
    assert worst["robustness"] == pytest.approx(cases["robustness"].min(), abs=1e-9) and worst["robustness"] < -0.3
    assert cases.loc[0, "patch_mu"] == 1.0 and cases.loc[0, "robustness"] > 0  # the nominal comes first, holds


def test_the_worst_case_reproduces_with_a_normal_run(first: Path, tmp_path: Path):
    run = json.loads((first / "run.json").read_text())
    out = run_suite(scenarios=[str(first / "worst.yaml")], observers=["mu_promise"], render=False,
                    out=tmp_path / "rerun", progress=False)
    m = pd.read_csv(out / "metrics.csv")
    row = m[(m["observer"] == "mu_promise") & (m["state"] == "mu_fl")].iloc[0]
    assert row["coverage"] < 1.0
    truth = pd.read_csv(next(out.glob("worst*/truth.csv")))
    assert truth["mu_fl"].min() == pytest.approx(run["worst"]["point"]["patch_mu"], abs=1e-5)
    assert (first / "worst.txt").read_text().startswith("roadtruth run --scenario worst.yaml --observer mu_promise")


def test_a_rerun_loads_every_case_from_the_cache_and_writes_the_same_bytes(first: Path, inputs, tmp_path: Path):
    again = _falsify(inputs, tmp_path / "again")
    assert json.loads((again / "timings.json").read_text())["n_computed"] == 0
    for name in ("cases.csv", "run.json", "worst.yaml", "smallest.yaml", "index.html"):
        assert (again / name).read_bytes() == (first / name).read_bytes(), name


def test_the_same_seed_gives_the_same_cases_computed_afresh_in_two_processes(first: Path, inputs, tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv("ROADTRUTH_CACHE", str(tmp_path / "empty_cache"))
    fresh = _falsify(inputs, tmp_path / "fresh", jobs=2)
    assert json.loads((fresh / "timings.json").read_text())["n_computed"] == BUDGET
    assert (fresh / "cases.csv").read_bytes() == (first / "cases.csv").read_bytes()


@pytest.mark.parametrize(("args", "message"), [
    (["--observer", "mu_promise", "--property", "coverage:beta_rad"], "does not estimate 'beta_rad'"),
    (["--observer", "kf_bicycle", "--property", "coverage"], "gives no bounds"),
    (["--observer", "interval_wang", "--property", "rmse:beta_rad<0.x"], "--property"),
    (["--observer", "interval_wang", "--property", "coverage", "--space", "SPACE_BAD"], "unknown parameter"),
])
def test_bad_input_is_one_line_and_exit_2_with_no_folder(args, message, cache, inputs, tmp_path: Path, capsys):
    bad = tmp_path / "bad_space.yaml"
    bad.write_text("parameters:\n  patch_muu: {low: 0.1, high: 1.0}\n")
    args = [str(bad) if a == "SPACE_BAD" else a for a in args]
    rc = main(["falsify", *args, "--scenario", str(inputs[0]), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()
