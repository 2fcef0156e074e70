"""Metrics on synthetic signals whose answers are known in closed form."""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from scipy.stats import chi2

from roadtruth.harness.evaluation import scoring
from roadtruth.harness.truth.vehicle import G


@dataclass(frozen=True)
class Run:
    status: str = "ok"
    us_per_step: float = 3.5
    certified: bool | None = True
    design_reason: str = ""
    n_steps: int = 0


def truth_frame(t: np.ndarray, **cols: np.ndarray) -> pd.DataFrame:
    return pd.DataFrame({"t_s": t, **cols})


def long(observer: str, state: str, t: np.ndarray, value: np.ndarray, lo=None, hi=None, var=None):
    n = t.size
    d = {"t_s": t, "observer": observer, "state": state, "value": value,
         "lo": np.full(n, np.nan) if lo is None else lo, "hi": np.full(n, np.nan) if hi is None else hi}
    if var is not None:
        d["var"] = var
    return pd.DataFrame(d)


def one_row(truth: pd.DataFrame, est: pd.DataFrame, runs=None, **kw) -> pd.Series:
    runs = runs if runs is not None else {o: Run() for o in est["observer"].unique()}
    m = scoring.score(truth, est, scenario="synthetic", runs=runs, **kw)
    assert list(m.columns) == list(scoring.COLUMNS)
    assert len(m) == 1
    return m.iloc[0]


T = np.round(np.arange(0, 5.0, 0.001), 9)


def test_constant_offset_gives_exact_rmse_mae_bias():
    y = np.sin(T)
    est = long("kf", "vy_mps", T, y + 0.25)
    r = one_row(truth_frame(T, vy_mps=y), est)
    assert r.rmse == pytest.approx(0.25, rel=1e-12)
    assert r.mae == pytest.approx(0.25, rel=1e-12)
    assert r.bias == pytest.approx(0.25, rel=1e-12)
    assert r.max_abs == pytest.approx(0.25, rel=1e-12)
    assert r.p95_abs == pytest.approx(0.25, rel=1e-12)
    # Offset outside the 0.1 m/s band the whole time: never converges.
    assert math.isnan(r.conv_time_s)
    assert r.status == "ok" and r.us_per_step == 3.5 and bool(r.certified)


def test_rmse_of_a_sine_error_is_amplitude_over_root_two():
    t = np.round(np.arange(0, 10.0, 0.001), 9)  # 10 whole periods of 1 Hz
    est = long("kf", "vy_mps", t, 0.3 * np.sin(2 * np.pi * t))
    r = one_row(truth_frame(t, vy_mps=np.zeros_like(t)), est)
    assert r.rmse == pytest.approx(0.3 / math.sqrt(2), rel=1e-3)
    assert r.mae == pytest.approx(0.3 * 2 / math.pi, rel=1e-3)
    assert r.bias == pytest.approx(0.0, abs=1e-9)


def test_angle_errors_are_wrapped():
    psi = np.full_like(T, math.pi - 0.01)
    est = long("ekf", "psi_rad", T, np.full_like(T, -math.pi + 0.01))  # 0.02 rad apart across ±pi
    r = one_row(truth_frame(T, psi_rad=psi), est)
    assert r.rmse == pytest.approx(0.02, rel=1e-9)
    assert r.bias == pytest.approx(0.02, rel=1e-9)


def test_convergence_time_of_an_exponential_decay():
    # e(t) = e0 exp(-t/tau) enters the 0.5 deg band at t* = tau ln(e0/band) and stays.
    e0, tau = 5 * scoring.DEG, 0.4
    beta = 0.02 * np.sin(3 * T)
    est = long("lpv", "beta_rad", T, beta + e0 * np.exp(-T / tau))
    r = one_row(truth_frame(T, beta_rad=beta), est)
    expected = tau * math.log(e0 / (0.5 * scoring.DEG))
    assert r.conv_band == pytest.approx(0.5 * scoring.DEG)
    assert r.conv_time_s == pytest.approx(expected, abs=1.5e-3)


def test_convergence_needs_to_stay_in_band():
    err = np.where((T > 2.0) & (T < 2.5), 0.5, 0.0)  # leaves the band once, comes back
    est = long("x", "vy_mps", T, err)
    r = one_row(truth_frame(T, vy_mps=np.zeros_like(T)), est)
    assert r.conv_time_s == pytest.approx(2.5, abs=1.5e-3)


