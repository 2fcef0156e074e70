"""Neuro-adaptive observers of Bessafa (2024, ch. 3): certification, the S3a design-model run, MuJoCo.

Prints every number of the neuro-adaptive section of docs/OBSERVERS.md:

1. LMI (3.12): the largest certifiable lambda under P <= diag(1e-2, ..., 1e-5) for the fresh design and
   for the printed gains, and each variant's status.
2. The design model (3.27) with the input (3.30) (S3a), position only, x(0) = (0, 20, 0), x_hat(0) =
   (0, 18, 0.5, 0), 1 ms samples: steady-state |error| of p, v, a and the unknown term x_4 = f(x) (max
   over the windows 5-10 s after each change of the input) next to the thesis's claim (< 1e-6), the
   time after which every error stays below 1e-2 / 1e-4 (thesis: converged "< 0.1 s"), the history
   stack's final minimum singular value and the loop's cost in us/step.
3. ``car_following`` on MuJoCo truth with automotive sensors (seed of the scenario, 12): RMSE of range,
   range rate and lead acceleration, status and certification (--no-mujoco skips it).

Run: ``MUJOCO_GL=egl .venv/bin/python benchmarks/bench_neuro_adaptive.py``
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from roadtruth.observers import neuro_adaptive as na
from roadtruth.observers import neuro_adaptive_design as nad
from roadtruth.observers.lmi import SolverSettings

WINDOWS = ((5.0, 10.0), (15.0, 20.0), (25.0, 30.0), (35.0, 40.0), (45.0, 50.0), (55.0, 60.0))
VARIANTS = ((na.NeuroAdaptiveCL, {}), (na.NeuroAdaptiveCLPrinted, {}),
            (na.CLAEORanXie, {"eps": 0.05, "eta1": 100.0, "eta2": 100.0}), (na.NeuroAdaptiveChakrabarty, {}))


def certification() -> None:
    print("LMI (3.12), P <= diag(1e-2, 1e-3, 1e-4, 1e-5) (printed lambda = 1e5 is infeasible for any gains:")
    print(f"  lambda <= 2 sqrt(D_33 D_44) = {2 * np.sqrt(1e-9):.3g})")
    for variant in ("lmi", "printed"):
        d = nad.design(variant, 1e-3, SolverSettings())
        m = d.margins
        print(f"  {variant:8s} {d.status.value:9s} largest certifiable lambda {m['lambda_max_certifiable']:.4g}; "
              f"L~ = {np.round(np.r_[d.gain('L'), d.gain('K')], 1).tolist()}; poles {m['fastest_pole_radps']:.4g} .. "
              f"{m['slowest_pole_radps']:.4g} rad/s; certified V decay {m['decay_rate_V_per_s']:.3g} /s")


def s3a() -> None:
    dt = 1e-3
    t = np.round(np.arange(0.0, 60.0 + dt / 2, dt), 9)
    x, f = nad.simulate_m7c(t, (0.0, 20.0, 0.0), nad.s3a_input, substeps=1)
    u = np.array([nad.s3a_input(float(tt)) for tt in t])
    print("\nS3a (design model (3.27), input (3.30), position only, 1 ms): steady |error| (thesis: < 1e-6), "
          "convergence (thesis: < 0.1 s)")
    print(f"  {'observer':28s} {'p [m]':>9s} {'v [m/s]':>9s} {'a [m/s2]':>9s} {'x4 [m/s3]':>9s} "
          f"{'t<1e-2':>7s} {'t<1e-4':>7s} {'smin':>6s} {'us/step':>8s}")
    for cls, opts in VARIANTS:
        obs = cls(None, **opts)
        obs.run_model(t[:10], x[:10, 0], u[:10], np.array([0.0, 18.0, 0.5, 0.0]))  # compile
        t0 = time.perf_counter()
        tr = obs.run_model(t, x[:, 0], u, np.array([0.0, 18.0, 0.5, 0.0]))
        us = (time.perf_counter() - t0) / len(t) * 1e6
        err = np.abs(np.column_stack([tr.z[:, :3] - x, tr.z[:, 3] - f]))
        ss = np.max([err[(t >= a) & (t <= b)].max(axis=0) for a, b in WINDOWS], axis=0)
        worst = err.max(axis=1)
        conv = [t[np.nonzero(worst[t <= 10] > thr)[0][-1] + 1] for thr in (1e-2, 1e-4)]
        print(f"  {cls.name:28s} {ss[0]:9.2e} {ss[1]:9.2e} {ss[2]:9.2e} {ss[3]:9.2e} {conv[0]:7.3f} {conv[1]:7.3f} "
              f"{tr.smin[-1]:6.3f} {us:8.2f}")
    print(f"  max |df/dt| after 5 s: {np.abs(np.diff(f) / dt)[t[1:] > 5].max():.2e} m/s^4 (the disturbance "
          "of the x_4 channel); f ranges over [" f"{f.min():.3f}, {f.max():.4f}] m/s^3")


def mujoco() -> None:
    import pandas as pd

    from roadtruth.harness.jobs.pipeline import run_suite

    names = [cls.name for cls, _ in VARIANTS]
    with tempfile.TemporaryDirectory() as tmp:
        out = run_suite(scenarios=["car_following"], observers=names, out=Path(tmp) / "r", render=False,
                        progress=False)
        m = pd.read_csv(out / "metrics.csv")
        truth = pd.read_csv(out / "car_following" / "truth.csv")
    print("\ncar_following (MuJoCo, automotive sensors: radar 20 Hz, 0.1 m range noise, 50 ms latency; seed 12)")
    print(f"  RMS of the lead acceleration itself: {np.sqrt(np.mean(truth['lead_accel_mps2'] ** 2)):.3f} m/s^2")
    for name in names:
        r = m[m["observer"] == name].set_index("state")
        print(f"  {name:28s} RMSE range {r.loc['range_m', 'rmse']:.3f} m, range rate "
              f"{r.loc['range_rate_mps', 'rmse']:.3f} m/s, lead accel {r.loc['lead_accel_mps2', 'rmse']:.3f} m/s^2; "
              f"status {r['status'].iloc[0]}, certified {bool(r['certified'].iloc[0])}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-mujoco", action="store_true", help="skip the MuJoCo scenario")
    args = ap.parse_args()
    certification()
    s3a()
    if not args.no_mujoco:
        mujoco()


if __name__ == "__main__":
    main()
