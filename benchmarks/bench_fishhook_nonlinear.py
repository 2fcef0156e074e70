"""Wang (2014) sec. 5.4.2 fishhook finding on MuJoCo truth with automotive sensors.

Run: ``python benchmarks/bench_fishhook_nonlinear.py [--seed N] [--vehicle sedan|wang2014]
[--amplitudes 7.7,9,11]``. The dissertation's claim (fig. 5.8): the linear-tire LPV observer errs
once |alpha| exceeds about 0.1 rad, the gain-scheduled nonlinear observer keeps tracking. Each run is
the ``fishhook`` scenario (NHTSA fishhook at 17.88 m/s) with the road-wheel amplitude scaled (a
temporary scenario file; 7.7 deg is the shipped one). Printed per amplitude: the truth's peak
|alpha_f|, |alpha_r| and |beta| [deg], whether the car left the linear range, then per observer the
slip-angle RMSE [deg] (mean of front and rear) over the whole run and over the samples where the
true |alpha| of that axle exceeds 0.1 rad, and the peak error there. Also the mu_step scenario
(friction steps), and each observer's cost in us/step.

The sensor noise seed is ``--seed`` (default 1); the MuJoCo truth is deterministic. Figures quoted in
docs/OBSERVERS.md (nonlinear Wang section) come from this script.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

OBSERVERS = ("lpv_wang", "nonlinear_wang", "nonlinear_wang_l2", "nonlinear_wang_arcak", "nonlinear_wang_luenberger",
             "nonlinear_wang_printed", "ekf_bicycle")
BIG = 0.1  # rad: where the dissertation says the linear tire model fails


def _scenario(amplitude_deg: float, folder: Path):
    """The shipped fishhook with the road-wheel amplitude replaced (a scenario file in ``folder``)."""
    from roadtruth.harness.truth.scenario import load_scenario
    src = Path(__file__).resolve().parents[1] / "harness" / "scenarios" / "fishhook.yaml"
    text = src.read_text().replace("amplitude_deg: 7.7", f"amplitude_deg: {amplitude_deg}")
    name = f"fishhook_{amplitude_deg:g}".replace(".", "_")
    path = folder / f"{name}.yaml"
    path.write_text(text.replace("name: fishhook", f"name: {name}"))
    return load_scenario(str(path))


def run_one(sc, vehicle_name: str, seed: int) -> tuple[dict[str, float], dict[str, dict[str, float]]]:
    """Truth summary and per-observer errors [deg] for one scenario."""
    from roadtruth.harness.evaluation.estimate import run_observers
    from roadtruth.harness.sensors import load_sensor_config
    from roadtruth.harness.sensors.suite import emulate
    from roadtruth.harness.truth.simulate import simulate
    from roadtruth.harness.truth.vehicle import load_vehicle

    sc = sc.with_vehicle(vehicle_name)
    vehicle = load_vehicle(vehicle_name)
    truth = simulate(sc)
    tf = truth.frame
    meas = emulate(tf, vehicle, load_sensor_config(sc.sensors, sc.sensor_overrides, None), seed,
                   outages=sc.outages, lane_gaps=sc.lane_gaps)
    a_true = tf[["alpha_f_rad", "alpha_r_rad"]].to_numpy()
    summary = {"peak_alpha_f_deg": float(np.rad2deg(np.nanmax(np.abs(a_true[:, 0])))),
               "peak_alpha_r_deg": float(np.rad2deg(np.nanmax(np.abs(a_true[:, 1])))),
               "peak_beta_deg": float(np.rad2deg(np.nanmax(np.abs(tf["beta_rad"].to_numpy())))),
               "big_fraction": float(np.mean(np.abs(a_true) > BIG))}
    t0 = time.perf_counter()
    est, runs = run_observers(meas.frame, vehicle, list(OBSERVERS))
    del t0
    out: dict[str, dict[str, float]] = {}
    tt = tf["t_s"].to_numpy()
    for name in OBSERVERS:
        sub = est[est["observer"] == name]
        if sub.empty:
            out[name] = {"rmse": np.nan, "rmse_big": np.nan, "max_big": np.nan}
            continue
        errs, big = [], []
        for j, st in enumerate(("alpha_f_rad", "alpha_r_rad")):
            s = sub[sub["state"] == st].sort_values("t_s")
            xe = np.interp(tt, s["t_s"].to_numpy(), s["value"].to_numpy())
            e = xe - a_true[:, j]
            ok = tt >= 1.0  # after the dissertation's 1 s start-up
            errs.append(e[ok])
            big.append(e[ok & (np.abs(a_true[:, j]) > BIG)])
        allv, bigv = np.concatenate(errs), np.concatenate(big)
        out[name] = {"rmse": float(np.rad2deg(np.sqrt(np.mean(allv ** 2)))),
                     "rmse_big": float(np.rad2deg(np.sqrt(np.mean(bigv ** 2)))) if bigv.size else np.nan,
                     "max_big": float(np.rad2deg(np.abs(bigv).max())) if bigv.size else np.nan}
    return summary, out


def us_per_step(vehicle_name: str, n: int = 20000) -> dict[str, float]:
    """Cost of each nonlinear observer on synthetic inputs [us/step] (design cached, numba warm)."""
    from roadtruth.harness.truth.vehicle import load_vehicle
    from roadtruth.observers.registry import create
    v = load_vehicle(vehicle_name)
    t = np.arange(n) * 0.01
    Y = np.column_stack([0.05 * np.sin(t), 0.1 * np.sin(t), 20 + np.sin(0.1 * t), np.cos(t)])
    out = {}
    for name in OBSERVERS[1:6]:
        obs = create(name, v)
        obs.run(t[:100], Y[:100])
        t0 = time.perf_counter()
        obs.run(t, Y)
        out[name] = (time.perf_counter() - t0) / n * 1e6
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--vehicle", default="sedan")
    ap.add_argument("--amplitudes", default="7.7,9,11")
    args = ap.parse_args()
    from roadtruth.harness.truth.scenario import load_scenario
    print(f"vehicle {args.vehicle}, sensors automotive, noise seed {args.seed}; RMSE after t = 1 s [deg]")
    with tempfile.TemporaryDirectory() as tmp:
        cases = [(f"fishhook {a} deg", _scenario(float(a), Path(tmp))) for a in args.amplitudes.split(",")]
        cases.append(("mu_step", load_scenario("mu_step")))
        for label, sc in cases:
            summary, res = run_one(sc, args.vehicle, args.seed)
            print(f"\n{label}: peak |alpha_f| {summary['peak_alpha_f_deg']:.2f}, |alpha_r| "
                  f"{summary['peak_alpha_r_deg']:.2f}, |beta| {summary['peak_beta_deg']:.2f} deg; "
                  f"samples with |alpha| > {BIG} rad: {100 * summary['big_fraction']:.1f} %")
            if summary["peak_beta_deg"] > 20.0:
                print("  the car spun out (|beta| > 20 deg): not scored, a spin is not an observer error")
                continue
            print(f"  {'observer':28s} {'rmse':>7s} {'rmse|a|>0.1':>12s} {'max|a|>0.1':>11s}")
            for name, r in res.items():
                print(f"  {name:28s} {r['rmse']:7.3f} {r['rmse_big']:12.3f} {r['max_big']:11.3f}")
    print("\nus/step:", {k: round(v, 2) for k, v in us_per_step(args.vehicle).items()})


if __name__ == "__main__":
    main()
