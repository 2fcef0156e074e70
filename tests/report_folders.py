"""Run folders for report tests, derived cheaply from ``synthetic_run.make_run_folder`` (no simulation).

* ``skips_only_run_folder``: like the default suite — every observer ok except a radar observer that
  is skipped (no radar) in every scenario. Its report must count 0 failures and must not call the
  skipped observer's design rejected.
* ``wide_start_run_folder``: the interval observer starts with ±100° bounds and a 60° error, as
  interval observers do before they converge.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
from synthetic_run import make_run_folder

RADAR = "hgo_radar_standard"


def skips_only_run_folder(root: Path) -> Path:
    root = make_run_folder(root)
    m = pd.read_csv(root / "metrics.csv")
    m = m[m["observer"] != "ts_uio"]  # the synthetic folder's one failed observer
    skipped = []
    for scen in m["scenario"].unique():
        for state in ("range_m", "range_rate_mps"):
            skipped.append({"scenario": scen, "observer": RADAR, "state": state, "rmse": math.nan,
                            "us_per_step": math.nan, "certified": False, "status": "skipped: missing range_m"})
    m = pd.concat([m, pd.DataFrame(skipped)], ignore_index=True)
    m.to_csv(root / "metrics.csv", index=False, float_format="%.10g")
    run = json.loads((root / "run.json").read_text())
    run["suite"] = "default"
    run["observers"] = [o for o in run["observers"] if o["name"] != "ts_uio"] + [
        {"name": RADAR, "citation": "Author, 2020, eq. (1)", "states": ["range_m", "range_rate_mps"]}]
    run["observer_runs"] = {
        s["name"]: {
            "lpv_interval": {"status": "ok", "design_status": "certified", "certified": True},
            "ekf": {"status": "ok", "design_status": "not_applicable", "certified": False},
            RADAR: {"status": "skipped: missing range_m", "design_status": "", "certified": False},
        } for s in run["scenarios"]}
    (root / "run.json").write_text(json.dumps(run, indent=1))
    return root


def wide_start_run_folder(root: Path) -> Path:
    root = make_run_folder(root)
    for scen in ("step_steer", "ice_patch"):
        path = root / scen / "estimates.csv"
        est = pd.read_csv(path)
        sel = (est["observer"] == "lpv_interval") & (est["state"] == "beta_rad")
        t = est.loc[sel, "t_s"].to_numpy(float)
        start = np.exp(-t / 0.4)
        value = est.loc[sel, "value"].to_numpy(float) + math.radians(60.0) * start
        est.loc[sel, "value"] = value
        est.loc[sel, "lo"] = value - math.radians(100.0) * start - 0.01
        est.loc[sel, "hi"] = value + math.radians(100.0) * start + 0.01
        est.to_csv(path, index=False, float_format="%.10g")
    return root
