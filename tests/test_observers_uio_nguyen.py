"""Regularised UIO of seed 003: certified design, corrected equations, paper protocol, MuJoCo run."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.vehicle import G, VehicleParams, load_vehicle
from roadtruth.observers.lmi import DesignStatus, SolverSettings
from roadtruth.observers.registry import create
from roadtruth.observers.uio_nguyen import affine_rk4
from roadtruth.observers.uio_nguyen_design import (
    C_OUT,
    D_REG,
    E_REG,
    N_ZETA,
    d_bar,
    d_cal,
    design,
    lmi_126,
    rank_condition,
    regularize,
    scheduling_points,
    unmovable_modes,
    vehicle_model,
)

SEDAN = load_vehicle("sedan")


pytestmark = pytest.mark.usefixtures("isolated_design_cache")


def textbook_sedan() -> VehicleParams:
    """Digest 003's assumed car: m 1573 kg, I_z 2873 kg m^2, l_f 1.10, l_r 1.58 m, C_f = C_r = 160 kN/rad."""
    m, lf, lr = 1573.0, 1.10, 1.58
    fzf, fzr = m * G * lr / (lf + lr), m * G * lf / (lf + lr)
    t = SEDAN.tires
    tires = dataclasses.replace(t, front=dataclasses.replace(t.front, By=160e3 / (t.front.Cy * fzf)),
                                rear=dataclasses.replace(t.rear, By=160e3 / (t.rear.Cy * fzr)))
    return SEDAN.with_overrides(name="textbook", mass_kg=m, yaw_inertia_kgm2=2873.0, lf_m=lf, lr_m=lr, tires=tires)


# ---- design and certificate ----------------------------------------------------------------------

@pytest.mark.parametrize("vehicle", [SEDAN, textbook_sedan()], ids=["sedan", "textbook"])
def test_design_is_certified_on_vertices_and_dense_grid(vehicle: VehicleParams) -> None:
    obs = create("uio_nguyen", vehicle)
    d = obs.design()
    assert d.status is DesignStatus.CERTIFIED and d.certified, d.reason
    m = d.margins
    assert m["lmi_126_max_eig_vertices"] <= -1e-7 and m["lmi_126_max_eig_grid"] <= -1e-7
    assert m["closed_loop_max_real_eig"] < 0 and m["unmovable_mode_max_real"] < 0
    assert (m["rank_c_bmu"], m["normal_rank_g"], m["observability_rank"], m["observability_rank_without_psi"]) \
        == (1, 1, 4, 3)
    # Independent re-check of (1.26) with +I on a denser grid than the certificate's.
    model, reg = vehicle_model(vehicle), regularize(vehicle_model(vehicle), 0.0, 0.1)
    P, K = np.array(d.P), d.gain("K")
    np.testing.assert_allclose(d.gain("Q_zeta"), reg.Q_zeta)
    verts, grid = scheduling_points((5.0, 30.0), 400)
    for p in np.vstack([verts, grid]):
        Az = model.A_zeta(*p)
        M = lmi_126(P, K.T @ P, m["lambda"], reg.P_zeta @ Az, reg.E_cal(Az), reg.H, reg.D_cal, 0.01)
        assert np.linalg.eigvalsh(M).max() < 0
    # lambda_delta >= 1 whenever delta1 = 0 (digest 2.5): sigma_max(Q D) = 1/delta2 exactly.
    assert np.linalg.norm(reg.Q_zeta @ D_REG, 2) == pytest.approx(10.0, rel=1e-9)
    assert d.gamma is not None and d.gamma >= 1.0
    # PBH (digest 7.1): the modes no gain can move are eigenvalues of every closed loop P A - K H.
    for p in verts:
        PA = reg.P_zeta @ model.A_zeta(*p)
        fixed = unmovable_modes(PA, reg.H)
        assert fixed.size >= 1 and np.all(fixed.real < 0)
        eig = np.linalg.eigvals(PA - K @ reg.H)
        assert all(np.min(np.abs(eig - s)) < 1e-6 * max(1.0, abs(s)) for s in fixed)


