"""A synthetic ``stress.csv`` with known behaviour, built without simulating anything.

Scenario ``lane_change`` (no rule in the shipped CI thresholds, so the default β limit of 1° applies),
three seeds per case, two observers:

* ``steady``: β RMSE 0.2° ± 0.02° everywhere it is judged; at μ = 0.4 two of the three seeds spin out
  (truth_status ``spun out at …``) and their β error is 60° — the truth's fault, not the observer's;
  at μ = 0.2 every seed spins out;
* ``fragile``: β RMSE 0.3° + 2° × (1 − μ) ± 0.05°, so it crosses 1° between μ = 0.8 (0.7°) and
  μ = 0.6 (1.1°): its breaking point on the μ axis is 0.6; against GNSS dropout (at μ = 1) it
  grows 3° per unit of dropout rate, crossing 1° at the 0.3 level.
"""

from __future__ import annotations

import math

import pandas as pd

MUS = (1.0, 0.8, 0.6, 0.4, 0.2)
DROPOUTS = (0.3, 0.6)
SEED_SPREAD = (-1.0, 0.0, 1.0)


def stress_rows() -> pd.DataFrame:
    rows = []
    case = 0
    specs = [(mu, "none") for mu in MUS] + [(1.0, f"gnss:dropout={d}") for d in DROPOUTS]
    for mu, faults in specs:
        level = float(faults.split("=")[1]) if "=" in faults else 0.0
        for k, spread in enumerate(SEED_SPREAD):
            spun = (mu == 0.4 and k < 2) or mu == 0.2
            truth_status = "spun out at t=3.20 s" if spun else "ok"
            for obs in ("steady", "fragile"):
                if spun:
                    rmse_deg = 60.0
                elif obs == "steady":
                    rmse_deg = 0.2 + 0.02 * spread + 0.5 * level
                else:
                    rmse_deg = 0.3 + 2.0 * (1.0 - mu) + 3.0 * level + 0.05 * spread
                rows.append({"case": case, "friction": f"{mu:g}", "mu": mu, "faults": faults, "seed_index": k,
                             "seed": 100 + k, "truth_status": truth_status, "peak_abs_ay_mps2": 9.0 * mu,
                             "peak_abs_beta_rad": math.radians(175.0 if spun else 3.0),
                             "scenario": "lane_change", "observer": obs, "state": "beta_rad",
                             "rmse": math.radians(rmse_deg), "coverage": math.nan, "status": "ok"})
            case += 1
    return pd.DataFrame(rows)


RUN = {"scenarios": ["lane_change"], "observers": ["steady", "fragile"], "frictions": [f"{m:g}" for m in MUS],
       "faults": ["none", *(f"gnss:dropout={d}" for d in DROPOUTS)], "seeds": 3, "base_seed": 0, "n_cases": 21,
       "executor": "in-process"}
