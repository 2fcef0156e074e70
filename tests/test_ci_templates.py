"""The shipped CI workflow files: what they declare, and that the shell commands they contain work.

The commands are taken from the parsed files (GitHub Actions ``run:`` steps and GitLab CI
``before_script``/``script``, with their ``env``/``variables``) and run with bash in a project written
by ``roadtruth init``, in a fresh virtual environment: they must install the project, pass the gate and
leave the JUnit file and the report folder where the publishing steps look for them.
"""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from importlib.resources import files
from pathlib import Path

import pytest
import yaml
from scaffold_env import fresh_venv, run_shell, venv_env

from roadtruth.harness.jobs.scaffold import init_project


def _template(name: str) -> dict:
    return yaml.safe_load((files("roadtruth.harness") / "ci_templates" / name).read_text())


def _github() -> dict:
    return _template("github-actions.yml")


def _gitlab_job() -> dict:
    return _template("gitlab-ci.yml")["roadtruth-check"]


def _github_run_steps() -> list[dict]:
    (job,) = _github()["jobs"].values()
    return [s for s in job["steps"] if "run" in s]


def test_github_workflow_publishes_junit_and_keeps_the_report() -> None:
    wf = _github()
    # PyYAML (YAML 1.1) reads the `on:` key as True; GitHub reads it as the trigger list.
    assert {"push", "pull_request"} <= set(wf.get("on") or wf.get(True))
    (job,) = wf["jobs"].values()
    uses = {s["uses"].split("@")[0]: s for s in job["steps"] if "uses" in s}
    assert {"actions/checkout", "actions/setup-python", "mikepenz/action-junit-report",
            "actions/upload-artifact"} <= set(uses)
    junit_step, artifact_step = uses["mikepenz/action-junit-report"], uses["actions/upload-artifact"]
    # Published and kept also when the gate failed: that is when they are needed.
    assert junit_step["if"] == "always()" and artifact_step["if"] == "always()"
    check = " ".join(s["run"] for s in _github_run_steps() if "roadtruth check" in s["run"])
    assert "--junit reports/junit.xml" in check and "--out reports/check" in check
    assert junit_step["with"]["report_paths"] == "reports/junit.xml"
    assert artifact_step["with"]["path"].rstrip("/") == "reports"


def test_gitlab_job_publishes_junit_and_keeps_the_report() -> None:
    job = _gitlab_job()
    assert any("roadtruth check" in c and "--junit reports/junit.xml" in c for c in job["script"])
    art = job["artifacts"]
    assert art["when"] == "always"
    assert art["reports"]["junit"] == "reports/junit.xml"
    assert [p.rstrip("/") for p in art["paths"]] == ["reports"]
    # Both files gate the same scenarios and observers.
    (gh_job,) = _github()["jobs"].values()
    assert job["variables"] == gh_job["env"]


def _run_all(commands: list[str], project: Path, env: dict[str, str]) -> None:
    for command in commands:
        res = run_shell(command, project, env)
        assert res.returncode == 0, f"{command!r} failed ({res.returncode}):\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}"


def _assert_gate_passed(project: Path) -> None:
    junit = project / "reports" / "junit.xml"
    assert junit.is_file()
    root = ET.parse(junit).getroot()
    assert root.tag == "testsuites"
    assert int(root.get("tests")) >= 7 and int(root.get("failures")) == 0
    suites = {s.get("name") for s in root.iter("testsuite")}
    assert {"step_steer", "brake_in_turn", "double_lane_change"} <= suites
    cases = [c for c in root.iter("testcase") if c.get("classname", "").endswith(".complementary_vy")]
    assert any("rmse" in c.get("name") for c in cases)
    assert (project / "reports" / "check" / "check.html").is_file()
    assert (project / "reports" / "check" / "metrics.csv").is_file()


@pytest.mark.slow
def test_workflow_commands_run_in_a_fresh_project(tmp_path_factory: pytest.TempPathFactory,
                                                   tmp_path: Path) -> None:
    venv = fresh_venv(tmp_path_factory)
    (job,) = _github()["jobs"].values()

    gh = tmp_path / "gh-project"
    init_project(gh)
    _run_all([s["run"] for s in _github_run_steps()], gh, venv_env(venv, job["env"]))
    _assert_gate_passed(gh)

    gl = tmp_path / "gl-project"
    shutil.copytree(gh, gl, ignore=shutil.ignore_patterns("reports", "build", "*.egg-info"))
    lab = _gitlab_job()
    _run_all(list(lab["before_script"]) + list(lab["script"]), gl, venv_env(venv, lab["variables"]))
    _assert_gate_passed(gl)