def test_feasibility_limits_of_the_digest() -> None:
    """delta2 <= 0.05 leaves a mode no gain moves unstable; epsilon >= 0.1 is infeasible (digest 7.2)."""
    model, s = vehicle_model(SEDAN), SolverSettings()
    base = {"delta1": 0.0, "delta2": 0.1, "epsilon": 0.01, "vx_range_mps": (5.0, 30.0), "grid_points": 41}
    low = design(model, {**base, "delta2": 0.05}, s)
    assert low.status is DesignStatus.INFEASIBLE and low.margins["unmovable_mode_max_real"] > 0
    assert design(model, {**base, "epsilon": 0.1}, s).status is DesignStatus.INFEASIBLE
    assert rank_condition(0.0, 0.0) < 2 and rank_condition(0.0, 0.1) == 2
    # Digest 7.2 PBH table on its textbook car (max Re of the modes K cannot move over the 4 vertices).
    tb = vehicle_model(textbook_sedan())
    verts, _ = scheduling_points((5.0, 30.0), 2)
    for d2, expected in ((1.0, -0.0107), (0.1, -0.119), (0.05, 1.51), (0.01, 46.1)):
        reg = regularize(tb, 0.0, d2)
        worst = max(unmovable_modes(reg.P_zeta @ tb.A_zeta(*p), reg.H).real.max() for p in verts)
        assert worst == pytest.approx(expected, rel=0.02)


# ---- corrections of the printed equations --------------------------------------------------------

def test_corrected_equations_hold_and_printed_ones_do_not() -> None:
    rng = np.random.default_rng(3)
    model = vehicle_model(SEDAN)
    d1, d2 = 0.05, 0.1  # delta1 > 0 exercises E_bar as well
    reg = regularize(model, d1, d2)
    np.testing.assert_allclose(reg.P_zeta @ reg.E_bb + reg.Q_zeta @ reg.H, np.eye(N_ZETA), atol=1e-12)  # (1.9)
    x, mu, dmu = rng.normal(size=4), rng.normal(size=2), rng.normal(size=2)
    zeta, omega = np.concatenate([x, mu]), np.concatenate([d1 * dmu, d2 * mu])
    # (1.5)-(1.7): y = H zeta + D_bar omega must equal C x; the printed +D doubles the regularisation.
    np.testing.assert_allclose(reg.H @ zeta + d_bar() @ omega, C_OUT @ x, atol=1e-14)
    printed = reg.H @ zeta + d_bar(printed=True) @ omega
    np.testing.assert_allclose(printed - C_OUT @ x, 2 * d2 * D_REG @ mu, atol=1e-14)
    # Error dynamics (1.13) at a frozen rho, from the definitions: E_bb zeta' = x' + delta1 E_reg mu',
    # eta' from (1.10), xi = P_zeta E_bb zeta - eta.
    Az = model.A_zeta(17.0, 1 / 17.0)
    K = rng.normal(size=(N_ZETA, 3))
    u, eta = rng.normal(size=2), rng.normal(size=N_ZETA)
    y = C_OUT @ x
    zhat = eta + reg.Q_zeta @ y
    xdot = Az @ zeta + model.Bu @ u
    eta_dot = reg.P_zeta @ (Az @ zhat + model.Bu @ u) + K @ (y - reg.H @ zhat)
    xi_dot = reg.P_zeta @ (xdot + d1 * E_REG @ dmu) - eta_dot
    xi = reg.P_zeta @ reg.E_bb @ zeta - eta
    PA = reg.P_zeta @ Az
    ok = (PA - K @ reg.H) @ xi + (reg.E_cal(Az) - K @ reg.D_cal) @ omega
    np.testing.assert_allclose(xi_dot, ok, rtol=1e-9, atol=1e-9)
    bad = (PA - K @ reg.H) @ xi + (reg.E_cal(Az) - K @ d_cal(reg.H, reg.Q_zeta, reg.D_bar, printed=True)) @ omega
    assert np.abs(bad - xi_dot).max() > 1e-3
    # Printed E_cal lacks P_zeta (n_x rows, not n_zeta), printed vertices are 6x6: neither fits.
    with pytest.raises(ValueError):
        _ = reg.E_bar - PA @ reg.Q_zeta @ reg.D_bar
    with pytest.raises(ValueError):
        _ = reg.P_zeta @ np.vstack([Az, np.zeros((2, N_ZETA))])


