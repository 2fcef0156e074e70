"""Kalman baselines: steady Riccati covariance, NEES consistency on their own models, robustness."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are
from scipy.stats import chi2

from harness.vehicle import load_vehicle
from observers.bicycle import ay_output
from observers.registry import create

SEDAN = load_vehicle("sedan")


def test_kf_covariance_converges_to_the_riccati_solution() -> None:
    kf = create("kf_bicycle", SEDAN)
    h, n, vx = 0.01, 1500, 22.0
    t = np.arange(n) * h
    Y = np.column_stack([np.full(n, 0.01), np.full(n, vx), np.zeros(n), np.zeros(n)])
    kf.run(t, Y)
    Ad, _, Qd = kf.discrete_model(vx, h)
    H, _, R = kf.measurement_model(vx)
    X = solve_discrete_are(Ad.T, H.T, Qd, R)  # steady predicted covariance
    P_filt = X - X @ H.T @ np.linalg.solve(H @ X @ H.T + R, H @ X)
    np.testing.assert_allclose(kf.state_covariance(), P_filt, rtol=1e-6)


def _nees_runs(name: str, n_runs: int, n_steps: int, rng: np.random.Generator) -> np.ndarray:
    """NEES per (run, step) of the 2-state filter on trajectories of its own model with noise."""
    obs = create(name, SEDAN)
    o = obs.options
    h, vx = 0.01, 15.0
    q = np.array([o["process_std_vy_mps2"], o["process_std_r_radps2"]]) ** 2 * h
    sr, say = o["meas_std_r_radps"], o["meas_std_ay_mps2"]
    p0 = np.array([o["init_std_vy_mps"], o["init_std_r_radps"]])
    t = np.arange(n_steps) * h
    delta = 0.06 * np.sin(2 * np.pi * 0.5 * t)  # up to ~0.1 rad of front slip: nonlinear tire range
    c, d = ay_output(SEDAN, vx)
    out = np.empty((n_runs, n_steps))
    for k in range(n_runs):
        x = rng.normal(0.0, p0)
        X, Y = [], []
        for i in range(n_steps):
            if i:
                if name == "kf_bicycle":
                    Ad, Bd, _ = obs.discrete_model(vx, h)
                    x = Ad @ x + Bd * delta[i]
                else:
                    x = np.array(obs.simulate_step(tuple(x), delta[i], vx, h))
                x = x + rng.normal(0.0, np.sqrt(q))
            if name == "kf_bicycle":
                ay = c @ x + d * delta[i]
            else:
                ay = obs._forces(x[0], x[1], delta[i], vx)[0]
            X.append(x)
            Y.append([delta[i], vx, x[1] + rng.normal(0, sr), ay + rng.normal(0, say)])
        obs.reset(0.0)
        est, covs = [], []
        for i in range(n_steps):
            obs.step(t[i], np.array(Y[i]))
            est.append(list(obs._z))
            covs.append(obs.state_covariance())
        e = np.array(X) - np.array(est)
        out[k] = np.einsum("ni,nij,nj->n", e, np.linalg.inv(np.array(covs)), e)
    return out


@pytest.mark.parametrize("name", ["kf_bicycle", "ekf_bicycle", "ukf_bicycle"])
def test_nees_inside_chi2_band(name: str) -> None:
    n_runs, n_steps = 30, 300
    nees = _nees_runs(name, n_runs, n_steps, np.random.default_rng(7))
    avg = nees.mean(axis=0)  # average over runs at each step: chi2(2 N) / N under consistency
    lo, hi = chi2.ppf(0.025, 2 * n_runs) / n_runs, chi2.ppf(0.975, 2 * n_runs) / n_runs
    inside = np.mean((avg >= lo) & (avg <= hi))
    assert inside >= 0.85, f"{name}: only {inside:.0%} of steps in the 95% band"
    # after a 0.2 s transient (the first nonlinear updates from a 1 m/s prior are overconfident)
    assert 1.7 <= nees[:, 20:].mean() <= 2.3


@pytest.mark.parametrize("name", ["kf_bicycle", "ekf_bicycle", "ukf_bicycle"])
def test_long_hostile_run_keeps_covariance_valid(name: str) -> None:
    """60 s at 100 Hz: standstill, harsh steering into saturation, a long outage, speed jumps."""
    rng = np.random.default_rng(3)
    n = 6000
    t = np.arange(n) * 0.01
    vx = np.clip(np.cumsum(rng.normal(0, 0.3, n)) + 20, 0, 60)
    vx[:300] = 0.0
    delta = 0.35 * np.sign(np.sin(2 * np.pi * 0.2 * t))
    Y = np.column_stack([delta, vx, rng.normal(0, 0.5, n), rng.normal(0, 5, n)])
    Y[2000:3500, 2:] = np.nan
    Y[rng.random(n) < 0.2, :] = np.nan
    obs = create(name, SEDAN)
    tr = obs.run(t, Y)
    assert np.all(np.isfinite(tr.x)) and np.all(np.isfinite(tr.var)) and np.all(tr.var >= 0)
    assert np.all(np.linalg.eigvalsh(obs.state_covariance()) > 0)
