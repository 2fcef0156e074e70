"""The least severe friction change that breaks each interval observer's inclusion (docs/FALSIFY.md).

Run: ``python benchmarks/bench_falsify.py [--budget 24] [--seed 0] [--jobs 1]``. For every interval
observer it runs ``roadtruth falsify --property coverage:beta_rad`` on ``step_steer`` (ISO 7401,
2° at 20 m/s, step at t = 1 s) over a space of one μ patch across the lane: μ ∈ [0.1, 1.0] (nominal 1.0,
the dry road), starting 30 to 60 m down the road (where the car turns in), 2 to 40 m long (nominal
2 m). It prints per observer the nominal's robustness, the worst case and the smallest breaking
case (closest to the nominal in normalised distance), with the seed and budget.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

OBSERVERS = ("interval_wang", "flpv_interval_bessafa", "interval_efimov_lpv", "switched_interval_ifqir")
SPACE = """\
parameters:
  patch_mu: {low: 0.1, high: 1.0, nominal: 1.0}
  patch_start_m: {low: 30.0, high: 60.0}
  patch_length_m: {low: 2.0, high: 40.0, nominal: 2.0}
"""


def main() -> None:
    import pandas as pd

    from roadtruth.harness.jobs.falsify import run_falsify

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=int, default=24)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--observer", action="append", help="only these observers (repeatable)")
    a = ap.parse_args()
    print(f"falsify coverage:beta_rad on step_steer, budget {a.budget}, seed {a.seed}")
    with tempfile.TemporaryDirectory(prefix="bench-falsify-") as tmp:
        space = Path(tmp) / "space.yaml"
        space.write_text(SPACE)
        for obs in a.observer or OBSERVERS:
            t = time.perf_counter()
            out = run_falsify(observer=obs, prop="coverage:beta_rad", scenario="step_steer", space=space,
                              budget=a.budget, jobs=a.jobs, seed=a.seed, out=Path(tmp) / obs, progress=False)
            run = json.loads((out / "run.json").read_text())
            cases = pd.read_csv(out / "cases.csv")
            nominal = cases.iloc[0]
            line = (f"{obs:24s} nominal robustness {nominal['robustness']:+.4g} rad; "
                    f"{run['n_violated']}/{run['n_cases']} violate, {run['n_not_counted']} not counted")
            if "worst" in run:
                w = run["worst"]
                line += (f"; worst {w['robustness']:+.4g} rad (μ {w['point']['patch_mu']:.3g}, "
                         f"{w['point']['patch_length_m']:.3g} m)")
            if "smallest" in run:
                line += f"; smallest: {run['smallest']['finding']} (distance {run['smallest']['distance']:.3g})"
            print(f"{line}  [{time.perf_counter() - t:.0f} s]", flush=True)


if __name__ == "__main__":
    main()
