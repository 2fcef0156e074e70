"""Bad input of any kind is one line on stderr and exit 2, never a traceback, and nothing is written.

Covers YAML data files (non-string keys, deep nesting, alias bombs, oversize files, YAML 1.2
numbers), scenario files given by path (absolute, ``../``) and the folders they get in a run,
``report`` on malformed or crafted run folders, and recorded logs with ±inf samples or a time
column in µs/ms read as seconds.
"""

from __future__ import annotations

import json
import os
import shutil
import tracemalloc
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from synthetic_run import make_run_folder

from roadtruth.harness.cli import main
from roadtruth.harness.errors import InputError
from roadtruth.harness.files.strict_yaml import MAX_YAML_BYTES, load_mapping
from roadtruth.harness.jobs.replay_log import apply_map, load_column_map, read_log
from roadtruth.harness.report.rundata import new_scenario_folder, scenario_folder_name
from roadtruth.harness.truth.scenario import scenarios_dir


def bad_input(capsys: pytest.CaptureFixture[str], args: list[str], *needles: str) -> str:
    """Run the CLI in-process; assert exit 2 with exactly one stderr line holding every needle."""
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and err.endswith("\n"), err[:2000]
    assert "Traceback" not in err
    for n in needles:
        assert n in err, (n, err)
    return err


def step_steer_text() -> str:
    return (scenarios_dir() / "step_steer.yaml").read_text()


# ---- YAML data files ----------------------------------------------------------------------------

def test_integer_key_in_scenario_names_file_and_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "step_steer.yaml"
    bad.write_text(step_steer_text().replace("duration_s: 5.0", "duration_s: 5.0\n42: oops"))
    err = bad_input(capsys, ["simulate", str(bad), "--out", str(tmp_path / "out")], "step_steer.yaml", "42",
                    "not a string")
    assert "line " in err
    assert not (tmp_path / "out").exists()


