"""Finite-time and interval estimators of Bessafa (2024), ch. 2, on their own discrete LPV bicycle model
(2.32)-(2.37), simulated exactly: exactness after m = 2 steps, interval inclusion at ±5 % / ±10 %
stiffness error, the Table 2.1 comparison, certification of every variant, and a MuJoCo run."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers.finite_time_interval_design import closed_loop
from roadtruth.observers.lmi import DesignStatus
from roadtruth.observers.registry import create

pytestmark = pytest.mark.usefixtures("isolated_design_cache")
TS = 0.1  # the thesis's step (author's code)


def simulate_model(obs, unc: float, n: int, seed: int, schedule: str = "random", x0=None):
    """Truth of (2.32): ``x+ = A(rho, c) x + B(rho, c) u`` with the stiffness ``c = c_N + dc``, ``dc``
    drawn uniformly in the ±unc box at every step (so ``v_k`` is anywhere in its set).

    ``schedule``: 'random' = rho1, rho2 independent and uniform in the box, u random in ±0.1 rad;
    'thesis' = rho1(k) = 0.06 - |sin(0.2 k)|/20, rho2 = rho1^2, u = 0.1 sin(10 t) (author's code).
    Returns t (n,), inputs (n, 3) in the observer's order and the states (n, 2)."""
    m = obs.model
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    if schedule == "thesis":
        rho1 = 0.06 - np.abs(np.sin(0.2 * k)) / 20
        rho2 = rho1**2
        u = 0.1 * np.sin(10 * k * m.ts_s)
    else:
        rho1 = rng.uniform(*m.rho1_range, n)
        rho2 = rng.uniform(*m.rho2_range, n)
        u = rng.uniform(-0.1, 0.1, n)
    x = np.array([0.1, 0.6]) if x0 is None else np.asarray(x0, dtype=float)
    X = []
    for j in range(n):
        X.append(x.copy())
        dcf, dcr = rng.uniform(-unc, unc, 2) * (m.cf_Npr, m.cr_Npr)
        x = m.a(rho1[j], rho2[j], dcf, dcr) @ x + m.b(rho1[j], dcf) * u[j]
    # the observer takes v_x; rho2 is re-derived from it in the observer as 1/v_x^2, so feed the
    # model's own independent rho2 through a v_x consistent with rho1 only when rho2 = rho1^2
    return k * m.ts_s, np.column_stack([np.array(X)[:, 1], u, 1.0 / rho1]), np.array(X), rho2


def physical(obs, unc, n, seed, x0=None):
    """Random physical schedule (rho2 = rho1^2, the observer computes it from v_x)."""
    m = obs.model
    rng = np.random.default_rng(seed)
    rho1 = np.clip(0.035 + np.cumsum(rng.normal(0, 0.006, n)), *m.rho1_range)
    u = 0.08 * np.sin(0.7 * np.arange(n)) + rng.uniform(-0.02, 0.02, n)
    x = np.array([0.1, 0.6]) if x0 is None else np.asarray(x0, dtype=float)
    X = []
    for j in range(n):
        X.append(x.copy())
        dcf, dcr = rng.uniform(-unc, unc, 2) * (m.cf_Npr, m.cr_Npr)
        x = m.a(rho1[j], rho1[j] ** 2, dcf, dcr) @ x + m.b(rho1[j], dcf) * u[j]
    return np.arange(n) * m.ts_s, np.column_stack([np.array(X)[:, 1], u, 1.0 / rho1]), np.array(X)


@pytest.fixture(scope="module")
def carla():
    return load_vehicle("carla_bessafa")


@pytest.mark.parametrize("name", ["flpv_interval_bessafa", "finite_time_chaibdraa"])
def test_exact_after_two_steps_on_the_nominal_model(carla, name) -> None:
    """Theorem 2.3.1: from any initial state, x_hat_k = x_k for k >= m = 2 (nominal model, v = 0)."""
    obs = create(name, carla, sample_time_s=TS, stiffness_uncertainty=0.0)
    assert obs.design().certified, obs.design().reason
    for seed in range(4):
        x0 = np.random.default_rng(100 + seed).uniform([-0.1, -0.6], [0.1, 0.6])
        t, Y, X = physical(obs, 0.0, 300, seed, x0)
        tr = obs.run(t, Y)
        assert np.abs(tr.x[2:] - X[2:]).max() <= 1e-9
        assert np.abs(tr.x[1, 0] - X[1, 0]) > 1e-3 or np.abs(X[1, 0]) < 1e-3  # not exact before m


def test_printed_gains_lose_exactness_on_long_runs(carla) -> None:
    """The printed gains make both observers unstable at a vertex (|eig| up to 1.28/1.42): the
    combination stays exact only while zeta, eta are representable; certified gains stay exact."""
    fresh = create("flpv_interval_bessafa", carla, sample_time_s=TS, stiffness_uncertainty=0.0)
    printed = create("flpv_interval_bessafa_printed", carla, sample_time_s=TS, stiffness_uncertainty=0.0)
    t, Y, X = physical(fresh, 0.0, 1500, 7)
    Y[:, 2] = 100.0   # v_x = 100 m/s: rho at the vertex (0.01, 1e-4) where the printed L observer has |eig| 1.0975
    X = np.zeros_like(X)
    x = np.array([0.1, 0.6])
    for j in range(len(t)):
        X[j] = x
        x = fresh.model.a(0.01, 1e-4) @ x + fresh.model.b(0.01) * Y[j, 1]
    Y[:, 0] = X[:, 1]
    assert np.abs(fresh.run(t, Y).x[2:] - X[2:]).max() <= 1e-9
    err = np.abs(printed.run(t, Y).x[2:] - X[2:])
    assert err[:50].max() <= 1e-9                 # short runs: exact, as in the thesis's 6 s
    assert not np.all(np.isfinite(err)) or err.max() > 1e-3


@pytest.mark.parametrize("unc", [0.05, 0.10])
def test_interval_inclusion_under_stiffness_uncertainty(carla, unc) -> None:
    """(2.24)-(2.25): x_lo <= x <= x_hi for k >= m when c = c_N + dc, |dc| <= unc c_N (any variation
    in time), on random physical schedules; Efimov's observer includes from k = 0."""
    flpv = create("flpv_interval_bessafa", carla, sample_time_s=TS, stiffness_uncertainty=unc)
    efim = create("interval_efimov_lpv", carla, sample_time_s=TS, stiffness_uncertainty=unc)
    widths = []
    for seed in range(6):
        t, Y, X = physical(flpv, unc, 200, seed)
        assert np.abs(X[:, 0]).max() <= 0.15   # the a-priori beta bound holds on these runs
        tr = flpv.run(t, Y)
        assert np.all(tr.lo[2:] <= X[2:] + 1e-12) and np.all(X[2:] <= tr.hi[2:] + 1e-12), seed
        widths.append((tr.hi - tr.lo)[2:, 0].mean())
        te = efim.run(t, Y)
        assert np.all(te.lo <= X + 1e-12) and np.all(X <= te.hi + 1e-12), seed
    assert np.mean(widths) < 0.25 * 0.3 * unc / 0.05   # far inside the a-priori ±0.15 rad bracket
    # the bounds are tight: at the same stiffness error a box half as wide is violated somewhere
    t, Y, X = physical(flpv, unc, 400, 11)
    tr = flpv.run(t, Y)
    mid, half = tr.x[2:, 0], 0.5 * (tr.hi - tr.lo)[2:, 0]
    assert np.any(np.abs(X[2:, 0] - mid) > 0.25 * half)


def test_bounds_need_both_window_terms(carla) -> None:
    """v_{k-2} reaches x_k through G_2 (2.22): with v only at k-2 the bounds are violated without it."""
    obs = create("flpv_interval_bessafa", carla, sample_time_s=TS, stiffness_uncertainty=0.1)
    t, Y, X = physical(obs, 0.1, 400, 3)
    tr = obs.run(t, Y)
    err = np.abs(tr.x[2:, 0] - X[2:, 0])
    half = 0.5 * (tr.hi - tr.lo)[2:, 0]
    assert np.all(err <= half + 1e-12)
    assert err.max() > 0.3 * half.max()


def test_estimate_is_gain_independent_for_m_equal_n(carla) -> None:
    """For n = 2 states, a scalar output and m = 2, the combined estimate is the unique state
    consistent with y_{k-2}, y_{k-1} and the inputs: the printed and the fresh gains give the same
    estimate and bounds (up to round-off) wherever both observers are still representable."""
    a = create("flpv_interval_bessafa", carla, sample_time_s=TS, stiffness_uncertainty=0.1)
    b = create("flpv_interval_bessafa_printed", carla, sample_time_s=TS, stiffness_uncertainty=0.1)
    t, Y, X = physical(a, 0.1, 60, 5)
    ta, tb = a.run(t, Y), b.run(t, Y)
    np.testing.assert_allclose(ta.lo[2:], tb.lo[2:], atol=1e-8)
    np.testing.assert_allclose(ta.hi[2:], tb.hi[2:], atol=1e-8)


def test_table_2_1_comparison_on_the_thesis_scenario(carla) -> None:
    """Thesis scenario (author's code: T_s = 0.1 s, 6 s, x0 = (0.1, 0.6), rho1(k) = 0.06 - |sin 0.2k|/20,
    u = 0.1 sin 10t), ±10 %. FLPV's r is exact (y = r; its bounds are intersected with y); its beta
    midpoint is the two combined observers' estimate (the v box is symmetric); Efimov's midpoint has the
    lower beta MSE here: the printed ordering (FLPV 1.99e-4 < 3.93e-4 for the H-inf set-membership
    observer, not implemented) does not carry over to Efimov's observer."""
    mse = {}
    for name in ("flpv_interval_bessafa", "finite_time_chaibdraa", "interval_efimov_lpv"):
        obs = create(name, carla, sample_time_s=TS, stiffness_uncertainty=0.1)
        t, Y, X, _ = simulate_model(obs, 0.1, 61, 0, schedule="thesis")
        tr = obs.run(t, Y)
        mse[name] = np.mean((tr.x[2:] - X[2:]) ** 2, axis=0)
    f, c, e = mse["flpv_interval_bessafa"], mse["finite_time_chaibdraa"], mse["interval_efimov_lpv"]
    assert f[1] == 0.0 and c[1] > 1e-5 and e[1] > 1e-5
    assert f[0] == pytest.approx(c[0], rel=1e-9)
    assert e[0] < f[0]


def test_certification_of_every_variant(carla) -> None:
    fresh = create("flpv_interval_bessafa", carla, sample_time_s=TS).design()
    assert fresh.status is DesignStatus.CERTIFIED and fresh.margins["m"] == 2.0
    assert fresh.margins["L_spectral_radius_max"] < fresh.margins["alpha"] <= 0.4
    assert fresh.margins["K_spectral_radius_max"] < 0.5
    obs = create("flpv_interval_bessafa_printed", carla, sample_time_s=TS)
    printed = obs.design()
    assert printed.status is DesignStatus.REJECTED and not printed.certified
    assert printed.margins["L_radius_vertex1"] == pytest.approx(1.0975, abs=5e-4)   # rho = (0.01, 1e-4)
    L = printed.gain("L")
    assert np.abs(np.linalg.eigvals(closed_loop(obs.model, L, (0.01, 1e-4)))).max() == pytest.approx(1.0975, abs=5e-4)
    assert printed.margins["L_spectral_radius_max"] == pytest.approx(1.281, abs=2e-3)  # at (0.01, 3.6e-3)
    assert printed.margins["K_spectral_radius_max"] == pytest.approx(1.418, abs=2e-3)
    e5 = create("interval_efimov_lpv", carla, sample_time_s=TS, stiffness_uncertainty=0.05).design()
    e10 = create("interval_efimov_lpv", carla, sample_time_s=TS, stiffness_uncertainty=0.10).design()
    assert e5.certified and e5.margins["lmi_2_7_feasible"] == 0.0 and e5.margins["width_contraction"] < 1.0
    assert e10.status is DesignStatus.REJECTED
    sedan = load_vehicle("sedan")
    assert create("flpv_interval_bessafa", sedan).design().certified            # default T_s = 0.05 s
    assert create("interval_efimov_lpv", sedan).design().certified
    bad = create("interval_efimov_lpv", sedan, sample_time_s=0.1).design()
    assert bad.status is DesignStatus.INFEASIBLE and "nonnegative" in bad.reason


def test_mujoco_suite_rows(tmp_path) -> None:
    from roadtruth.harness.jobs.pipeline import run_suite

    names = ["flpv_interval_bessafa", "flpv_interval_bessafa_printed", "interval_efimov_lpv", "finite_time_chaibdraa"]
    out = run_suite(scenarios=["double_lane_change"], observers=names, render=False, out=tmp_path / "run",
                    progress=False)
    m = pd.read_csv(out / "metrics.csv")
    rows = m[m["observer"].isin(names) & (m["state"] == "beta_rad")]
    assert set(rows["observer"]) == set(names)
    assert np.all(np.isfinite(rows["rmse"])), rows[["observer", "status", "rmse"]].to_string()
    ok = rows.set_index("observer")
    assert ok.loc["flpv_interval_bessafa", "status"] in ("ok", "saturated")
    assert 0.0 <= ok.loc["flpv_interval_bessafa", "coverage"] <= 1.0
