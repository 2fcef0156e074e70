"""Radar high-gain observers on ``car_following``: range, range rate and lead acceleration errors.

Run: ``python benchmarks/bench_radar_lead.py [--sensors automotive|ideal] [--seed N]``. It runs what
``roadtruth run --scenario car_following --observer hgo_radar_standard,hgo_radar_multi,
hgo_radar_standard_printed --no-render`` runs (the scenario's own seed, 12, by default) and prints

* the ``metrics.csv`` rows (scored from the first sample of the record, t = 0);
* the same errors from the first radar sample on (before it the observers hold a placeholder 0:
  with the automotive radar's 50 ms latency that is the first five rows);
* two references that need no observer: the radar's own range and range rate held zero-order
  (latency and noise included) and the constant guess ``a_L = 0`` for the lead acceleration.

Figures quoted in docs/OBSERVERS.md (radar section) come from this script.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

OBSERVERS = ("hgo_radar_standard", "hgo_radar_multi", "hgo_radar_standard_printed")
STATES = ("range_m", "range_rate_mps", "lead_accel_mps2")


def held(t_truth: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``v`` (samples at ``t``, NaN = none) held zero-order onto ``t_truth`` (NaN before the first)."""
    ok = np.isfinite(v)
    t, v = t[ok], v[ok]
    idx = np.searchsorted(t, t_truth + 1e-9, side="right") - 1
    return np.where(idx >= 0, v[np.clip(idx, 0, None)], np.nan)


def rms(e: np.ndarray) -> float:
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sensors", default=None, help="sensor preset (default: the scenario's, automotive)")
    p.add_argument("--seed", type=int, default=None)
    a = p.parse_args()

    import pandas as pd

    from harness.pipeline import run_suite

    with tempfile.TemporaryDirectory(prefix="bench-radar-") as tmp:
        out = run_suite(scenarios=["car_following"], observers=list(OBSERVERS), out=Path(tmp) / "r",
                        sensors=a.sensors, seed=a.seed, render=False, progress=False)
        metrics = pd.read_csv(out / "metrics.csv")
        folder = out / "car_following"
        truth = pd.read_csv(folder / "truth.csv")
        meas = pd.read_csv(folder / "measurements.csv")
        est = pd.read_csv(folder / "estimates.csv")

    print(f"sensors: {a.sensors or 'automotive (scenario default)'}, seed: {a.seed or 'scenario (12)'}")
    print("\nmetrics.csv (scored from t = 0 on the 1 kHz truth):")
    cols = ["observer", "state", "rmse", "mae", "p95_abs", "max_abs", "n_scored", "status"]
    print(metrics[metrics["observer"].isin(OBSERVERS)][cols].to_string(index=False, float_format="%.4g"))

    # the same on the truth.csv grid (100 Hz), from t = 0 and from the first radar sample
    tt = truth["t_s"].to_numpy(float)
    t_meas = meas["t_s"].to_numpy(float)
    first = float(t_meas[np.flatnonzero(np.isfinite(meas["range_m"].to_numpy(float)))[0]])
    after = tt >= first - 1e-9
    print(f"\nRMS error on the 100 Hz truth grid; first radar sample at t = {first:.3f} s")
    print(f"{'':28s}" + "".join(f"{s + ' t>=0':>22s}{s + ' t>=first':>26s}" for s in STATES))
    for name in OBSERVERS:
        line = f"{name:28s}"
        for s in STATES:
            g = est[(est["observer"] == name) & (est["state"] == s)]
            e = held(tt, g["t_s"].to_numpy(float), g["value"].to_numpy(float)) - truth[s].to_numpy(float)
            line += f"{rms(e):22.4g}{rms(e[after]):26.4g}"
        print(line)
    line = f"{'radar held / a_L = 0':28s}"
    for s in STATES:
        if s == "lead_accel_mps2":
            ref = np.zeros_like(tt)
        else:
            ref = held(tt, t_meas, meas[s].to_numpy(float))
        e = ref - truth[s].to_numpy(float)
        line += f"{rms(e):22.4g}{rms(e[after]):26.4g}"
    print(line)


if __name__ == "__main__":
    main()
