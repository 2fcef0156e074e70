"""``compare.html``: run B against run A in the run report's look.

Top: a warning when the runs were made with different settings, then counts (worse, better, same,
one-sided, not comparable). Then the largest regressions and improvements, what only one run has,
and every row (values in display units: angles in degrees, forces in kN; the CSV stays SI).
"""

from __future__ import annotations

from roadtruth.harness.jobs.compare import (
    NOT_COMPARABLE,
    ONLY_A,
    ONLY_B,
    REL_TOL,
    TERMINAL_HEAD,
    Comparison,
    _row_cells,
    display_value,
)
from roadtruth.harness.report.job_page import esc, page, table

#: Rows of the regression and improvement tables on the page.
PAGE_ROWS = 25


def _change_table(rows: list[dict], cls: str) -> str:
    body = []
    for d in rows:
        cells = [esc(c) for c in _row_cells(d)]
        cells[-1] = f"<span class='{cls}'>{cells[-1]}</span>"
        body.append(cells)
    return table(TERMINAL_HEAD, body, raw=True, numeric=(4, 5))


def compare_page(c: Comparison) -> str:
    """The whole page of one comparison."""
    counts = c.counts()
    if c.settings:
        items = "".join(f"<li><b>{esc(d.name)}</b>: {esc(d.a)} (A) vs {esc(d.b)} (B)</li>" for d in c.settings)
        top = ("<div class='verdict warn' id='settings-warning'><div class='big'>Different settings</div>"
               "<p>The two runs were not made with the same settings, so the deltas below mix changes of the "
               f"setup with changes of the code:</p><ul>{items}</ul></div>")
    else:
        top = ("<div class='verdict pass' id='settings-same'><div class='big'>Same settings</div><p>Vehicle, "
               "friction, sensors, faults, seeds and the roadtruth and MuJoCo versions match: the deltas are "
               "changes of the observers or the code.</p></div>")
    cards = [("worse", counts["worse"], "bad" if counts["worse"] else ""),
             ("better", counts["better"], "good" if counts["better"] else ""),
             ("same", counts["same"], ""), (ONLY_A, counts[ONLY_A], ""), (ONLY_B, counts[ONLY_B], ""),
             (NOT_COMPARABLE, counts[NOT_COMPARABLE], "")]
    top += "<div class='cards'>" + "".join(
        f"<div class='card {cls}'><div class='big'>{n}</div><div class='muted'>{esc(label)}</div></div>"
        for label, n, cls in cards) + "</div>"
    top += (f"<p class='muted small'>A = <code>{esc(c.dir_a)}</code>, B = <code>{esc(c.dir_b)}</code>. A row is "
            f"better or worse when its RMSE changed by more than {REL_TOL:.0%} or its status changed (an observer "
            "that stops being ok is worse). Rows present in one run only, or where the observer does not apply "
            "on one side, are listed apart and counted as neither.</p>")

    sections: list[tuple[str, str, str]] = []
    reg, imp = c.regressions(), c.improvements()
    for anchor, title, rows, cls in (("regressions", "Largest regressions", reg, "bad-text"),
                                     ("improvements", "Largest improvements", imp, "")):
        if rows.empty:
            inner = "<p class='muted'>None.</p>"
        else:
            shown = rows.head(PAGE_ROWS).to_dict("records")
            more = f"<p class='muted small'>{len(rows) - PAGE_ROWS} more in the full table.</p>" \
                if len(rows) > PAGE_ROWS else ""
            inner = _change_table(shown, cls) + more
        sections.append((anchor, f"{title} ({len(rows)})", inner))

    one_sided = []
    for side, only in (("A", c.only_a), ("B", c.only_b)):
        for kind in ("scenarios", "observers", "rows"):
            for item in only.get(kind, ()):
                one_sided.append((f"only in {side}", kind[:-1], item))
    sections.append(("one-sided", f"Only in one run ({len(one_sided)})",
                     table(("where", "kind", "name"), one_sided) if one_sided
                     else "<p class='muted'>Both runs have the same scenarios, observers and states.</p>"))
    if c.settings:
        sections.append(("settings", "Settings that differ",
                         table(("setting", "A", "B"), [(d.name, d.a, d.b) for d in c.settings])))

    all_rows = []
    for d in c.table.to_dict("records"):
        s = str(d["state"])
        verdict = str(d["verdict"])
        cls = {"worse": "worse", "better": "better"}.get(verdict, "na" if verdict not in ("same",) else "")
        all_rows.append([esc(d["scenario"]), esc(d["observer"]), f"<code>{esc(s or '-')}</code>",
                         esc(d["status_a"]), esc(d["status_b"]), esc(display_value(s, d["rmse_a"])),
                         esc(display_value(s, d["rmse_b"])), esc(_row_cells(d)[3]),
                         f"<span class='{cls}'>{esc(verdict)}</span>" if cls else esc(verdict)])
    sections.append(("all", f"All rows ({len(all_rows)})",
                     "<details><summary>show every row</summary>"
                     + table(("scenario", "observer", "state", "status A", "status B", "RMSE A", "RMSE B", "unit",
                              "verdict"), all_rows, raw=True, numeric=(5, 6)) + "</details>"
                     + "<p class='muted small'>Every metric of both runs, in SI units: <code>compare.csv</code>.</p>"))
    return page("roadtruth compare — B against A", sections, top=top)
