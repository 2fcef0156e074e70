"""The command line: listings, exit codes and one-line errors (the contract's outside promises)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from harness.cli import main


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "harness.cli", *args], capture_output=True, text=True,
                          timeout=300)


def test_help_for_every_command() -> None:
    for cmd in ("run", "simulate", "scenarios", "observers", "vehicles", "report", "compare", "replay", "check",
                "stress"):
        with pytest.raises(SystemExit) as ex:
            main([cmd, "--help"])
        assert ex.value.code == 0


def test_vehicles_json_lists_every_set_with_bicycle_parameters(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["vehicles", "--json"]) == 0
    sets = json.loads(capsys.readouterr().out)
    names = {s["name"] for s in sets}
    assert {"sedan", "wang2014", "yacine2016", "carla_bessafa", "ferrari_250lm"} <= names
    for s in sets:
        for key in ("mass_kg", "yaw_inertia_kgm2", "lf_m", "lr_m"):
            assert s[key] > 0
        assert s["derived"]["cornering_stiffness_f_Npr"] > 0


def test_usage_error_is_one_line_exit_2() -> None:
    res = run_cli("run", "--jobs", "0")
    assert res.returncode == 2
    assert res.stderr.count("\n") == 1 and "--jobs" in res.stderr


def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path: Path) -> None:
    out = tmp_path / "out"
    res = run_cli("simulate", "no_such_scenario", "--out", str(out))
    assert res.returncode == 2, res.stderr
    assert res.stderr.count("\n") == 1 and "no_such_scenario" in res.stderr
    assert "Traceback" not in res.stderr
    assert not out.exists()
    assert [p for p in tmp_path.iterdir()] == []
