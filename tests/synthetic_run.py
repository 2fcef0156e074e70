"""A synthetic run folder (the files ``run_suite`` writes), built without simulating anything.

Truth is a smooth analytic manoeuvre; three observers estimate it: a good one with bounds, a noisy
Kalman-like one with variances, and one that failed. Metrics come from the real ``roadtruth.harness.evaluation.scoring``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from roadtruth.harness.evaluation import scoring


@dataclass(frozen=True)
class FakeRun:
    status: str = "ok"
    us_per_step: float = 2.0
    certified: bool | None = None
    design_reason: str = ""
    n_steps: int = 0


def _png(path: Path, shade: int) -> None:
    import cv2

    img = np.full((240, 320, 3), shade, np.uint8)
    cv2.putText(img, path.stem, (10, 120), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1)
    cv2.imwrite(str(path), img)


def make_run_folder(root: Path, scenarios: tuple[str, ...] = ("step_steer", "ice_patch")) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    (root / "frames").mkdir(exist_ok=True)
    rng = np.random.default_rng(3)
    all_metrics = []
    entries = []
    for k, name in enumerate(scenarios):
        folder = root / name
        folder.mkdir(exist_ok=True)
        t = np.round(np.arange(0.0, 4.0, 0.01), 9)
        beta = 0.03 * np.sin(1.5 * t) * (1 + k)
        r = 0.2 * np.sin(1.5 * t + 0.3)
        truth = pd.DataFrame({"t_s": t, "x_m": 20 * t, "y_m": 2 * np.sin(0.5 * t), "beta_rad": beta,
                              "yaw_rate_radps": r, "vx_mps": np.full_like(t, 20.0)})
        truth.to_csv(folder / "truth.csv", index=False, float_format="%.10g")
        good = beta + 0.01 * np.exp(-t / 0.3)
        noisy = beta + 0.004 * rng.standard_normal(t.size)
        est = pd.concat([
            pd.DataFrame({"t_s": t, "observer": "lpv_interval", "state": "beta_rad", "value": good,
                          "lo": good - 0.012, "hi": good + 0.012}),
            pd.DataFrame({"t_s": t, "observer": "lpv_interval", "state": "yaw_rate_radps", "value": r + 0.001,
                          "lo": r - 0.01, "hi": r + 0.01}),
            pd.DataFrame({"t_s": t, "observer": "ekf", "state": "beta_rad", "value": noisy,
                          "lo": np.nan, "hi": np.nan, "var": np.full(t.size, 0.004**2)}),
        ], ignore_index=True)
        est.to_csv(folder / "estimates.csv", index=False, float_format="%.10g")
        events = [{"t_s": 1.0, "label": "steer step"}, {"t_s": 2.5, "label": "ice patch entry"}]
        (folder / "events.json").write_text(json.dumps(events))
        info = {"name": name, "description": f"synthetic {name}", "tags": ["synthetic"], "duration_s": 4.0,
                "friction": {"mu_default": 1.0, "patches": [
                    {"name": "ice", "surface": "ice", "mu": 0.1, "t_start_s": 0.0, "t_end_s": None,
                     "vertices": [[40, -5], [60, -5], [60, 5], [40, 5]]}]},
                "road": {"x_m": [0, 80], "y_m": [0, 0], "lane_width_m": 3.5}}
        (folder / "scenario.json").write_text(json.dumps(info))
        runs = {"lpv_interval": FakeRun(certified=True, design_reason="LMI feasible, margin 0.02"),
                "ekf": FakeRun(us_per_step=5.0),
                "ts_uio": FakeRun(status="error: LMI infeasible", certified=False, us_per_step=math.nan)}
        m = scoring.score(truth, est, scenario=name, runs=runs)
        all_metrics.append(m)
        frames = []
        for j, (tf, label) in enumerate([(0.0, "start"), (1.0, "steer step"), (4.0, "end")]):
            f = f"frames/{name}_{j:02d}.png"
            _png(root / f, 40 + 60 * j)
            frames.append({"file": f, "t_s": tf, "label": label})
        entries.append({"name": name, "status": "ok", "seed": 100 + k, "duration_s": 4.0,
                        "description": f"synthetic {name}", "tags": ["synthetic"],
                        "render": {"frames": frames, "video": None, "reason": None}})
    metrics = pd.concat(all_metrics, ignore_index=True)
    metrics.to_csv(root / "metrics.csv", index=False, float_format="%.10g")
    run = {"suite": "synthetic", "seed": None, "scenarios": entries,
           "observers": [{"name": "lpv_interval", "citation": "seed 004", "states": ["beta_rad", "yaw_rate_radps"]},
                         {"name": "ekf", "citation": "textbook", "states": ["beta_rad"]},
                         {"name": "ts_uio", "citation": "seed 003", "states": ["beta_rad"]}],
           "versions": {"roadtruth": "0.1.0", "numpy": np.__version__}, "git_revision": None,
           "timings_s": {"simulate": 0.0}, "wall_s": 0.1, "render": {"enabled": True, "reason": None}}
    (root / "run.json").write_text(json.dumps(run, indent=1))
    return root