def test_printed_lmi_without_identity_is_homogeneous() -> None:
    """(1.26) as printed (no +I) still holds after scaling (P, Q, lambda) by 1e-6: its lambda can be
    driven to 0 and bounds nothing; the corrected LMI rejects the scaled point."""
    obs = create("uio_nguyen", SEDAN)
    d = obs.design()
    model, reg = vehicle_model(SEDAN), regularize(vehicle_model(SEDAN), 0.0, 0.1)
    P, K, lam = np.array(d.P), d.gain("K"), d.margins["lambda"]
    verts, _ = scheduling_points((5.0, 30.0), 2)
    for p in verts:
        Az = model.A_zeta(*p)
        args = (reg.P_zeta @ Az, reg.E_cal(Az), reg.H, reg.D_cal, 0.01)
        s = 1e-6
        assert np.linalg.eigvalsh(lmi_126(s * P, s * K.T @ P, s * lam, *args, plus_identity=False)).max() < 0
        assert np.linalg.eigvalsh(lmi_126(s * P, s * K.T @ P, s * lam, *args)).max() > 0.5


# ---- behaviour on the observer's own model -------------------------------------------------------

def _linear_truth(vehicle: VehicleParams, mu_kN, T: float = 20.0):
    model = vehicle_model(vehicle)

    def a_fn(t: float) -> float:
        return 0.5 * math.sin(0.2 * t)

    def d_fn(t: float) -> float:
        return 0.06 * math.sin(2 * math.pi * 0.4 * t)

    def f(t: float, x: np.ndarray) -> np.ndarray:
        return model.A(x[0]) @ x + model.Bu @ np.array([a_fn(t), d_fn(t)]) + model.Bmu @ mu_kN(t)

    t = np.arange(0.0, T, 0.01)
    X = solve_ivp(f, (0, T), [15.0, 0.0, 0.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12, method="DOP853").y.T
    Y = np.column_stack([X[:, 0], X[:, 3], [a_fn(s) for s in t], [d_fn(s) for s in t]])
    return t, X, Y


def test_error_decays_at_certified_rate_without_unknown_input() -> None:
    """With mu = 0 (omega = 0) (1.14) gives V' <= -|xi|^2 <= -V / lambda_max(P): two runs that differ
    only in the initial state differ by an xi whose P-norm decays at least as exp(-t / lambda_max(P))."""
    t, X, Y = _linear_truth(SEDAN, lambda s: np.zeros(2), T=20.0)
    obs = create("uio_nguyen", SEDAN)
    P = np.array(obs.design().P)
    rate = 1.0 / np.linalg.eigvalsh(P).max()
    states = []
    for x0 in ({"vy_mps": 0.0}, {"vy_mps": 0.5, "yaw_rate_radps": 0.05}):
        obs.reset(float(t[0]), x0)
        zs = []
        for i in range(len(t)):
            obs.step(float(t[i]), Y[i])
            zs.append(obs.zeta_hat())
        states.append(np.array(zs))
    dz = states[1] - states[0]
    V = np.einsum("ni,ij,nj->n", dz, P, dz)
    assert np.all(V <= V[0] * np.exp(-rate * (t - t[0])) * (1 + 1e-6) + 1e-24)
    good = create("uio_nguyen", SEDAN).run(t, Y).x
    assert np.sqrt(np.mean((good[t > 5, 0] - X[t > 5, 1]) ** 2)) < 1e-3  # started right, it tracks


def _paper_protocol(vehicle: VehicleParams, T: float = 40.0):
    """Digest 003 sec. 4/7.2: truth = m, I_z, C_f, C_r x 1.2, Pacejka F = 0.9 F_z sin(1.3 atan(B alpha)),
    full (1.52) with sin/cos and mu g = 0.015 g; a = 0.5 sin(0.2 t); noise (0.05 m/s, 0.002 rad/s)."""
    s = 1.2
    m, iz, lf, lr = vehicle.mass_kg * s, vehicle.yaw_inertia_kgm2 * s, vehicle.lf_m, vehicle.lr_m
    cf, cr = vehicle.cornering_stiffness_f_Npr * s, vehicle.cornering_stiffness_r_Npr * s
    Df, Dr = 0.9 * m * G * lr / (lf + lr), 0.9 * m * G * lf / (lf + lr)
    Bf, Br = cf / (1.3 * Df), cr / (1.3 * Dr)

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
                (lf * Ff * math.cos(d) - lr * Fr) / iz]

    t = np.arange(0.0, T, 0.01)
    X = solve_ivp(f, (0, T), [15.0, 0, 0, 0], t_eval=t, rtol=1e-8, atol=1e-10, max_step=2e-3).y.T
    rng = np.random.default_rng(0)
    Y = np.column_stack([X[:, 0] + rng.normal(0, 0.05, len(t)), X[:, 3] + rng.normal(0, 0.002, len(t)),
                         [a_fn(x) for x in t], [d_fn(x) for x in t]])
    return t, X, Y