def test_force_band_is_five_percent_of_weight_from_normal_loads():
    m = 1500.0
    fz = np.full_like(T, m * G / 4)
    truth = truth_frame(T, fy_f_N=np.zeros_like(T), fz_fl_N=fz, fz_fr_N=fz, fz_rl_N=fz, fz_rr_N=fz)
    r = one_row(truth, long("ts", "fy_f_N", T, np.zeros_like(T)))
    assert r.conv_band == pytest.approx(0.05 * m * G)
    assert r.conv_time_s == pytest.approx(0.0)


def test_coverage_violation_and_width_of_a_known_interval():
    truth = np.zeros_like(T)
    # The interval excludes truth for t in [1, 2): 1 s of 5 s.
    shift = np.where((T >= 1.0) & (T < 2.0), 1.0, 0.0)
    lo, hi = shift - 0.2 + 0 * T, shift + 0.3 + 0 * T
    hi = hi + 0.1 * (T > 4.0)  # widen at the end: max width 0.6
    est = long("interval", "vy_mps", T, shift, lo=lo, hi=hi)
    r = one_row(truth_frame(T, vy_mps=truth), est)
    assert r.coverage == pytest.approx(0.8, abs=1e-3)
    assert r.violation_time_s == pytest.approx(1.0, abs=2e-3)
    assert r.max_width == pytest.approx(0.6)
    assert r.mean_width == pytest.approx(0.5 + 0.1 * 0.2, abs=1e-3)


def test_no_bounds_means_no_interval_metrics():
    r = one_row(truth_frame(T, vy_mps=np.zeros_like(T)), long("kf", "vy_mps", T, np.zeros_like(T)))
    assert math.isnan(r.coverage) and math.isnan(r.mean_width) and math.isnan(r.violation_time_s)
    assert math.isnan(r.nees_mean) and math.isnan(r.nees_in_band)


def test_nees_of_a_correctly_specified_gaussian_error_lies_in_band():
    rng = np.random.default_rng(7)
    t = np.round(np.arange(0, 20.0, 0.01), 9)  # 2000 outputs at 100 Hz
    sigma = 0.05 + 0.02 * np.sin(t)  # time-varying, correctly reported variance
    truth = np.cos(t)
    est = long("ukf", "vy_mps", t, truth + sigma * rng.standard_normal(t.size), var=sigma**2)
    t_truth = np.round(np.arange(0, 20.0, 0.001), 9)  # scored on a 1 kHz truth base
    r = one_row(truth_frame(t_truth, vy_mps=np.cos(t_truth)), est)
    lo, hi = chi2.ppf([0.025, 0.975], t.size) / t.size
    assert lo <= r.nees_mean <= hi
    assert r.nees_in_band == 1.0


def test_nees_of_an_overconfident_filter_is_out_of_band():
    rng = np.random.default_rng(8)
    t = np.round(np.arange(0, 20.0, 0.01), 9)
    est = long("ukf", "vy_mps", t, 0.1 * rng.standard_normal(t.size), var=np.full(t.size, 0.05**2))
    r = one_row(truth_frame(t, vy_mps=np.zeros_like(t)), est)
    assert r.nees_mean == pytest.approx(4.0, rel=0.1)
    assert r.nees_in_band == 0.0


def test_estimates_are_held_zero_order_from_the_first_output():
    t_truth = np.round(np.arange(0, 1.0, 0.001), 9)
    t_est = np.round(np.arange(0.1, 1.0, 0.01), 9)  # first output at 0.1 s, 100 Hz
    est = long("kf", "vy_mps", t_est, t_est.copy())
    r = one_row(truth_frame(t_truth, vy_mps=t_truth), est)
    assert r.n_scored == t_truth.size - 100
    # Held values lag truth by 0..9 ms uniformly: mean error -4.5 ms.
    assert r.bias == pytest.approx(-0.0045, abs=1e-9)
    assert r.max_abs == pytest.approx(0.009, abs=1e-9)



