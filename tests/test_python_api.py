"""docs/PYTHON.md: every Python example on the page runs, in page order, in one namespace."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

import roadtruth as rt

PAGE = Path(__file__).resolve().parents[1] / "docs" / "PYTHON.md"


def _examples() -> list[str]:
    return re.findall(r"```python\n(.*?)```", PAGE.read_text(encoding="utf-8"), flags=re.S)


def test_page_has_examples_for_every_stage() -> None:
    code = "\n".join(_examples())
    for name in ("rt.simulate", "rt.emulate", "rt.run_observers", "rt.score", "rt.register", "rt.run_suite"):
        assert name in code


def test_examples_run_in_order(tmp_path: Path) -> None:
    # As a user runs them: one script, its own process (a registered class lives in ``__main__``).
    checks = """
assert runs["yaw_rate_beta_example"].status == "ok", runs["yaw_rate_beta_example"].status
assert set(beta.index) == {"kf_bicycle", "kinematic_vy"}
assert beta.loc["kf_bicycle", "rmse"] < beta.loc["kinematic_vy", "rmse"]
assert (folder / "metrics.csv").is_file() and (folder / "run.json").is_file()
print("PAGE-OK")
"""
    script = tmp_path / "page.py"
    script.write_text("\n".join(_examples()) + checks, encoding="utf-8")
    res = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.rstrip().endswith("PAGE-OK")


def test_public_names_resolve_and_import_is_light() -> None:
    for name in rt.__all__:
        assert getattr(rt, name) is not None
    with pytest.raises(AttributeError):
        rt.no_such_name  # noqa: B018
    code = "import sys, roadtruth; print(sorted(m for m in ('mujoco', 'numba', 'cvxpy', 'pandas') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_wheel_installs_one_top_level_name() -> None:
    text = (PAGE.parents[1] / "pyproject.toml").read_text(encoding="utf-8")
    packages = re.search(r"^packages = \[(.*?)\]", text, flags=re.S | re.M).group(1)
    names = re.findall(r'"([\w.]+)"', packages)
    assert names and {n.split(".")[0] for n in names} == {"roadtruth"}
