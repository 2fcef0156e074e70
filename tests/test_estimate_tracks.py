"""Estimates as arrays (observer -> EstimateTrack) give exactly what the long frame gives.

``run`` and ``replay`` hand the observers' tracks straight to scoring and to the wide table writer;
these tests hold them to the long-frame path they replace: the same metrics and the same wide table,
bit for bit, including bounds and variances that are absent, all-NaN or partly NaN, a diverged start,
tracks that cover only some replay segments, and the χ² band of the NEES test.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy.stats import chi2

from roadtruth.harness.evaluation import scoring
from roadtruth.harness.evaluation.estimate import ObserverRun, long_estimates
from roadtruth.harness.files.table_io import WideEstimates, estimates_wide, tracks_wide
from roadtruth.observers.base import EstimateTrack


def _tracks(t: np.ndarray, seed: int = 7) -> dict[str, EstimateTrack]:
    rng = np.random.default_rng(seed)
    n = t.size
    beta = 0.02 * np.sin(t)
    vy = 0.4 * np.sin(t)
    x_kf = np.column_stack([beta + 0.001 * rng.standard_normal(n), vy + 0.01 * rng.standard_normal(n)])
    var_kf = np.column_stack([np.full(n, 1e-6), np.full(n, 1e-4)])
    var_kf[:5] = np.nan  # no covariance yet at the start
    x_iv = np.column_stack([beta + 0.002])
    x_iv[:20] = np.nan  # a radar-like observer before its first sample
    lo = x_iv - 0.01
    hi = x_iv + 0.01
    x_ol = np.column_stack([beta * 3.0, vy, 0.1 * np.cos(t)])
    nan_lo = np.full((n, 3), np.nan)  # declared bounds that are never finite: no _lo column
    return {
        "kf": EstimateTrack("kf", ("beta_rad", "vy_mps"), t, x_kf, None, None, var_kf),
        "iv": EstimateTrack("iv", ("beta_rad",), t, x_iv, lo, hi, None),
        "ol": EstimateTrack("ol", ("beta_rad", "vy_mps", "yaw_rate_radps"), t, x_ol, nan_lo, nan_lo.copy(), None),
    }


def _truth(t: np.ndarray) -> pd.DataFrame:
    return pd.DataFrame({"t_s": t, "beta_rad": 0.02 * np.sin(t), "vy_mps": 0.4 * np.sin(t),
                         "yaw_rate_radps": 0.1 * np.cos(t)})


T = np.round(np.arange(0.0, 8.0, 0.01), 9)


def test_scoring_the_tracks_gives_the_metrics_of_the_long_frame_bit_for_bit():
    tracks = _tracks(T)
    truth = pd.DataFrame({"t_s": np.round(np.arange(0.0, 8.0, 0.001), 9)})
    for c, v in _truth(truth["t_s"].to_numpy()).items():
        truth[c] = v
    ok = ObserverRun("ok", 1.0, True, "", 0)
    runs = {"kf": ok, "iv": ok, "ol": ok, "failed": ObserverRun("error: boom", 1.0, True, "", 0)}
    kw = dict(scenario="s", runs=runs, mass_kg=1500.0, scored_until_s=7.5)
    a = scoring.score(truth, long_estimates(tracks), **kw)
    b = scoring.score(truth, tracks, **kw)
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    # ... and the metrics are the real ones, not NaN placeholders on both sides.
    kf_beta = b[(b["observer"] == "kf") & (b["state"] == "beta_rad")].iloc[0]
    assert kf_beta["rmse"] == pytest.approx(0.001, rel=0.1)
    iv = b[b["observer"] == "iv"].iloc[0]
    assert iv["coverage"] == 1.0
    assert b[b["observer"] == "failed"]["status"].iloc[0] == "error: boom"


def test_the_wide_table_of_the_tracks_is_that_of_the_long_frame():
    tracks = _tracks(T)
    a = estimates_wide(long_estimates(tracks))
    b = tracks_wide(tracks)
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert "iv.beta_rad_lo" in b and "kf.vy_mps_var" in b and "ol.beta_rad_lo" not in b
    empty = tracks_wide({})
    assert list(empty.columns) == ["t_s"] and len(empty) == 0


def test_a_replay_track_over_segments_is_the_long_rows_with_shifted_times():
    w = WideEstimates()
    t0, t1, t2 = T[:300], T[300:500] + 100.0, T[500:]
    for seg, t in enumerate((t0, t1, t2)):
        w.add_times(seg, t)
    for seg, t in ((0, t0), (2, t2)):  # "iv" and "ol" skip segment 1
        for track in _tracks(t, seed=seg).values():
            w.add_track(seg, track)
    w.add_track(1, _tracks(t1, seed=1)["kf"])
    shift = {0: 0.0, 1: -97.0, 2: -100.0}
    for name in ("kf", "iv", "ol"):
        long = w.long(name, shift)
        track = w.track(name, shift)
        from_track = long_estimates({name: track})
        for col in ("t_s", "value", "lo", "hi", "var"):
            np.testing.assert_array_equal(long[col].to_numpy(float), from_track[col].to_numpy(float))
        assert list(long["state"].astype(str)) == list(from_track["state"].astype(str))
    assert len(w.track("iv").t_s) == t0.size + t2.size
    assert w.track("nobody") is None
    # the segment every observer skipped still has its rows in the table
    assert len(w.frame()) == T.size


@pytest.mark.parametrize("n", [1, 2, 3, 10, 99, 1000, 54321, 200000])
def test_the_nees_band_is_the_chi2_quantile_to_the_bit(n: int):
    lo, hi = scoring.nees_band(n)
    assert (lo, hi) == tuple(float(v) for v in chi2.ppf([0.025, 0.975], n) / n)


def test_the_nees_band_holds_95_percent_of_seeded_chi2_means():
    rng = np.random.default_rng(2024)
    n, trials = 50, 4000
    means = (rng.standard_normal((trials, n)) ** 2).mean(axis=1)
    lo, hi = scoring.nees_band(n)
    inside = float(np.mean((means >= lo) & (means <= hi)))
    assert inside == pytest.approx(0.95, abs=0.012)
    assert math.isclose(lo + hi, 2.0, rel_tol=0.2)
