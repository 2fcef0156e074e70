"""GNSS kinematic observers (Bessafa 2024, sec. 5.3) on MuJoCo truth with the automotive sensors.

Prints: the fresh and the printed designs (theta, theta_0, k_f, K chain, certification); metrics
(RMSE) of HGO, fused HGO, EKF and fused EKF on ``gnss_drive`` with 10/40/80 % GNSS position dropouts
(velocity kept: ``gnss.position:channel_dropout``) and on ``gnss_outage``; us/step. Seed: each
scenario's own (gnss_drive 21, gnss_outage 13).

    MUJOCO_GL=egl python benchmarks/bench_gnss_kinematic.py [OUT_DIR]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from roadtruth.harness.jobs.pipeline import run_suite
from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers.gnss_kinematic_design import PRINTED_BASE, PRINTED_FUSED
from roadtruth.observers.registry import create

OBSERVERS = ["hgo_gnss_kinematic", "hgo_gnss_kinematic_printed", "hgo_gnss_kinematic_imu",
             "ekf_gnss_kinematic", "ekf_gnss_kinematic_imu"]
STATES = ["x_m", "y_m", "psi_rad", "vx_mps", "yaw_rate_radps"]


def designs() -> None:
    sedan = load_vehicle("sedan")
    for name in ("hgo_gnss_kinematic", "hgo_gnss_kinematic_printed", "hgo_gnss_kinematic_imu",
                 "hgo_gnss_kinematic_imu_printed"):
        d = create(name, sedan).design()
        m = d.margins
        k = np.asarray(d.gains.get("K", [[np.nan]] * 3), dtype=float)[:3, 0]
        print(f"{name}: {d.status.value}; theta {m.get('theta', float('nan')):.3f}, theta_0 "
              f"{m.get('theta0', float('nan')):.3f}, k_f {m.get('k_f', float('nan')):.4f}, kappa "
              f"{m.get('kappa_per_s', float('nan')):.3f} 1/s, K chain {np.round(k, 4)}; {d.reason}")
    print(f"printed (sec. 5.3.3): K chain {[r[0] for r in PRINTED_BASE['K'][:3]]}, theta {PRINTED_BASE['theta']}, "
          f"theta_0 {PRINTED_BASE['theta0']}, k_f {PRINTED_BASE['k_f']}; (sec. 5.3.5) K chain "
          f"{[r[0] for r in PRINTED_FUSED['K'][:3]]}, theta {PRINTED_FUSED['theta']}")


def table(out: Path, label: str) -> None:
    m = pd.read_csv(out / "metrics.csv")
    m = m[m.state.isin(STATES)]
    # unstack, not pivot_table: an observer that diverged has NaN everywhere and must still be listed.
    piv = (m.drop_duplicates(["observer", "state"]).set_index(["observer", "state"])["rmse"].unstack()
           .reindex(index=pd.unique(m["observer"]), columns=STATES))
    us = m.groupby("observer")["us_per_step"].first()
    st = m.groupby("observer")["status"].agg(lambda s: ",".join(sorted(set(s))))
    print(f"\n{label}: RMSE per state [m, m, rad, m/s, rad/s], us/step, status")
    for obs, row in piv.iterrows():
        print(f"  {obs:32s} " + " ".join(f"{v:9.3f}" for v in row.to_numpy()) + f"  {us[obs]:7.2f}  {st[obs]}")


def main() -> None:
    base = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="bench_gnss_"))
    designs()
    for p in (0.1, 0.4, 0.8):
        out = run_suite(scenarios=["gnss_drive"], observers=OBSERVERS, render=False, out=base / f"drive_{p:g}",
                        faults=f"gnss.position:channel_dropout={p:g}", progress=False)
        table(out, f"gnss_drive, {p:.0%} GNSS position dropout (seed 21)")
    out = run_suite(scenarios=["gnss_outage"], observers=OBSERVERS, render=False, out=base / "outage",
                    progress=False)
    table(out, "gnss_outage (seed 13)")


if __name__ == "__main__":
    main()
