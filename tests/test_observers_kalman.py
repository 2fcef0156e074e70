"""Kalman baselines: steady Riccati covariance, NEES consistency on their own models, robustness; the
nonlinear filters' tire curves, compiled kernels (= plain-Python twins, = matrix-form UKF), state
constraints and behaviour under persistent model mismatch, on synthetic data and the Revs log."""

from __future__ import annotations

import math
import types
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from numba.core.registry import CPUDispatcher as Dispatcher
from scipy.linalg import solve_discrete_are
from scipy.optimize import minimize
from scipy.stats import chi2

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.vehicle import G, load_vehicle
from roadtruth.observers.bicycle import ay_output
from roadtruth.observers.kalman import ekf_advance, plausible_box, project_box, ukf_advance
from roadtruth.observers.registry import create
from roadtruth.observers.tire_curves import axle_curves, magic_formula, peak_lateral_acceleration

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
                ay = obs.model_ay(x[0], x[1], delta[i], vx)
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


# ---- nonlinear filters: tire curves, compiled kernels, constraints, robustness ----------------------

FERRARI = load_vehicle("ferrari_250lm")
GUARD_OFF = {"beta_max_rad": 1.5, "constraint_margin": 10.0, "innovation_gate": math.inf}


@pytest.mark.parametrize("mu", [1.0, 0.5])
def test_axle_curves_scale_the_peak_by_grip_and_mu_and_keep_the_stiffness(mu: float) -> None:
    alpha = np.linspace(0.0, 0.6, 6001)
    for curve, tire, fz in zip(axle_curves(FERRARI, mu), (FERRARI.tires.front, FERRARI.tires.rear),
                               (FERRARI.fz_front_static_N, FERRARI.fz_rear_static_N), strict=True):
        force = np.array([magic_formula(a, curve.B, curve.C, curve.E, curve.D)[0] for a in alpha])
        assert force.max() == pytest.approx(FERRARI.tires.grip * mu * fz, rel=1e-6)
        slope0 = magic_formula(0.0, curve.B, curve.C, curve.E, curve.D)[1]
        assert slope0 == pytest.approx(tire.By * tire.Cy * fz, rel=1e-12)
        # analytic slope = finite difference of the force
        a0 = 0.1
        fd = (magic_formula(a0 + 1e-6, curve.B, curve.C, curve.E, curve.D)[0]
              - magic_formula(a0 - 1e-6, curve.B, curve.C, curve.E, curve.D)[0]) / 2e-6
        assert magic_formula(a0, curve.B, curve.C, curve.E, curve.D)[1] == pytest.approx(fd, rel=1e-6)
    assert peak_lateral_acceleration(FERRARI, mu) == pytest.approx(1.3 * mu * G)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, "dry", 3.0])
def test_bad_mu_option_is_an_input_error(bad: object) -> None:
    with pytest.raises(InputError, match="mu"):
        create("ekf_bicycle", SEDAN, mu=bad)


def _interpreted(fn: Any) -> Any:
    """The plain-Python twin of a compiled function with every compiled callee interpreted as well."""
    py = fn.py_func
    g = dict(py.__globals__)
    for key in py.__code__.co_names:  # only the globals this function refers to
        if isinstance(g.get(key), Dispatcher):
            g[key] = _interpreted(g[key])
    return types.FunctionType(py.__code__, g, py.__name__, py.__defaults__, py.__closure__)


def _hostile_inputs(n: int, rng: np.random.Generator) -> np.ndarray:
    """Steering into saturation, a persistent a_y far beyond any tire, dropouts: (n, 4) inputs."""
    t = np.arange(n) * 0.01
    delta = 0.15 * np.sin(2 * np.pi * 0.4 * t)
    vx = 18.0 + 4.0 * np.sin(2 * np.pi * 0.05 * t)
    Y = np.column_stack([delta, vx, 0.9 * vx * delta / 2.7 + rng.normal(0, 0.01, n), rng.normal(0, 0.3, n)])
    Y[:, 3] += 25.0 * np.sign(np.sin(2 * np.pi * 0.1 * t))
    Y[rng.random(n) < 0.2, 2:] = np.nan
    return Y


