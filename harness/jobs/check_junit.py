"""JUnit XML of the CI gate's outcomes (the common Ant/Jenkins "JUnit XML" schema).

Mapping (docs/CHECK.md): ``<testsuites name="roadtruth check">`` holds one ``<testsuite>`` per
scenario (in first-seen order) plus one named ``thresholds`` for rules that matched no row; each
outcome is a ``<testcase>`` with ``classname="<scenario>.<observer>"`` and
``name="<state>: <check>"``; a failed outcome carries ``<failure message=… type=…>``, a skipped one
``<skipped message=…/>``. Counts (``tests``, ``failures``, ``errors``, ``skipped``) are written on
every suite and on the root, as GitLab, Jenkins and GitHub test reporters read them.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence

from roadtruth.harness.jobs.check_rules import CheckOutcome

#: Suite name for outcomes that belong to no scenario (a rule that matched nothing).
RULES_SUITE = "thresholds"


def _case_name(o: CheckOutcome) -> str:
    if o.kind == "simulation":
        return "simulation: status == ok"
    if o.kind == "rule":
        return f"{o.source}: {o.check}"
    return f"{o.state or '-'}: {o.check}"


def junit_xml(outcomes: Sequence[CheckOutcome], *, times: Mapping[str, float] | None = None,
              properties: Mapping[str, str] | None = None) -> str:
    """The outcomes as a JUnit XML document (a string with an XML declaration).

    Parameters
    ----------
    outcomes : every check outcome (pass, fail and skip).
    times : seconds per scenario, written as each suite's ``time`` (0 when unknown).
    properties : name -> value written as ``<properties>`` of every suite (thresholds file, baseline…).
    """
    times = dict(times or {})
    groups: dict[str, list[CheckOutcome]] = {}
    for o in outcomes:
        groups.setdefault(o.scenario or RULES_SUITE, []).append(o)
    root = ET.Element("testsuites", name="roadtruth check")
    totals = {"tests": 0, "failures": 0, "skipped": 0}
    total_time = 0.0
    for suite_name, items in groups.items():
        n_fail = sum(o.verdict == "fail" for o in items)
        n_skip = sum(o.verdict == "skip" for o in items)
        t = float(times.get(suite_name, 0.0))
        total_time += t
        suite = ET.SubElement(root, "testsuite", name=suite_name, tests=str(len(items)), failures=str(n_fail),
                              errors="0", skipped=str(n_skip), time=f"{t:.3f}")
        if properties:
            props = ET.SubElement(suite, "properties")
            for k, v in properties.items():
                ET.SubElement(props, "property", name=str(k), value=str(v))
        for o in items:
            classname = f"{suite_name}.{o.observer}" if o.observer else suite_name
            case = ET.SubElement(suite, "testcase", name=_case_name(o), classname=classname, time="0")
            if o.verdict == "fail":
                fail = ET.SubElement(case, "failure", message=o.message, type=o.kind)
                fail.text = f"{o.message}\nsource: {o.source}\nvalue: {o.value!s}\n"
            elif o.verdict == "skip":
                ET.SubElement(case, "skipped", message=o.message)
        totals["tests"] += len(items)
        totals["failures"] += n_fail
        totals["skipped"] += n_skip
    root.set("tests", str(totals["tests"]))
    root.set("failures", str(totals["failures"]))
    root.set("errors", "0")
    root.set("skipped", str(totals["skipped"]))
    root.set("time", f"{total_time:.3f}")
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