def test_estimate_rows_out_of_time_order_score_as_in_order():
    # A plug-in may return rows in any order: scoring holds them in time order either way.
    t_truth = np.round(np.arange(0, 1.0, 0.001), 9)
    t_est = np.round(np.arange(0.1, 1.0, 0.01), 9)
    value = np.sin(3 * t_est)
    lo, hi = value - 0.01, value + 0.02
    ordered = one_row(truth_frame(t_truth, vy_mps=np.sin(3 * t_truth)), long("kf", "vy_mps", t_est, value, lo, hi))
    perm = np.random.default_rng(3).permutation(t_est.size)
    shuffled = one_row(truth_frame(t_truth, vy_mps=np.sin(3 * t_truth)),
                       long("kf", "vy_mps", t_est[perm], value[perm], lo[perm], hi[perm]))
    for k in ("rmse", "bias", "max_abs", "coverage", "mean_width", "n_scored"):
        assert shuffled[k] == ordered[k]
    assert ordered.n_scored == t_truth.size - 100 and 0.0 < ordered.coverage < 1.0

def test_bad_status_still_gets_rows_with_nan_metrics():
    est = long("kf", "vy_mps", T, np.zeros_like(T))
    runs = {"kf": Run(), "lpv": Run(status="error: LMI infeasible", certified=False, us_per_step=math.nan)}
    m = scoring.score(truth_frame(T, vy_mps=np.zeros_like(T)), est, scenario="s", runs=runs)
    bad = m[m.observer == "lpv"]
    assert len(bad) >= 1
    assert (bad.status == "error: LMI infeasible").all()
    assert bad[list(scoring.METRIC_COLUMNS)].isna().all().all()
    assert m[m.observer == "kf"].rmse.iloc[0] == 0.0


def test_state_missing_from_truth_is_skipped_not_crashed():
    est = long("kf", "range_m", T, np.zeros_like(T))
    r = one_row(truth_frame(T, vy_mps=np.zeros_like(T)), est)
    assert r.status.startswith("skipped:") and math.isnan(r.rmse)


def test_band_override_and_nees_band_helper():
    lo, hi = scoring.nees_band(100)
    assert lo < 1.0 < hi
    est = long("kf", "vy_mps", T, 0.05 * np.exp(-T))
    r = one_row(truth_frame(T, vy_mps=np.zeros_like(T)), est, bands={"vy_mps": 0.01})
    assert r.conv_time_s == pytest.approx(math.log(5.0), abs=1.5e-3)


def test_an_estimate_worse_than_assuming_zero_is_unusable_on_that_state_only():
    """RMS error above the state's own RMS (and its band) -> ``unusable`` on that row; the other
    states of the observer stay ``ok``; poses have no natural zero and are never judged so."""
    t = np.round(np.arange(0.0, 5.0, 0.01), 9)
    truth = pd.DataFrame({"t_s": t, "beta_rad": 0.02 * np.sin(t), "vy_mps": 0.3 * np.sin(t),
                          "x_m": 20.0 * t})
    rows = []
    for state, value in (("beta_rad", 0.02 * np.sin(t) + 0.05),   # biased: 3.4x the signal's RMS
                         ("vy_mps", 0.3 * np.sin(t) + 0.01),      # good
                         ("x_m", 20.0 * t + 3.0)):                 # 3 m off, but a pose
        rows.append(pd.DataFrame({"t_s": t, "observer": "o", "state": state, "value": value}))
    m = scoring.score(truth, pd.concat(rows, ignore_index=True), scenario="s",
              runs={"o": SimpleNamespace(status="ok", us_per_step=1.0, certified=False, design_reason="",
                                         n_steps=t.size)})
    st = dict(zip(m["state"], m["status"], strict=True))
    # RMS of 0.02 sin t over 5 s is 0.0145 rad: the 0.05 rad bias is 3.45x that of the estimate 0
    assert st["beta_rad"].startswith("unusable (RMS error 3.45×"), st
    assert st["vy_mps"] == "ok" and st["x_m"] == "ok", st


def test_scoring_starts_at_the_first_estimate_not_the_first_row():
    """Leading NaN rows (no measurement yet) are not scored and not 'missing'."""
    t = np.round(np.arange(0.0, 2.0, 0.01), 9)
    truth = pd.DataFrame({"t_s": t, "range_m": 30.0 + t})
    value = 30.0 + t
    value[t < 0.5] = np.nan
    est = pd.DataFrame({"t_s": t, "observer": "o", "state": "range_m", "value": value})
    m = scoring.score(truth, est, scenario="s", runs={"o": SimpleNamespace(status="ok", us_per_step=1.0,
                                                                  certified=False, design_reason="",
                                                                  n_steps=t.size)})
    row = m.iloc[0]
    assert row["status"] == "ok" and row["n_scored"] == int(np.sum(t >= 0.5 - 1e-9))
    assert row["rmse"] == pytest.approx(0.0, abs=1e-12)
