"""Seed spread of the shipped CI gate (the figures of docs/CHECK.md), and the rules measured from it.

Run:

* ``python benchmarks/bench_ci_spread.py [THRESHOLDS.yaml]`` reads the trailing comments
  ``# <default-seed value> (<min>-<max>)`` of every RMSE rule of ``harness/thresholds/ci.yaml``
  (written from five runs of the ci suite: the scenarios' own seeds and ``--seed 1 … 4``) and prints,
  per scenario, the number of RMSE rules, the median and the largest ``max / min`` ratio over the
  five seeds, and the smallest ceiling / default-seed value ratio (the margin).
* ``python benchmarks/bench_ci_spread.py --propose RUN0 RUN1 …`` prints the
  ``rules:`` of a thresholds file measured from those run folders (RUN0 = the default seeds), the
  way ``ci.yaml`` is made: per scenario and observer a ``status == ok`` rule on the states that are
  ``ok`` in every run (the others listed in a comment with their status), the ``certified == true``
  rule, the EKF/UKF sideslip NEES band per scenario (half the lowest, double the highest value),
  coverage floors (worst run - 0.10) and RMSE ceilings (1.5 × the worst run) of every state of
  every observer that is ``ok`` in every run (``roadtruth.harness.jobs.check_rules.propose_rules``).
"""

from __future__ import annotations

import argparse
import math
import re
from collections import defaultdict
from pathlib import Path

import numpy as np
import pandas as pd

NUM = r"-?\d+(?:\.\d*)?(?:[eE][+-]?\d+)?"
RULE = re.compile(rf"scenario: (?P<scenario>\w+),.*metric: rmse, max: (?P<max>{NUM})\}}\s*#\s*"
                  rf"(?P<value>{NUM})\s*\((?P<lo>{NUM})-(?P<hi>{NUM})\)")
DEFAULT = Path(__file__).resolve().parents[1] / "harness/thresholds/ci.yaml"
#: The nonlinear Kalman filters whose sideslip NEES is gated, and the manoeuvres their model covers
#: (on split_mu_braking their NEES is ~50: the single-track model ignores the yaw moment of split mu).
NEES_OBSERVERS = ("ekf_bicycle", "ukf_bicycle")
NEES_SCENARIOS = ("step_steer", "brake_in_turn")


def spread(path: Path) -> None:
    """Print the per-scenario seed spread and margin of the RMSE rules of a thresholds file."""
    ratio: dict[str, list[float]] = defaultdict(list)
    margin: dict[str, list[float]] = defaultdict(list)
    for line in path.read_text().splitlines():
        m = RULE.search(line)
        if m and float(m["lo"]) > 0:
            ratio[m["scenario"]].append(float(m["hi"]) / float(m["lo"]))
            margin[m["scenario"]].append(float(m["max"]) / float(m["value"]))
    print(f"{'scenario':20s} {'rules':>5s} {'median max/min':>15s} {'largest max/min':>16s} {'min ceiling/value':>18s}")
    for sc in sorted(ratio):
        s = np.array(ratio[sc])
        print(f"{sc:20s} {s.size:5d} {np.median(s):15.2f} {s.max():16.2f} {min(margin[sc]):18.2f}")


def _status_rules(runs: list[pd.DataFrame]) -> list[str]:
    """``status == ok`` per scenario on the (observer, states) ok in every run; comments for the rest."""
    first = runs[0]
    lines: list[str] = []
    for scenario in dict.fromkeys(first["scenario"]):
        rows = first[first["scenario"] == scenario]
        whole: list[str] = []
        partial: list[str] = []
        notes: list[str] = []
        for observer in sorted(set(rows["observer"])):
            states = list(rows.loc[rows["observer"] == observer, "state"].fillna(""))
            bad: dict[str, str] = {}
            for k, r in enumerate(runs):
                sel = r[(r["scenario"] == scenario) & (r["observer"] == observer)]
                for state, status in zip(sel["state"].fillna(""), sel["status"].astype(str), strict=True):
                    if status != "ok" and state not in bad:
                        bad[state] = status if k == 0 else f"{status} under seed {k}"
            good = [s for s in states if s not in bad]
            if not bad:
                whole.append(observer)
                continue
            first_bad = next(iter(bad.values()))
            if all(v.startswith("skipped: missing") for v in bad.values()):
                notes.append(f"  # {observer}: not applicable ({first_bad}): skipped by check, no rule")
                continue
            if good:
                partial.append(f"  - {{scenario: {scenario}, observer: {observer}, state: [{', '.join(good)}], "
                               f"metric: status, equals: ok}}")
            for state, status in bad.items():
                notes.append(f"  # {observer} {state or '-'}: {status}: not gated")
        lines.append(f"  # --- {scenario}: {len(whole)} observers ok on every state in every run ---")
        lines.append(f"  - {{scenario: {scenario}, observer: [{', '.join(whole)}], state: \"*\", metric: status, "
                     f"equals: ok}}")
        lines += partial + notes
    return lines


def _nees_rules(runs: list[pd.DataFrame]) -> list[str]:
    """EKF/UKF beta NEES band per scenario: [half the lowest, double the highest] over the runs."""
    lines = []
    for scenario in NEES_SCENARIOS:
        vals = [float(v) for r in runs for v in r.loc[(r["scenario"] == scenario) & r["observer"].isin(NEES_OBSERVERS)
                                                       & (r["state"] == "beta_rad"), "nees_mean"]]
        first = runs[0]
        v0 = first.loc[(first["scenario"] == scenario) & first["observer"].isin(NEES_OBSERVERS)
                       & (first["state"] == "beta_rad"), "nees_mean"]
        lo = math.floor(0.5 * min(vals) * 100) / 100
        hi = math.ceil(2.0 * max(vals) * 10) / 10
        lines.append(f"  - {{scenario: {scenario}, observer: [{', '.join(NEES_OBSERVERS)}], state: beta_rad, "
                     f"metric: nees_mean, min: {lo:g}, max: {hi:g}}}   # {', '.join(f'{v:.3g}' for v in v0)} "
                     f"({min(vals):.3g}-{max(vals):.3g})")
    return lines


def propose(run_dirs: list[Path]) -> None:
    """Print the measured ``rules:`` of a thresholds file from run folders (first = default seeds)."""
    from roadtruth.harness.jobs.check_rules import propose_rules

    runs = [pd.read_csv(d / "metrics.csv") for d in run_dirs]
    states = tuple(dict.fromkeys(runs[0]["state"].dropna()))
    cov_states = tuple(dict.fromkeys(runs[0].loc[runs[0]["coverage"].notna(), "state"]))
    print("rules:")
    print("\n".join(_status_rules(runs)))
    print("\n".join(line for line in propose_rules(runs, states=("beta_rad",)) if "metric: certified" in line))
    print("\n".join(_nees_rules(runs)))
    print("\n".join(propose_rules(runs, metric="coverage", states=cov_states, slack=0.10, certified=False)))
    print("\n".join(propose_rules(runs, states=states, margin=1.5, certified=False)))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("thresholds", nargs="?", type=Path, default=DEFAULT)
    p.add_argument("--propose", nargs="+", type=Path, metavar="RUN", help="run folders: print measured rules")
    a = p.parse_args()
    if a.propose:
        propose(a.propose)
    else:
        spread(a.thresholds)


if __name__ == "__main__":
    main()
