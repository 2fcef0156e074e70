"""The inputs of the CI gate, validated: thresholds YAML (rules + regression tolerance) and a baseline.

Format reference: ``docs/CHECK.md``. Every mistake raises ``ThresholdsError`` or ``BaselineError``
(both ``InputError``) with a one-line message naming the file, the field (``rules[3].max``,
``regression.abs_tol.beta_rad``, a CSV column) and the value.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any

import pandas as pd

from roadtruth.harness.errors import InputError
from roadtruth.harness.evaluation.scoring import COLUMNS, KEY_COLUMNS
from roadtruth.harness.files.parsed_files import ParsedFiles
from roadtruth.harness.files.strict_yaml import Fields, load_mapping
from roadtruth.harness.jobs.compare import COMPARED
from roadtruth.harness.signals import is_canonical

KEYS: list[str] = list(KEY_COLUMNS)
#: The shipped thresholds, used when ``--thresholds`` is not given.
DEFAULT_THRESHOLDS = Path(__file__).resolve().parents[1] / "thresholds" / "ci.yaml"
#: Columns of metrics.csv a rule may test (everything but the keys).
RULE_METRICS: tuple[str, ...] = tuple(c for c in COLUMNS if c not in KEY_COLUMNS)
#: metric -> sense for regressions: "low" lower is better, "high" higher is better, "abs" nearer 0,
#: "one" nearer 1 (``roadtruth.harness.jobs.compare``'s table, plus the metrics it does not compare).
SENSE: dict[str, str] = {**COMPARED, "max_width": "low"}
_FLAGS = ("certified", "nees_in_band")
_GLOB_CHARS = set("*?[")


class ThresholdsError(InputError):
    """A thresholds YAML is malformed or names an unknown metric, state or option."""


class BaselineError(InputError):
    """A baseline metrics.csv is missing, unreadable or lacks the columns the regression compares."""


def metric_kind(metric: str) -> str:
    """``text`` (status), ``flag`` (certified, nees_in_band) or ``number`` (every other metric)."""
    return "text" if metric == "status" else "flag" if metric in _FLAGS else "number"


@dataclass(frozen=True)
class CheckOutcome:
    """One judged check.

    ``kind`` is ``simulation``, ``threshold``, ``regression`` or ``rule`` (a rule that matched no
    row); ``verdict`` is ``pass``, ``fail`` or ``skip``; ``message`` says why (empty on a pass);
    ``source`` is where the check comes from (``rules[3]``, ``regression``, ``simulation``).
    """

    kind: str
    scenario: str
    observer: str
    state: str
    metric: str
    check: str
    value: Any
    verdict: str
    message: str
    source: str


@dataclass(frozen=True)
class Rule:
    """One threshold rule: patterns select rows, then ``metric`` must satisfy min/max or equal ``equals``."""

    metric: str
    scenario: tuple[str, ...] = ("*",)
    observer: tuple[str, ...] = ("*",)
    state: tuple[str, ...] = ("*",)
    max: float | None = None
    min: float | None = None
    equals: bool | float | str | None = None
    if_missing: str = "fail"
    name: str | None = None
    where: str = "rules[?]"

    @property
    def label(self) -> str:
        """Short text of the rule (JUnit test name, summary): ``rmse <= 0.035``."""
        if self.name:
            return self.name
        if self.equals is not None:
            eq = ("true" if self.equals else "false") if isinstance(self.equals, bool) else f"{self.equals:g}" \
                if isinstance(self.equals, float) else str(self.equals)
            return f"{self.metric} == {eq}"
        if self.min is not None and self.max is not None:
            return f"{self.min:g} <= {self.metric} <= {self.max:g}"
        return f"{self.metric} <= {self.max:g}" if self.max is not None else f"{self.metric} >= {self.min:g}"


@dataclass(frozen=True)
class RegressionSpec:
    """How a run is compared with a baseline: a metric m of state s fails when its "worse" change
    exceeds ``rel_tol * |baseline| + abs_tol(s)``."""

    metrics: tuple[str, ...] = ("rmse", "p95_abs")
    rel_tol: float = 0.10
    abs_tol: tuple[tuple[str, float], ...] = field(default_factory=tuple)

    def abs_tol_for(self, state: str) -> float:
        """Absolute slack of a state [state unit]: an exact key first, then the first matching glob, else 0."""
        table = dict(self.abs_tol)
        if state in table:
            return table[state]
        return next((v for k, v in self.abs_tol if fnmatchcase(state, k)), 0.0)


@dataclass(frozen=True)
class Thresholds:
    """A parsed thresholds file."""

    rules: tuple[Rule, ...]
    regression: RegressionSpec
    source: Path
    description: str = ""


def _number(f: Fields, key: str, default: Any = ..., **limits: Any) -> float:
    """``Fields.number`` with a hint for ``1e-6``, which YAML 1.1 (PyYAML) reads as a string."""
    v = f.data.get(key)
    if isinstance(v, str):
        try:
            float(v)
        except ValueError:
            pass
        else:
            f.raw(key)
            raise f.fail(key, f"must be a number (got the string {v!r}; YAML needs a dot and a signed "
                              f"exponent, e.g. 1.0e-6, or write {float(v):f})")
    return f.number(key, default, **limits)


def _patterns(f: Fields, key: str) -> tuple[str, ...]:
    v = f.raw(key, "*")
    items = v if isinstance(v, list) else [v]
    if not items or not all(isinstance(p, str) and p.strip() for p in items):
        raise f.fail(key, f"must be a glob pattern or a list of them (got {v!r})")
    return tuple(p.strip() for p in items)


def _parse_rule(data: Any, where: str, source: str) -> Rule:
    f = Fields(data, source=source, error=ThresholdsError, prefix=where)
    metric = f.string("metric")
    if metric not in RULE_METRICS:
        raise f.fail("metric", f"unknown metric {metric!r} (known: {', '.join(RULE_METRICS)})")
    kind = metric_kind(metric)
    scenario, observer, state = _patterns(f, "scenario"), _patterns(f, "observer"), _patterns(f, "state")
    for p in state:
        if not (_GLOB_CHARS & set(p)) and not is_canonical(p):
            raise f.fail("state", f"unknown state {p!r} (a canonical signal name or a glob)")
    lo = _number(f, "min", None) if f.has("min") else None
    hi = _number(f, "max", None) if f.has("max") else None
    equals: bool | float | str | None = None
    if f.has("equals"):
        raw = f.raw("equals")
        if kind == "text" and not isinstance(raw, str):
            raise f.fail("equals", f"{metric} is text: must be a string, e.g. ok (got {raw!r})")
        if kind == "flag" and not isinstance(raw, bool):
            raise f.fail("equals", f"{metric} is a flag: must be true or false (got {raw!r})")
        if kind == "number":
            equals = _number(f, "equals")
        else:
            equals = raw
    if_missing = f.string("if_missing", "fail", choices=("fail", "skip"))
    name = f.string("name", None)
    f.done()  # an unknown key (a typo such as ``mx``) is the likeliest mistake: report it first
    if kind != "number" and (lo is not None or hi is not None):
        raise f.fail("min" if lo is not None else "max", f"{metric} is not a number: use equals")
    if equals is not None and (lo is not None or hi is not None):
        raise f.fail("equals", "use either equals or min/max, not both")
    if equals is None and lo is None and hi is None:
        raise f.fail("max", "a rule needs max, min or equals")
    if lo is not None and hi is not None and lo > hi:
        raise f.fail("min", f"min {lo:g} is above max {hi:g}")
    return Rule(metric=metric, scenario=scenario, observer=observer, state=state, max=hi, min=lo, equals=equals,
                if_missing=if_missing, name=name, where=where)


def _parse_regression(f: Fields) -> RegressionSpec:
    raw = f.raw("metric", ["rmse", "p95_abs"])
    metrics = raw if isinstance(raw, list) else [raw]
    if not metrics or not all(isinstance(m, str) for m in metrics):
        raise f.fail("metric", f"must be a metric name or a list of them (got {raw!r})")
    for m in metrics:
        if m not in SENSE:
            raise f.fail("metric", f"cannot compare {m!r} with a baseline (comparable: {', '.join(SENSE)})")
    rel = _number(f, "rel_tol", 0.10, lo=0.0, hi=100.0)
    abs_raw = f.raw("abs_tol", 0.0)
    table: list[tuple[str, float]]
    if isinstance(abs_raw, dict):
        sub = f.sub("abs_tol")
        table = []
        for key in abs_raw:
            if not isinstance(key, str) or not ((_GLOB_CHARS & set(key)) or is_canonical(key)):
                raise sub.fail(str(key), "unknown state (a canonical signal name or a glob)")
            table.append((key, _number(sub, key, lo=0.0)))
        sub.done()
    else:
        table = [("*", _number(f, "abs_tol", 0.0, lo=0.0))]
    f.done()
    return RegressionSpec(metrics=tuple(dict.fromkeys(metrics)), rel_tol=rel, abs_tol=tuple(table))


#: Parsed thresholds files (an edited file is read again): a stress page looks up the shipped CI
#: limits once per breaking point, and parsing that file costs ~50 ms each time.
_THRESHOLDS = ParsedFiles()


def load_thresholds(path: Path) -> Thresholds:
    """Read and validate a thresholds YAML (format: docs/CHECK.md). Raises ``ThresholdsError``.

    The result is frozen, so every caller shares one parse while the file is unchanged.
    """
    return _THRESHOLDS.get(Path(path), lambda: _parse_thresholds(path), variant=str(path))


def _parse_thresholds(path: Path) -> Thresholds:
    src = str(path)
    f = Fields(load_mapping(path, ThresholdsError), source=src, error=ThresholdsError)
    description = f.string("description", "")
    items = f.items("rules", [])
    rules = tuple(_parse_rule(d, f"rules[{i}]", src) for i, d in enumerate(items))
    regression = _parse_regression(f.sub("regression", {}))
    has_regression = f.has("regression")
    f.done()
    if not rules and not has_regression:
        raise ThresholdsError("no rules and no regression section: nothing to check", source=src, field="rules")
    return Thresholds(rules=rules, regression=regression, source=Path(path), description=description)


def load_baseline(path: Path, metrics: tuple[str, ...]) -> pd.DataFrame:
    """A baseline ``metrics.csv`` (or a run folder holding one), checked for the compared ``metrics``.

    Raises ``BaselineError`` naming the file and the column, row or value at fault.
    """
    from roadtruth.harness.evaluation.metrics_file import read_metrics_file

    # The same validation as ``compare`` (roadtruth.harness.evaluation.metrics_file), raised as BaselineError.
    return read_metrics_file(Path(path), required=tuple(metrics), finite=tuple(metrics), error=BaselineError)


# ---- proposing thresholds from measured runs ------------------------------------------------------

def round_up(x: float, digits: int = 2) -> float:
    """``x`` rounded *up* to ``digits`` significant digits (a limit must never fall below the measurement)."""
    if x <= 0 or not math.isfinite(x):
        return x
    step = 10.0 ** (math.floor(math.log10(x)) - digits + 1)
    return float(f"{math.ceil(x / step - 1e-9) * step:.{digits}g}")


def _yaml_float(x: float) -> str:
    """``x`` as text PyYAML reads back as a float (its YAML 1.1 resolver wants ``1.0e-05``, not ``1e-05``)."""
    s = f"{x:g}"
    return re.sub(r"^(-?\d+)e", r"\1.0e", s)


def propose_rules(runs: list[pd.DataFrame], *, metric: str = "rmse",
                  states: tuple[str, ...] = ("beta_rad", "vy_mps", "yaw_rate_radps"), margin: float = 1.5,
                  slack: float = 0.10, certified: bool = True) -> list[str]:
    """Threshold rules grounded in measured runs, as YAML lines for a ``rules:`` list.

    For each (scenario, observer, state) of ``states`` in the first run whose ``metric`` is finite
    in some run, a rule limits it: for a "lower is better" metric (rmse, p95_abs …) the ceiling is
    ``margin`` × the worst value over all ``runs`` (e.g. the suite under several seeds), rounded up
    to two significant digits; for a "higher is better" metric (coverage) the floor is the worst
    value minus ``slack``, rounded down to 0.01. The trailing comment gives the first run's value and
    the range. A row not ``ok`` or NaN in some run gets a comment instead of a rule. With
    ``certified``, a first line requires ``certified == true`` of the observers certified in every
    row of every run.

    Parameters
    ----------
    runs : metrics frames (``metrics.csv`` of each run); the first one orders the output.
    metric : a metric with sense "low" or "high" in ``SENSE``.
    states : states to write rules for.
    margin : factor above the worst value of a "low" metric (>= 1).
    slack : distance below the worst value of a "high" metric (>= 0).
    certified : also propose the ``certified`` rule.
    """
    sense = SENSE.get(metric)
    if not runs or margin < 1.0 or slack < 0.0 or sense not in ("low", "high"):
        raise ValueError("propose_rules needs runs, a metric that is lower- or higher-is-better, margin >= 1, "
                         "slack >= 0")
    keyed = [r.assign(state=r["state"].fillna("")).set_index(KEYS) for r in runs]
    first = runs[0].assign(state=runs[0]["state"].fillna(""))
    lines: list[str] = []
    for scenario in dict.fromkeys(first["scenario"]):
        lines.append(f"  # --- {scenario} ---")
        for state in states:
            rows = first[(first["scenario"] == scenario) & (first["state"] == state)]
            for observer in sorted(rows["observer"]):
                key = (scenario, observer, state)
                got = [k.loc[key] for k in keyed if key in k.index]
                vals = [float(g[metric]) for g in got]
                if not any(math.isfinite(v) for v in vals):
                    continue  # the observer does not give this metric (e.g. no bounds, no coverage)
                healthy = len(got) == len(runs) and all(str(g["status"]).startswith("ok") for g in got)
                if not healthy or not all(math.isfinite(v) for v in vals):
                    lines.append(f"  # {scenario} {observer} {state}: not ok or NaN in some run, no rule")
                    continue
                if sense == "low":
                    bound = f"max: {_yaml_float(round_up(margin * max(vals)))}"
                else:
                    bound = f"min: {max(0.0, math.floor((min(vals) - slack) * 100 + 1e-9) / 100):.2f}"
                rule = f"{{scenario: {scenario}, observer: {observer}, state: {state}, metric: {metric}, {bound}}}"
                lines.append(f"  - {rule:<100} # {vals[0]:.3g} ({min(vals):.3g}-{max(vals):.3g})")
    names = [o for o in dict.fromkeys(first["observer"])
             if all(bool((r.loc[r["observer"] == o, "certified"].astype(str).str.lower() == "true").all())
                    and (r["observer"] == o).any() for r in runs)]
    if certified and names:
        lines.insert(0, f"  - {{observer: [{', '.join(names)}], state: \"*\", metric: certified, equals: true}}")
    return lines
