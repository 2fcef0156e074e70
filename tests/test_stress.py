"""Stress sweeps: exact Cartesian product, seeds independent of how the work is spread (in-process,
worker processes, a real Dask LocalCluster on loopback), physical bounds of the truth, crashes as
statuses, and one-line input errors naming the bad value."""

from __future__ import annotations

import io
import itertools
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from roadtruth.harness.errors import InputError, ScenarioError, SensorConfigError
from roadtruth.harness.jobs.stress import (
    NO_FAULTS,
    StressSpecError,
    build_cases,
    monte_carlo_seeds,
    parse_fault_specs,
    parse_friction_list,
    parse_seed_count,
    run_stress,
)

G = 9.80665
SCENARIO = "step_steer"
OBSERVERS = ["kf_bicycle", "lpv_wang"]
FRICTIONS = ["1.0", "0.3"]
BASE_SEED = 7
# Columns that measure the machine, not the result.
TIMING_COLUMNS = ["us_per_step"]


def _sweep(out: Path, **kw: object) -> Path:
    args: dict[str, object] = {"scenarios": [SCENARIO], "observers": OBSERVERS, "frictions": FRICTIONS,
                               "faults": None, "seeds": 2, "base_seed": BASE_SEED, "progress": False,
                               "fresh": True}  # compute every case: these tests compare executors
    args.update(kw)
    return run_stress(out=out, **args)  # type: ignore[arg-type]


def _rows(folder: Path) -> pd.DataFrame:
    return pd.read_csv(folder / "stress.csv", keep_default_na=False, na_values=[""])


@pytest.fixture(scope="module")
def serial(tmp_path_factory: pytest.TempPathFactory, isolated_design_cache: None) -> Path:
    return _sweep(tmp_path_factory.mktemp("stress") / "serial", jobs=1)


def test_cases_and_seeds_are_exactly_the_cartesian_product(serial: Path) -> None:
    rows = _rows(serial)
    seeds = monte_carlo_seeds(BASE_SEED, 2)
    cases = rows.drop_duplicates("case")
    got = sorted(zip(cases["scenario"], cases["friction"].astype(str), cases["faults"], cases["seed"], strict=True))
    want = sorted(itertools.product([SCENARIO], FRICTIONS, [NO_FAULTS], seeds))
    assert got == want
    assert list(cases["case"]) == list(range(4))
    # every case scores every observer, and the seed index maps to its seed
    assert rows.groupby("case")["observer"].nunique().eq(len(OBSERVERS)).all()
    assert all(seeds[k] == s for k, s in zip(cases["seed_index"], cases["seed"], strict=True))
    # every case ran and was judged (an observer may honestly be "unusable" on a state; none errored)
    assert not rows["status"].str.startswith(("error", "skipped")).any(), rows["status"].unique()
    summary = pd.read_csv(serial / "summary.csv", keep_default_na=False, na_values=[""])
    assert summary["n_cases"].eq(2).all()  # two seeds per (observer, state, friction, faults)
    assert len(summary) == rows.groupby(["observer", "state", "friction"]).ngroups
    html = (serial / "index.html").read_text()
    # Self-contained: charts as inline plotly specs, nothing fetched from the network.
    assert "<div class='plot' data-spec='stress-0'>" in html and "Plotly" in html
    assert not re.search(r"<(script|link|img)[^>]+(src|href)=[\"']?https?:", html)


def test_seeds_derive_from_the_base_seed_and_extend() -> None:
    a, b = monte_carlo_seeds(3, 2), monte_carlo_seeds(3, 5)
    assert a == b[:2] and len(set(b)) == 5
    assert monte_carlo_seeds(4, 2) != a
    cases = build_cases(["x", "y"], ["1.0", "ice"], ["none", "gnss:dropout=0.5"], a, ["o"])
    assert len(cases) == 2 * 2 * 2 * 2
    assert len({(c.scenario, c.friction, c.faults, c.seed) for c in cases}) == len(cases)


def test_peak_lateral_acceleration_is_bounded_by_road_friction(serial: Path) -> None:
    """|a_y| <= mu * g * grip (tire peak force <= grip * mu * Fz), with 15 % for load transfer
    dynamics and the unfiltered 1 kHz signal."""
    from roadtruth.harness.truth.scenario import load_scenario

    grip = load_scenario(SCENARIO).vehicle_params().tires.grip
    cases = _rows(serial).drop_duplicates("case")
    for mu, peak in zip(cases["mu"], cases["peak_abs_ay_mps2"], strict=True):
        assert 0.0 < peak <= mu * G * grip * 1.15
    low = cases[cases["mu"] == 0.3]
    # at mu = 0.3 the car saturates: the peak is near the friction limit, not far below it
    assert (low["peak_abs_ay_mps2"] > 0.8 * 0.3 * G * grip).all()


