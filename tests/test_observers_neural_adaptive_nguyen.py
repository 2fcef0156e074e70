"""Neural adaptive observer of Nguyen ch. 1 (Sections 5-6): LMI gain of Theorem 2 with the Euler disk,
exact sensitivity gradient, the chapter's protocol (what holds and what does not), MuJoCo suite rows."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers.lmi import DesignStatus
from roadtruth.observers.neural_adaptive_nguyen import N_THETA, init_theta
from roadtruth.observers.neural_adaptive_nguyen_design import lmi_141
from roadtruth.observers.neural_adaptive_nguyen_loop import substep
from roadtruth.observers.registry import create
from roadtruth.observers.uio_nguyen_design import scheduling_points, vehicle_model

sys.path.insert(0, str(Path(__file__).parent))
from test_observers_uio_nguyen import _paper_protocol, textbook_sedan  # noqa: E402

SEDAN = load_vehicle("sedan")
pytestmark = pytest.mark.usefixtures("isolated_design_cache")


def test_gain_certified_with_euler_disk_and_printed_lmi_homogeneous() -> None:
    d = create("nao_nguyen", SEDAN).design()
    assert d.status is DesignStatus.CERTIFIED, d.reason
    m = d.margins
    assert m["euler_spectral_radius"] < 0.95 + 1e-6 and m["lmi_141_max_eig_grid"] <= -1e-7
    model = vehicle_model(SEDAN)
    P, L = np.array(d.P), d.gain("L")
    verts, _ = scheduling_points((5.0, 30.0), 2)
    for p in verts:
        A = model.A0 + p[0] * model.A1 + p[1] * model.A2
        s = 1e-6  # as printed (no +I) the scaled point still holds: sigma -> 0 bounds nothing
        assert np.linalg.eigvalsh(lmi_141(s * P, s * L.T @ P, s * m["sigma"], A, model.Bmu, model.C,
                                          plus_identity=False)).max() < 0
        assert np.linalg.eigvalsh(lmi_141(s * P, s * L.T @ P, s * m["sigma"], A, model.Bmu, model.C)).max() > 0.5


def test_sensitivity_gradient_equals_finite_differences() -> None:
    """(1.45)-(1.50): the accumulated gradient over a 30-step window of the observer's compiled
    sub-step equals the central finite difference of the summed loss (the forward sensitivity is
    exact for the Euler model)."""
    model = vehicle_model(SEDAN)
    L = create("nao_nguyen", SEDAN).design().gain("L")
    A = model.A(20.0)
    rng = np.random.default_rng(2)
    theta0 = init_theta(1)
    theta0[-66:] *= 100.0  # a non-trivial last layer, so every block of the gradient matters
    ys = rng.normal(size=(30, 3)) * [0.1, 0.01, 0.05] + [20.0, 0.0, 0.1]
    xt = np.array([20.0, 0.1, 0.0, 0.1])
    mut = np.array([0.3, -0.2])
    Ty, Tu = np.array([1.0, 100.0, 100.0]), np.array([1.0, 10.0, 0.0, 10.0])

    def window(theta: np.ndarray, learn: bool) -> tuple[float, np.ndarray]:
        x = np.array([20.0, 0.05, 0.0, 0.08])
        S, g = np.zeros((4, N_THETA)), np.zeros(N_THETA)
        mu, Jth, Jx = np.zeros(2), np.zeros((2, N_THETA)), np.zeros((2, 4))
        work, Acl, ex = np.zeros((6, 32)), np.empty((4, 4)), np.empty(4)
        tot = 0.0
        for k in range(30):
            tot += substep(x, S, g, theta, A, model.Bu, model.Bmu, L, ys[k], np.array([0.1, 0.02]), xt, mut, Ty, Tu,
                           1.0, 0.01, learn, mu, Jth, Jx, work, Acl, ex)
        return tot, g

    _, g = window(theta0, True)
    idx = rng.choice(N_THETA, 40, replace=False)
    for k in idx:
        e = np.zeros(N_THETA)
        e[k] = 1e-6
        fd = (window(theta0 + e, True)[0] - window(theta0 - e, True)[0]) / 2e-6
        assert g[k] == pytest.approx(fd, rel=1e-4, abs=1e-7), k


@pytest.fixture(scope="module")
def protocol_runs():
    """The chapter's protocol (truth x1.2, Pacejka, 60 s, noise), NAO variants next to PI and UIO."""
    v = textbook_sedan()
    t, X, Y = _paper_protocol(v, T=60.0)
    out = {}
    for name in ("pi_observer_nguyen", "uio_nguyen", "nao_nguyen", "nao_nguyen_stepwise", "nao_nguyen_ensemble"):
        o = create(name, v)
        x = o.run(t, Y).x
        out[name] = (x, np.array(getattr(o, "loss_trace", [])))
    return t, X, out


