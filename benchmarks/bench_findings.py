"""The observer findings on the MuJoCo truth: every figure of README "Findings" and of the finding
paragraphs of docs/OBSERVERS.md (interval, unknown-input, Takagi–Sugeno, switched interval observers).

Run: ``python benchmarks/bench_findings.py [--seed N]``. Each case is one scenario simulated and sensed
exactly as ``roadtruth run --no-render`` does (``roadtruth.harness.jobs.pipeline`` stages: the scenario's own seed
unless ``--seed``, so the truth and the sensor noise are those of the default run), then the observers
run with the options shown and are scored by ``roadtruth.harness.evaluation.scoring.score`` (the ``metrics.csv`` rows).
Printed, per case: seeds, the metrics rows quoted in the docs, and derived figures (interval width
ratios, effective tire stiffness ``F_y/α`` relative to the static axle stiffness, inclusion-loss
windows, lane-camera curvature error). About a minute on a quiet core; nothing is written to disk.
"""

from __future__ import annotations

import argparse
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

#: Margins of the widened interval observer: ±35 % stiffness box plus sensor-error bounds on the
#: yaw rate [rad/s] and on the pseudo-output [rad] (docs/OBSERVERS.md, interval observer).
WIDE_INTERVAL = {"stiffness_uncertainty": 0.35, "yaw_rate_error_bound_radps": 0.015, "y_error_bound_rad": 0.002}
#: Slip angles below this [rad] are left out of F_y/α (the ratio of two small numbers is meaningless).
MIN_SLIP_RAD = 0.01


@dataclass(frozen=True)
class Case:
    """One evaluated scenario: the truth frame, measurements, long estimates and metrics."""

    scenario: str
    sensors: str
    seed: int
    truth: Any
    measurements: Any
    estimates: Any
    metrics: Any
    vehicle: Any


def evaluate(scenario: str, observers: list[str], *, sensors: str | None = None, seed: int | None = None,
             options: dict[str, dict[str, Any]] | None = None, label: dict[str, str] | None = None) -> Case:
    """Simulate, sense, estimate and score one scenario as ``roadtruth run`` does.

    ``label`` renames observers in the estimates and metrics (to run one observer twice with
    different ``options``, evaluate twice and concatenate)."""
    import pandas as pd

    from roadtruth.harness.evaluation.estimate import run_observers
    from roadtruth.harness.evaluation.scoring import score
    from roadtruth.harness.jobs.pipeline import prepare_scenario, scenario_seeds, sensor_config
    from roadtruth.harness.sensors import emulate
    from roadtruth.harness.truth.simulate import simulate
    from roadtruth.harness.truth.truth_events import scored_until_of

    sc = prepare_scenario(scenario, None, None)
    veh = sc.vehicle_params()
    _, sim_seed, sensor_seed = scenario_seeds(sc.seed, scenario, seed)
    truth = simulate(sc, seed=sim_seed)
    meas = emulate(truth.frame, veh, sensor_config(sc, sensors, None), sensor_seed,
                   outages=sc.outages, lane_gaps=sc.lane_gaps)
    est, runs = run_observers(meas.frame, veh, observers, options=options)
    metrics = score(truth.frame, est, scenario=scenario, runs=runs, mass_kg=veh.mass_kg,
                    scored_until_s=scored_until_of(truth))
    if label:
        est = est.assign(observer=est["observer"].replace(label))
        metrics = metrics.assign(observer=metrics["observer"].replace(label))
    return Case(scenario, sensors or sc.sensors, sc.seed if seed is None else seed, truth.frame, meas.frame,
                est, pd.DataFrame(metrics), veh)


def metric(case: Case, observer: str, state: str, column: str) -> float:
    m = case.metrics
    row = m[(m["observer"] == observer) & (m["state"] == state)]
    return float(row[column].iloc[0]) if len(row) else float("nan")


def stiffness_ratio(case: Case, t0: float = -np.inf, t1: float = np.inf) -> tuple[float, float, float, float]:
    """Min/max of ``F_y/α`` over the static axle stiffness, front then rear, on ``t0 <= t <= t1``."""
    tr = case.truth
    w = (tr["t_s"] >= t0) & (tr["t_s"] <= t1)
    out = []
    for axle, c in (("f", case.vehicle.cornering_stiffness_f_Npr), ("r", case.vehicle.cornering_stiffness_r_Npr)):
        a, f = tr[f"alpha_{axle}_rad"][w].to_numpy(float), tr[f"fy_{axle}_N"][w].to_numpy(float)
        ok = np.abs(a) >= MIN_SLIP_RAD
        k = f[ok] / a[ok] / c
        out += [float(k.min()), float(k.max())] if k.size else [float("nan")] * 2
    return out[0], out[1], out[2], out[3]