def test_paper_protocol_meets_the_digest_vy_level() -> None:
    """Digest 7.2: v_y RMS error 0.024 m/s at delta2 = 0.1 (textbook car), v_y RMS 0.162 m/s."""
    v = textbook_sedan()
    t, X, Y = _paper_protocol(v)
    late = t >= 10.0
    assert np.sqrt(np.mean(X[late, 1] ** 2)) == pytest.approx(0.162, abs=0.01)
    x = create("uio_nguyen", v).run(t, Y).x
    rms = float(np.sqrt(np.mean((x[late, 0] - X[late, 1]) ** 2)))
    assert rms <= 0.029
    open_loop = create("open_loop_bicycle", v).run(t, Y[:, [3, 0]]).x[:, 0]
    assert rms < float(np.sqrt(np.mean((open_loop[late] - X[late, 1]) ** 2)))
    beta = np.arctan2(X[:, 1], X[:, 0])
    assert np.sqrt(np.mean((x[late, 2] - beta[late]) ** 2)) < 0.003


# ---- implementation details ----------------------------------------------------------------------

def test_kernel_matches_python_twin_and_exact_solution() -> None:
    rng = np.random.default_rng(7)
    Ms, Gs = rng.normal(size=(3, 6, 6)), rng.normal(size=(3, 6, 5))
    w0, w1, z = rng.normal(size=5), rng.normal(size=5), rng.normal(size=6)
    a, b = z.copy(), z.copy()
    affine_rk4(a, Ms, Gs, w0, w1, 1.3, 0.4, 0.01, 3)
    affine_rk4.py_func(b, Ms, Gs, w0, w1, 1.3, 0.4, 0.01, 3)
    assert a.tobytes() == b.tobytes()
    # Against a tight reference solution of z' = M z + G w(t), w linear in t.
    M = Ms[0] + 1.3 * Ms[1] + 0.4 * Ms[2]
    Gm = Gs[0] + 1.3 * Gs[1] + 0.4 * Gs[2]
    ref = solve_ivp(lambda s, x: M @ x + Gm @ (w0 + s / 0.01 * (w1 - w0)), (0, 0.01), z, rtol=1e-12, atol=1e-14).y[:, -1]
    np.testing.assert_allclose(a, ref, rtol=1e-7, atol=1e-9)


def test_outages_heading_wrap_and_options() -> None:
    """Steady cornering (psi passes many multiples of pi), a 1 s outage of everything: finite and back
    on track; unknown or bad options are input errors."""
    t, X, Y = _linear_truth(SEDAN, lambda s: np.zeros(2), T=20.0)
    Y = Y.copy()
    Y[:, 3] += 0.03  # steady turn: r ~ 0.3 rad/s, psi reaches ~6 rad
    obs = create("uio_nguyen", SEDAN)
    clean = obs.run(t, Y).x
    Y2 = Y.copy()
    Y2[800:900] = np.nan
    Y2[1::3, 1] = np.nan  # gyro at 2/3 rate
    gap = obs.run(t, Y2).x
    assert np.all(np.isfinite(gap))
    assert np.max(np.abs(gap[-100:, :2] - clean[-100:, :2])) < 0.02
    with pytest.raises(InputError):
        create("uio_nguyen", SEDAN, typo=1)
    with pytest.raises(InputError):
        create("uio_nguyen", SEDAN, delta2=-1.0)