def _same_results(a: Path, b: Path) -> None:
    ra, rb = _rows(a).drop(columns=TIMING_COLUMNS), _rows(b).drop(columns=TIMING_COLUMNS)
    pd.testing.assert_frame_equal(ra, rb, check_exact=True)


def test_worker_processes_give_identical_results(serial: Path, tmp_path: Path) -> None:
    _same_results(serial, _sweep(tmp_path / "jobs2", jobs=2))


def test_real_dask_local_cluster_gives_identical_results(serial: Path, tmp_path: Path) -> None:
    pytest.importorskip("distributed")
    out = _sweep(tmp_path / "dask", jobs=2, dask="local")
    _same_results(serial, out)
    import json

    run = json.loads((out / "run.json").read_text())
    assert run["executor"] == "dask local" and run["dask"]["workers"] == 2


def test_a_crashing_case_becomes_error_rows_and_the_sweep_goes_on(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    import roadtruth.harness.sensors as sensors

    real = sensors.emulate

    def emulate_failing_on_ice(frame: pd.DataFrame, *args: object, **kw: object) -> object:
        # mu = 0.1 only limits a_y below 0.1 g * grip * 1.15: fail there, run normally on dry road
        if np.nanmax(np.abs(frame["ay_mps2"].to_numpy())) < 0.15 * G:
            raise RuntimeError("sensor rig on fire")
        return real(frame, *args, **kw)

    monkeypatch.setattr(sensors, "emulate", emulate_failing_on_ice)
    out = _sweep(tmp_path / "crash", frictions=["1.0", "ice"], seeds=1, jobs=1)
    rows = _rows(out)
    ice, dry = rows[rows["friction"] == "ice"], rows[rows["friction"] == "1.0"]
    assert set(ice["observer"]) == set(OBSERVERS) == set(dry["observer"])
    assert ice["status"].eq("error: RuntimeError: sensor rig on fire").all()
    assert ice["rmse"].isna().all()
    assert dry["status"].str.startswith("ok").all()
    summary = pd.read_csv(out / "summary.csv", keep_default_na=False, na_values=[""])
    assert summary.loc[summary["friction"] == "ice", "frac_error"].eq(1.0).all()


@pytest.mark.parametrize(("call", "error", "named"), [
    (lambda: parse_friction_list("1.0,,0.3"), StressSpecError, "1.0,,0.3"),
    (lambda: parse_friction_list("1.0,tarmac"), ScenarioError, "tarmac"),
    (lambda: parse_friction_list("0.6,2.5"), ScenarioError, "2.5"),
    (lambda: parse_fault_specs("none;gnss:wobble=3"), SensorConfigError, "gnss:wobble=3"),
    (lambda: parse_fault_specs(" ; "), StressSpecError, " ; "),
    (lambda: parse_seed_count("0"), StressSpecError, "0"),
    (lambda: parse_seed_count("two"), StressSpecError, "two"),
])
def test_bad_lists_raise_one_line_input_errors_naming_the_value(call, error, named: str) -> None:
    with pytest.raises(error) as info:
        call()
    assert isinstance(info.value, InputError)
    msg = str(info.value)
    assert named in msg and "\n" not in msg


def test_lists_parse_and_a_disabled_sensor_fault_is_refused_before_work(tmp_path: Path) -> None:
    assert parse_friction_list("1.0, ice,1.0") == ["1.0", "ice"]
    assert parse_fault_specs("None; gnss:dropout=0.5,imu:bias_step=0.3") == [
        "none", "gnss:dropout=0.5,imu:bias_step=0.3"]
    with pytest.raises(SensorConfigError, match="ogs"):
        _sweep(tmp_path / "x", faults=["ogs:dropout=0.5"])
    assert not (tmp_path / "x").exists()


# ---- the report: curves, breaking points, truth context (synthetic stress.csv, no simulation) ----------

def test_breaking_point_at_the_known_mu_and_fault_level_with_the_threshold_used() -> None:
    import math

    from stress_synthetic import stress_rows

    from roadtruth.harness.report.stress_report import DEFAULT_RMSE_LIMITS, breaking_points, summarize

    summary = summarize(stress_rows())
    bp = breaking_points(summary).set_index(["observer", "axis"])
    frag_mu = bp.loc[("fragile", "μ")]
    # 0.3° + 2°(1 − μ) crosses the default 1° limit between μ = 0.8 (0.7°) and 0.6 (1.1°).
    assert frag_mu.verdict == "breaks" and frag_mu.breaks_at == 0.6
    assert frag_mu.threshold == DEFAULT_RMSE_LIMITS["beta_rad"] == math.radians(1.0)
    assert frag_mu.threshold_source == "default" and "1.1 deg > 1 deg" in frag_mu.reason
    frag_fault = bp.loc[("fragile", "gnss:dropout")]
    assert frag_fault.verdict == "breaks" and frag_fault.breaks_at == 0.3
    # Spun-out seeds (60° "error") are the truth's fault: steady holds, and μ = 0.2 is not judged.
    steady = bp.loc[("steady", "μ")]
    assert steady.verdict == "holds" and math.isnan(steady.breaks_at)
    assert "down to 0.4" in steady.reason and "not judged where every seed lost control: 0.2" in steady.reason
    row = summary[(summary.observer == "steady") & (summary.friction == "0.4")].iloc[0]
    assert row.n_controlled == 1 and row.truth_lost == 2
    assert math.degrees(row.rmse_mean) == pytest.approx(0.22, abs=1e-9)  # the one controlled seed only
    # P5–P95 over the seeds: fragile at μ = 1 is 0.3° ± 0.05°.
    r1 = summary[(summary.observer == "fragile") & (summary.friction == "1") & (summary.faults == "none")].iloc[0]
    assert math.degrees(r1.rmse_p5) == pytest.approx(0.255, abs=1e-9)
    assert math.degrees(r1.rmse_p95) == pytest.approx(0.345, abs=1e-9)


def test_thresholds_come_from_the_shipped_ci_rules_when_one_matches() -> None:
    import re

    import yaml

    from roadtruth.harness.jobs.check_rules import DEFAULT_THRESHOLDS
    from roadtruth.harness.report.stress_report import rmse_threshold

    limit, source = rmse_threshold("step_steer", "kf_bicycle", "beta_rad")
    m = re.fullmatch(r"ci\.yaml rules\[(\d+)\]", source)
    assert m, source
    rule = yaml.safe_load(DEFAULT_THRESHOLDS.read_text(encoding="utf-8"))["rules"][int(m.group(1))]

    def names(v: object) -> list[str]:
        return [v] if isinstance(v, str) else list(v)  # type: ignore[arg-type]

    # The limit is the shipped rule's own ceiling, and that rule is about this scenario, observer and state.
    assert rule["metric"] == "rmse" and limit == rule["max"] > 0.0
    assert "step_steer" in names(rule["scenario"]) and "kf_bicycle" in names(rule["observer"])
    assert "beta_rad" in names(rule["state"])
    assert rmse_threshold("lane_change", "kf_bicycle", "vy_mps") == (0.3, "default")


def test_stress_page_shows_curves_in_degrees_breaking_points_and_spin_outs(tmp_path: Path) -> None:
    import json
    import re

    from stress_synthetic import RUN, stress_rows

    from roadtruth.harness.report.stress_report import summarize, write_index

    page = write_index(tmp_path, summarize(stress_rows()), RUN).read_text()
    specs = {m.group(1): json.loads(m.group(2)) for m in
             re.finditer(r"<script type='application/json' id='(stress-\d+)'>(.*?)</script>", page)}
    assert len(specs) == 2  # β against μ, β against GNSS dropout
    mu_fig = next(s for s in specs.values() if "vs μ" in s["layout"]["title"]["text"])
    mean = next(t for t in mu_fig["data"] if t.get("name") == "fragile")
    assert mean["x"] == [0.2, 0.4, 0.6, 0.8, 1.0] or sorted(mean["x"]) == [0.4, 0.6, 0.8, 1.0]
    assert mean["y"][mean["x"].index(1.0)] == pytest.approx(0.3, rel=1e-4)  # degrees, not radians
    bands = [t for t in mu_fig["data"] if t.get("fill") == "tonexty"]
    assert len(bands) == 2  # one P5–P95 band per observer
    assert any(t["marker"].get("symbol") == "x" and t["x"] == [0.6] for t in mu_fig["data"] if "marker" in t)
    assert any("2/3 lost control" in a["text"] for a in mu_fig["layout"]["annotations"])
    assert "<td>μ = 0.6</td><td>1 deg</td><td>default</td>" in page
    assert "spun out at t=3.20 s" in page and "1 of 3" in page
    assert "Plotly" in page and "https://" not in page.split("<script>")[0]


def test_a_worker_reuses_prepared_scenarios_within_a_sweep_and_results_do_not_depend_on_order(
        serial: Path) -> None:
    """Cases of one sweep share one prepared scenario per (scenario, friction) in a process; a later
    case sees exactly what a fresh load gives (nothing is changed by use), whatever ran before it,
    and a new sweep loads afresh (a file edited in between is read again)."""
    from roadtruth.harness.jobs import stress
    seeds = monte_carlo_seeds(BASE_SEED, 2)
    fwd = stress.run_cases(build_cases([SCENARIO], FRICTIONS, [NO_FAULTS], seeds, OBSERVERS, sweep="a"))
    assert set(stress._PREPARED) == {("a", SCENARIO, f) for f in FRICTIONS}
    first = {k: v[0] for k, v in stress._PREPARED.items()}
    rev = stress.run_cases(build_cases([SCENARIO], FRICTIONS, [NO_FAULTS], seeds, OBSERVERS, sweep="b")[::-1])
    assert set(stress._PREPARED) == {("b", SCENARIO, f) for f in FRICTIONS}  # the old sweep's are gone
    assert all(stress._PREPARED[("b", SCENARIO, f)][0] is not first[("a", SCENARIO, f)] for f in FRICTIONS)
    a, b = (pd.concat([r.rows for r in sorted(res, key=lambda r: r.index)], ignore_index=True).drop(
        columns=TIMING_COLUMNS) for res in (fwd, rev))
    pd.testing.assert_frame_equal(a, b, check_exact=True)  # bit-identical whatever ran first
    # and the values of the sweep written to stress.csv (which rounds floats to its float format)
    want = _rows(serial).drop(columns=TIMING_COLUMNS)
    got = pd.read_csv(io.StringIO(a.to_csv(index=False)), keep_default_na=False, na_values=[""])
    pd.testing.assert_frame_equal(got, want, check_exact=False, rtol=1e-8, check_dtype=False)


def test_dask_batches_cover_every_case_once_in_order() -> None:
    from roadtruth.harness.jobs.stress import dask_batches

    cases = build_cases(["x"], ["1.0", "0.3"], [NO_FAULTS], list(range(48)), ["o"])
    for workers in (1, 2, 3, 8):
        batches = dask_batches(cases, workers)
        assert [c for b in batches for c in b] == cases
        assert max(len(b) for b in batches) <= 16
        assert len(batches) >= min(len(cases), 4 * workers) or len(batches[0]) == 16
    assert dask_batches(cases[:3], 2) == [[c] for c in cases[:3]]
    assert dask_batches([], 2) == []


def test_summary_fractions_counts_and_missing_labels_per_group() -> None:
    """Status fractions over every seed, failures over the controlled ones, distinct cases counted
    once, and rows without a state label summarised together (one group), as their own row."""
    import math

    from roadtruth.harness.report.stress_report import summarize

    nan = math.nan
    base = {"scenario": "s", "observer": "o", "friction": "1", "faults": "none", "mu": 1.0, "coverage": nan,
            "peak_abs_beta_rad": 0.01}
    rows = pd.DataFrame([
        {**base, "case": 0, "state": "beta_rad", "status": "ok", "rmse": 0.01, "truth_status": "ok"},
        {**base, "case": 1, "state": "beta_rad", "status": "diverged at t=2 s", "rmse": 0.5, "truth_status": "ok"},
        {**base, "case": 2, "state": "beta_rad", "status": "error: boom", "rmse": nan, "truth_status": nan},
        {**base, "case": 3, "state": "beta_rad", "status": "ok", "rmse": 9.0, "truth_status": "spun out at t=1 s"},
        {**base, "case": 4, "state": nan, "status": "skipped: missing radar", "rmse": nan, "truth_status": "ok"},
        {**base, "case": 5, "state": nan, "status": "skipped: missing radar", "rmse": nan, "truth_status": "ok"},
    ])
    s = summarize(rows)
    assert len(s) == 2
    beta = s[s["state"] == "beta_rad"].iloc[0]
    assert (beta.n_cases, beta.n_controlled, beta.truth_lost) == (4, 3, 1)
    assert (beta.frac_ok, beta.frac_diverged, beta.frac_error) == (0.5, 0.25, 0.25)
    assert beta.frac_failed == 2 / 3  # diverged + error among the three controlled seeds
    assert beta.rmse_max == 0.5 and beta.rmse_mean == pytest.approx(0.255, abs=1e-15)  # spun-out 9.0 left out
    assert beta.truth_statuses == "spun out at t=1 s"
    none = s[s["state"].isna()].iloc[0]
    assert (none.n_cases, none.frac_not_applicable, none.frac_failed) == (2, 1.0, 0.0)
    assert math.isnan(none.rmse_mean)
