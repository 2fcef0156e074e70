"""Same seed, same bytes: two identical runs differ only in ``timings.json`` and the ``us_per_step``
column of ``metrics.csv``; and ``run.json`` records roadtruth's own git revision, never that of the
repository the user happens to run it from."""

from __future__ import annotations

import csv
import importlib.util
import io
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import roadtruth.harness as harness
from roadtruth.harness.jobs.pipeline import run_suite
from roadtruth.harness.report import build_report
from roadtruth.harness.report.rundata import git_revision

#: The only cells that measure the machine rather than the result.
TIMING_FILE, TIMING_COLUMN = "timings.json", "us_per_step"
OBSERVERS = ["kf_bicycle", "lpv_wang_printed"]  # a filter and a (cached) LMI design


def _git(cwd: Path, *args: str) -> str:
    return subprocess.run(["git", "-c", "user.email=t@example.org", "-c", "user.name=t", *args], cwd=cwd,
                          check=True, capture_output=True, text=True).stdout.strip()


@pytest.fixture
def foreign_repo(tmp_path: Path) -> Path:
    """Another project's git repository (the user's thesis, say), with one commit."""
    repo = tmp_path / "thesis"
    repo.mkdir()
    _git(repo, "init", "-q")
    (repo / "pyproject.toml").write_text('[project]\nname = "thesis"\nversion = "1"\n')
    _git(repo, "add", "pyproject.toml")
    _git(repo, "commit", "-q", "-m", "start")
    return repo


def _tiny_scenario(folder: Path) -> Path:
    src = (Path(__file__).parents[1] / "harness" / "scenarios" / "step_steer.yaml").read_text()
    text = (src.replace("name: step_steer", "name: tiny_step").replace("duration_s: 5.0", "duration_s: 1.5")
            .replace("t_start_s: 1.0, amplitude", "t_start_s: 0.3, amplitude").replace("{t_s: 1.0,", "{t_s: 0.3,"))
    path = folder / "tiny_step.yaml"
    path.write_text(text)
    return path


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _without_column(csv_bytes: bytes, column: str) -> list[list[str]]:
    rows = list(csv.reader(io.StringIO(csv_bytes.decode())))
    i = rows[0].index(column)
    return [r[:i] + r[i + 1:] for r in rows]


def test_two_identical_runs_have_the_same_bytes_but_for_the_timings(tmp_path: Path, foreign_repo: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    scenario = _tiny_scenario(tmp_path)
    monkeypatch.chdir(foreign_repo)  # also: the revision recorded is roadtruth's, not the cwd's
    runs = [run_suite(scenarios=[str(scenario)], observers=OBSERVERS, seed=5, out=tmp_path / name,
                      render=False, progress=False) for name in ("a", "b")]
    a, b = (_files(r) for r in runs)
    assert a.keys() == b.keys()
    assert {"run.json", "index.html", "metrics.csv", TIMING_FILE, "tiny_step/truth.csv"} <= a.keys()
    differing = sorted(k for k in a if a[k] != b[k])
    assert set(differing) <= {TIMING_FILE, "metrics.csv"}, differing
    assert _without_column(a["metrics.csv"], TIMING_COLUMN) == _without_column(b["metrics.csv"], TIMING_COLUMN)
    assert b"wall time" not in a["index.html"]
    timings = json.loads(a[TIMING_FILE])
    assert timings["wall_s"] > 0 and set(timings["us_per_step"]["tiny_step"]) == set(OBSERVERS)
    run = json.loads(a["run.json"])
    assert run["git_revision"] == git_revision()
    assert run["git_revision"] is None or not run["git_revision"].startswith(_git(foreign_repo, "rev-parse", "HEAD"))
    # `roadtruth report DIR` rebuilds exactly the page the run wrote
    build_report(runs[0])
    assert (runs[0] / "index.html").read_bytes() == a["index.html"]


def test_git_revision_is_roadtruths_own_from_any_working_folder(foreign_repo: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    source = Path(harness.__file__).resolve().parents[1]
    if not (source / ".git").exists() or shutil.which("git") is None:
        pytest.skip("roadtruth is not run from a git checkout here")
    own = _git(source, "rev-parse", "HEAD")
    monkeypatch.chdir(foreign_repo)
    monkeypatch.setenv("GIT_DIR", str(foreign_repo / ".git"))  # a caller's git environment is not consulted
    rev = git_revision()
    assert rev is not None and rev.split("+")[0] == own


def test_an_installed_copy_inside_another_repository_reports_no_revision(foreign_repo: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """roadtruth installed into a virtual environment inside the user's repository: that repository's
    revision is not roadtruth's, so none is recorded."""
    site = foreign_repo / ".venv" / "lib" / "site-packages" / "harness" / "report"
    site.mkdir(parents=True)
    copy = site / "rundata.py"
    shutil.copy(Path(harness.__file__).parent / "report" / "rundata.py", copy)
    spec = importlib.util.spec_from_file_location("rundata_installed_copy", copy)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    assert module.git_revision() is None