def test_mujoco_double_lane_change_runs_with_finite_metrics() -> None:
    from roadtruth.harness.evaluation.estimate import run_observers
    from roadtruth.harness.sensors import load_sensor_config
    from roadtruth.harness.sensors.suite import emulate
    from roadtruth.harness.truth.scenario import load_scenario
    from roadtruth.harness.truth.simulate import simulate

    sc = dataclasses.replace(load_scenario("double_lane_change"), duration_s=4.0)
    truth = simulate(sc)
    meas = emulate(truth.frame, SEDAN, load_sensor_config(sc.sensors, sc.sensor_overrides, None), 1,
                   outages=sc.outages, lane_gaps=sc.lane_gaps)
    est, runs = run_observers(meas.frame, SEDAN, ["uio_nguyen"])
    assert runs["uio_nguyen"].status == "ok" and runs["uio_nguyen"].certified, runs["uio_nguyen"]
    sub = est[est["state"] == "vy_mps"]
    assert len(sub) > 300 and np.all(np.isfinite(sub["value"].to_numpy()))
    vy = np.interp(sub["t_s"].to_numpy(), truth.frame["t_s"].to_numpy(), truth.frame["vy_mps"].to_numpy())
    assert np.sqrt(np.mean((sub["value"].to_numpy() - vy) ** 2)) < 0.3


# ---- one compiled kernel shared by step() and run() ---------------------------------------------

