"""LPV slip-angle observer of seed 001: decay at the certified rate on its own model."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers.lmi import DesignFailed, DesignStatus
from roadtruth.observers.registry import create

pytestmark = pytest.mark.usefixtures("isolated_design_cache")


def _maneuver(vehicle, h: float = 2e-3, T: float = 6.0):
    """Linear bicycle with v_x(t) from a_x(t) (speed 5 to ~17 m/s, inside the design domain)."""
    m, iz, lf, lr = vehicle.mass_kg, vehicle.yaw_inertia_kgm2, vehicle.lf_m, vehicle.lr_m
    cf, cr = vehicle.cornering_stiffness_f_Npr, vehicle.cornering_stiffness_r_Npr

    def ax(t):
        return 7.0 * np.exp(-t) + 3.0 * np.sin(1.3 * t)

    def steer(t):
        return 0.03 * np.sin(2 * np.pi * 0.6 * t) + 0.01 * np.sin(2 * np.pi * 1.7 * t)

    def f(t, s):
        vy, r, vx = s
        af, ar = steer(t) - (vy + lf * r) / vx, -(vy - lr * r) / vx
        return [(cf * af + cr * ar) / m - vx * r, (lf * cf * af - lr * cr * ar) / iz, ax(t)]

    t = np.arange(0.0, T, h)
    s = solve_ivp(f, (0, T), [0.3, 0.05, 5.0], t_eval=t, rtol=1e-10, atol=1e-12, method="DOP853").y
    vy, r, vx = s
    d = steer(t)
    alpha = np.column_stack([d - (vy + lf * r) / vx, -(vy - lr * r) / vx])
    Y = np.column_stack([d, r, vx, ax(t)])
    return t, Y, alpha, np.arctan2(vy, vx)


@pytest.mark.parametrize("vehicle_name", ["sedan", "wang2014"])
@pytest.mark.parametrize("name", ["lpv_wang", "lpv_wang_hinf", "lpv_wang_printed", "lpv_wang_h2"])
def test_error_decays_at_certified_rate(vehicle_name: str, name: str) -> None:
    """Two runs differ only in the initial state; by linearity their difference is the error
    transition, whose P-norm must shrink at least as exp(-sigma t) (sigma = 0 for H-infinity)."""
    vehicle = load_vehicle(vehicle_name)
    t, Y, alpha, beta = _maneuver(vehicle)
    obs = create(name, vehicle)
    d = obs.design()
    assert d.certified, d.reason
    P = np.array(d.P)
    sigma = d.margins.get("decay_rate_radps", 0.0)
    a0 = {"alpha_f_rad": float(alpha[0, 0]), "alpha_r_rad": float(alpha[0, 1])}
    good = obs.run(t, Y, x0=a0).x
    bad = obs.run(t, Y).x  # default initial state: zero slip
    diff = good[:, :2] - bad[:, :2]
    V = np.einsum("ni,ij,nj->n", diff, P, diff)
    assert np.all(V <= V[0] * np.exp(-2 * sigma * t) * (1 + 1e-9) + 1e-30)
    if sigma > 0:
        assert V[-1] < V[0] * 1e-6
    # started right, it tracks its own model; beta from the contract definitions is close. The
    # correct observers stay within 3.0e-4 / 2.3e-4 rad; without the a_x/v_x scheduling (theta2 = 0)
    # the own-model error is 1.3e-3 / 0.9e-3 rad or more, so these bounds fail that mutant.
    assert np.max(np.abs(good[:, :2] - alpha)) < 5e-4
    assert np.max(np.abs(good[:, 2] - beta)) < 4e-4


def test_neutral_steer_common_mode_is_unobservable() -> None:
    """wang2014 has a Cf = b Cr: a common slip error decays at exactly ((Cf+Cr)/m)/vx, whatever L."""
    v = load_vehicle("wang2014")
    n, h, vx = 500, 0.01, 20.0
    t = np.arange(n) * h
    Y = np.column_stack([np.zeros(n), np.zeros(n), np.full(n, vx), np.zeros(n)])
    for name in ("lpv_wang", "lpv_wang_hinf_printed"):
        obs = create(name, v)
        x = obs.run(t, Y, x0={"alpha_f_rad": 0.01, "alpha_r_rad": 0.01}).x[:, :2]
        rate = (v.cornering_stiffness_f_Npr + v.cornering_stiffness_r_Npr) / v.mass_kg / vx
        np.testing.assert_allclose(x, 0.01 * np.exp(-rate * t)[:, None] * np.ones(2), rtol=1e-8)


def test_design_limits_and_printed_gains_on_seed_vehicle() -> None:
    """Digest 001 2.4 / 8.5: sigma_max = 3.633 1/s (unobservable mode); H-inf gamma* = 0.2292;
    the printed H-inf gains certify only gamma ~ 9.2."""
    v = load_vehicle("wang2014")
    nominal = create("lpv_wang", v).design()
    limit = ((v.cornering_stiffness_f_Npr + v.cornering_stiffness_r_Npr) / v.mass_kg - 8.0) / (150 / 3.6)
    assert limit * 0.99 <= nominal.margins["max_decay_rate_radps"] <= limit * (1 + 1e-6)
    assert nominal.margins["decay_rate_radps"] > nominal.margins["open_loop_decay_rate_radps"]
    hinf = create("lpv_wang_hinf", v).design()
    assert hinf.certified and hinf.margins["gamma_optimal"] == pytest.approx(0.2292, abs=2e-3)
    printed = create("lpv_wang_hinf_printed", v).design()
    assert printed.status is DesignStatus.CERTIFIED
    assert printed.gamma == pytest.approx(9.21, rel=0.02)


def test_infeasible_design_is_a_status_and_the_observer_refuses_to_run() -> None:
    obs = create("lpv_wang", load_vehicle("sedan"), decay_rate_radps=500.0)
    d = obs.design()
    assert not d.certified and d.status in (DesignStatus.INFEASIBLE, DesignStatus.REJECTED)
    if d.status is DesignStatus.INFEASIBLE:
        with pytest.raises(DesignFailed):
            obs.run(np.arange(3) * 0.01, np.ones((3, 4)))


def test_missing_samples_still_converge() -> None:
    v = load_vehicle("sedan")
    t, Y, alpha, _ = _maneuver(v, h=0.01)
    Y = Y.copy()
    Y[1::2, 1] = np.nan  # gyro at half rate
    Y[300:400, :] = np.nan  # a 1 s outage of everything
    x = create("lpv_wang", v).run(t, Y).x
    assert np.all(np.isfinite(x))
    assert np.max(np.abs(x[-50:, :2] - alpha[-50:])) < 5e-3


# ---- robust H2 / unstructured family (Wang 2014, sec. 3.2.3) -------------------------------------

ROBUST = ("lpv_wang_hinf", "lpv_wang_h2", "lpv_wang_unstructured_hinf", "lpv_wang_unstructured_h2")


def _design_model(vehicle, eps, h: float = 1e-3, T: float = 4.0, seed: int = 0):
    """The LPV design model (3.19) with exogenous scheduling, sampled every h.

    ``x' = A(theta) x + B(theta)(delta, delta', r)``, ``theta = (1/v, a/v)`` with v (15-40 km/h) and a
    (+-8 m/s^2) random smooth signals inside the design box (Lemma 9 treats them as independent);
    ``r`` is the yaw rate that makes the pseudo-output exact, ``delta - (l_f + l_r) r / v = x1 - x2``.
    Returns t, the observer inputs Y (measured v, a exact: the observer applies ``eps``), the true
    alpha, the steering rate, and theta."""
    from roadtruth.observers.bicycle import slip_model_terms
    rng = np.random.default_rng(seed)
    A1, _ = slip_model_terms(vehicle)
    ell = vehicle.lf_m + vehicle.lr_m
    f1, f2, f3 = rng.uniform(0.3, 1.5, 3)
    p1, p2, p3 = rng.uniform(0, 2 * np.pi, 3)
    amp = rng.uniform(0.01, 0.04, 2)

    def sched(t):
        v = (27.5 + 12.5 * np.sin(f1 * t + p1)) / 3.6
        return v, 8.0 * np.sin(f2 * t + p2)

    def steer(t):
        return amp[0] * np.sin(f3 * 2 * np.pi * t + p3) + amp[1] * np.sin(2.3 * 2 * np.pi * t)

    def dsteer(t):
        return amp[0] * f3 * 2 * np.pi * np.cos(f3 * 2 * np.pi * t + p3) + amp[1] * 2.3 * 2 * np.pi * np.cos(2.3 * 2 * np.pi * t)

    def f(t, x):
        v, a = sched(t)
        th1, th2 = 1 / v, a / v
        d = steer(t)
        r = v * (d - x[0] + x[1]) / ell
        return (th1 * A1 - th2 * np.eye(2)) @ x + np.array([th2 * d + dsteer(t) + r, r])

    t = np.arange(0.0, T, h)
    x = solve_ivp(f, (0, T), [0.02, 0.01], t_eval=t, rtol=1e-11, atol=1e-13, method="DOP853").y.T
    v, a = sched(t)
    d = steer(t)
    r = v * (d - x[:, 0] + x[:, 1]) / ell
    return t, np.column_stack([d, r, v, a]), x, dsteer(t), eps


@pytest.mark.parametrize("vehicle_name", ["sedan", "wang2014"])
@pytest.mark.parametrize("name", ["lpv_wang_hinf", "lpv_wang_unstructured_hinf"])
def test_l2_gain_below_certified_gamma_in_simulation(vehicle_name: str, name: str) -> None:
    """(3.43)/(3.53): with e(0) = 0, ||e||_2 <= gamma ||w||_2 for w = (x_hat, delta, delta', r), for
    scheduling errors anywhere in the design box (the 16 corners included) and random inputs."""
    vehicle = load_vehicle(vehicle_name)
    gamma = create(name, vehicle).design().gamma
    worst = 0.0
    for k, eps in enumerate([(-0.1, 0.2), (0.1, -0.2), (-0.1, -0.2), (0.1, 0.2), (-0.04, 0.06), (-0.1, 0.15)]):
        t, Y, x, dd, _ = _design_model(vehicle, eps, seed=k)
        obs = create(name, vehicle, scheduling_error=eps)
        xh = obs.run(t, Y, x0={"alpha_f_rad": float(x[0, 0]), "alpha_r_rad": float(x[0, 1])}).x[:, :2]
        e = x - xh
        w = np.column_stack([xh, Y[:, 0], dd, Y[:, 1]])
        ratio = np.sqrt(np.sum(e**2) / np.sum(w**2))
        worst = max(worst, ratio)
        assert ratio < gamma, (eps, ratio, gamma)
    # The scheduling error reaches the observer (e is not zero); realistic inputs stay far below
    # the worst case (ratio / gamma ~ 2 %): the frozen-vertex test below shows the bound is tight.
    assert worst > 1e-3


@pytest.mark.parametrize("name", ["lpv_wang_hinf", "lpv_wang_unstructured_hinf"])
def test_frozen_worst_case_gain_is_close_to_gamma(name: str) -> None:
    """The H-inf norm of the error system frozen at each of the 16 vertices (frequency sweep of
    sigma_max(I (jw - A_e)^-1 B_e)) is <= gamma, and the worst vertex reaches > 50 % of it."""
    from roadtruth.observers.bicycle import slip_model_terms
    from roadtruth.observers.lmi import robust_vertices
    from roadtruth.observers.lpv_wang_robust_design import error_system
    v = load_vehicle("wang2014")
    A1, _ = slip_model_terms(v)
    d = create(name, v).design()
    g = _observer_matrices(name, d)
    if "unstructured" not in name:
        from roadtruth.observers.lpv_wang_robust_design import luenberger_as_unstructured
        g = luenberger_as_unstructured(A1, [d.gain(f"L{i}") for i in range(3)])
    peak = 0.0
    for pt in robust_vertices((15 / 3.6, 150 / 3.6), (-8.0, 8.0), (-0.1, 0.1), (-0.2, 0.2)):
        Ae, Be = error_system(A1, g, pt)
        for om in np.r_[0.0, np.logspace(-2, 4, 300)]:
            peak = max(peak, float(np.linalg.svd(np.linalg.solve(1j * om * np.eye(2) - Ae, Be), compute_uv=False)[0]))
    assert peak <= d.gamma
    assert peak > 0.5 * d.gamma


def _observer_matrices(name: str, d):
    from roadtruth.observers.bicycle import slip_model_terms
    from roadtruth.observers.lpv_wang_robust_design import UNSTRUCTURED_KEYS, luenberger_as_unstructured
    if "unstructured" in name:
        return {k: d.gain(k) for k in UNSTRUCTURED_KEYS}
    A1, _ = slip_model_terms(load_vehicle("sedan"))
    return luenberger_as_unstructured(A1, [d.gain(f"L{i}") for i in range(3)])


@pytest.mark.parametrize("name", ["lpv_wang_h2", "lpv_wang_unstructured_hinf", "lpv_wang_unstructured_h2",
                                  "lpv_wang_unstructured_hinf_printed", "lpv_wang_unstructured_h2_printed"])
def test_observer_runs_exactly_its_designed_equations(name: str) -> None:
    """Independent implementation of (3.47) in alpha coordinates: held inputs, x1 jumping by the
    steering step (the integral of delta'), scipy expm of the augmented matrix per step, y built
    from the held delta, r, v; and theta_m from the scheduling error. Agreement to 1e-9 rad."""
    from scipy.linalg import expm

    from roadtruth.observers.lpv_wang_robust_design import observer_matrices
    vehicle = load_vehicle("sedan")
    eps = (-0.1, 0.15)
    t, Y, x, _, _ = _design_model(vehicle, eps, h=0.01, T=2.0, seed=3)
    obs = create(name, vehicle, scheduling_error=eps)
    g = _observer_matrices(name, obs.design())
    xh = obs.run(t, Y, x0={"alpha_f_rad": 0.03, "alpha_r_rad": -0.01}).x[:, :2]
    ell = vehicle.lf_m + vehicle.lr_m
    ref = np.zeros_like(xh)
    ref[0] = (0.03, -0.01)
    for k in range(1, len(t)):
        d, r, v, a = Y[k]
        # the measured scheduling, clamped into the design domain as documented
        vm, am = np.clip((1 + eps[0]) * v, 15 / 3.6, 150 / 3.6), np.clip((1 + eps[1]) * a, -8.0, 8.0)
        m1, m2 = 1 / vm, am / vm
        Ao, Bou, Boy = observer_matrices(g, m1, m2)
        s = ref[k - 1] + np.array([d - Y[k - 1, 0], 0.0])
        aug = np.zeros((3, 3))
        aug[:2, :2] = Ao
        aug[:2, 2] = Bou[:, 0] * d + Bou[:, 2] * r + Boy[:, 0] * (d - ell * r / v)
        ref[k] = (expm(aug * (t[k] - t[k - 1])) @ np.r_[s, 1.0])[:2]
    np.testing.assert_allclose(xh, ref, atol=1e-9, rtol=0)


@pytest.mark.parametrize("vehicle_name", ["sedan", "wang2014"])
@pytest.mark.parametrize("name", ["lpv_wang_h2", "lpv_wang_unstructured_h2"])
def test_h2_impulse_energy_below_certified_bound(vehicle_name: str, name: str) -> None:
    """H2 promise: an impulse in each of the 5 channels of w at t = 0 gives total error energy
    sum_j int |e_j|^2 <= gamma^2 = trace Z, for theta(t) moving anywhere in the polytope (one
    Lyapunov matrix); simulated on the error system (3.49) with random vertex weights. At the frozen
    worst vertex the exact squared H2 norm (Lyapunov equation) is within a factor 12 of the bound."""
    from scipy.linalg import solve_continuous_lyapunov

    from roadtruth.observers.bicycle import slip_model_terms
    from roadtruth.observers.lmi import robust_vertices
    from roadtruth.observers.lpv_wang_robust_design import error_system
    vehicle = load_vehicle(vehicle_name)
    A1, _ = slip_model_terms(vehicle)
    d = create(name, vehicle).design()
    assert d.certified, d.reason
    g = _observer_matrices(name, d) if "unstructured" in name else None
    if g is None:
        from roadtruth.observers.lpv_wang_robust_design import luenberger_as_unstructured
        g = luenberger_as_unstructured(A1, [d.gain(f"L{i}") for i in range(3)])
    verts = robust_vertices((15 / 3.6, 150 / 3.6), (-8.0, 8.0), (-0.1, 0.1), (-0.2, 0.2))
    frozen = []
    for pt in verts:
        Ae, Be = error_system(A1, g, pt)
        W = solve_continuous_lyapunov(Ae.T, -np.eye(2))
        frozen.append(float(np.trace(Be.T @ W @ Be)))
    assert max(frozen) <= d.gamma**2
    assert max(frozen) > 0.08 * d.gamma**2  # one P and Z for all 16 vertices: 8-12x conservative
    rng = np.random.default_rng(7)
    for trial in range(3):
        lam = rng.dirichlet(np.ones(16), size=40)  # a new point of the polytope every 50 ms

        def f(t, e, lam=lam):
            pt = lam[min(int(t / 0.05), 39)] @ verts
            return error_system(A1, g, pt)[0] @ e

        pt0 = lam[0] @ verts
        Be0 = error_system(A1, g, pt0)[1]
        energy = 0.0
        for j in range(5):
            ts = np.linspace(0, 2.0, 20001)
            sol = solve_ivp(f, (0, 2.0), Be0[:, j], t_eval=ts, rtol=1e-9, atol=1e-12, method="LSODA")
            energy += np.trapezoid(np.sum(sol.y**2, axis=0), ts)
            # the rest of the energy after 2 s, bounded by e(2)^T P e(2)
            energy += float(sol.y[:, -1] @ np.array(d.P) @ sol.y[:, -1])
        assert energy <= d.gamma**2, (trial, energy, d.gamma**2)


def test_robust_family_certification_on_both_vehicles() -> None:
    """Fresh designs certify; the unstructured H-inf optimum is at most the Luenberger one (the
    unstructured observer contains it); printed: H2 Luenberger and unstructured H-inf certify only
    far larger bounds; the printed unstructured H2 matrices leave A - B_oy C unstable although the
    observer's own A_o is stable, so no bound exists (rejected)."""
    for vehicle_name in ("sedan", "wang2014"):
        v = load_vehicle(vehicle_name)
        luen = create("lpv_wang_hinf", v).design()
        un = create("lpv_wang_unstructured_hinf", v).design()
        assert un.certified and luen.certified
        assert un.margins["gamma_optimal"] <= luen.margins["gamma_optimal"] + 1e-4
        h2, uh2 = create("lpv_wang_h2", v).design(), create("lpv_wang_unstructured_h2", v).design()
        assert h2.certified and uh2.certified and uh2.margins["gamma_optimal"] <= h2.margins["gamma_optimal"]
        assert h2.gamma <= 1.05 * h2.margins["gamma_optimal"] * 1.01
        p = create("lpv_wang_h2_printed", v).design()
        assert p.certified and p.gamma > 10 * h2.gamma
        pu = create("lpv_wang_unstructured_hinf_printed", v).design()
        assert pu.certified and pu.gamma > 100 * un.gamma
        pu2 = create("lpv_wang_unstructured_h2_printed", v).design()
        assert pu2.status is DesignStatus.REJECTED and not pu2.certified
        assert pu2.margins["closed_loop_max_real_eig"] > 100 and pu2.margins["observer_max_real_eig"] < -3
    seed_car = load_vehicle("wang2014")
    assert create("lpv_wang_unstructured_hinf", seed_car).design().margins["gamma_optimal"] == pytest.approx(0.2087, abs=2e-3)
    h2 = create("lpv_wang_h2", seed_car).design()
    assert h2.margins["gamma_optimal"] == pytest.approx(1.864, abs=0.02)
    # (3.41) exactly as printed, re-solved independently before: optimum 0.565, printed gains 28.6
    assert h2.margins["gamma_as_printed_lmi_optimum"] == pytest.approx(0.565, abs=5e-3)
    assert create("lpv_wang_h2_printed", seed_car).design().margins["gamma_as_printed_lmi"] == pytest.approx(28.6, rel=0.01)


def test_scheduling_error_option() -> None:
    from roadtruth.harness.errors import InputError
    v = load_vehicle("sedan")
    t, Y, alpha, _ = _maneuver(v, h=0.01, T=2.0)
    base = create("lpv_wang_unstructured_hinf", v).run(t, Y).x
    zero = create("lpv_wang_unstructured_hinf", v, scheduling_error=(0.0, 0.0)).run(t, Y).x
    np.testing.assert_array_equal(base, zero)
    moved = create("lpv_wang_unstructured_hinf", v, scheduling_error=(-0.1, 0.15)).run(t, Y).x
    assert np.abs(moved - base).max() > 1e-4
    # the option does not change the design (same cache entry)
    assert create("lpv_wang_hinf", v, scheduling_error=(0.05, 0.1)).design().key == create("lpv_wang_hinf", v).design().key
    for bad in [(1.0, 0.0), (0.0, float("nan")), 0.1, ("a", 0)]:
        with pytest.raises(InputError, match="scheduling_error"):
            create("lpv_wang", v, scheduling_error=bad)


def test_robust_family_runs_in_the_harness_on_mujoco(tmp_path) -> None:
    import pandas as pd

    from roadtruth.harness.jobs.pipeline import run_suite
    names = ["lpv_wang_h2", "lpv_wang_unstructured_hinf", "lpv_wang_unstructured_h2_printed"]
    out = run_suite(scenarios=["double_lane_change"], observers=names, render=False, out=tmp_path / "run")
    m = pd.read_csv(out / "metrics.csv")
    rows = m[m["observer"].isin(names) & (m["state"] == "alpha_r_rad")]
    assert set(rows["observer"]) == set(names)
    fresh = rows[~rows["observer"].str.endswith("_printed")]
    assert (fresh["status"] == "ok").all(), rows[["observer", "status"]]
    # the printed unstructured H2 gains are rejected by certification, and on the multibody car their
    # rear slip is worse than assuming 0: the verdict says so
    printed = rows[rows["observer"] == "lpv_wang_unstructured_h2_printed"]
    assert printed["status"].str.startswith("unusable").all(), printed[["observer", "status"]]
    assert (fresh["rmse"] < np.deg2rad(0.6)).all(), fresh[["observer", "rmse"]]


# ---- the compiled kernel shared by step() and run() (observers/lpv_wang_loop.py) -----------------

ALL_LPV = ("lpv_wang", "lpv_wang_printed", "lpv_wang_hinf", "lpv_wang_hinf_printed", "lpv_wang_h2",
           "lpv_wang_h2_printed", "lpv_wang_unstructured_h2", "lpv_wang_unstructured_h2_printed",
           "lpv_wang_unstructured_hinf", "lpv_wang_unstructured_hinf_printed")


def _hard_log(vehicle):
    """The own-model manoeuvre with everything the per-sample update has to get right: no steering
    for the first samples (the change of variable waits for it), 20 % random dropouts, a 0.6 s gap of
    r and v_x (past hold_s: prediction without correction), speeds below the design domain and below
    the output floor, a_x beyond its range, a repeated and an irregular time stamp."""
    t, Y, _, _ = _maneuver(vehicle, h=0.01, T=6.0)
    Y, t = Y.copy(), t.copy()
    gen = np.random.default_rng(5)
    Y[:3] = np.nan
    Y[gen.random(Y.shape) < 0.2] = np.nan
    Y[200:260, 1:3] = np.nan
    Y[300:320, 2] = 3.0
    Y[320:330, 2] = 0.5
    Y[330:340, 3] = -12.0
    t[150] = t[149]
    t[350:] += 0.0041
    return t, Y


def _python_reference(obs, t, Y, x0=None):
    """The observer's update written out in plain Python (the loop the kernel replaced): held inputs,
    z1 = alpha_f - delta from the first steering sample, theta_m clamped into the domain, exact ZOH
    with (fresh inputs) or without (older than hold_s) the correction, derived v_y and beta."""
    import math

    from roadtruth.observers.bicycle import expm2_zoh, slip_model_terms
    v, o = obs.vehicle, obs.options
    A = slip_model_terms(v)[0].reshape(-1)
    lf, lr, ell = v.lf_m, v.lr_m, v.lf_m + v.lr_m
    (vlo, vhi), (alo, ahi) = o["vx_range_mps"], o["ax_range_mps2"]
    e1, e2 = o["scheduling_error"]
    g = obs.gains()
    unstructured = len(g) == 36
    u, tl = [math.nan] * 4, [-math.inf] * 4
    z = [0.0, 0.0] if not x0 else [x0.get("alpha_f_rad", 0.0), x0.get("alpha_r_rad", 0.0)]
    tc, have = float(t[0]), False
    out = []
    for ts, row in zip(t.tolist(), Y.tolist(), strict=True):
        for j, val in enumerate(row):
            if val == val:
                u[j], tl[j] = val, ts
        h = ts - tc if ts > tc else 0.0
        tc = max(tc, ts)
        d, r, vx, ax = u
        if d == d:
            if not have:
                z[0] -= d
                have = True
            if h > 0.0 and r == r and vx == vx and ax == ax:
                vc = min(max(vx * (1.0 + e1), vlo), vhi)
                m1 = 1.0 / vc
                m2 = min(max(ax * (1.0 + e2), alo), ahi) * m1
                fresh = ts - min(tl[:3]) <= o["hold_s"]
                yp = -ell * r / max(vx, o["vx_min_output_mps"])
                P = [m1 * A[0] - m2, m1 * A[1], m1 * A[2], m1 * A[3] - m2]
                if unstructured and fresh:
                    c = [g[k] + m1 * g[k + 4] + m2 * g[k + 8] for k in range(4)]
                    bu = [g[k] + m1 * g[k + 6] + m2 * g[k + 12] for k in range(12, 18)]
                    by = [g[k] + m1 * g[k + 2] + m2 * g[k + 4] for k in (30, 31)]
                    f1 = (c[0] + bu[0]) * d + bu[2] * r + by[0] * (d + yp)
                    f2 = (c[2] + bu[3]) * d + bu[5] * r + by[1] * (d + yp)
                elif unstructured:
                    c, f1, f2 = P, (P[0] + m2) * d + r, P[2] * d + r
                else:
                    la, lb = (g[0] + m1 * g[2] + m2 * g[4], g[1] + m1 * g[3] + m2 * g[5]) if fresh else (0.0, 0.0)
                    c = [P[0] - la, P[1] + la, P[2] - lb, P[3] + lb]
                    f1, f2 = m1 * A[0] * d + r + la * yp, m1 * A[2] * d + r + lb * yp
                E, G = expm2_zoh(*c, h)
                z = [E[0] * z[0] + E[1] * z[1] + G[0] * f1 + G[1] * f2, E[2] * z[0] + E[3] * z[1] + G[2] * f1 + G[3] * f2]
        af, ar = (z[0] + d if have else z[0]), z[1]
        if not have or r != r or vx != vx:
            out.append([af, ar, 0.0, 0.0])
            continue
        vv = max(vx, o["vx_min_output_mps"])
        vy = 0.5 * (vv * math.tan(d - af) - lf * r - vv * math.tan(ar) + lr * r)
        out.append([af, ar, math.atan2(vy, vv), vy])
    return np.array(out)


@pytest.mark.parametrize("name", ALL_LPV)
def test_kernel_equals_the_python_update(name: str) -> None:
    """The compiled kernel computes the documented per-sample update: equal to a plain-Python loop of
    the same equations to 1e-12 (relative) through every guard rail of the hard log, with a scheduling
    error and with an initial state."""
    v = load_vehicle("sedan")
    t, Y = _hard_log(v)
    for opts, x0 in (({}, None), ({"scheduling_error": (-0.1, 0.15)}, {"alpha_f_rad": 0.02, "alpha_r_rad": -0.01})):
        obs = create(name, v, **opts)
        got = obs.run(t, Y, x0).x
        want = _python_reference(obs, t, Y, x0)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
        assert np.ptp(got[:, 0]) > 1e-3  # the slip estimates moved


@pytest.mark.parametrize("name", ALL_LPV)
def test_run_is_one_compiled_call_and_equals_stepping_bit_for_bit(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """run() advances the whole log in one call of the compiled kernel that step() calls per sample, so
    the estimates are the same bits (hard log: dropouts, an outage past hold_s, speeds outside the
    domain, a repeated and an irregular time stamp), from the default and from a given initial state;
    afterwards run() leaves the observer where stepping leaves it (the next step agrees)."""
    import roadtruth.observers.lpv_wang as module

    v = load_vehicle("sedan")
    t, Y = _hard_log(v)
    calls: list[int] = []
    kernel = module.lpv_run

    def counted(tt: np.ndarray, *args: object) -> None:
        calls.append(len(tt))
        kernel(tt, *args)

    for x0 in (None, {"alpha_f_rad": 0.01, "alpha_r_rad": -0.005}):
        monkeypatch.setattr(module, "lpv_run", counted)
        calls.clear()
        obs = create(name, v)
        tr = obs.run(t, Y, x0)
        assert calls == [len(t)]   # one compiled call for the whole run
        monkeypatch.undo()
        ref = create(name, v)
        ref.reset(float(t[0]), x0)
        want = np.array([ref.step(float(t[i]), Y[i]).x for i in range(len(t))])
        assert tr.x.tobytes() == want.tobytes()
        assert np.all(np.isfinite(tr.x))
        if x0:
            assert tr.x[0, 0] == x0["alpha_f_rad"] and tr.x[0, 1] == x0["alpha_r_rad"]  # no steering yet
        row = np.array([0.01, 0.05, 15.0, 0.5])
        nxt, nref = obs.step(float(t[-1]) + 0.01, row), ref.step(float(t[-1]) + 0.01, row)
        assert nxt.x.tobytes() == nref.x.tobytes()
        assert nxt.x.tobytes() != tr.x[-1].tobytes()  # the step did move the state
