"""Assemble the report from sections and write ``index.html`` (self-contained: CSS, JS and plotly.js
inlined; frames and the video sit next to it in ``frames/`` and ``videos/``)."""

from __future__ import annotations

import os
import re
import tempfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import cache
from importlib.resources import files
from pathlib import Path
from typing import Any

import jinja2
import orjson
from markupsafe import Markup

from roadtruth.harness import __version__
from roadtruth.harness.report.figures import LineStyle, observer_style, observer_styles, swatch_svg
from roadtruth.harness.report.rundata import RunData
from roadtruth.harness.report.sections.base import Section
from roadtruth.harness.report.sections.leaderboard import LeaderboardSection
from roadtruth.harness.report.sections.observers import ObserversSection
from roadtruth.harness.report.sections.provenance import ProvenanceSection
from roadtruth.harness.report.sections.scenarios import ScenariosSection
from roadtruth.harness.report.sections.summary import SummarySection
from roadtruth.harness.report.verdicts import (
    DESIGN_ORDER,
    NOT_APPLICABLE,
    design_class,
    design_label,
    status_kind,
)


@dataclass(frozen=True)
class Page:
    """Page-wide values shared by the sections."""

    #: observer -> line style (colour × dash), the same on every page (``observer_styles``).
    styles: dict[str, LineStyle] = field(default_factory=dict)
    #: observer -> design status ("certified", "rejected", "infeasible", "solver_failed",
    #: "not_applicable", "not_evaluated"), from run.json's observer runs or, failing that, the
    #: ``certified`` column of the rows of runs that got as far as a design.
    designs: dict[str, str] = field(default_factory=dict)
    #: scenario figures drawn before the page was built, by the plan they were drawn under
    #: (``roadtruth.harness.report.sections.scenarios.drawn_figures``); a scenario whose plan on
    #: this page differs, or that is missing, is drawn by the page itself.
    figures: Mapping[Any, list[dict[str, Any]]] = field(default_factory=dict)

    @property
    def colours(self) -> dict[str, str]:
        return {k: v.colour for k, v in self.styles.items()}

    def swatch(self, observer: str) -> Markup:
        """Inline SVG sample of the observer's line (colour and dash), for tables."""
        return Markup(swatch_svg(self.styles.get(observer) or observer_style(observer)))


def design_statuses(run: RunData) -> dict[str, str]:
    """One design status per observer: the worst seen over the scenarios where it was designed.

    A skipped run never designed anything: it says nothing about certification (an observer skipped
    everywhere is "not_evaluated", not "rejected").
    """
    from roadtruth.harness.report.sections.leaderboard import certification_of

    order = list(DESIGN_ORDER)
    seen: dict[str, list[str]] = {}
    for per_obs in run.run.get("observer_runs", {}).values():
        if not isinstance(per_obs, dict):
            continue
        for obs, r in per_obs.items():
            if isinstance(r, dict) and r.get("design_status") in order:
                seen.setdefault(obs, []).append(r["design_status"])
    out = {}
    applicable: dict[str, list[dict]] = {}  # observer -> its rows that are not "not applicable"
    for r in run.records:
        if status_kind(r["status"]) != NOT_APPLICABLE:
            applicable.setdefault(str(r["observer"]), []).append(r)
    for obs in run.observer_names:
        if obs in seen:
            out[obs] = min(seen[obs], key=order.index)
            continue
        rows = applicable.get(obs, [])
        c = certification_of(rows)
        if not rows:
            out[obs] = "not_evaluated"
        else:
            out[obs] = {"certified": "certified", "not certified": "rejected"}.get(c, "not_applicable")
    return out


def default_sections() -> list[Section]:
    return [SummarySection(), LeaderboardSection(), ObserversSection(), ScenariosSection(), ProvenanceSection()]


@cache
def _environment() -> jinja2.Environment:
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("roadtruth.harness.report", "templates"),
        autoescape=jinja2.select_autoescape(["html"], default=True),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    # ``tojson`` through orjson: the figure data are most of the page, and the standard library's
    # encoder took longer to write them than the figures took to make (same JSON, except that a
    # non-finite float is null instead of the invalid ``NaN``).
    env.policies["json.dumps_function"] = json_text
    env.policies["json.dumps_kwargs"] = {}
    env.filters["num"] = _format_number
    env.filters["design_label"] = design_label
    env.filters["design_class"] = design_class
    return env