@pytest.mark.parametrize("kernel", [ekf_advance, ukf_advance])
def test_compiled_kernel_equals_its_plain_python_twin(kernel: Any) -> None:
    obs = create("ekf_bicycle", FERRARI)
    model, filt = obs._model, obs._filt
    Y = _hostile_inputs(400, np.random.default_rng(11))
    twin = _interpreted(kernel)
    a = b = (50.0, 2.0, 1.0, 0.0, 0.01)  # outside the plausible set: the first step projects
    for delta, vx, r_meas, ay_meas in Y.tolist():
        fresh_r, fresh_ay = r_meas == r_meas, ay_meas == ay_meas
        a = kernel(*a, delta, vx, 0.01, r_meas, ay_meas, fresh_r, fresh_ay, model, filt)
        b = twin(*b, delta, vx, 0.01, r_meas, ay_meas, fresh_r, fresh_ay, model, filt)
        assert a == b
        assert abs(a[0]) <= plausible_box(vx, filt)[0] and abs(a[1]) <= plausible_box(vx, filt)[1]


def _ukf_matrix_form(x: np.ndarray, P: np.ndarray, delta: float, v: float, h: float, z: tuple[float, float],
                     obs: Any) -> tuple[np.ndarray, np.ndarray]:
    """Textbook UKF step in matrix form (eigh square root, weights 1/3, 1/6; r then a_y), no constraints."""
    W = np.array([1 / 3, 1 / 6, 1 / 6, 1 / 6, 1 / 6])

    def sigma(x: np.ndarray, P: np.ndarray) -> np.ndarray:
        w, V = np.linalg.eigh(P)
        S = V * np.sqrt(3.0 * w)
        return np.vstack([x, x + S.T, x - S.T])

    X = np.array([obs.simulate_step(tuple(s), delta, v, h) for s in sigma(x, P)])
    x = W @ X
    P = ((X - x).T * W) @ (X - x) + np.diag([obs._q1, obs._q2]) * h
    for row, (zk, R) in enumerate(zip(z, (obs._Rr, obs._Ray), strict=True)):
        X = sigma(x, P)
        Z = X[:, 1] if row == 0 else np.array([obs.model_ay(s[0], s[1], delta, v) for s in X])
        zm = W @ Z
        S = W @ (Z - zm) ** 2 + R
        K = ((X - x).T * W) @ (Z - zm) / S
        x = x + K * (zk - zm)
        P = P - np.outer(K, K) * S
    return x, P


