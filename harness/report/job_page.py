"""The page shell of the ``check``, ``compare`` and ``stress`` pages: the run report's look.

Each page is one self-contained HTML file: the run report's stylesheet
(``harness/report/assets/report.css``) and, when the page has charts, its script
(``report.js``, which draws every ``div.plot[data-spec]`` from a JSON ``<script>`` element) and the
plotly.js bundle, all inlined. No CDN, works offline. Small functions here build the pieces the pages
share (a verdict banner, a plain table, a plot placeholder, an observer's line style).
"""

from __future__ import annotations

import html
import json
import math
from collections.abc import Iterable, Sequence
from importlib.resources import files
from typing import Any

from roadtruth.harness import __version__

#: Rules the three pages add to report.css: a layout that also works 400 px wide (charts shrink to
#: the screen, wide tables scroll inside their box, the header wraps) and the verdict banner.
PAGE_CSS = """
.plots { grid-template-columns: repeat(auto-fill, minmax(min(560px, 100%), 1fr)); }
.plot { min-width: 0; }
header.top { flex-wrap: wrap; row-gap: 4px; }
header.top nav a:first-child { margin-left: 0; }
main p, main li { overflow-wrap: anywhere; }
table td, table th { overflow-wrap: normal; word-break: normal; }
.verdict { border-radius: 10px; padding: 14px 20px; margin: 18px 0 6px; border: 1px solid var(--line); }
.verdict .big { font-size: 30px; font-weight: 700; letter-spacing: .5px; }
.verdict.pass { background: var(--okbg); color: var(--ok); border-color: #a6dcb5; }
.verdict.fail { background: var(--badbg); color: var(--bad); border-color: #f3b4ab; }
.verdict.warn { background: #fff7e0; color: #7a5200; border-color: #f5d37a; }
.verdict p { margin: 4px 0 0; color: var(--ink); }
.better { color: var(--ok); font-weight: 600; } .worse { color: var(--bad); font-weight: 600; }
.na { color: var(--na); }
@media (max-width: 640px) {
  header.top { padding: 8px 12px; gap: 8px; } main { padding: 4px 10px 30px; }
  section.section { padding: 4px 12px 14px; }
  .table-wrap td, .table-wrap th { white-space: nowrap; }
  .plot { min-height: 300px; }
}
"""

#: Line dashes cycled after the colours, so that more observers than colours stay distinct.
DASHES: tuple[str, ...] = ("solid", "dash", "dot", "dashdot", "longdash", "longdashdot")


def _asset(name: str) -> str:
    return files("roadtruth.harness.report").joinpath("assets", name).read_text(encoding="utf-8")


def observer_line_styles(names: Iterable[str]) -> dict[str, dict[str, str]]:
    """Colour and dash of each observer, as on every other page (``roadtruth.harness.report.figures.observer_styles``).

    Falls back to the run report's palette in page order (then dashes) if that function is missing.
    """
    from roadtruth.harness.report import figures

    names = list(dict.fromkeys(names))
    styler = getattr(figures, "observer_styles", None)
    if styler is not None:
        return {n: {"color": str(st.colour), "dash": str(st.dash)} for n, st in styler(names).items()}
    palette = figures.PALETTE
    return {n: {"color": palette[i % len(palette)], "dash": DASHES[(i // len(palette)) % len(DASHES)]}
            for i, n in enumerate(names)}


def esc(v: Any) -> str:
    return html.escape(str(v), quote=True)


def table(head: Sequence[str], rows: Iterable[Sequence[str]], *, cls: str = "plain", raw: bool = False,
          numeric: Sequence[int] = ()) -> str:
    """A ``<table>`` in a horizontally scrolling box. Cells are escaped unless ``raw`` (pre-built HTML)."""
    num = set(numeric)
    th = "".join(f"<th>{esc(h)}</th>" for h in head)
    body = []
    for r in rows:
        cells = []
        for j, c in enumerate(r):
            text = c if raw else esc(c)
            cells.append(f"<td class='num'>{text}</td>" if j in num else f"<td>{text}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return (f"<div class='table-wrap'><table class='{cls}'><thead><tr>{th}</tr></thead>"
            f"<tbody>{''.join(body)}</tbody></table></div>")


def plot_div(spec_id: str, spec: dict[str, Any]) -> str:
    """A plot placeholder and its figure JSON (drawn by report.js when scrolled into view)."""
    data = json.dumps(spec, allow_nan=False, separators=(",", ":")).replace("</", "<\\/")
    return (f"<div class='plot' data-spec='{esc(spec_id)}'><div class='plot-placeholder'>chart</div></div>"
            f"<script type='application/json' id='{esc(spec_id)}'>{data}</script>")


def finite_or_none(x: float) -> float | None:
    """A JSON-safe number (NaN and ±inf become null, which plotly draws as a gap)."""
    return float(f"{x:.6g}") if isinstance(x, int | float) and math.isfinite(x) else None


def page(title: str, sections: Sequence[tuple[str, str, str]], *, top: str = "", charts: bool = False) -> str:
    """A whole page.

    Parameters
    ----------
    title : shown in the header bar and the browser tab.
    sections : (anchor, heading, inner HTML) in order; each becomes a card as in the run report.
    top : HTML put above the first section (the verdict banner).
    charts : inline report.js and plotly.js (only pages with ``plot_div`` need them).
    """
    nav = "".join(f"<a href='#{esc(a)}'>{esc(h)}</a>" for a, h, _ in sections)
    body = "".join(f"<section id='{esc(a)}' class='section'><h2>{esc(h)}</h2>{inner}</section>"
                   for a, h, inner in sections)
    scripts = ""
    if charts:
        from roadtruth.harness.report.builder import plotly_js

        scripts = f"<script>\n{plotly_js()}\n</script>\n<script>\n{_asset('report.js')}\n</script>"
    return f"""<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="generator" content="roadtruth {esc(__version__)}">
<title>{esc(title)}</title>
<script>
window.__roadtruthErrors = [];
window.addEventListener("error", function (e) {{ window.__roadtruthErrors.push(String(e.message || e)); }});
</script>
<style>
{_asset('report.css')}
{PAGE_CSS}
</style>
</head>
<body>
<header class="top"><div class="brand">road<b>truth</b></div><div class="title">{esc(title)}</div>
<nav>{nav}</nav></header>
<main>
{top}
{body}
</main>
<footer>Generated by roadtruth {esc(__version__)}. This page is self-contained and works offline.</footer>
{scripts}
<script>
(function () {{
  function measure() {{
    var b = document.body;
    b.dataset.scrollWidth = String(document.documentElement.scrollWidth);
    b.dataset.viewWidth = String(window.innerWidth);
    b.dataset.jsErrors = String(window.__roadtruthErrors.length);
  }}
  // Measured on load and again once the charts have been drawn (they can change the width).
  function later() {{ measure(); setTimeout(measure, 1500); }}
  if (document.readyState === "complete") later(); else window.addEventListener("load", later);
}})();
</script>
</body>
</html>
"""
