"""Ground-truth physics checks of the MuJoCo car: the figures of the README "Ground truth" table.

Run: ``python benchmarks/bench_truth.py``. It simulates the manoeuvres of ``tests/test_simulate.py``
(default sedan at 20 m/s: 1° and 3° step steer, 1.5 °/s ramp steer, 5 °/s ramp to 20° on μ = 1 and
μ = 0.3, a 2° turn onto an ice patch) and prints the measured values the tests assert bounds on.
The simulation draws no random numbers for these scenarios (seed 0), so the output is identical on
every run.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")


def scenario(duration_s: float, steer: dict[str, Any], **extra: Any) -> Any:
    from roadtruth.harness.truth.scenario import parse_scenario

    data = {"name": "bench", "vehicle": "sedan", "duration_s": duration_s, "initial_speed_mps": 20.0,
            "driver": {"steer": steer}, **extra}
    return parse_scenario(data, "bench")


def linear_yaw_rate(v: Any, t: np.ndarray, vx: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Yaw rate [rad/s] of the linear single-track model driven by the same δ(t), v_x(t) (Euler)."""
    m, iz, lf, lr = v.mass_kg, v.yaw_inertia_kgm2, v.lf_m, v.lr_m
    cf, cr = v.cornering_stiffness_f_Npr, v.cornering_stiffness_r_Npr
    vy = r = 0.0
    out = np.empty_like(t)
    dt = t[1] - t[0]
    for k in range(t.size):
        out[k] = r
        fyf = cf * (delta[k] - (vy + lf * r) / vx[k])
        fyr = -cr * (vy - lr * r) / vx[k]
        vy += dt * ((fyf + fyr) / m - vx[k] * r)
        r += dt * (lf * fyf - lr * fyr) / iz
    return out


def main() -> None:
    from roadtruth.harness.truth.simulate import simulate
    from roadtruth.harness.truth.vehicle import G, load_vehicle

    sedan = load_vehicle("sedan")
    f = simulate(scenario(4.0, {"type": "step", "t_start_s": 0.5, "amplitude_deg": 1.0})).frame
    late = f[f.t_s > 3.0]
    r_ss, r_lin = late.yaw_rate_radps.mean(), sedan.steady_yaw_rate(late.vx_mps.mean(), late.delta_rad.mean())
    print(f"1 deg step steer, steady yaw rate: MuJoCo {r_ss:.5f} vs linear bicycle {r_lin:.5f} rad/s "
          f"({(r_ss / r_lin - 1) * 100:+.1f} %)")

    f = simulate(scenario(5.0, {"type": "ramp", "t_start_s": 0.5, "rate_degps": 1.5, "max_deg": 8.0})).frame
    r_model = linear_yaw_rate(sedan, f.t_s.to_numpy(), f.vx_mps.to_numpy(), f.delta_rad.to_numpy())
    ratio = f.yaw_rate_radps.to_numpy() / np.where(r_model > 1e-3, r_model, np.nan)
    ay = f.ay_mps2.to_numpy()
    bins = [np.nanmean(ratio[(ay > a) & (ay < a + 1.5)]) for a in (1.0, 2.5, 4.0, 5.5, 7.0)]
    print("ramp steer, yaw-rate gain / linear model in a_y bands 1-2.5 ... 7-8.5 m/s^2: "
          + ", ".join(f"{b:.2f}" for b in bins))

    for mu in (1.0, 0.3):
        sc = scenario(4.5, {"type": "ramp", "t_start_s": 0.5, "rate_degps": 5.0, "max_deg": 20.0},
                      friction={"mu_default": mu})
        a = np.convolve(simulate(sc).frame.ay_mps2, np.ones(101) / 101, mode="valid")  # 0.1 s average
        print(f"peak lateral acceleration (0.1 s mean) on uniform mu = {mu}: {np.max(np.abs(a)) / (mu * G):.2f} mu g")

    f = simulate(scenario(3.5, {"type": "step", "t_start_s": 0.5, "amplitude_deg": 3.0})).frame
    late = f[f.t_s > 2.5]
    fz = late[["fz_fl_N", "fz_fr_N", "fz_rl_N", "fz_rr_N"]].mean()
    transfer = ((fz.fz_fr_N - fz.fz_fl_N) / 2 * sedan.track_f_m + (fz.fz_rr_N - fz.fz_rl_N) / 2 * sedan.track_r_m)
    roll = late.roll_rad.mean()
    expected = sedan.mass_kg * sedan.h_cg_m * (late.ay_mps2.mean() + G * math.sin(roll))
    print(f"3 deg step steer: wheel loads sum to the weight within {abs(fz.sum() / (sedan.mass_kg * G) - 1) * 100:.3f} %; "
          f"load transfer moment vs m h (a_y + g sin phi) {(transfer / expected - 1) * 100:+.1f} %")
    vr = (late.vx_mps * late.yaw_rate_radps).mean()
    f_y = late.fspec_y_body_mps2.mean()
    print(f"accelerometer a_y vs v r cos phi + g sin phi: {(f_y / (vr * math.cos(roll) + G * math.sin(roll)) - 1) * 100:+.3f} % "
          f"(roll {math.degrees(roll):.2f} deg)")

    ice = {"patches": [{"name": "ice", "surface": "ice", "rect": {"x_m": [50.0, 200.0], "y_m": [-100.0, 100.0]}}]}
    f = simulate(scenario(5.0, {"type": "constant", "t_start_s": 0.3, "amplitude_deg": 2.0}, friction=ice)).frame
    on_ice = f.t_s[f.mu_rl == 0.1].min()
    before = np.abs(f.beta_rad[(f.t_s > on_ice - 0.5) & (f.t_s < on_ice)]).max()
    after = np.abs(f.beta_rad[f.t_s > on_ice + 1.0]).max()
    print(f"ice patch in a steady turn: peak |beta| {math.degrees(before):.2f} deg before, "
          f"{math.degrees(after):.2f} deg after ({after / before:.1f} x)")


if __name__ == "__main__":
    main()
