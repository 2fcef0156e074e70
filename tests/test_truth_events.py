"""The truth says when the car did something no observer can be blamed for, and scoring stops there."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from roadtruth.harness.evaluation import scoring
from roadtruth.harness.files.table_io import read_estimates
from roadtruth.harness.truth import truth_events
from roadtruth.harness.truth.road import Road
from roadtruth.harness.truth.truth_events import (
    TruthEvent,
    detect_events,
    detect_wheel_lift,
    scoring_end_s,
    truth_status,
)

DT = 0.001


def frame(n: int, **cols: np.ndarray) -> pd.DataFrame:
    t = np.round(np.arange(n) * DT, 9)
    base = {"t_s": t, "vx_mps": np.full(n, 20.0), "vy_mps": np.zeros(n), "x_m": 20.0 * t, "y_m": np.zeros(n),
            "psi_rad": np.zeros(n)}
    base.update(cols)
    return pd.DataFrame(base)


# ---- detection on synthetic frames ---------------------------------------------------------------

def test_wheel_lift_needs_the_load_near_zero_for_a_tenth_of_a_second():
    n = 3000
    t = np.arange(n) * DT
    static = np.array([4000.0, 4000.0, 3500.0, 3500.0])
    fz = np.tile(static, (n, 1))
    fz[(t >= 1.0) & (t < 1.3), 2] = 0.0            # rl off the ground for 0.3 s
    fz[(t >= 2.0) & (t < 2.05), 0] = 0.0           # fl hops for 50 ms: not a lift
    fz[(t >= 2.5) & (t < 2.8), 3] = 0.1 * 3500.0   # rr unloaded to 10 %: still on the ground
    ev = detect_wheel_lift(t, fz, static)
    assert ev == [TruthEvent(1.0, "wheel lift", "rl")]
    # the same through detect_events, with the static loads taken from the start of the record
    cols = {f"fz_{w}_N": fz[:, i] for i, w in enumerate(("fl", "fr", "rl", "rr"))}
    assert detect_events(frame(n, **cols)) == (TruthEvent(1.0, "wheel lift", "rl"),)


def test_spin_by_sideslip_and_the_speed_guard():
    n = 2000
    t = np.arange(n) * DT
    beta = np.where(t < 1.0, 0.0, np.radians(40.0) * (t - 1.0))  # 20 deg at t = 1.5 s
    f = frame(n, vx_mps=20.0 * np.cos(beta), vy_mps=20.0 * np.sin(beta), beta_rad=beta)
    (ev,) = detect_events(f)
    assert ev.kind == "spun out" and ev.t_s == pytest.approx(1.5, abs=2 * DT)
    # a car at walking pace turning on the spot has any sideslip; that is not a spin-out
    slow = frame(n, vx_mps=0.5 * np.cos(beta), vy_mps=0.5 * np.sin(beta), beta_rad=beta)
    assert [e.kind for e in detect_events(slow)] == []


def test_spin_by_heading_and_leaving_the_road():
    n = 4000
    t = np.arange(n) * DT
    road = Road.straight_default(200.0)
    psi = np.where(t < 1.0, 0.0, np.radians(60.0) * (t - 1.0))   # 90 deg off the road at t = 2.5 s
    y = np.where(t < 0.5, 0.0, 2.0 * (t - 0.5))                   # lane 3.5 m, half track 0.8 m: 2.55 m at t = 1.775 s
    f = frame(n, psi_rad=psi, y_m=y, beta_rad=np.zeros(n), s_m=20.0 * t)
    ev = detect_events(f, road=road, half_track_m=0.8)
    assert [e.kind for e in ev] == ["left the road", "spun out"]
    assert ev[0].t_s == pytest.approx(1.775, abs=2 * DT) and "left" in ev[0].detail
    assert ev[1].t_s == pytest.approx(2.5, abs=2 * DT) and "heading" in ev[1].detail
    # without a road to follow (an open-loop manoeuvre) neither is judged
    assert detect_events(f) == ()


def test_stopped_and_rolled_over():
    n = 5000
    t = np.arange(n) * DT
    v = np.maximum(5.0 - 2.0 * t, 0.0)          # below 0.3 m/s at t = 2.35 s
    # at standstill the sideslip of the noise is anything; it must not read as a spin
    f = frame(n, vx_mps=v, vy_mps=np.full(n, 0.01), beta_rad=np.arctan2(0.01, v))
    ev = detect_events(f, divergence=(4.2, "rolled over"))
    assert [(e.kind, round(e.t_s, 2)) for e in ev] == [("stopped", 2.35), ("rolled over", 4.2)]
    assert detect_events(f, divergence=(4.2, "non-finite state"))[-1].kind == "stopped"


def test_truth_status_and_scoring_end():
    ev = (TruthEvent(1.2, "wheel lift", "fl"), TruthEvent(1.5, "wheel lift", "fr"),
          TruthEvent(3.414, "spun out", "|β| > 20°"), TruthEvent(3.9, "left the road"))
    assert truth_status(ev) == "wheel lift at t=1.20 s; spun out at t=3.41 s; left the road at t=3.90 s"
    assert truth_status(()) == "ok"
    assert truth_status((), "diverged: non-finite state at t=2.000 s") == "diverged: non-finite state at t=2.000 s"
    assert truth_status((TruthEvent(2.0, "rolled over"),), "diverged: rolled over at t=2.000 s") == \
        "rolled over at t=2.00 s"
    assert scoring_end_s(ev) == pytest.approx(3.414 - truth_events.SCORING_MARGIN_S)
    assert scoring_end_s(ev[:2]) is None


# ---- simulated scenarios ---------------------------------------------------------------------------

STRAIGHT = """\
name: straight
description: "straight at constant speed"
standard: "none"
tags: [test]
vehicle: sedan
duration_s: 2.0
initial_speed_mps: 20.0
seed: 1
friction: {mu_default: 1.0}
driver:
  steer: {type: path_follower, preview_s: 1.0, gain: 1.0}
  speed: {type: hold}
