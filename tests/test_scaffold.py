"""``roadtruth init``: the starter project, its refusals, and the observer it ships.

The full gate of a fresh project (install, ``roadtruth check`` with the shipped thresholds, JUnit)
runs in tests/test_ci_templates.py through the project's own CI workflow commands.
"""

from __future__ import annotations

import importlib.util
import json
import math
from importlib.resources import files
from pathlib import Path

import numpy as np
import pytest
from scaffold_env import fresh_venv, run_shell, venv_env

from roadtruth.harness import cli
from roadtruth.harness.jobs.scaffold import project_names
from roadtruth.harness.truth.vehicle import load_vehicle


def test_init_writes_the_project(tmp_path: Path) -> None:
    target = tmp_path / "My Car-Observers"
    assert cli.main(["init", str(target)]) == 0
    dist, pkg = project_names(target)
    assert (dist, pkg) == ("my-car-observers", "my_car_observers")
    written = sorted(str(p.relative_to(target)) for p in target.rglob("*") if p.is_file())
    assert written == sorted([".github/workflows/roadtruth.yml", ".gitlab-ci.yml", "README.md", "pyproject.toml",
                              "thresholds.yaml", f"src/{pkg}/__init__.py", f"src/{pkg}/complementary_vy.py"])
    pyproject = (target / "pyproject.toml").read_text()
    assert f'complementary_vy = "{pkg}.complementary_vy:ComplementarySideslip"' in pyproject
    assert "$" not in pyproject and "$" not in (target / "README.md").read_text()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no partial folder left


def test_init_into_an_empty_folder(tmp_path: Path) -> None:
    (tmp_path / "proj").mkdir()
    assert cli.main(["init", str(tmp_path / "proj")]) == 0
    assert (tmp_path / "proj" / "thresholds.yaml").is_file()


@pytest.mark.parametrize("kind", ["non-empty folder", "file", "hidden file only"])
def test_init_never_replaces_a_users_files(tmp_path: Path, kind: str, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "proj"
    if kind == "file":
        target.write_text("my notes")
        before = {target: "my notes"}
    else:
        target.mkdir()
        mine = target / ("pyproject.toml" if kind == "non-empty folder" else ".env")
        mine.write_text("mine")
        before = {mine: "mine"}
    assert cli.main(["init", str(target)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("roadtruth: error: init:")
    for p, text in before.items():
        assert p.read_text() == text
    if target.is_dir():
        assert [p.name for p in target.iterdir()] == [next(iter(before)).name]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["proj"]


def _observer_class():
    spec = importlib.util.spec_from_file_location("scaffold_observer",
                                                  str(files("roadtruth.harness") / "scaffold_template" / "observer.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.ComplementarySideslip


def _steady_turn(obs, vx: float, r: float, bias: float, t_end: float, h: float = 0.001) -> np.ndarray:
    t = np.arange(0.0, t_end + h / 2, h)
    Y = np.column_stack([np.full_like(t, vx * r + bias), np.full_like(t, r), np.full_like(t, vx)])
    return obs.run(t, Y).x


def test_observer_converges_to_the_rear_axle_steady_state_with_its_time_constant() -> None:
    cls = _observer_class()
    car = load_vehicle("sedan")
    tau = 0.5
    obs = cls(car, tau_s=tau)
    vx, r = 20.0, 0.2
    vy_ss = r * (car.lr_m - car.mass_kg * car.lf_m * vx**2 / (car.cornering_stiffness_r_Npr * car.wheelbase_m))
    assert vy_ss < 0.0  # at 20 m/s the rear slides outwards: the speed term dominates l_r
    x = _steady_turn(obs, vx, r, 0.0, 3.0)
    # a_y = v_x r exactly: the kinematic term is zero and v_y follows vy_ss (1 - exp(-t / tau)).
    assert x[int(tau / 0.001), 0] == pytest.approx(vy_ss * (1.0 - math.exp(-1.0)), rel=1e-3)
    assert x[-1, 0] == pytest.approx(vy_ss * (1.0 - math.exp(-3.0 / tau)), rel=1e-3)
    assert x[-1, 1] == pytest.approx(math.atan2(x[-1, 0], vx), rel=1e-12)


def test_observer_error_from_an_accelerometer_bias_stays_tau_times_the_bias() -> None:
    cls = _observer_class()
    car = load_vehicle("sedan")
    vx, r, bias = 20.0, 0.0, 0.3
    for tau in (0.25, 1.0):
        x = _steady_turn(cls(car, tau_s=tau), vx, r, bias, 20.0 * tau)
        assert x[-1, 0] == pytest.approx(tau * bias, rel=2e-3)  # bounded, not growing as bias * t


@pytest.mark.slow
def test_fresh_venv_install_registers_the_observer(tmp_path_factory: pytest.TempPathFactory, tmp_path: Path) -> None:
    venv = fresh_venv(tmp_path_factory)
    env = venv_env(venv)
    project = tmp_path / "starter"
    res = run_shell(f"roadtruth init {project}", tmp_path, env)
    assert res.returncode == 0, res.stderr
    res = run_shell("python -m pip install .", project, env)
    assert res.returncode == 0, res.stderr[-2000:]
    res = run_shell("roadtruth observers --json", project, env)
    assert res.returncode == 0, res.stderr[-2000:]
    listed = {o["name"]: o for o in json.loads(res.stdout)}
    assert listed["complementary_vy"]["states"] == ["vy_mps", "beta_rad"]