def test_protocol_what_holds_and_what_does_not(protocol_runs) -> None:
    """Digest protocol on the chapter's own model. Holds: the loss reaches a plateau; NAO v_y bounded.
    Does not hold here (asserted as measured, documented): NAO v_y and r errors below the PI's,
    accumulation lowering the early peak."""
    t, X, out = protocol_runs
    late, early = t >= 10.0, t < 10.0

    def rms(name: str, col: int, truth: np.ndarray) -> float:
        return float(np.sqrt(np.mean((out[name][0][late, col] - truth[late]) ** 2)))

    nao_vy, pi_vy = rms("nao_nguyen", 0, X[:, 1]), rms("pi_observer_nguyen", 0, X[:, 1])
    nao_r, pi_r = rms("nao_nguyen", 1, X[:, 3]), rms("pi_observer_nguyen", 1, X[:, 3])
    assert nao_vy < 0.15 and np.all(np.isfinite(out["nao_nguyen"][0]))
    assert nao_vy > pi_vy and nao_r > pi_r  # the chapter's claim is not reproduced (numbers in the docs)
    loss = out["nao_nguyen"][1]
    n = len(loss)
    halves = [float(loss[i:i + n // 6].mean()) for i in range(0, n - n // 6 + 1, n // 6)]
    assert max(halves[2:]) < 1.5 * min(halves[2:]) + 0.05 and max(halves[2:]) < halves[1]
    peak = {k: float(np.abs(out[k][0][early, 0] - X[early, 1]).max()) for k in ("nao_nguyen", "nao_nguyen_stepwise")}
    assert abs(peak["nao_nguyen"] - peak["nao_nguyen_stepwise"]) < 0.05  # accumulation changes little here
    ens = rms("nao_nguyen_ensemble", 0, X[:, 1])
    assert abs(ens - nao_vy) < 0.02


def test_mujoco_suite_rows(tmp_path) -> None:
    import pandas as pd

    from roadtruth.harness.jobs.pipeline import run_suite

    names = ["nao_nguyen", "nao_nguyen_ensemble"]
    out = run_suite(scenarios=["fishhook", "mu_step"], observers=names, render=False, out=tmp_path / "run",
                    progress=False)
    m = pd.read_csv(out / "metrics.csv")
    for sc in ("fishhook", "mu_step"):
        for n in names:
            rows = m[(m["scenario"] == sc) & (m["observer"] == n)].set_index("state")
            assert set(rows.index) == {"vy_mps", "yaw_rate_radps", "beta_rad"} and rows["certified"].all()
            assert np.isfinite(rows.loc["vy_mps", "rmse"])


def _protocol_with_yaw_step(v, step_knm: float, T: float = 40.0, t_step: float = 30.0):
    """The protocol truth of ``_paper_protocol`` with an external yaw moment ``step_knm`` [kN m] from
    ``t_step`` (integrated in two pieces across the discontinuity); same noise (seed 0)."""
    import math

    from scipy.integrate import solve_ivp

    from roadtruth.harness.truth.vehicle import G

    s = 1.2
    m, iz, lf, lr = v.mass_kg * s, v.yaw_inertia_kgm2 * s, v.lf_m, v.lr_m
    Df, Dr = 0.9 * m * G * lr / (lf + lr), 0.9 * m * G * lf / (lf + lr)
    Bf, Br = v.cornering_stiffness_f_Npr * s / (1.3 * Df), v.cornering_stiffness_r_Npr * s / (1.3 * Dr)

    def a_fn(t: float) -> float:
        return 0.5 * math.sin(0.2 * t)

    def d_fn(t: float) -> float:
        return 0.06 * math.sin(2 * math.pi * 0.4 * t) * (t > 1) + 0.04 * (math.sin(2 * math.pi * 0.15 * t) > 0.7)

    def f(t: float, x: np.ndarray) -> list[float]:
        vx, vy, _, r = x
        d = d_fn(t)
        Ff = Df * math.sin(1.3 * math.atan(Bf * (d - (vy + lf * r) / vx)))
        Fr = Dr * math.sin(1.3 * math.atan(Br * (-(vy - lr * r) / vx)))
        return [a_fn(t) - Ff * math.sin(d) / m - 0.015 * G + r * vy, (Fr + Ff * math.cos(d)) / m - r * vx, r,
                (lf * Ff * math.cos(d) - lr * Fr + 1000.0 * step_knm * (t >= t_step)) / iz]

    t = np.arange(0.0, T, 0.01)
    pieces, x0 = [], [15.0, 0.0, 0.0, 0.0]
    for a, b in ((0.0, t_step), (t_step, T)):
        sol = solve_ivp(f, (a, b), x0, t_eval=t[(t >= a - 1e-9) & (t < b - 1e-9)], rtol=1e-8, atol=1e-10,
                        max_step=2e-3, dense_output=True)
        pieces.append(sol.y.T)
        x0 = list(sol.sol(b))
    X = np.vstack(pieces)
    rng = np.random.default_rng(0)
    Y = np.column_stack([X[:, 0] + rng.normal(0, 0.05, len(t)), X[:, 3] + rng.normal(0, 0.002, len(t)),
                         [a_fn(x) for x in t], [d_fn(x) for x in t]])
    model = vehicle_model(v)
    rdot = np.array([f(tt, x)[3] for tt, x in zip(t, X, strict=True)])
    nominal = np.array([model.A(x[0])[3] @ x + model.Bu[3] @ [a_fn(tt), d_fn(tt)] for tt, x in zip(t, X, strict=True)])
    return t, Y, (rdot - nominal) * v.yaw_inertia_kgm2 / 1000.0  # true equivalent yaw moment [kN m]


def test_protocol_mu_lag_not_less_than_the_pi_baseline() -> None:
    """Digest protocol, "the NAO mu_hat lags the truth less than the baseline": a 1 kN m yaw-moment step
    at 30 s; the change of each estimate's yaw moment l_f f_yf - l_r f_yr (step run minus the run
    without the step, same noise) reaches 63 % of the true change several seconds late, and the
    neural observer's later than the PI baseline's (benchmarks/bench_nao.py: 7.9 s vs 5.3 s). The
    true equivalent input steps at once (it is the step itself, plus the tire residual)."""
    v = textbook_sedan()
    t, Y0, mz0 = _protocol_with_yaw_step(v, 0.0)
    _, Y1, mz1 = _protocol_with_yaw_step(v, 1.0)
    after = t >= 30.0
    final = float((mz1 - mz0)[(t >= 34.0) & (t < 35.0)].mean())
    assert 0.7 < final < 1.0  # the truth's own change: the nominal I_z is 1/1.2 of the true one
    assert (mz1 - mz0)[after][0] >= 0.63 * final  # the truth reaches 63 % at the step

    def yaw_moment(name: str, Y: np.ndarray) -> np.ndarray:
        o = create(name, v)
        o.reset(0.0)
        out = np.empty(len(t))
        for i in range(len(t)):
            o.step(float(t[i]), Y[i])
            u = np.asarray(o.unknown_input_N(), dtype=float)
            out[i] = u[2] / 1000.0 if u.size == 3 else (v.lf_m * u[0] - v.lr_m * u[1]) / 1000.0
        return out

    t63 = {}
    for name in ("pi_observer_nguyen", "nao_nguyen"):
        d = yaw_moment(name, Y1) - yaw_moment(name, Y0)
        idx = np.nonzero(after & (d >= 0.63 * final))[0]
        assert idx.size, name  # both do reach it within 10 s (a sign error in mu_hat would not)
        t63[name] = float(t[idx[0]] - 30.0)
    assert t63["pi_observer_nguyen"] > 3.0 and t63["nao_nguyen"] > t63["pi_observer_nguyen"] + 1.0, t63


def test_protocol_accumulation_does_not_remove_the_early_spikes(protocol_runs) -> None:
    """Digest protocol, "accumulation lowers the early peak": on this protocol the accumulated
    (50-step) variant has the higher early v_y peak and the larger loss spikes in the first 20 s
    (benchmarks/bench_nao.py: peak 0.216 vs 0.188 m/s; largest 5 s loss mean 0.090 vs 0.021); both
    losses then settle on the same plateau."""
    t, X, out = protocol_runs
    early = t < 10.0
    peak = {k: float(np.abs(out[k][0][early, 0] - X[early, 1]).max()) for k in ("nao_nguyen", "nao_nguyen_stepwise")}
    assert peak["nao_nguyen"] > peak["nao_nguyen_stepwise"] + 0.01, peak
    win = {k: np.array([out[k][1][i:i + 500].mean() for i in range(0, len(out[k][1]) - 499, 500)])
           for k in ("nao_nguyen", "nao_nguyen_stepwise")}
    assert win["nao_nguyen"][:4].max() > 2.0 * win["nao_nguyen_stepwise"][:4].max(), win
    late = {k: float(out[k][1][len(out[k][1]) // 2:].mean()) for k in win}
    assert abs(late["nao_nguyen"] - late["nao_nguyen_stepwise"]) < 0.3 * late["nao_nguyen_stepwise"], late


def test_an_infeasible_design_fails_the_run_not_the_construction():
    """Creating the observer (the harness does, to check a user's options) never solves its LMI;
    the disk radius 0.8 is infeasible on the sedan at 10 ms, which only the run reports."""
    from roadtruth.observers.lmi import DesignFailed

    obs = create("nao_nguyen", load_vehicle("sedan"), disk_radius=0.8)
    t = np.arange(5) * 0.01
    with pytest.raises(DesignFailed):
        obs.run(t, np.tile([20.0, 0.0, 0.0, 0.0], (5, 1)))
