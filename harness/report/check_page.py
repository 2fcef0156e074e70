"""``check.html``: the CI gate's verdict first (PASS / FAIL, how many checks and rules, which failed
and why), then every failed check, the rules with their counts, the skipped checks with their reason,
and the inputs. Written next to ``check.csv`` by :func:`roadtruth.harness.jobs.check.run_check`."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from roadtruth.harness.jobs.check_rules import DEFAULT_THRESHOLDS
from roadtruth.harness.report.job_page import esc, page, table

if TYPE_CHECKING:
    from roadtruth.harness.jobs.check import CheckResult

#: Failed checks listed in the verdict banner itself (the full list follows in its own section).
BANNER_ROWS = 8


def _thresholds_label(path: Path) -> str:
    return "the shipped CI thresholds (ci.yaml)" if Path(path).resolve() == DEFAULT_THRESHOLDS else str(path)


def check_page(result: CheckResult, *, thresholds: Path, baseline: Path | None, run_report: str | None) -> str:
    """The HTML page of one ``check`` run.

    Parameters
    ----------
    result : the judged outcomes.
    thresholds : the thresholds file used.
    baseline : the baseline metrics file, or None (no regression checks).
    run_report : relative link to the run report (``index.html``) when it exists.
    """
    from roadtruth.harness.jobs.check import _fmt, reason_of

    outcomes = list(result.outcomes)
    failed = [o for o in outcomes if o.verdict == "fail"]
    skipped = [o for o in outcomes if o.verdict == "skip"]
    word, cls = ("PASS", "pass") if result.passed else ("FAIL", "fail")
    bad_rules = result.failed_rules
    lines = [f"{result.n_failed} of {result.n_checks} checks failed; {len(bad_rules)} of {result.n_rules} rules "
             f"broken; {len(skipped)} checks skipped (not applicable or not selected)."]
    if failed:
        items = "".join(f"<li><b>{esc(o.source)}</b> {esc(o.scenario or '')} {esc(o.observer or '')} "
                        f"<code>{esc(o.state or '-')}</code>: {esc(reason_of(o))}</li>" for o in failed[:BANNER_ROWS])
        more = (f"<li><a href='#failed'>… and {len(failed) - BANNER_ROWS} more</a></li>"
                if len(failed) > BANNER_ROWS else "")
        lines.append(f"<ul>{items}{more}</ul>")
    else:
        lines.append("<p>Every judged check passed.</p>")
    top = (f"<div class='verdict {cls}' id='verdict'><div class='big'>{word}</div>"
           f"<p>{lines[0]}</p>{''.join(lines[1:])}</div>")

    sections: list[tuple[str, str, str]] = []
    if failed:
        rows = [(o.kind, o.scenario or "-", o.observer or "-", o.state or "-", o.check, _fmt(o.value), o.source,
                 reason_of(o)) for o in failed]
        sections.append(("failed", f"Failed checks ({len(failed)})",
                         table(("kind", "scenario", "observer", "state", "check", "value", "rule", "reason"), rows)))

    per_rule: dict[str, dict[str, int | str]] = {}
    for o in outcomes:
        r = per_rule.setdefault(o.source, {"check": o.check if o.kind != "regression" else "no worse than baseline",
                                           "pass": 0, "fail": 0, "skip": 0})
        r[o.verdict] = int(r[o.verdict]) + 1
    rule_rows = []
    for source, r in per_rule.items():
        state = "<span class='pill fail'>broken</span>" if r["fail"] else \
            "<span class='pill ok'>held</span>" if r["pass"] else "<span class='pill na'>not judged</span>"
        rule_rows.append((esc(source), esc(r["check"]), str(r["pass"]), str(r["fail"]), str(r["skip"]), state))
    sections.append(("rules", f"Rules ({len(per_rule)})",
                     "<p class='muted'>Each rule of the thresholds file, the baseline regression and the "
                     "simulation status, with how many checks it made.</p>"
                     + table(("rule", "check", "passed", "failed", "skipped", "verdict"), rule_rows, raw=True,
                             numeric=(2, 3, 4))))
    if skipped:
        rows = [(o.scenario or "-", o.observer or "-", o.state or "-", o.source, reason_of(o) or o.check)
                for o in skipped]
        sections.append(("skipped", f"Skipped checks ({len(skipped)})",
                         "<p class='muted'>Skipped is not failed: an observer that needs a sensor the scenario "
                         "does not have, a rule naming a scenario this run did not select, a metric the baseline "
                         "lacks.</p>"
                         + f"<details><summary>show the {len(skipped)} skipped checks</summary>"
                         + table(("scenario", "observer", "state", "rule", "reason"), rows) + "</details>"))
    facts = [("thresholds", esc(_thresholds_label(thresholds))),
             ("baseline", esc(str(baseline)) if baseline is not None else "none (no regression checks)"),
             ("run folder", esc(str(result.out))),
             ("all outcomes", "<code>check.csv</code> (one row per check)")]
    if run_report:
        facts.append(("run report", f"<a href='{esc(run_report)}'>{esc(run_report)}</a>"))
    sections.append(("inputs", "Inputs", table(("", ""), facts, cls="plain compact", raw=True)))
    return page(f"roadtruth check — {word}", sections, top=top)
