"""Microseconds per step of every registered observer, and the cold design time of each LMI design.

Run: ``.venv/bin/python benchmarks/bench_observers.py [--vehicle sedan] [--seconds 60] [--runs 7]
[--only NAME,...] [--no-design]``.
Inputs: a 60 s, 100 Hz lateral manoeuvre of the linear bicycle model (no MuJoCo needed) with every
measurement column a registered observer reads: IMU, steering, wheel speed, lane camera (100 Hz),
GNSS position and speed (10 Hz, NaN between fixes) and a radar lead 30 m ahead (20 Hz, NaN between
samples). us/step is the median (and best) of ``--runs`` whole runs after one warm-up run (which
also compiles and loads the numba kernels).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np


def manoeuvre(vehicle, seconds: float, hz: float = 100.0) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    from roadtruth.observers.bicycle import ay_output, expm2_zoh, vy_r_model

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
    x_pos = np.cumsum(vx * np.cos(psi) - X[:, 0] * np.sin(psi)) * h
    # GNSS at 10 Hz: position [m] and ground speed [m/s]; NaN = no fix at this row.
    gnss = np.arange(len(t)) % int(round(hz / 10.0)) == 0
    speed = np.hypot(vx, X[:, 0])
    # Radar lead: speed 20 m/s + 3 sin(2 pi t / 20), 30 m ahead at t = 0, sampled at 20 Hz.
    v_lead = 20.0 + 3.0 * np.sin(2 * np.pi * t / 20.0)
    rate = v_lead - vx
    rng = 30.0 + np.concatenate([[0.0], np.cumsum(rate[:-1]) * h])
    radar = np.arange(len(t)) % int(round(hz / 20.0)) == 0
    return t, {"delta_rad": delta, "vx_mps": vx, "ax_mps2": ax, "yaw_rate_radps": X[:, 1],
               "ay_mps2": np.array(AY), "psi_lane_rad": psi, "y_lane_m": y + 0.5 * np.sin(psi),
               "rho_1pm": np.zeros_like(t),
               "gnss_x_m": np.where(gnss, x_pos, np.nan), "gnss_y_m": np.where(gnss, y, np.nan),
               "gnss_speed_mps": np.where(gnss, speed, np.nan),
               "range_m": np.where(radar, rng, np.nan), "range_rate_mps": np.where(radar, rate, np.nan)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicle", default="sedan")
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--runs", type=int, default=7, help="timed runs per observer (median and best)")
    ap.add_argument("--only", default="", help="comma-separated observer names (default: all)")
    ap.add_argument("--no-design", action="store_true", help="skip the cold/warm design timing")
    args = ap.parse_args()
    if not args.no_design:
        os.environ["ROADTRUTH_CACHE"] = tempfile.mkdtemp(prefix="roadtruth-bench-")  # cold designs

    from roadtruth.harness.truth.vehicle import load_vehicle
    from roadtruth.observers import lmi
    from roadtruth.observers.registry import available_observers, create

    vehicle = load_vehicle(args.vehicle)
    t, sig = manoeuvre(vehicle, args.seconds)
    print(f"vehicle {vehicle.name}, {len(t)} steps ({args.seconds:g} s at 100 Hz)\n")
    names = available_observers()
    if args.only:
        wanted = [n.strip() for n in args.only.split(",") if n.strip()]
        names = [n for n in names if n in wanted]
    print(f"{'observer':32s} {'us/step':>8s} {'best':>7s} {'design s':>9s} {'warm s':>8s}  design")
    for name in names:
        lmi.clear_memory_cache()
        obs = create(name, vehicle)
        t0 = time.perf_counter()
        d = obs.design()
        cold = time.perf_counter() - t0
        warm = 0.0
        if not args.no_design:
            lmi.clear_memory_cache()
            t0 = time.perf_counter()
            create(name, vehicle).design()
            warm = time.perf_counter() - t0
        missing = [c for c in obs.inputs if c not in sig]
        if missing:
            print(f"{name:32s} skipped: the benchmark manoeuvre has no {', '.join(missing)}")
            continue
        Y = np.column_stack([sig[c] for c in obs.inputs])
        obs.run(t, Y)  # warm-up: numba compile / cache load, first-call allocations
        times = []
        for _ in range(max(1, args.runs)):
            t0 = time.perf_counter()
            obs.run(t, Y)
            times.append(time.perf_counter() - t0)
        lmi_design = d.status.value != "not_applicable" and not args.no_design
        print(f"{name:32s} {np.median(times) / len(t) * 1e6:8.1f} {min(times) / len(t) * 1e6:7.1f} "
              f"{cold if lmi_design else 0:9.2f} {warm if lmi_design else 0:8.3f}  "
              f"{d.status.value}: {d.reason[:60]}")


if __name__ == "__main__":
    main()
