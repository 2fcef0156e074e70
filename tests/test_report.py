"""The report is rebuilt from a run folder's files alone, has every section, and is written atomically."""

from __future__ import annotations

import json
import re
from html.parser import HTMLParser
from pathlib import Path

import pandas as pd
import pytest
from synthetic_run import make_run_folder

from harness.errors import InputError
from harness.report import ReportBuilder, build_report
from harness.report.builder import default_sections
from harness.report.rundata import RunData


class Collect(HTMLParser):
    """Ids, tags with attributes, and script bodies of a page."""

    def __init__(self) -> None:
        super().__init__()
        self.ids: set[str] = set()
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.external: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        self.tags.append((tag, a))
        if a.get("id"):
            self.ids.add(a["id"])
        for key in ("src", "href"):
            v = a.get(key) or ""
            if re.match(r"^(https?:)?//", v):
                self.external.append(v)


@pytest.fixture()
def run_dir(tmp_path: Path) -> Path:
    return make_run_folder(tmp_path / "run")


def parse(path: Path) -> Collect:
    c = Collect()
    c.feed(path.read_text(encoding="utf-8"))
    return c


def test_every_section_is_present_and_self_contained(run_dir: Path):
    page = build_report(run_dir)
    assert page == run_dir / "index.html"
    doc = parse(page)
    for s in default_sections():
        assert s.anchor in doc.ids, s.anchor
    # Offline: nothing is fetched from the network (plotly.js is inlined once).
    assert doc.external == []
    text = page.read_text(encoding="utf-8")
    assert text.count("plotly.js v") == 1
    # One leaderboard per scored state; the failed observer is visible with its status.
    boards = [a for t, a in doc.tags if t == "table" and "leaderboard" in (a.get("class") or "")]
    assert {b["data-state"] for b in boards} == {"beta_rad", "yaw_rate_radps"}
    assert "error: LMI infeasible" in text
    assert "✔ certified" in text
    # Frames are referenced relatively and exist.
    imgs = [a["src"] for t, a in doc.tags if t == "img"]
    assert len(imgs) == 6 and all((run_dir / s).is_file() for s in imgs)
    # Every figure has a JSON spec that parses and names its traces.
    specs = re.findall(r'<script type="application/json" id="(fig-[^"]+)">(.*?)</script>', text, re.S)
    assert len(specs) == 2 * 3  # per scenario: path + beta + yaw rate
    for _, body in specs:
        spec = json.loads(body)
        assert spec["data"] and "layout" in spec
    # Events appear as vertical lines in the time plots.
    beta_spec = json.loads(dict(specs)["fig-step_steer-beta_rad"])
    assert [s["x0"] for s in beta_spec["layout"]["shapes"]] == [1.0, 2.5]


def test_rebuild_uses_saved_files_only_and_reflects_them(run_dir: Path):
    build_report(run_dir)
    m = pd.read_csv(run_dir / "metrics.csv")
    m.loc[m.observer == "ekf", "observer"] = "ekf_renamed"
    m.to_csv(run_dir / "metrics.csv", index=False)
    text = build_report(run_dir).read_text(encoding="utf-8")
    assert "ekf_renamed" in text


def test_rebuild_is_atomic(run_dir: Path, monkeypatch: pytest.MonkeyPatch):
    first = build_report(run_dir).read_text(encoding="utf-8")

    def boom(self: ReportBuilder) -> str:
        raise RuntimeError("section failed half-way")

    monkeypatch.setattr(ReportBuilder, "build", boom)
    with pytest.raises(RuntimeError):
        build_report(run_dir)
    assert (run_dir / "index.html").read_text(encoding="utf-8") == first
    assert not list(run_dir.glob(".index.html.*"))


def test_no_gl_is_said_and_the_rest_is_complete(run_dir: Path):
    run = json.loads((run_dir / "run.json").read_text())
    run["render"] = {"enabled": False, "reason": "offscreen OpenGL unavailable (MUJOCO_GL=egl): no EGL"}
    for s in run["scenarios"]:
        s["render"] = {"frames": [], "video": None, "reason": "offscreen OpenGL unavailable"}
    (run_dir / "run.json").write_text(json.dumps(run))
    text = build_report(run_dir).read_text(encoding="utf-8")
    assert "Frames and videos were not rendered: offscreen OpenGL unavailable (MUJOCO_GL=egl): no EGL" in text
    assert "<img" not in text
    doc = parse(run_dir / "index.html")
    assert {"leaderboard", "scenarios", "provenance"} <= doc.ids


def test_user_strings_are_escaped(run_dir: Path):
    run = json.loads((run_dir / "run.json").read_text())
    run["scenarios"][0]["description"] = "<script>alert(1)</script>"
    (run_dir / "run.json").write_text(json.dumps(run))
    text = build_report(run_dir).read_text(encoding="utf-8")
    assert "<script>alert(1)</script>" not in text
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in text


def test_not_a_run_folder_is_an_input_error(tmp_path: Path):
    with pytest.raises(InputError, match="does not exist"):
        build_report(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="metrics.csv"):
        build_report(tmp_path / "empty")


def test_run_data_orders_states_canonically(run_dir: Path):
    run = RunData.load(run_dir)
    assert run.states == ["beta_rad", "yaw_rate_radps"]
    assert run.scenario_names == ["step_steer", "ice_patch"]
