"""β RMSE of every observer on the real Ferrari 250 LM log, next to the plain linear Kalman filter.

Replays ``shared/data/revs-250lm`` (55,001 rows, 100 Hz, INS sideslip reference) through
``harness.replay.replay`` with the shipped column map and vehicle, and prints a Markdown table:
every registered observer, the signals it needs, and its β RMSE in degrees (or why it was skipped).

    .venv/bin/python benchmarks/bench_replay.py [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import pandas as pd

from harness.replay import replay
from harness.replay_log import load_column_map
from observers.registry import observer_info

REVS_LOG = (Path(__file__).resolve().parents[1].parent / "shared" / "data" / "revs-250lm"
            / "revs_250lm_2014-02-22.csv.gz")
BASELINE = "kf_bicycle"


def beta_table(metrics: pd.DataFrame, measured: tuple[str, ...], details: dict[str, str] | None = None) -> str:
    """Markdown table of β RMSE [deg] per observer: the baseline first, then by RMSE, then the rest.

    ``details`` (observer -> text) is appended to a status that is not ``ok`` (why it diverged).
    """
    details = details or {}
    info = {i["name"]: i for i in observer_info()}
    beta = metrics[metrics["state"] == "beta_rad"].set_index("observer")
    base = float(beta.loc[BASELINE, "rmse"]) if BASELINE in beta.index else math.nan
    rows = []
    for name, i in info.items():
        missing = [s for s in i["inputs"] if s not in measured]
        needs = ", ".join(i["inputs"])
        if missing:
            rows.append((2, math.inf, f"| {name} | {needs} | — | — | skipped: log has no {', '.join(missing)} |"))
        elif "beta_rad" not in i["states"]:
            rows.append((2, math.inf, f"| {name} | {needs} | — | — | no β state ({', '.join(i['states'])}) |"))
        elif name not in beta.index:
            rows.append((2, math.inf, f"| {name} | {needs} | — | — | not run |"))
        else:
            r = beta.loc[name]
            rmse_deg = math.degrees(float(r["rmse"])) if pd.notna(r["rmse"]) else math.nan
            ratio = float(r["rmse"]) / base if math.isfinite(base) and base > 0 else math.nan
            status = str(r["status"]) + (f": {details[name]}" if details.get(name) and r["status"] != "ok" else "")
            if math.isfinite(rmse_deg):
                rows.append((0 if name == BASELINE else 1, rmse_deg,
                             f"| {name} | {needs} | {rmse_deg:.3f} | {ratio:.2f} | {status} |"))
            else:
                rows.append((2, math.inf, f"| {name} | {needs} | — | — | {status} |"))
    head = ("| observer | needs | β RMSE [deg] | × kf_bicycle | status |\n"
            "|---|---|---:|---:|---|")
    return "\n".join([head, *(line for _, _, line in sorted(rows))])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="keep the replay folder here (default: a temporary one)")
    a = ap.parse_args()
    cmap = load_column_map("revs_250lm")
    with tempfile.TemporaryDirectory() as tmp:
        out = a.out or Path(tmp) / "replay"
        t = time.perf_counter()
        folder = replay(REVS_LOG, vehicle="ferrari_250lm", columns="revs_250lm", out=out)
        wall = time.perf_counter() - t
        metrics = pd.read_csv(folder / "metrics.csv")
        runs = json.loads((folder / "run.json").read_text())["observer_runs"]
        truth = pd.concat([pd.read_csv(f) for f in sorted(folder.glob("*/truth.csv"))], ignore_index=True)
    details = {k: v.get("detail") or "" for one in runs.values() for k, v in one.items()}
    print(f"Revs Ferrari 250 LM log, {REVS_LOG.name}: replay with every observer took {wall:.1f} s")
    t = truth["t_s"].to_numpy(float)
    line = f"reference: {t[-1] - t[0]:.0f} s at {1 / float(pd.Series(t).diff().median()):.0f} Hz"
    if "beta_rad" in truth:
        b = truth["beta_rad"].map(math.degrees)
        line += f", beta {b.min():+.1f} ... {b.max():+.1f} deg"
    if "ay_mps2" in truth:
        line += f", peak |a_y| {truth['ay_mps2'].abs().max() / 9.80665:.2f} g"
    print(line + "\n")
    print(beta_table(metrics, cmap.measured, details))


if __name__ == "__main__":
    main()