sensors: {preset: automotive}
"""


def test_a_straight_steady_run_has_no_events_and_is_scored_to_the_end(tmp_path: Path):
    from roadtruth.harness.truth.scenario import load_scenario
    from roadtruth.harness.truth.simulate import simulate

    p = tmp_path / "straight.yaml"
    p.write_text(STRAIGHT)
    truth = simulate(load_scenario(p))
    assert truth.truth_events == () and truth.truth_status == "ok" and truth.scored_until_s is None
    t = truth.frame["t_s"].to_numpy()
    est = pd.DataFrame({"t_s": t, "observer": "zero", "state": "vy_mps", "value": 0.0, "lo": np.nan, "hi": np.nan})
    m = scoring.score(truth.frame, est, scenario="straight", runs={}, scored_until_s=truth.scored_until_s)
    assert m["scored_until_s"].iloc[0] == pytest.approx(t[-1]) == pytest.approx(2.0)
    assert m["n_scored"].iloc[0] == t.size


def test_a_spin_out_is_an_event_and_ends_scoring(tmp_path: Path):
    """Sine with dwell on a 0.5 friction road: the sedan spins. The run says so, and the observer is
    scored only up to the spin (its RMSE is the one of that window, not of the car going backwards)."""
    from roadtruth.harness.jobs.pipeline import ScenarioTask, compute_scenario, prepare_scenario
    from roadtruth.harness.truth.simulate import simulate

    task = ScenarioTask(name="sine_with_dwell", run_dir=tmp_path, observers=("kf_bicycle",), seed=None,
                        vehicle=None, friction="0.5", sensors=None, faults=None, log_rate_hz=100.0,
                        render=False)
    outcome, _ = compute_scenario(task)
    truth = simulate(prepare_scenario("sine_with_dwell", None, "0.5"))  # the truth is deterministic
    f = truth.frame
    t = f["t_s"].to_numpy()
    beta = f["beta_rad"].to_numpy()
    k = int(np.flatnonzero(np.abs(beta) > math.radians(20.0))[0])
    t_spin = t[k]
    assert 2.0 < t_spin < 5.0

    e = outcome.entry
    spins = [x for x in e["truth_events"] if x["kind"] == "spun out"]
    assert len(spins) == 1 and spins[0]["t_s"] == pytest.approx(t_spin)
    assert e["truth_status"] == f"spun out at t={t_spin:.2f} s"
    assert e["scored_until_s"] == pytest.approx(t_spin)
    folder = next(p for p in tmp_path.rglob("events.json"))
    labels = [(x["t_s"], x["label"]) for x in json.loads(folder.read_text())]
    assert any(abs(tt - t_spin) < 1e-9 and lab.startswith("spun out") for tt, lab in labels)

    m = outcome.metrics.set_index("state")
    assert np.allclose(m["scored_until_s"], t_spin)
    assert (m["n_scored"] == k).all() and k < len(f)

    # RMSE of beta over the scored window, by hand from the written estimates
    est_path = next(p for p in tmp_path.rglob("estimates.csv"))
    est = read_estimates(est_path.parent)
    est = est[(est["observer"] == "kf_bicycle") & (est["state"] == "beta_rad")].sort_values("t_s")
    te, ve = est["t_s"].to_numpy(), est["value"].to_numpy()
    idx = np.searchsorted(te, t + 1e-9, side="right") - 1
    err = scoring.wrap_angle(ve[np.maximum(idx, 0)] - beta)
    scored = (idx >= 0) & (t < t_spin)
    manual = float(np.sqrt(np.mean(err[scored] ** 2)))
    assert m.loc["beta_rad", "rmse"] == pytest.approx(manual, rel=1e-6)
    # the tail is what the old score was made of: the whole record scores far worse
    whole = float(np.sqrt(np.nanmean(err[idx >= 0] ** 2)))  # beta is NaN where the spinning car stands
    assert whole > 3.0 * manual


def test_every_stop_of_a_stop_and_go_drive_is_an_event():
    n = 12000
    t = np.arange(n) * DT
    # 5 m/s, stop at t = 2.5 s, rest, pull away from t = 5 s to 4 m/s, second stop at t = 10 s
    v = np.interp(t, [0.0, 2.5, 5.0, 7.0, 8.0, 10.0, 12.0], [5.0, 0.0, 0.0, 4.0, 4.0, 0.0, 0.0])
    f = frame(n, vx_mps=v, vy_mps=np.zeros(n), beta_rad=np.zeros(n))
    stops = [round(e.t_s, 2) for e in detect_events(f) if e.kind == "stopped"]
    assert stops == [2.35, 9.85]
    # a car standing still the whole time never "stopped"
    assert not [e for e in detect_events(frame(n, vx_mps=np.zeros(n), vy_mps=np.zeros(n), beta_rad=np.zeros(n)))]
