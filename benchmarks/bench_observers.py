"""Microseconds per step of every registered observer, and the cold design time of each LMI design.

Run: ``.venv/bin/python benchmarks/bench_observers.py [--vehicle sedan] [--seconds 60]``.
Inputs: a 60 s, 100 Hz lateral manoeuvre of the linear bicycle model (no MuJoCo needed).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np


def manoeuvre(vehicle, seconds: float, hz: float = 100.0) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    from observers.bicycle import ay_output, expm2_zoh, vy_r_model

    h = 1.0 / hz
    t = np.arange(0.0, seconds, h)
    vx = 20.0 + 5.0 * np.sin(2 * np.pi * t / 30.0)
    ax = np.gradient(vx, h)
    delta = 0.04 * np.sin(2 * np.pi * 0.5 * t) * (np.sin(2 * np.pi * t / 10) > 0)
    x = np.zeros(2)
    X, AY = [], []
    for k in range(len(t)):
        A, B = vy_r_model(vehicle, vx[k])
        E, G = expm2_zoh(*A.reshape(-1), h)
        x = np.array(E).reshape(2, 2) @ x + np.array(G).reshape(2, 2) @ B * delta[k]
        c, d = ay_output(vehicle, vx[k])
        X.append(x)
        AY.append(c @ x + d * delta[k])
    X = np.array(X)
    # Lane camera on a straight road along x (look-ahead 0.5 m): heading relative to the lane = psi.
    psi = np.cumsum(X[:, 1]) * h
    y = np.cumsum(vx * np.sin(psi) + X[:, 0] * np.cos(psi)) * h
    return t, {"delta_rad": delta, "vx_mps": vx, "ax_mps2": ax, "yaw_rate_radps": X[:, 1],
               "ay_mps2": np.array(AY), "psi_lane_rad": psi, "y_lane_m": y + 0.5 * np.sin(psi),
               "rho_1pm": np.zeros_like(t)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicle", default="sedan")
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    os.environ["ROADTRUTH_CACHE"] = tempfile.mkdtemp(prefix="roadtruth-bench-")  # cold designs

    from harness.vehicle import load_vehicle
    from observers import lmi
    from observers.registry import available_observers, create

    vehicle = load_vehicle(args.vehicle)
    t, sig = manoeuvre(vehicle, args.seconds)
    print(f"vehicle {vehicle.name}, {len(t)} steps ({args.seconds:g} s at 100 Hz)\n")
    print(f"{'observer':24s} {'us/step':>8s} {'design s':>9s} {'warm s':>8s}  design")
    for name in available_observers():
        lmi.clear_memory_cache()
        obs = create(name, vehicle)
        t0 = time.perf_counter()
        d = obs.design()
        cold = time.perf_counter() - t0
        lmi.clear_memory_cache()
        t0 = time.perf_counter()
        create(name, vehicle).design()
        warm = time.perf_counter() - t0
        missing = [c for c in obs.inputs if c not in sig]
        if missing:
            print(f"{name:24s} skipped: the benchmark manoeuvre has no {', '.join(missing)}")
            continue
        Y = np.column_stack([sig[c] for c in obs.inputs])
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            obs.run(t, Y)
            best = min(best, time.perf_counter() - t0)
        lmi_design = d.status.value != "not_applicable"
        print(f"{name:24s} {best / len(t) * 1e6:8.1f} {cold if lmi_design else 0:9.2f} "
              f"{warm if lmi_design else 0:8.3f}  {d.status.value}: {d.reason[:70]}")


if __name__ == "__main__":
    main()
