"""Observer options from the command line (``-O``, ``--observer-options``) and the Python API.

Bad options are one stderr line and exit 2 before anything is simulated or written; good ones
change the observer's result, are recorded in run.json, and are part of a stress case's cache key.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from roadtruth.harness.cli import main
from roadtruth.harness.evaluation.observer_options import (
    ObserverOptionsError,
    check_observer_options,
    options_from_cli,
    parse_assignment,
)


def one_line_exit_2(capsys: pytest.CaptureFixture[str], args: list[str], *needles: str) -> str:
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, (n, err)
    return err


@pytest.mark.parametrize("option, needles", [
    ("-O nope_observer.gain=1", ("unknown observer", "nope_observer")),
    ("-O kf_bicycle.no_such_option=1", ("unknown option", "no_such_option", "meas_std_ay_mps2")),
    ("-O kf_bicycle.meas_std_ay_mps2=loud", ("kf_bicycle.meas_std_ay_mps2", "must be a number", "loud")),
    ("-O kf_bicycle.meas_std_ay_mps2=true", ("must be a number",)),
    ("-O ekf_bicycle.mu=0.9", ("ekf_bicycle", "not being run")),
    ("-O kf_bicycle=3", ("observer.option=value",)),
    ("-O kf_bicycle.meas_std_ay_mps2=[1,", ("not a YAML value",)),
])
@pytest.mark.parametrize("command", ["run", "check", "stress"])
def test_bad_option_is_one_line_exit_2_before_any_work(command: str, option: str, needles: tuple[str, ...],
                                                       tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    flag, value = option.split(" ", 1)
    one_line_exit_2(capsys, [command, "--scenario", "step_steer", "--observer", "kf_bicycle", "--out", str(out),
                             flag, value], *needles)
    assert not out.exists()


def test_bad_options_file_and_replay(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    opts = tmp_path / "opts.yaml"
    opts.write_text("kf_bicycle: 3\n")
    one_line_exit_2(capsys, ["run", "--scenario", "step_steer", "--observer", "kf_bicycle", "--out",
                             str(tmp_path / "o"), "--observer-options", str(opts)], "opts.yaml", "kf_bicycle")
    log = tmp_path / "log.csv"
    pd.DataFrame({"t_s": np.arange(0, 5, 0.01), "vx_mps": 20.0, "delta_rad": 0.0, "yaw_rate_radps": 0.0,
                  "ay_mps2": 0.0}).to_csv(log, index=False)
    one_line_exit_2(capsys, ["replay", str(log), "--vehicle", "ferrari_250lm", "--observer", "kf_bicycle",
                             "--out", str(tmp_path / "r"), "-O", "kf_bicycle.vx_min_mps=fast"], "vx_min_mps")
    assert not (tmp_path / "r").exists() and not (tmp_path / "o").exists()


def test_values_are_yaml_scalars_and_the_command_line_overrides_the_file(tmp_path: Path) -> None:
    assert parse_assignment("hgo_radar_method1.m1_direction=[0, 0, 1]") == ("hgo_radar_method1", "m1_direction",
                                                                             [0, 0, 1])
    assert parse_assignment("ekf_bicycle.innovation_gate=.inf")[2] == float("inf")
    assert parse_assignment("kf_bicycle.meas_std_ay_mps2=1e-3")[2] == pytest.approx(1e-3)  # YAML 1.2: a number
    f = tmp_path / "o.yaml"
    f.write_text("kf_bicycle: {meas_std_ay_mps2: 1.0, meas_std_r_radps: 0.02}\nekf_bicycle: {mu: 0.8}\n")
    merged = options_from_cli(str(f), ["kf_bicycle.meas_std_ay_mps2=2"])
    assert merged == {"kf_bicycle": {"meas_std_ay_mps2": 2, "meas_std_r_radps": 0.02}, "ekf_bicycle": {"mu": 0.8}}
    checked = check_observer_options(merged, ["kf_bicycle", "ekf_bicycle"])
    assert checked["kf_bicycle"]["meas_std_ay_mps2"] == 2.0 and isinstance(checked["kf_bicycle"]["meas_std_ay_mps2"],
                                                                            float)
    m1 = check_observer_options({"hgo_radar_method1": {"m1_direction": [0, 1, 0]}}, ["hgo_radar_method1"])
    assert m1["hgo_radar_method1"]["m1_direction"] == (0.0, 1.0, 0.0)
    with pytest.raises(ObserverOptionsError, match="list of 3"):
        check_observer_options({"hgo_radar_method1": {"m1_direction": [0, 1]}}, ["hgo_radar_method1"])


def test_options_change_the_result_and_are_recorded(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from roadtruth.harness.jobs.pipeline import run_suite

    base = run_suite(scenarios=["step_steer"], observers=["kf_bicycle"], seed=3, out=tmp_path / "a",
                     render=False, progress=False)
    code = main(["run", "--scenario", "step_steer", "--observer", "kf_bicycle", "--seed", "3", "--no-render",
                 "--out", str(tmp_path / "b"), "-O", "kf_bicycle.meas_std_ay_mps2=3.0"])
    assert code == 0, capsys.readouterr().err

    def beta_rmse(d: Path) -> float:
        m = pd.read_csv(d / "metrics.csv")
        return float(m[(m.observer == "kf_bicycle") & (m.state == "beta_rad")]["rmse"].iloc[0])

    # Trusting the accelerometer 100x less (variance) changes the filter's gain and so its error.
    assert abs(beta_rmse(base) - beta_rmse(tmp_path / "b")) > 1e-6
    assert json.loads((base / "run.json").read_text())["observer_options"] == {}
    assert json.loads((tmp_path / "b" / "run.json").read_text())["observer_options"] == {
        "kf_bicycle": {"meas_std_ay_mps2": 3.0}}


def test_replay_api_options_take_effect_and_are_recorded(tmp_path: Path) -> None:
    from roadtruth.harness.jobs.replay import replay

    t = np.arange(0.0, 8.0, 0.01)
    rng = np.random.default_rng(2)
    delta = 0.03 * np.sin(2 * np.pi * 0.4 * t)
    r = 20.0 * delta / 2.6
    log = pd.DataFrame({"t_s": t, "vx_mps": 20.0, "beta_rad": -0.2 * delta, "delta_rad": delta,
                        "yaw_rate_radps": r + rng.normal(0, 0.005, t.size),
                        "ay_mps2": 20.0 * r + rng.normal(0, 0.5, t.size)})
    log.to_csv(tmp_path / "drive.csv", index=False)
    outs = [replay(tmp_path / "drive.csv", vehicle="ferrari_250lm", observers=["kf_bicycle"], out=tmp_path / k,
                   observer_options=o, progress=lambda _m: None)
            for k, o in (("a", None), ("b", {"kf_bicycle": {"meas_std_ay_mps2": 2.0}}))]
    rmse = [pd.read_csv(o / "metrics.csv").query("state == 'beta_rad'")["rmse"].iloc[0] for o in outs]
    assert rmse[0] != pytest.approx(rmse[1], rel=1e-6)
    assert json.loads((outs[1] / "run.json").read_text())["observer_options"] == {
        "kf_bicycle": {"meas_std_ay_mps2": 2.0}}


def test_options_are_part_of_the_stress_case_key() -> None:
    from roadtruth.harness.jobs.stress_cache import CaseKeys

    keys = CaseKeys()
    plain = keys.key("step_steer", None, None, 11, ("kf_bicycle",))
    again = keys.key("step_steer", None, None, 11, ("kf_bicycle",), options={})
    tuned = keys.key("step_steer", None, None, 11, ("kf_bicycle",), options={"kf_bicycle": {"meas_std_ay_mps2": 2.0}})
    other = keys.key("step_steer", None, None, 11, ("kf_bicycle",), options={"kf_bicycle": {"meas_std_ay_mps2": 2.5}})
    assert plain is not None and plain == again
    assert len({plain, tuned, other}) == 3