def inclusion(case: Case, observer: str, state: str) -> tuple[float, float, float]:
    """First and last time [s] the truth is outside the bounds, and the largest excess [state unit]."""
    e = case.estimates
    g = e[(e["observer"] == observer) & (e["state"] == state)]
    t = g["t_s"].to_numpy(float)
    x = np.interp(t, case.truth["t_s"].to_numpy(float), case.truth[state].to_numpy(float))
    excess = np.maximum(x - g["hi"].to_numpy(float), g["lo"].to_numpy(float) - x)
    out = np.flatnonzero(excess > 0)
    if not out.size:
        return float("nan"), float("nan"), 0.0
    return float(t[out[0]]), float(t[out[-1]]), float(excess[out].max())


def camera_curvature_rmse(case: Case) -> float:
    """RMS of the lane camera's curvature output minus the true curvature at the sample times [1/m]."""
    m = case.measurements
    ok = np.isfinite(m["rho_1pm"].to_numpy(float))
    t = m["t_s"].to_numpy(float)[ok]
    truth = np.interp(t, case.truth["t_s"].to_numpy(float), case.truth["rho_1pm"].to_numpy(float))
    return float(np.sqrt(np.mean((m["rho_1pm"].to_numpy(float)[ok] - truth) ** 2)))


def lane_rate_errors(case: Case, lipschitz: tuple[float, ...] = (0.3, 1.0, 3.0, 10.0, 30.0)) -> dict[float, float]:
    """RMS error [m/s] of the order-2 Levant derivative of the camera's lane offset against the true
    ``d y_L / dt`` at each sample's arrival (latency included; restarted after a gap > 0.2 s, the first 2 s after
    each start left out),
    per Lipschitz constant ``L`` [m/s^3]: the error of the algebraic ``v_y`` premise of Yacine et al."""
    from roadtruth.observers.levant_differentiator import LevantDifferentiator

    m = case.measurements
    y = m["y_lane_m"].to_numpy(float)
    ok = np.isfinite(y)
    t, y = m["t_s"].to_numpy(float)[ok], y[ok]
    tt = case.truth["t_s"].to_numpy(float)
    rate = np.interp(t, tt, np.gradient(case.truth["y_lane_m"].to_numpy(float), tt))
    out = {}
    for L in lipschitz:
        d = LevantDifferentiator(2, L)
        z = np.empty_like(y)
        since = np.empty_like(y)  # time since the differentiator (re)started [s]
        start = t[0]
        for k in range(y.size):
            if k == 0 or t[k] - t[k - 1] > 0.2:  # first sample, or after a marking gap / lost lock
                d.reset(float(y[k]))
                start = t[k]
            else:
                d.update(float(y[k]), float(t[k] - t[k - 1]))
            z[k], since[k] = d.derivative(1), t[k] - start
        late = (since > 2.0) & np.isfinite(rate)
        out[L] = float(np.sqrt(np.mean((z[late] - rate[late]) ** 2)))
    return out


def head(case: Case) -> None:
    print(f"\n== {case.scenario}, {case.sensors} sensors, seed {case.seed}")


def interval_section(seed: int | None) -> None:
    import pandas as pd

    print("\n# Interval observer (Wang 2014 ch. 4) on the double lane change")
    states = ("alpha_f_rad", "alpha_r_rad", "beta_rad")
    for sensors in ("ideal", "automotive"):
        base = evaluate("double_lane_change", ["interval_wang"], sensors=sensors, seed=seed)
        wide = evaluate("double_lane_change", ["interval_wang"], sensors=sensors, seed=seed,
                        options={"interval_wang": WIDE_INTERVAL}, label={"interval_wang": "interval_wang_wide"})
        head(base)
        both = Case(base.scenario, base.sensors, base.seed, base.truth, base.measurements,
                    pd.concat([base.estimates, wide.estimates]), pd.concat([base.metrics, wide.metrics]), base.vehicle)
        for name in ("interval_wang", "interval_wang_wide"):
            cov = " / ".join(f"{metric(both, name, s, 'coverage'):.2f}" for s in states)
            width = " / ".join(f"{metric(both, name, s, 'mean_width'):.4g}" for s in states)
            print(f"{name:20s} coverage a_f/a_r/beta {cov}   mean width [rad] {width}")
        ratio = " / ".join(f"{metric(both, 'interval_wang_wide', s, 'mean_width') / metric(both, 'interval_wang', s, 'mean_width'):.2f}"
                           for s in states)
        print(f"{'':20s} width ratio wide/default a_f/a_r/beta {ratio}")
        if sensors == "automotive":
            kf0, kf1, kr0, kr1 = stiffness_ratio(base)
            print(f"F_y/alpha / static stiffness (|alpha| >= {MIN_SLIP_RAD} rad): front {kf0:.2f}-{kf1:.2f}, "
                  f"rear {kr0:.2f}-{kr1:.2f}")


