"""Three separate ideas behind every status the report shows.

* **not applicable** — the observer could not run here (``skipped: …``: a missing input such as the
  radar, a state without truth, a simulation that failed before any observer ran). Neutral grey; it
  says nothing about the observer.
* **failed** — it ran and its estimate is not usable (``error…``, ``diverged…``, ``saturated…``, any
  other status that is not ``ok``). Red.
* **certification** of the observer's LMI design — certified / rejected / no LMI design — a property
  of the design, independent of how a run went.

Progress lines, the summary, the leaderboard and the observers table all use these functions, so a
skipped run is never counted or coloured as a failure.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache

OK, NOT_APPLICABLE, FAILED, ABSENT = "ok", "n/a", "failed", "absent"

#: Which sensor provides a missing input, so that "skipped: missing range_m" reads "needs radar".
_SENSOR_OF_SIGNAL = {
    "range_m": "radar", "range_rate_mps": "radar",
    "y_lane_m": "lane camera", "psi_lane_rad": "lane camera", "rho_1pm": "lane camera",
    "gnss_x_m": "GNSS", "gnss_y_m": "GNSS", "gnss_speed_mps": "GNSS", "gnss_course_rad": "GNSS",
}


def status_kind(status: str) -> str:
    """``"ok"``, ``"n/a"`` (skipped), ``"failed"`` or ``"absent"`` (no row at all) for a status."""
    if type(status) is str:  # a run has a few distinct statuses and the page asks tens of thousands of times
        return _kind_of_text(status)
    return _kind_of_text(str(status))


@lru_cache(maxsize=4096)
def _kind_of_text(status: str) -> str:
    s = status.strip()
    if s == "" or s.startswith("ok"):
        return OK
    if s.startswith("skipped"):
        return NOT_APPLICABLE
    if s == "absent":
        return ABSENT
    return FAILED


def status_label(status: str) -> str:
    """Short text for a cell: ``ok``; ``n/a — needs radar``; ``diverged``; ``saturated (31 % …)``."""
    s = str(status).strip()
    kind = status_kind(s)
    if kind == OK:
        return "ok"
    if kind == ABSENT:
        return "not run"
    if kind == NOT_APPLICABLE:
        reason = s.split(":", 1)[1].strip() if ":" in s else ""
        m = re.match(r"missing (\S+)", reason)
        if m:
            return f"n/a — needs {_SENSOR_OF_SIGNAL.get(m.group(1), m.group(1))}"
        if reason.startswith("simulation"):
            return "n/a — simulation failed"
        if reason.startswith("truth has no"):
            return "n/a — no truth"
        return "n/a"
    if s.startswith("saturated"):
        return s  # "saturated (x % of the time)" is already short and says how much
    return s.split(":", 1)[0].strip() or "failed"


@dataclass(frozen=True)
class StatusCounts:
    """How many observer runs were ok, not applicable, failed."""

    ok: int
    not_applicable: int
    failed: int

    @property
    def total(self) -> int:
        return self.ok + self.not_applicable + self.failed

    @property
    def applicable(self) -> int:
        return self.ok + self.failed


def count_statuses(statuses: Iterable[str]) -> StatusCounts:
    kinds = [status_kind(s) for s in statuses]
    return StatusCounts(ok=kinds.count(OK), not_applicable=kinds.count(NOT_APPLICABLE), failed=kinds.count(FAILED))


#: Design statuses (``DesignStatus`` values in run.json) worst first; "not_evaluated" means no run of
#: this observer got as far as designing it (all skipped), so the report cannot say either way.
DESIGN_ORDER = ("solver_failed", "infeasible", "rejected", "certified", "not_applicable", "not_evaluated")


def design_label(design: str) -> str:
    """Text for a design status: ``✔ certified``, ``✘ rejected``, ``no LMI design``, ``not designed``."""
    return {
        "certified": "✔ certified",
        "not_applicable": "no LMI design",
        "not_evaluated": "not designed here (never ran)",
    }.get(design, "✘ " + design.replace("_", " "))


def design_class(design: str) -> str:
    """CSS class of a design status: ``ok`` (certified), ``na`` (no design / not evaluated), ``fail``."""
    if design == "certified":
        return "ok"
    if design in ("not_applicable", "not_evaluated"):
        return "na"
    return "fail"


def run_verdict(run_status: str, row_statuses: Iterable[str]) -> str:
    """The status of one observer run (scenario × observer) as the report counts it.

    The run's own status decides if it is not ``ok``. An ``ok`` run with a state whose estimate is
    not usable (e.g. ``saturated (…)`` on β) is a failure: its first failed row status is returned.
    State-level skips (no truth for a state) leave an ``ok`` run ``ok``.
    """
    if status_kind(run_status) != OK:
        return run_status
    for s in row_statuses:
        if status_kind(s) == FAILED:
            return s
    return run_status
