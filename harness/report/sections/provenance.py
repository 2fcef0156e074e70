"""Provenance: versions, git revision, seeds and options from run.json (times are in timings.json, kept
off the page so that it is reproducible)."""

from __future__ import annotations

import json
from typing import Any

from roadtruth.harness.report.rundata import RunData
from roadtruth.harness.report.sections.base import Section


class ProvenanceSection(Section):
    template = "provenance.html"
    title = "Provenance"
    anchor = "provenance"

    def context(self, run: RunData, page: Any) -> dict[str, Any]:
        r = run.run
        options = {k: r.get(k) for k in ("suite", "seed", "vehicle", "friction", "sensors", "faults",
                                         "log_rate_hz", "jobs") if k in r}
        seeds = [{"name": s.get("name"), "seed": s.get("seed"), "entropy": s.get("entropy"),
                  "vehicle": s.get("vehicle"), "sensors": s.get("sensors")}
                 for s in r.get("scenarios", []) if isinstance(s, dict)]
        return {
            "versions": r.get("versions", {}),
            "git_revision": r.get("git_revision"),
            "options": options,
            "seeds": seeds,
            "raw": json.dumps(r, indent=1, sort_keys=True, default=str)[:20000],
        }
