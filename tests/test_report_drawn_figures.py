"""A run draws each scenario's figures where the scenario's files were written (in its worker with
``--jobs``), and the page only assembles them: the page uses a drawn figure only under the plan it
would draw it under itself, and is the same bytes as ``roadtruth report DIR``, which draws them all."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

import roadtruth.harness.report.sections.scenarios as scenarios_section
from roadtruth.harness.files.table_io import read_table, write_table
from roadtruth.harness.jobs.pipeline import run_suite
from roadtruth.harness.report import build_report
from roadtruth.harness.report.rundata import RunData
from roadtruth.harness.report.sections.scenarios import FigurePlan, drawn_figures, figure_plan

OBSERVERS = ["kf_bicycle", "lpv_wang_printed"]


def _tiny_scenario(folder: Path) -> Path:
    src = (Path(__file__).parents[1] / "harness" / "scenarios" / "step_steer.yaml").read_text()
    text = (src.replace("name: step_steer", "name: tiny_step").replace("duration_s: 5.0", "duration_s: 1.5")
            .replace("t_start_s: 1.0, amplitude", "t_start_s: 0.3, amplitude").replace("{t_s: 1.0,", "{t_s: 0.3,"))
    path = folder / "tiny_step.yaml"
    path.write_text(text)
    return path


@pytest.fixture
def drawing_calls(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The scenarios whose figures were drawn, in call order."""
    calls: list[str] = []
    real = scenarios_section.scenario_figures

    def counted(files: Any, plan: FigurePlan) -> list[dict[str, Any]]:
        calls.append(plan.name)
        return real(files, plan)

    monkeypatch.setattr(scenarios_section, "scenario_figures", counted)
    return calls


def test_the_run_draws_each_scenarios_figures_once_and_its_page_is_the_rebuilt_page(
        tmp_path: Path, drawing_calls: list[str]) -> None:
    out = run_suite(scenarios=[str(_tiny_scenario(tmp_path))], observers=OBSERVERS, seed=5,
                    out=tmp_path / "run", render=False, progress=False)
    assert drawing_calls == ["tiny_step"]  # drawn after the scenario's files, never again by the page
    page = (out / "index.html").read_bytes()
    assert page.count(b'id="fig-tiny_step-') >= 3  # the path and at least two states
    build_report(out)  # `roadtruth report DIR`: draws every figure itself
    assert drawing_calls == ["tiny_step", "tiny_step"]
    assert (out / "index.html").read_bytes() == page


def test_figures_drawn_under_another_plan_are_not_used(tmp_path: Path, drawing_calls: list[str]) -> None:
    out = run_suite(scenarios=[str(_tiny_scenario(tmp_path))], observers=OBSERVERS, seed=5,
                    out=tmp_path / "run", render=False, progress=False)
    page = (out / "index.html").read_bytes()
    run = RunData.load(out)
    rows = [r for r in run.records if r["scenario"] == "tiny_step"]
    truth = run.scenario("tiny_step")
    plan = figure_plan("tiny_step", rows, run.scenario_entry("tiny_step"), truth.events, truth.truth,
                       run.observer_names)
    bogus = [{"id": "fig-bogus", "spec": {"data": []}, "wide": False}]
    other = FigurePlan(name=plan.name, observers=plan.observers[::-1], styles=plan.styles[::-1], states=plan.states,
                       scored_until_s=plan.scored_until_s, unscored_reason=plan.unscored_reason)
    build_report(out, figures={other: bogus})  # the observers in another order: drawn again
    assert (out / "index.html").read_bytes() == page
    # The same observers coloured otherwise (drawn in a process that registered other observers,
    # whose styles follow the registry): drawn again, so lines and legends agree.
    recoloured = dataclasses.replace(plan, styles=plan.styles[1:] + plan.styles[:1])
    assert recoloured != plan
    build_report(out, figures={recoloured: bogus})
    assert (out / "index.html").read_bytes() == page
    build_report(out, figures={plan: bogus})  # the page's own plan: used as given
    assert b"fig-bogus" in (out / "index.html").read_bytes()


def test_a_drawn_plan_reads_the_scored_until_time_as_the_page_reads_it_back(tmp_path: Path) -> None:
    """Scoring stopped at a time that ``metrics.csv`` keeps to ten digits: the figures drawn from
    the full-precision rows are planned with the time the page will read, so they are used."""
    out = run_suite(scenarios=[str(_tiny_scenario(tmp_path))], observers=OBSERVERS, seed=5,
                    out=tmp_path / "run", render=False, progress=False)
    until = 1.23456789012345  # inside the 1.5 s scenario; "%.10g" keeps 1.234567890
    metrics = read_table(out / "metrics.csv")
    metrics["scored_until_s"] = until
    write_table(metrics, out, "metrics")
    entry = next(s for s in json.loads((out / "run.json").read_text())["scenarios"] if s["name"] == "tiny_step")
    drawn = drawn_figures(out, "tiny_step", pd.DataFrame(metrics), entry)
    run = RunData.load(out)
    files = run.scenario("tiny_step")
    page_plan = figure_plan("tiny_step", [r for r in run.records if r["scenario"] == "tiny_step"], entry,
                            files.events, files.truth, run.observer_names)
    assert page_plan.scored_until_s == pytest.approx(until, rel=1e-9) and page_plan.scored_until_s != until
    assert list(drawn) == [page_plan]


def test_a_serial_run_does_the_page_s_one_time_work_beside_its_scenarios(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """Without workers the page's one-time work (templates, plotly.js) runs in a thread beside the
    scenarios, and is finished before the page is assembled."""
    import threading

    from roadtruth.harness.report import builder

    events: list[tuple[str, str]] = []
    real_warm, real_build = builder.warm_up, scenarios_section.ScenariosSection.context

    def warm() -> None:
        events.append(("warm-up started", threading.current_thread().name))
        real_warm()
        events.append(("warm-up done", threading.current_thread().name))

    def context(self: Any, run: Any, page: Any) -> Any:
        events.append(("page", threading.current_thread().name))
        return real_build(self, run, page)

    monkeypatch.setattr(builder, "warm_up", warm)
    monkeypatch.setattr(scenarios_section.ScenariosSection, "context", context)
    run_suite(scenarios=[str(_tiny_scenario(tmp_path))], observers=OBSERVERS, seed=5, out=tmp_path / "run",
              render=False, progress=False)
    assert [e for e, _ in events] == ["warm-up started", "warm-up done", "page"]
    assert events[0][1] == events[1][1] == "roadtruth-page-warm-up"
    assert events[2][1] == threading.main_thread().name
