"""Every bad input of the ground-truth command: exit 2, one line naming the problem, nothing written."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from roadtruth.harness.truth.scenario import scenarios_dir
from roadtruth.harness.truth.vehicle import vehicles_dir


def roadtruth(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "roadtruth.harness.cli", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=600)


def _edited(src: Path, dst: Path, old: str, new: str) -> Path:
    text = src.read_text()
    assert old in text, f"{old!r} not in {src}"
    dst.write_text(text.replace(old, new, 1))
    return dst


CASES = {
    "unknown scenario": (["simulate", "no_such_scenario"], "no_such_scenario"),
    "unknown vehicle": (["simulate", "step_steer", "--vehicle", "batmobile"], "batmobile"),
    "mu zero": (["simulate", "step_steer", "--friction", "0"], "friction"),
    "mu negative": (["simulate", "step_steer", "--friction", "-0.3"], "friction"),
    "mu unknown surface": (["simulate", "step_steer", "--friction", "lava"], "lava"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_command_line(case: str, tmp_path: Path) -> None:
    args, needle = CASES[case]
    res = roadtruth(*args, "--out", "out", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert res.stderr.count("\n") == 1 and needle in res.stderr and "Traceback" not in res.stderr
    assert list(tmp_path.iterdir()) == []


def test_negative_mass_vehicle_file(tmp_path: Path) -> None:
    bad = _edited(vehicles_dir() / "sedan.yaml", tmp_path / "heavy.yaml", "mass_kg: 1500.0", "mass_kg: -1500.0")
    res = roadtruth("simulate", "step_steer", "--vehicle", str(bad), "--out", "out", cwd=tmp_path)
    assert res.returncode == 2
    assert "heavy.yaml" in res.stderr and "mass_kg" in res.stderr and "-1500" in res.stderr
    assert not (tmp_path / "out").exists()


def test_start_speed_below_tire_model_support(tmp_path: Path) -> None:
    src = scenarios_dir() / "step_steer.yaml"
    line = next(ln for ln in src.read_text().splitlines() if ln.startswith("initial_speed_mps:"))
    bad = _edited(src, tmp_path / "step_steer.yaml", line, "initial_speed_mps: 1.0")
    res = roadtruth("simulate", str(bad), "--out", "out", cwd=tmp_path)
    assert res.returncode == 2
    assert "initial_speed_mps" in res.stderr and "tire model" in res.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("name", "text", "needle"), [
    ("broken", "name: [broken\n", "malformed YAML"),
    ("listy", "- just\n- a list\n", "mapping"),
])
def test_malformed_scenario_file(tmp_path: Path, name: str, text: str, needle: str) -> None:
    (tmp_path / f"{name}.yaml").write_text(text)
    res = roadtruth("simulate", f"{name}.yaml", "--out", "out", cwd=tmp_path)
    assert res.returncode == 2
    assert f"{name}.yaml" in res.stderr and needle in res.stderr
    assert not (tmp_path / "out").exists()


def test_simulate_writes_truth_and_measurements(tmp_path: Path) -> None:
    res = roadtruth("simulate", "step_steer", "--log-rate", "50", "--out", "out", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    import pandas as pd

    truth = pd.read_csv(tmp_path / "out" / "truth.csv")
    meas = pd.read_csv(tmp_path / "out" / "measurements.csv")
    assert truth["t_s"].diff().dropna().round(6).eq(0.02).all()
    for col in ("beta_rad", "yaw_rate_radps", "fz_fl_N", "mu_rr", "alpha_f_rad", "fy_r_N", "y_lane_m"):
        assert truth[col].notna().all(), col
    assert {"yaw_rate_radps", "imu_valid", "delta_rad", "steering_valid"} <= set(meas.columns)