def _gappy_inputs(n: int = 2500, h: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """(t, Y) of ``(v_x, r, a_x, delta)`` with random dropouts, a gyro outage past ``hold_s`` (prediction,
    then re-seeding), a total outage, a repeated and an irregular time stamp; r ~ 0.45 rad/s so the
    integrated gyro wraps past pi."""
    t = np.arange(n) * h
    vx = 14.0 + 4.0 * np.sin(2 * np.pi * t / 8.0)
    delta = 0.05 + 0.05 * np.sin(2 * np.pi * 0.4 * t)
    Y = np.column_stack([vx, vx * delta / 2.8, np.gradient(vx, h), delta])
    gen = np.random.default_rng(5)
    Y = Y + gen.normal(0.0, 1e-3, Y.shape)
    Y[:5] = np.nan
    Y[gen.random(Y.shape) < 0.15] = np.nan
    Y[900:960, 1] = np.nan
    Y[1500:1530] = np.nan
    t = t.copy()
    t[1200] = t[1199]
    t[1800:] += 0.0037
    return t, Y


def _stepped(obs, t: np.ndarray, Y: np.ndarray, x0: dict[str, float] | None = None) -> np.ndarray:
    obs.reset(float(t[0]), x0)
    return np.array([obs.step(float(t[i]), Y[i]).x for i in range(len(t))])


def test_run_is_one_compiled_call_equal_to_stepping_bit_for_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    import roadtruth.observers.uio_nguyen as module

    t, Y = _gappy_inputs()
    calls: list[int] = []
    kernel = module.nguyen_run

    def counted(tt: np.ndarray, *args: object) -> None:
        calls.append(len(tt))
        kernel(tt, *args)

    monkeypatch.setattr(module, "nguyen_run", counted)
    obs = create("uio_nguyen", SEDAN)
    got = obs.run(t, Y).x
    assert calls == [len(t)]   # the whole log in one compiled call, not a Python loop over step()
    monkeypatch.undo()
    ref = create("uio_nguyen", SEDAN)
    want = _stepped(ref, t, Y)
    assert np.all(np.isfinite(want)) and np.ptp(want, axis=0).min() > 0.0
    assert np.nansum(Y[:, 1]) * 0.01 > np.pi   # the heading pseudo-output wrapped
    assert got.tobytes() == want.tobytes(), np.abs(got - want).max(axis=0)
    # run() leaves the observer where stepping leaves it: internal state and the next step agree
    assert obs.zeta_hat().tobytes() == ref.zeta_hat().tobytes() and abs(ref._psi_m) <= np.pi
    assert obs.step(float(t[-1]) + 0.01, Y[-3]).x.tobytes() == ref.step(float(t[-1]) + 0.01, Y[-3]).x.tobytes()
    # a run split in two (a host resuming) gives the same bits as one call
    split = create("uio_nguyen", SEDAN)
    first = split.run(t[:1300], Y[:1300]).x
    rest = np.array([split.step(float(t[i]), Y[i]).x for i in range(1300, len(t))])
    assert np.vstack([first, rest]).tobytes() == got.tobytes()


def test_run_from_initial_state_equals_stepping() -> None:
    t, Y = _gappy_inputs()
    x0 = {"vy_mps": 0.4, "yaw_rate_radps": -0.1}
    got = create("uio_nguyen", SEDAN).run(t, Y, x0).x
    want = _stepped(create("uio_nguyen", SEDAN), t, Y, x0)
    assert want[2, 0] == 0.4 and want[2, 1] == -0.1   # before the first sample the estimate is x0
    assert got.tobytes() == want.tobytes()


def test_compiled_kernel_reproduces_the_plain_python_update() -> None:
    """The kernel against an independent plain-Python transcription of the update (1.10) + latch."""
    t, Y = _gappy_inputs(2000)
    obs = create("uio_nguyen", SEDAN)
    got = obs.run(t, Y).x
    Fs, Gs, Qz, Ms, Gp, bounds = obs.constants()
    lo, hi, hold, d2 = 5.0, 30.0, 0.1, 0.1
    u, tl = [math.nan] * 4, [-math.inf] * 4
    zeta, eta, w_prev, u_prev = np.zeros(6), np.zeros(6), np.zeros(5), None
    psi, r_prev, t_r_prev, tracking, started, t_cur = 0.0, math.nan, math.nan, False, False, float(t[0])
    want = []
    for ts, row in zip(t.tolist(), Y.tolist(), strict=True):
        fresh = [v == v for v in row]
        for j, v in enumerate(row):
            if v == v:
                u[j], tl[j] = v, ts
        h = ts - t_cur if ts > t_cur else 0.0
        t_cur = max(t_cur, ts)
        vx, r, ax, de = u
        if started or vx == vx:
            if not started:
                zeta[0], started = vx, True
            if fresh[1]:
                if r_prev == r_prev and tracking:
                    psi += 0.5 * (ts - t_r_prev) * (r_prev + r)
                r_prev, t_r_prev = r, ts
            v = min(max(vx if vx == vx else zeta[0], lo), hi)
            u1 = np.array([ax if ax == ax else 0.0, de if de == de else 0.0])
            u0, u_prev = (u_prev if u_prev is not None else u1), u1
            if not (r == r and vx == vx and ts - min(tl[0], tl[1]) <= hold):
                tracking = False
                if h > 0.0:
                    affine_rk4.py_func(zeta, Ms, Gp, u0, u1, v, 1.0 / v, h, max(1, math.ceil(h * bounds[1] / 0.5)))
            elif not tracking:
                psi, tracking = zeta[2] + d2 * zeta[4], True
                w_prev = np.array([vx, psi, r, *u1])
                eta = zeta - Qz @ w_prev[:3]
            else:
                if abs(psi) > math.pi:
                    c = 2.0 * math.pi * round(psi / (2.0 * math.pi))
                    psi -= c
                    eta[2] -= c
                    eta += c * Qz[:, 1]
                    w_prev[1] -= c
                w1 = np.array([vx, psi, r, *u1])
                if h > 0.0:
                    affine_rk4.py_func(eta, Fs, Gs, w_prev, w1, v, 1.0 / v, h, max(1, math.ceil(h * bounds[0] / 0.5)))
                w_prev = w1
                zeta = eta + Qz @ w1[:3]
        v = u[0] if u[0] == u[0] else zeta[0]
        want.append([zeta[1], zeta[3], math.atan2(zeta[1], v) if v > 0.0 else 0.0])
    np.testing.assert_allclose(got, np.array(want), rtol=0.0, atol=1e-12)