def test_integer_key_nested_in_scenario(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "step_steer.yaml"
    bad.write_text(step_steer_text().replace("speed: {type: hold}", "speed: {type: hold, 7: x}"))
    bad_input(capsys, ["simulate", str(bad), "--out", str(tmp_path / "out")], "step_steer.yaml", "7")
    assert not (tmp_path / "out").exists()


def test_integer_key_in_thresholds_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "gate.yaml"
    bad.write_text("description: gate\n1: [a]\nrules:\n  - {observer: '*', state: '*', metric: status, equals: ok}\n")
    bad_input(capsys, ["check", "--thresholds", str(bad), "--scenario", "step_steer", "--observer", "kf_bicycle",
                       "--out", str(tmp_path / "out")], "gate.yaml", "1")
    assert not (tmp_path / "out").exists()


def _tiny_log(path: Path, n: int = 400, dt: float = 0.01, t_scale: float = 1.0, t_name: str = "t_s") -> pd.DataFrame:
    """A short plausible vehicle log in canonical units (20 m/s, gentle weave)."""
    t = np.arange(n) * dt
    log = pd.DataFrame({t_name: t * t_scale, "vx_mps": np.full(n, 20.0), "delta_rad": 0.02 * np.sin(t),
                        "yaw_rate_radps": 0.1 * np.sin(t), "ay_mps2": 2.0 * np.sin(t),
                        "beta_rad": 0.005 * np.sin(t)})
    log.to_csv(path, index=False)
    return log


def test_integer_key_in_column_map(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _tiny_log(tmp_path / "log.csv")
    cmap = tmp_path / "map.yaml"
    cmap.write_text("time: t_s\n3: vx_mps\nmeasured: [vx_mps]\n")
    bad_input(capsys, ["replay", str(tmp_path / "log.csv"), "--vehicle", "sedan", "--columns", str(cmap),
                       "--out", str(tmp_path / "out")], "map.yaml", "3")
    assert not (tmp_path / "out").exists()


def test_deep_nesting_is_refused_not_a_recursion_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "deep.yaml"
    bad.write_text("name: " + "[" * 20_000 + "]" * 20_000 + "\n")
    bad_input(capsys, ["simulate", str(bad), "--out", str(tmp_path / "out")], "deep.yaml", "nested deeper than")
    assert not (tmp_path / "out").exists()


def _alias_bomb() -> str:
    """The classic "billion laughs": 9 levels of 9 aliases each, 9^9 ≈ 3.9e8 strings when expanded."""
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for prev, cur in zip("abcdefgh", "bcdefghi", strict=True):
        lines.append(f"{cur}: &{cur} [" + ",".join([f"*{prev}"] * 9) + "]")
    return "\n".join(lines) + "\n"


def test_alias_bomb_is_refused_cheaply(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = _alias_bomb()
    assert len(text.encode()) < 700
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("name: bomb\n" + text)
    tracemalloc.start()
    try:
        err = bad_input(capsys, ["simulate", str(bomb), "--out", str(tmp_path / "out")], "bomb.yaml",
                        "expands to more than")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(err) < 300
    assert peak < 20e6, f"{peak / 1e6:.0f} MB to refuse a {len(text)}-byte file"
    assert not (tmp_path / "out").exists()


def test_oversize_yaml_file_is_refused(tmp_path: Path) -> None:
    big = tmp_path / "big.yaml"
    big.write_text("description: " + "x" * (MAX_YAML_BYTES + 10) + "\n")
    with pytest.raises(InputError, match=r"big\.yaml: larger than"):
        load_mapping(big)


def test_yaml_error_values_are_shortened(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "step_steer.yaml"
    bad.write_text(step_steer_text().replace('standard: "ISO 7401"', "standard: [" + "1," * 50_000 + "1]"))
    err = bad_input(capsys, ["simulate", str(bad), "--out", str(tmp_path / "out")], "standard", "must be a string")
    assert len(err) < 400


def test_yaml_1_2_numbers(tmp_path: Path) -> None:
    f = tmp_path / "n.yaml"
    f.write_text("a: 1e-3\nb: 9.82e2\nc: -2.5E+2\nd: 0123\ne: yes\nf: 1:20\ng: 2024-05-02\nh: .inf\ni: true\n")
    d = load_mapping(f)
    assert d["a"] == pytest.approx(1e-3) and isinstance(d["a"], float)
    assert d["b"] == pytest.approx(982.0) and d["c"] == pytest.approx(-250.0)
    assert d["d"] == 123  # decimal, not YAML 1.1 octal 83
    assert d["e"] == "yes" and d["f"] == "1:20" and d["g"] == "2024-05-02"
    assert d["h"] == float("inf") and d["i"] is True


def test_column_map_scale_in_exponent_form(tmp_path: Path) -> None:
    cmap = tmp_path / "map.yaml"
    cmap.write_text("time: {column: t_raw, scale: 1e-3}\nvx_mps: Ux\nmeasured: [vx_mps]\n")
    assert load_column_map(cmap).channels["t_s"].scale == pytest.approx(1e-3)


def test_thresholds_in_exponent_form(tmp_path: Path) -> None:
    from roadtruth.harness.jobs.check_rules import load_thresholds

    gate = tmp_path / "gate.yaml"
    gate.write_text("rules:\n  - {metric: rmse, max: 1e-6}\n  - {metric: coverage, min: 9.5e-1}\n")
    rules = load_thresholds(gate).rules
    assert rules[0].max == pytest.approx(1e-6) and rules[1].min == pytest.approx(0.95)


def test_duplicate_key_is_refused(tmp_path: Path) -> None:
    f = tmp_path / "d.yaml"
    f.write_text("a: 1\nb: 2\na: 3\n")
    with pytest.raises(InputError, match=r"d\.yaml: line 3: duplicate key 'a'"):
        load_mapping(f)


# ---- scenario files by path, and their folders in a run --------------------------------------------

def test_run_with_absolute_and_parent_relative_scenario_paths(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    for d in ("a", "b", "work/sub"):
        (tmp_path / d).mkdir(parents=True)
    for d in ("a", "b"):  # two different files with the same scenario name
        (tmp_path / d / "step_steer.yaml").write_text(step_steer_text().replace("duration_s: 5.0", "duration_s: 2.0"))
    cwd = tmp_path / "work" / "sub"
    monkeypatch.chdir(cwd)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    code = main(["run", "--scenario", f"{tmp_path / 'a' / 'step_steer.yaml'},../../b/step_steer.yaml",
                 "--observer", "kf_bicycle", "--no-render", "--out", "out"])
    err = capsys.readouterr().err
    assert code == 0, err
    out = cwd / "out"
    after = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if not p.is_relative_to(out))
    assert after == before  # nothing written beside --out or above it
    folders = sorted(p.name for p in out.iterdir() if p.is_dir())
    assert folders == ["step_steer", "step_steer-2"]
    for f in folders:
        assert (out / f / "truth.csv").is_file() and (out / f / "estimates.csv").is_file()
    metrics = pd.read_csv(out / "metrics.csv")
    assert sorted(metrics["scenario"].unique()) == folders
    run = json.loads((out / "run.json").read_text())
    assert [s["name"] for s in run["scenarios"]] == folders
    assert sorted(run["observer_runs"]) == folders  # statuses keyed like the folders the report reads
    assert main(["report", "out"]) == 0


@pytest.mark.parametrize(("name", "expected"), [
    ("step_steer", "step_steer"), ("../../etc", "_.._etc"), ("/abs/x.yaml", "_abs_x.yaml"),
    (".hidden", "hidden"), ("..", "scenario"), ("grip ∞ test", "grip_test"), ("a" * 300, "a" * 100),
])
def test_scenario_folder_names_are_sanitised(name: str, expected: str) -> None:
    assert scenario_folder_name(name) == expected


def test_new_scenario_folder_stays_inside_and_is_unique(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    labels = [new_scenario_folder(run, n)[0] for n in ("../../x", "../../x", "frames", "videos")]
    assert labels == ["_.._x", "_.._x-2", "frames-2", "videos-2"]
    assert sorted(p.name for p in run.iterdir()) == sorted(labels)
    assert list(tmp_path.iterdir()) == [run]


# ---- report on malformed or crafted run folders ------------------------------------------------------

def _edit_json(path: Path, edit) -> None:  # type: ignore[no-untyped-def]
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


def _rename_scenario(run: Path, old: str, new: str) -> None:
    _edit_json(run / "run.json", lambda d: d["scenarios"][0].update(name=new))
    m = pd.read_csv(run / "metrics.csv")
    m["scenario"] = m["scenario"].replace(old, new)
    m.to_csv(run / "metrics.csv", index=False)


def _outside(tmp_path: Path) -> Path:
    """A folder outside the run holding a readable, well-formed scenario's worth of files."""
    secret = tmp_path / "secret"
    src = make_run_folder(tmp_path / "donor") / "step_steer"
    shutil.copytree(src, secret)
    return secret


BROKEN = {
    "missing run.json": (lambda run, tmp: (run / "run.json").unlink(), "run.json"),
    "garbled run.json": (lambda run, tmp: (run / "run.json").write_text("{garbled"), "invalid JSON"),
    "run.json not UTF-8": (lambda run, tmp: (run / "run.json").write_bytes(b"\xff\xfe\x00{"), "UTF-8"),
    "run.json a list": (lambda run, tmp: (run / "run.json").write_text("[1, 2]"), "JSON object"),
    "scenarios not a list": (lambda run, tmp: _edit_json(run / "run.json", lambda d: d.update(scenarios=5)),
                             "scenarios"),
    "observer_runs not a mapping": (lambda run, tmp: _edit_json(run / "run.json",
                                                                lambda d: d.update(observer_runs=[1])),
                                    "observer_runs"),
    "render frames garbled": (lambda run, tmp: _edit_json(run / "run.json",
                                                          lambda d: d["scenarios"][0].update(render={"frames": [1]})),
                              "frames"),
    "versions not a mapping": (lambda run, tmp: _edit_json(run / "run.json", lambda d: d.update(versions=3)),
                               "versions"),
    "metrics.csv wrong columns": (lambda run, tmp: (run / "metrics.csv").write_text("a,b\n1,2\n"), "metrics.csv"),
    "metrics.csv non-numeric rmse": (
        lambda run, tmp: (run / "metrics.csv").write_text(
            "scenario,observer,state,rmse,status\nstep_steer,ekf,beta_rad,abc,ok\n"), "rmse"),
    "events.json not JSON": (lambda run, tmp: (run / "step_steer" / "events.json").write_text("nope"),
                             "events.json"),
    "events.json an object": (lambda run, tmp: (run / "step_steer" / "events.json").write_text('{"a": 1}'),
                              "events.json"),
    "scenario.json a list": (lambda run, tmp: (run / "step_steer" / "scenario.json").write_text("[1]"),
                             "scenario.json"),
    "truth.csv without t_s": (lambda run, tmp: (run / "step_steer" / "truth.csv").write_text("x\n1\n"), "t_s"),
    "truth.csv text in a number column": (
        lambda run, tmp: (run / "step_steer" / "truth.csv").write_text("t_s,beta_rad\n0,abc\n"), "beta_rad"),
    "estimates.csv binary": (lambda run, tmp: (run / "step_steer" / "estimates.csv").write_bytes(b"\xff\xfe\x00\x01"),
                             "estimates.csv"),
    # Crafted run folders: nothing outside the folder may be read or linked.
    "scenario name ../../etc": (lambda run, tmp: _rename_scenario(run, "step_steer", "../../etc"), "../../etc"),
    "absolute scenario name": (lambda run, tmp: _rename_scenario(run, "step_steer", str(_outside(tmp))),
                               "secret"),
    "absolute frame path": (lambda run, tmp: _edit_json(
        run / "run.json", lambda d: d["scenarios"][0]["render"]["frames"][0].update(file="/etc/hostname")),
        "outside the run folder"),
    "video path escaping": (lambda run, tmp: _edit_json(
        run / "run.json", lambda d: d["scenarios"][0]["render"].update(video="../../x.mp4")),
        "outside the run folder"),
    "symlinked truth.csv": (lambda run, tmp: ((run / "step_steer" / "truth.csv").unlink(),
                                              (run / "step_steer" / "truth.csv").symlink_to(
                                                  _outside(tmp) / "truth.csv")), "outside the run folder"),
    "symlinked scenario folder": (lambda run, tmp: (shutil.rmtree(run / "step_steer"),
                                                    (run / "step_steer").symlink_to(_outside(tmp))),
                                  "outside the run folder"),
    "symlinked frame": (lambda run, tmp: ((run / "frames" / "step_steer_00.png").unlink(),
                                          (run / "frames" / "step_steer_00.png").symlink_to("/etc/hostname")),
                        "outside the run folder"),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_report_on_malformed_run_folder(case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = make_run_folder(tmp_path / "run")
    assert main(["report", str(run)]) == 0  # the intact folder is fine
    capsys.readouterr()
    (run / "index.html").unlink()
    breaker, needle = BROKEN[case]
    breaker(run, tmp_path)
    before = sorted(os.listdir(run))
    bad_input(capsys, ["report", str(run)], needle)
    assert sorted(os.listdir(run)) == before  # no index.html, no temporary file


@pytest.mark.parametrize("kind", ["empty folder", "missing", "a file"])
def test_report_on_something_that_is_not_a_run(kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "x"
    if kind == "empty folder":
        target.mkdir()
    elif kind == "a file":
        target.write_text("hello")
    bad_input(capsys, ["report", str(target)], "x")
    assert not (target / "index.html").exists()


# ---- replay: infinite samples and time units -------------------------------------------------------

def test_replay_refuses_infinite_samples(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = _tiny_log(tmp_path / "log.csv")
    log.loc[57, "yaw_rate_radps"] = -np.inf
    log.loc[80, "yaw_rate_radps"] = np.inf
    log.to_csv(tmp_path / "log.csv", index=False)
    bad_input(capsys, ["replay", str(tmp_path / "log.csv"), "--vehicle", "sedan", "--out", str(tmp_path / "out")],
              "'yaw_rate_radps'", "row 58", "infinite", "2 such rows")
    assert not (tmp_path / "out").exists()


def test_replay_refuses_microseconds_read_as_seconds(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _tiny_log(tmp_path / "log.csv", t_scale=1e6, t_name="time")
    cmap = tmp_path / "map.yaml"
    cmap.write_text("time: {column: time}\nvx_mps: vx_mps\nyaw_rate_radps: yaw_rate_radps\ndelta_rad: delta_rad\n"
                    "measured: [vx_mps, yaw_rate_radps, delta_rad]\n")
    bad_input(capsys, ["replay", str(tmp_path / "log.csv"), "--vehicle", "sedan", "--columns", str(cmap),
                       "--out", str(tmp_path / "out")], "median step 10000 s", "implausible", "unit")
    assert not (tmp_path / "out").exists()


def test_replay_refuses_time_column_named_in_microseconds(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _tiny_log(tmp_path / "log.csv", t_scale=1e6, t_name="t_us")
    cmap = tmp_path / "map.yaml"
    cmap.write_text("time: t_us\nvx_mps: vx_mps\nmeasured: [vx_mps]\n")
    bad_input(capsys, ["replay", str(tmp_path / "log.csv"), "--vehicle", "sedan", "--columns", str(cmap),
                       "--out", str(tmp_path / "out")], "'t_us'", "unit: us")
    assert not (tmp_path / "out").exists()


def test_time_unit_given_in_the_map_is_honoured(tmp_path: Path) -> None:
    _tiny_log(tmp_path / "log.csv", t_scale=1e6, t_name="t_us")
    for spec in ("{column: t_us, unit: us}", "{column: t_us, scale: 1e-6}"):
        cmap = tmp_path / "map.yaml"
        cmap.write_text(f"time: {spec}\nvx_mps: vx_mps\nmeasured: [vx_mps]\n")
        frame = apply_map(read_log(tmp_path / "log.csv"), load_column_map(cmap), "log.csv")
        assert np.median(np.diff(frame["t_s"])) == pytest.approx(0.01, rel=1e-9)


def test_a_missing_log_is_one_line_even_with_observer_hosts_started(tmp_path: Path) -> None:
    """``replay`` starts its observer hosts before it reads the log, so that they get ready while it
    does: when the log is missing the command exits before they are ready, and a host that finds
    its caller gone ends quietly (a fresh process, as a user runs it: the hosts outlive main())."""
    import subprocess
    import sys

    env = {**os.environ, "MUJOCO_GL": "egl", "ROADTRUTH_CACHE": str(tmp_path / "cache")}
    done = subprocess.run([sys.executable, "-m", "roadtruth.harness.cli", "replay", str(tmp_path / "missing.csv.gz"),
                           "--vehicle", "ferrari_250lm", "--columns", "revs_250lm", "--out", str(tmp_path / "out")],
                          env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr[-2000:]
    assert done.stderr.count("\n") == 1 and "file not found" in done.stderr, done.stderr[-2000:]
    assert not (tmp_path / "out").exists()
