"""β RMSE of every observer on the real Ferrari 250 LM log, next to the plain linear Kalman filter.

Replays ``shared/data/revs-250lm`` (55,001 rows, 100 Hz, INS sideslip reference) through
``roadtruth.harness.jobs.replay.replay`` with the shipped column map and vehicle, and prints a Markdown table:
every registered observer, the signals it needs, its β RMSE in degrees, the ratio to the linear KF
(``kf_bicycle``) and to assuming β = 0 (the RMS of the reference over the same scored rows), or why
it was skipped.

``--robustness`` replays the log again with deliberately wrong vehicles (grip 0.9 instead of 1.3,
both axle stiffnesses x0.7 and x1.3, the sedan's parameters) through the model-based filters and the
reference estimator, and prints β RMSE and ratios per vehicle.

    .venv/bin/python benchmarks/bench_replay.py [--out DIR] [--robustness]
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import pandas as pd

from roadtruth.harness.jobs.replay import replay
from roadtruth.harness.jobs.replay_log import load_column_map
from roadtruth.observers.registry import observer_info

REVS_LOG = (Path(__file__).resolve().parents[1].parent / "shared" / "data" / "revs-250lm"
            / "revs_250lm_2014-02-22.csv.gz")
BASELINE = "kf_bicycle"
ZERO_ROW = "β = 0"
ROBUST_OBSERVERS = ["reference_beta", "kf_bicycle", "ekf_bicycle", "ukf_bicycle", "open_loop_bicycle"]


def zero_beta_rmse(log: Path, columns: str) -> float:
    """RMS of the reference β [rad] over the rows the replay scores (its run segments): the error of
    assuming β = 0."""
    import numpy as np

    from roadtruth.harness.jobs.replay import prepare_log

    rl = prepare_log(log, columns)
    ref = rl.frame.set_index("t_s")["beta_rad"]
    parts = [ref.reindex(rl.measurements[s.index]["t_s"].to_numpy()).to_numpy() for s in rl.run_segments]
    b = np.concatenate(parts)
    b = b[np.isfinite(b)]
    return float(np.sqrt(np.mean(b * b)))


def beta_table(metrics: pd.DataFrame, measured: tuple[str, ...], details: dict[str, str] | None = None,
               zero_rmse: float = math.nan) -> str:
    """Markdown table of β RMSE [deg] per observer: the baseline first, then by RMSE, then the rest.

    ``details`` (observer -> text) is appended to a status that is not ``ok`` (why it diverged);
    ``zero_rmse`` [rad] is the error of assuming β = 0 (a row of its own and the last ratio column).
    """
    details = details or {}
    z = zero_rmse if math.isfinite(zero_rmse) and zero_rmse > 0 else math.nan
    info = {i["name"]: i for i in observer_info()}
    beta = metrics[metrics["state"] == "beta_rad"].set_index("observer")
    base = float(beta.loc[BASELINE, "rmse"]) if BASELINE in beta.index else math.nan
    rows = []
    for name, i in info.items():
        missing = [s for s in i["inputs"] if s not in measured]
        needs = ", ".join(i["inputs"])
        if missing:
            rows.append((2, math.inf, f"| {name} | {needs} | — | — | — | skipped: log has no {', '.join(missing)} |"))
        elif "beta_rad" not in i["states"]:
            rows.append((2, math.inf, f"| {name} | {needs} | — | — | — | no β state ({', '.join(i['states'])}) |"))
        elif name not in beta.index:
            rows.append((2, math.inf, f"| {name} | {needs} | — | — | — | not run |"))
        else:
            r = beta.loc[name]
            rmse_deg = math.degrees(float(r["rmse"])) if pd.notna(r["rmse"]) else math.nan
            ratio = float(r["rmse"]) / base if math.isfinite(base) and base > 0 else math.nan
            status = str(r["status"]) + (f": {details[name]}" if details.get(name) and r["status"] != "ok" else "")
            if math.isfinite(rmse_deg):
                rows.append((0 if name == BASELINE else 1, rmse_deg,
                             f"| {name} | {needs} | {rmse_deg:.3f} | {ratio:.2f} | {float(r['rmse']) / z:.2f} "
                             f"| {status} |"))
            else:
                rows.append((2, math.inf, f"| {name} | {needs} | — | — | — | {status} |"))
    if math.isfinite(z):
        ratio = z / base if math.isfinite(base) and base > 0 else math.nan
        rows.append((0, -1.0, f"| {ZERO_ROW} | — | {math.degrees(z):.3f} | {ratio:.2f} | 1.00 | baseline |"))
    head = ("| observer | needs | β RMSE [deg] | × kf_bicycle | × β = 0 | status |\n"
            "|---|---|---:|---:|---:|---|")
    return "\n".join([head, *(line for _, _, line in sorted(rows))])


def wrong_vehicles(folder: Path) -> dict[str, str]:
    """Deliberately wrong vehicle files for the Revs car, written into ``folder``: label -> path or name."""
    import re

    from roadtruth.harness.truth.vehicle import load_vehicle

    text = Path(load_vehicle("ferrari_250lm").path).read_text()

    def variant(label: str, grip: float | None = None, stiffness: float | None = None) -> str:
        t = text
        if grip is not None:
            t = re.sub(r"grip: [0-9.]+", f"grip: {grip}", t)
        if stiffness is not None:
            t = re.sub(r"cornering_stiffness_Npr: ([0-9.]+)",
                       lambda m: f"cornering_stiffness_Npr: {float(m.group(1)) * stiffness:.1f}", t)
        path = folder / f"{label}.yaml"
        path.write_text(t)
        return str(path)

    return {"ferrari_250lm (shipped)": "ferrari_250lm", "grip 0.9": variant("grip_0_9", grip=0.9),
            "axle stiffness x0.7": variant("stiff_0_7", stiffness=0.7),
            "axle stiffness x1.3": variant("stiff_1_3", stiffness=1.3), "sedan": "sedan"}


def robustness(zero: float) -> None:
    """β RMSE on the Revs log with wrong vehicles, per vehicle and observer (Markdown)."""
    print("\nThe same log with deliberately wrong vehicles (β RMSE [deg]; × kf_bicycle; status):\n")
    print("| vehicle | " + " | ".join(ROBUST_OBSERVERS) + f" | {ZERO_ROW} |")
    print("|---|" + "---:|" * (len(ROBUST_OBSERVERS) + 1))
    with tempfile.TemporaryDirectory() as tmp:
        for label, veh in wrong_vehicles(Path(tmp)).items():
            folder = replay(REVS_LOG, vehicle=veh, columns="revs_250lm", observers=ROBUST_OBSERVERS,
                            out=Path(tmp) / label.replace(" ", "_"))
            beta = pd.read_csv(folder / "metrics.csv").query("state == 'beta_rad'").set_index("observer")
            base = float(beta.loc[BASELINE, "rmse"])
            cells = [f"{math.degrees(float(beta.loc[n, 'rmse'])):.3f} ({float(beta.loc[n, 'rmse']) / base:.2f}; "
                     f"{beta.loc[n, 'status']})" for n in ROBUST_OBSERVERS]
            print(f"| {label} | " + " | ".join(cells) + f" | {math.degrees(zero):.3f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="keep the replay folder here (default: a temporary one)")
    ap.add_argument("--robustness", action="store_true", help="also replay with deliberately wrong vehicles")
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
    zero = zero_beta_rmse(REVS_LOG, "revs_250lm")
    print(beta_table(metrics, cmap.measured, details, zero))
    if a.robustness:
        robustness(zero)


if __name__ == "__main__":
    main()