def json_text(data: object) -> str:
    """``data`` as compact JSON text with sorted keys (numpy arrays and numbers included)."""
    return orjson.dumps(data, option=orjson.OPT_SORT_KEYS | orjson.OPT_NON_STR_KEYS
                        | orjson.OPT_SERIALIZE_NUMPY).decode("utf-8")


def _format_number(v: object, digits: int = 3) -> str:
    if v is None:
        return "—"
    try:
        f = float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return str(v)
    if f != f:
        return "—"
    return f"{f:.{digits}g}"


def _asset(name: str) -> str:
    return files("roadtruth.harness.report").joinpath("assets", name).read_text(encoding="utf-8")


@cache
def plotly_js() -> str:
    """plotly.js from the installed plotly package, made safe to inline in a <script> element."""
    import plotly

    text = (Path(plotly.__file__).parent / "package_data" / "plotly.min.js").read_text(encoding="utf-8")
    return re.sub(r"</(script)", r"<\\/\1", text, flags=re.IGNORECASE)


class ReportBuilder:
    """Render sections into one page."""

    def __init__(self, run: RunData, sections: list[Section] | None = None,
                 figures: Mapping[Any, list[dict[str, Any]]] | None = None) -> None:
        self.run = run
        self.sections = list(sections) if sections is not None else default_sections()
        self.figures = dict(figures or {})

    def add_section(self, section: Section) -> None:
        self.sections.append(section)

    def build(self) -> str:
        """The page as one string."""
        return "".join(self.pieces())

    def pieces(self) -> Iterator[str]:
        """The page in consecutive pieces (the sections are rendered first, then the layout streams
        them out): ``build_report`` writes them as they come instead of joining the whole page
        first, which took about three page sizes of memory (the text, 2 bytes a character once
        it holds a "β", and its UTF-8 copy) at what was the report's memory peak on a long log."""
        env = _environment()
        page = Page(styles=observer_styles(self.run.observer_names), designs=design_statuses(self.run),
                    figures=self.figures)
        parts = []
        for s in self.sections:
            ctx = s.context(self.run, page)
            parts.append({"title": s.title, "anchor": s.anchor,
                          "html": env.get_template(s.template).render(section=s, **ctx)})
        r = self.run.run
        what = r.get("suite") or ", ".join(self.run.scenario_names[:4]) + (" …" if len(self.run.scenario_names) > 4 else "")
        title = f"roadtruth {r.get('command', 'run')} — {what}"
        yield from env.get_template("layout.html").generate(
            title=title, sections=parts, css=_asset("report.css"), js=_asset("report.js"),
            plotly_js=plotly_js(), version=self.run.run.get("versions", {}).get("roadtruth", __version__),
        )


def render_report(run_dir: Path, sections: list[Section] | None = None) -> str:
    """The report page of a run folder as a string."""
    return ReportBuilder(RunData.load(Path(run_dir)), sections).build()


def warm_up() -> None:
    """Do the page's one-time work now (plotly.js read, every template compiled): a process that
    waits anyway (its workers' server is still starting) takes it off the end of the run."""
    plotly_js()
    env = _environment()
    for name in env.list_templates():
        env.get_template(name)


def build_report(run_dir: Path, figures: Mapping[Any, list[dict[str, Any]]] | None = None) -> Path:
    """Rebuild ``run_dir/index.html`` from the saved CSV/JSON files alone (no re-simulation).

    ``figures``: scenario figures already drawn from these files (``drawn_figures``), used where
    the page's plan for them is the same; the page is the same bytes with or without them.

    The page is written to a temporary file in the same folder and renamed over the old one, so a
    reader never sees a half-written page. Raises ``RunFolderError`` (an InputError) if ``run_dir``
    is not a run folder.
    """
    run_dir = Path(run_dir)
    pieces = ReportBuilder(RunData.load(run_dir), figures=figures).pieces()
    first = next(pieces, "")  # the sections are rendered before a temporary file is made
    fd, tmp = tempfile.mkstemp(prefix=".index.html.", suffix=".partial", dir=run_dir)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(first)
            for piece in pieces:
                f.write(piece)
        os.chmod(tmp, 0o644)
        os.replace(tmp, run_dir / "index.html")
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return run_dir / "index.html"