def switched_section(seed: int | None) -> None:
    print("\n# Switched interval observer (Ifqir et al. 2018) and interval observer on curvy_road and mu_step")
    for scenario in ("curvy_road", "mu_step"):
        c = evaluate(scenario, ["switched_interval_ifqir", "interval_wang"], seed=seed)
        head(c)
        for name, state in (("switched_interval_ifqir", "vy_mps"), ("switched_interval_ifqir", "beta_rad"),
                            ("switched_interval_ifqir", "yaw_rate_radps"), ("interval_wang", "beta_rad")):
            t0, t1, ex = inclusion(c, name, state)
            unit = {"beta_rad": "deg", "vy_mps": "m/s"}.get(state, "rad/s")
            k = np.degrees(ex) if state == "beta_rad" else ex
            print(f"{name:24s} {state:9s} coverage {metric(c, name, state, 'coverage'):.3f}  mean width "
                  f"{metric(c, name, state, 'mean_width'):.3g}  outside {t0:.2f}-{t1:.2f} s, max excess {k:.3g} {unit}")
        kf0, kf1, kr0, kr1 = stiffness_ratio(c)
        print(f"F_y/alpha / static stiffness, whole run: front {kf0:.2f}-{kf1:.2f}, rear {kr0:.2f}-{kr1:.2f}")
        t0, t1, _ = inclusion(c, "switched_interval_ifqir", "vy_mps")
        if np.isfinite(t0):
            kf0, kf1, kr0, kr1 = stiffness_ratio(c, t0, t1)
            print(f"  ... while v_y is outside ({t0:.2f}-{t1:.2f} s): front {kf0:.2f}-{kf1:.2f}, rear {kr0:.2f}-{kr1:.2f}")


def ts_uio_section(seed: int | None) -> None:
    print("\n# Takagi-Sugeno (Yacine et al. 2015) and unknown-input (Nguyen) observers")
    obs = ["ts_yacine", "ts_yacine_xhat", "kf_bicycle", "open_loop_bicycle", "uio_nguyen"]
    for scenario, sensors in (("curvy_road", "automotive"), ("curvy_road", "ideal"),
                              ("double_lane_change", "automotive"), ("step_steer", "automotive"),
                              ("mu_step", "automotive")):
        c = evaluate(scenario, obs, sensors=sensors, seed=seed)
        head(c)
        print(f"{'observer':20s} {'vy RMSE [m/s]':>14s} {'beta RMSE [deg]':>16s} {'r RMSE [rad/s]':>15s} "
              f"{'r max [rad/s]':>14s} {'rho RMSE [1/m]':>15s}")
        for name in obs:
            print(f"{name:20s} {metric(c, name, 'vy_mps', 'rmse'):14.4f} "
                  f"{np.degrees(metric(c, name, 'beta_rad', 'rmse')):16.3f} "
                  f"{metric(c, name, 'yaw_rate_radps', 'rmse'):15.4f} {metric(c, name, 'yaw_rate_radps', 'max_abs'):14.4f} "
                  f"{metric(c, name, 'rho_1pm', 'rmse'):15.3g}")
        if sensors == "automotive" and scenario == "curvy_road":
            errs = lane_rate_errors(c)
            vy = c.truth["vy_mps"].to_numpy(float)
            print("Levant d(y_L)/dt RMS error [m/s] per L [m/s^3]: "
                  + ", ".join(f"L {k:g}: {v:.3f}" for k, v in errs.items())
                  + f"; assuming v_y = 0 instead: {np.sqrt(np.mean(vy ** 2)):.3f}")
        if scenario == "curvy_road":
            print(f"{'lane camera rho':20s} {'':14s} {'':16s} {'':15s} {'':14s} {camera_curvature_rmse(c):15.3g}")
        if scenario == "step_steer":
            psi = c.measurements["psi_lane_rad"].to_numpy(float)
            t_last = c.measurements["t_s"].to_numpy(float)[np.isfinite(psi)][-1]
            print(f"camera heading |psi_L| up to {np.nanmax(np.abs(psi)):.2f} rad; last lane sample at {t_last:.2f} s")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=None, help="run seed (default: each scenario's own seed)")
    a = p.parse_args()
    interval_section(a.seed)
    switched_section(a.seed)
    ts_uio_section(a.seed)


if __name__ == "__main__":
    main()