def test_scalar_ukf_equals_the_matrix_form() -> None:
    obs = create("ukf_bicycle", SEDAN, **GUARD_OFF)
    rng = np.random.default_rng(5)
    x, P = np.array([0.3, 0.05]), np.array([[0.5, 0.02], [0.02, 0.01]])
    state = (0.3, 0.05, 0.5, 0.02, 0.01)
    for k in range(200):
        delta, v = 0.08 * math.sin(0.05 * k), 15.0 + 0.05 * k
        z = (float(x[1] + rng.normal(0, 0.02)), float(obs.model_ay(x[0], x[1], delta, v) + rng.normal(0, 0.5)))
        x, P = _ukf_matrix_form(x, P, delta, v, 0.01, z, obs)
        state = ukf_advance(*state, delta, v, 0.01, z[0], z[1], True, True, obs._model, obs._filt)
        np.testing.assert_allclose(state[:2], x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(state[2:], [P[0, 0], P[0, 1], P[1, 1]], rtol=1e-7, atol=1e-15)


def test_projection_is_the_covariance_weighted_least_squares_point() -> None:
    rng = np.random.default_rng(2)
    for _ in range(200):
        L = rng.normal(size=(2, 2))
        P = L @ L.T + 1e-3 * np.eye(2)
        a, b = rng.uniform(0.5, 3.0), rng.uniform(0.1, 1.0)
        x_hat = rng.normal(0.0, 3.0, 2)
        Wm = np.linalg.inv(P)

        def cost(x: np.ndarray, x_hat: np.ndarray = x_hat, Wm: np.ndarray = Wm) -> float:
            return float((x - x_hat) @ Wm @ (x - x_hat))

        def grad(x: np.ndarray, x_hat: np.ndarray = x_hat, Wm: np.ndarray = Wm) -> np.ndarray:
            return 2.0 * Wm @ (x - x_hat)

        got = np.array(project_box(*x_hat, P[0, 0], P[0, 1], P[1, 1], a, b))
        res = minimize(cost, np.clip(x_hat, [-a, -b], [a, b]), jac=grad, bounds=[(-a, a), (-b, b)],
                       method="L-BFGS-B", options={"ftol": 1e-15, "gtol": 1e-12})
        assert abs(got[0]) <= a and abs(got[1]) <= b
        assert cost(got) <= cost(res.x) * (1 + 1e-9) + 1e-12
        if np.all(np.abs(x_hat) <= [a, b]):
            assert np.array_equal(got, x_hat)


def _own_model_run(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, states (n, 2), inputs (n, 4)) of the sedan's nonlinear model in a gentle slalom at 20 m/s."""
    truth = create("ekf_bicycle", SEDAN)
    t = np.arange(n) * 0.01
    delta = 0.03 * np.sin(2 * np.pi * 0.3 * t)
    x, X, Y = (0.0, 0.0), [], []
    for i in range(n):
        if i:
            x = truth.simulate_step(x, delta[i], 20.0, 0.01)
        X.append(x)
        Y.append([delta[i], 20.0, x[1] + rng.normal(0, 0.01),
                  truth.model_ay(x[0], x[1], delta[i], 20.0) + rng.normal(0, 0.3)])
    return t, np.array(X), np.array(Y)


@pytest.mark.parametrize("name", ["ekf_bicycle", "ukf_bicycle"])
def test_persistent_ay_mismatch_stays_in_the_plausible_set_and_recovers(name: str) -> None:
    """15 s of measured a_y 25 m/s^2 above the model (2.5 g beyond any road tire), then clean data."""
    t, X, Y = _own_model_run(3000, np.random.default_rng(1))
    Y[(t > 2.0) & (t < 17.0), 3] += 25.0
    obs = create(name, SEDAN)
    tr = obs.run(t, Y)
    vy_max, r_max = obs.plausible_box(20.0)
    assert np.all(np.isfinite(tr.x)) and np.all(np.isfinite(tr.var))
    assert np.all(np.abs(tr.x[:, 0]) <= vy_max) and np.all(np.abs(tr.x[:, 1]) <= r_max)
    assert np.all(tr.var[:, 0] <= vy_max**2) and np.all(tr.var[:, 1] <= r_max**2)
    late = t > 22.0  # 5 s after the fault: back on the truth
    assert np.max(np.abs(tr.x[late, 0] - X[late, 0])) < 0.3
    assert np.max(np.abs(tr.x[late, 1] - X[late, 1])) < 0.05  # gyro noise 0.01 rad/s
    if name == "ekf_bicycle":
        # The same data without the guard (and the curves held at the configured grip): the EKF runs
        # away past the tire peak and stays there. (The grip adaptation alone also recovers: the
        # raised curves explain the fault, and the linear range they keep holds the truth after it.)
        loose = create(name, SEDAN, **GUARD_OFF, grip_headroom=0.0).run(t, Y)
        assert np.max(np.abs(loose.x[late, 0] - X[late, 0])) > 10.0
        adapted = create(name, SEDAN, **GUARD_OFF).run(t, Y)
        assert np.max(np.abs(adapted.x[late, 0] - X[late, 0])) < 0.3


def test_nonlinear_filters_track_the_revs_log(revs_log: Path) -> None:
    """The real Ferrari 250 LM log (1.2 g corners): the guarded filters stay in their set and beat the KF."""
    from roadtruth.harness.jobs.replay import prepare_log

    rl = prepare_log(revs_log, "revs_250lm")
    seg = rl.run_segments[0]
    m = rl.measurements[seg.index]
    m = m[(m["t_s"] >= 300.0) & (m["t_s"] < 400.0)]  # 100 s incl. the left-right transition at 340 s
    ref = rl.frame.set_index("t_s")["beta_rad"].reindex(m["t_s"].to_numpy()).to_numpy()
    ok = np.isfinite(ref)
    rmse = {}
    for name in ("kf_bicycle", "ekf_bicycle", "ukf_bicycle"):
        obs = create(name, FERRARI)
        tr = obs.run(m["t_s"].to_numpy(), m[list(obs.inputs)].to_numpy())
        assert np.all(np.isfinite(tr.x)) and np.max(np.abs(tr.x[:, 0])) < 5.0
        rmse[name] = float(np.sqrt(np.mean((tr.x[ok, 2] - ref[ok]) ** 2)))
    assert rmse["ekf_bicycle"] < rmse["kf_bicycle"] and rmse["ukf_bicycle"] < rmse["kf_bicycle"]
    assert max(rmse["ekf_bicycle"], rmse["ukf_bicycle"]) < math.radians(1.0)
    # Tire curves capped at 1.0 g (grip ignored) made the unguarded filters diverge at 342 s; guarded,
    # the same wrong model stays bounded.
    for name in ("ekf_bicycle", "ukf_bicycle"):
        obs = create(name, FERRARI, mu=1.0 / FERRARI.tires.grip)
        tr = obs.run(m["t_s"].to_numpy(), m[list(obs.inputs)].to_numpy())
        assert np.all(np.isfinite(tr.x)) and np.max(np.abs(tr.x[:, 0])) < 6.0
        assert np.max(np.abs(tr.x[:, 2])) < 0.3


# ---- grip the filter was not told --------------------------------------------------------------------

def _with_grip(vehicle: Any, grip: float) -> Any:
    import dataclasses
    return dataclasses.replace(vehicle, tires=dataclasses.replace(vehicle.tires, grip=grip))


def _corner_beyond_the_model(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, truth frame columns (beta, v_y, a_y), inputs (n, 4)): the sedan on 1.6 g tires at 30 m/s,
    steer ramped over 3 s into a 28 s steady corner at 1.42 g, then straight; gyro 0.01 rad/s, a_y 0.3."""
    truth = create("ekf_bicycle", _with_grip(SEDAN, 1.6))
    h, vx = 0.01, 30.0
    t = np.arange(0.0, 40.0, h)
    delta = np.interp(t, [0, 1, 4, 32, 34, 40], [0, 0, 0.08, 0.08, 0, 0])
    x, X, Y = (0.0, 0.0), [], []
    for i in range(t.size):
        if i:
            x = truth.simulate_step(x, delta[i], vx, h)
        ay = truth.model_ay(x[0], x[1], delta[i], vx)
        X.append((math.atan2(x[0], vx), x[0], ay))
        Y.append([delta[i], vx, x[1] + rng.normal(0, 0.01), ay + rng.normal(0, 0.3)])
    return t, np.array(X), np.array(Y)


@pytest.mark.parametrize("name", ["ekf_bicycle", "ukf_bicycle"])
def test_filter_facing_1_4_g_on_a_0_9_g_tire_model_tracks_and_does_not_pin(name: str) -> None:
    """The car holds 1.42 g while the filter's curves are told 0.9 g: the adapted curves follow the grip
    the car shows, the harness scores ``ok`` (no time on the beta bound) and the sideslip stays close.
    Without the adaptation (``grip_headroom = 0``) the same filter is more than 3 deg off in the corner."""
    from roadtruth.harness.evaluation.scoring import score

    t, X, Y = _corner_beyond_the_model(np.random.default_rng(4))
    assert X[:, 2].max() > 1.4 * G and np.mean(X[:, 2] > 1.4 * G) > 0.05   # the car is past the model
    frame = pd.DataFrame({"t_s": t, "beta_rad": X[:, 0], "vy_mps": X[:, 1]})
    hold = (t > 10.0) & (t < 32.0)
    results = {}
    for label, opts in (("adapted", {}), ("fixed", {"grip_headroom": 0.0})):
        obs = create(name, _with_grip(SEDAN, 0.9), **opts)
        tr = obs.run(t, Y)
        row = score(frame, tr.to_frame(), scenario="corner", runs={}).set_index("state").loc["beta_rad"]
        err = tr.x[:, 2] - X[:, 0]
        results[label] = (str(row["status"]), float(row["rmse"]), float(np.max(np.abs(err[hold]))),
                          float(np.max(np.abs(tr.x[:, 2]))), obs.grip())
    status, rmse, hold_err, beta_max, grip = results["adapted"]
    assert status == "ok"
    assert beta_max < 0.5 * obs.state_bounds["beta_rad"][1]      # nowhere near the projection bound
    assert rmse < math.radians(1.0) and hold_err < math.radians(1.5)
    assert 1.3 < grip < 1.6   # the peak went to 1.1 x the 1.42 g the car showed and decays after the corner
    assert results["fixed"][2] > math.radians(3.0)   # the fixed 0.9 g curves cannot explain the corner


def test_grip_adaptation_keeps_the_linear_range_and_rejects_a_headroom_below_one() -> None:
    """Raising the peak keeps the cornering stiffness (the model's a_y at small slip is unchanged)."""
    obs = create("ekf_bicycle", SEDAN)
    small = obs.model_ay(0.05, 0.02, 0.01, 20.0)
    near_peak = obs.model_ay(-1.5, 0.4, 0.08, 20.0)
    from roadtruth.observers.tire_curves import M_BF, M_BR, M_CF, M_CR, M_DF, M_DR, M_EF, M_ER, set_grip

    def stiffness(par: np.ndarray) -> tuple[float, float]:
        return (magic_formula(0.0, par[M_BF], par[M_CF], par[M_EF], par[M_DF])[1],
                magic_formula(0.0, par[M_BR], par[M_CR], par[M_ER], par[M_DR])[1])

    before = stiffness(obs._model)
    set_grip(obs._model, 1.5)
    np.testing.assert_allclose(stiffness(obs._model), before, rtol=1e-12)
    assert obs._model[M_DF] == pytest.approx(1.5 * SEDAN.fz_front_static_N, rel=1e-12)
    assert obs.model_ay(0.05, 0.02, 0.01, 20.0) == pytest.approx(small, rel=5e-3)
    assert abs(obs.model_ay(-1.5, 0.4, 0.08, 20.0)) > abs(near_peak) * 1.05
    with pytest.raises(InputError, match="grip_headroom"):
        create("ukf_bicycle", SEDAN, grip_headroom=0.8)


@pytest.mark.parametrize("name", ["kf_bicycle", "ekf_bicycle", "ukf_bicycle"])
def test_run_is_one_compiled_call_and_equals_stepping_bit_for_bit(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """run() advances the whole log in one call of the compiled loop that step() calls per sample: the
    estimates and variances are the same bits, and the adapted grip and covariance end equal, through
    dropouts, a full outage, a repeated and an irregular time stamp, an a_y beyond the tire peak (grip
    adaptation, innovation gate, projection) and an initial state."""
    import roadtruth.observers.kalman_loop as loop

    t, _, Y = _own_model_run(2000, np.random.default_rng(2))
    gen = np.random.default_rng(9)
    Y[:4] = np.nan
    Y[gen.random(Y.shape) < 0.2] = np.nan
    Y[700:800] = np.nan
    Y[(t > 10.0) & (t < 13.0), 3] += 12.0
    t = t.copy()
    t[300] = t[299]
    t[1200:] += 0.0043
    calls: list[int] = []
    kernel = loop.filter_run

    def counted(tt: np.ndarray, *args: object) -> None:
        calls.append(len(tt))
        kernel(tt, *args)

    x0 = {"vy_mps": 0.2, "yaw_rate_radps": 0.05}
    monkeypatch.setattr(loop, "filter_run", counted)
    obs = create(name, SEDAN)
    tr = obs.run(t, Y, x0)
    assert calls == [len(t)]   # one compiled call for the whole run, not a Python loop over step()
    monkeypatch.undo()
    ref = create(name, SEDAN)
    ref.reset(float(t[0]), x0)
    outs = [ref.step(float(t[i]), Y[i]) for i in range(len(t))]
    assert tr.x.tobytes() == np.array([o.x for o in outs]).tobytes()
    assert tr.var is not None and np.all(np.isfinite(tr.var))
    np.testing.assert_allclose(np.array([np.diag(o.cov) for o in outs]), tr.var, rtol=1e-12, atol=1e-300)
    assert tr.x[2, 0] == 0.2 and np.ptp(tr.x[:, 0]) > 0.1   # x0 until the first sample
    assert obs.state_covariance().tobytes() == ref.state_covariance().tobytes()
    if name != "kf_bicycle":
        assert obs.grip() == ref.grip() and obs.grip() > create(name, SEDAN).grip()   # the curves were raised
