"""Seed-002 Takagi-Sugeno observer: TS model, Theorem-1 certificate, own-model exactness, curvature."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers.registry import create
from roadtruth.observers.takagi_sugeno import expm_taylor, rule_weights, ts_step
from roadtruth.observers.takagi_sugeno_design import (
    C_OUT,
    RULES,
    SEED_STIFFNESS_NPR,
    secant_slope,
    sector_bounds,
)
from roadtruth.observers.tire_curves import axle_curves

SEED_CAR = load_vehicle("yacine2016")
SEDAN = load_vehicle("sedan")
SEED_RANGE = {"vx_range_mps": (0.2, 17.0)}


pytestmark = pytest.mark.usefixtures("isolated_design_cache")


def own_model(vehicle, *, t_end: float = 3.0, h: float = 1e-3, sub: int = 2, vy0: float = 1.0,
              vx: float = 15.0, delta_amp: float = 0.03, rho: float = 0.005, relax: float = 0.1,
              ls: float = 0.5) -> np.ndarray:
    """Seed model S1 + S2 (eqs. (8)-(9), slips (4), Magic Formula F = f(alpha) alpha, relaxation r/v_x),
    steering held over each sample (ZOH), RK4 with ``sub`` sub-steps.

    Returns (n, 11): ``t, r, delta, vx, y_L, psi_L`` (observer inputs, no noise) then the true
    ``v_y, r, F_f, F_r, rho``.
    """
    fc, rc = axle_curves(vehicle)
    m, iz, af, ar = vehicle.mass_kg, vehicle.yaw_inertia_kgm2, vehicle.lf_m, vehicle.lr_m

    def force(a: float, c) -> float:
        return secant_slope(a, c.B, c.C, c.E, c.D) * a

    def deriv(s: np.ndarray, d: float) -> np.ndarray:
        vy, r, ff, fr, pl, _ = s
        a_f, a_r = d - (vy + af * r) / vx, -(vy - ar * r) / vx
        dpl = r - vx * rho
        return np.array([(ff + fr) / m - vx * r, (af * ff - ar * fr) / iz, vx / relax * (force(a_f, fc) - ff),
                         vx / relax * (force(a_r, rc) - fr), dpl, vy + vx * pl + ls * dpl])

    s = np.array([vy0, 0.0, 0.0, 0.0, 0.0, 0.2])
    rows = []
    hs = h / sub
    for k in range(int(round(t_end / h))):
        t = k * h
        d = delta_amp * math.sin(2 * math.pi * 0.5 * t)
        rows.append([t, s[1], d, vx, s[5], s[4], s[0], s[1], s[2], s[3], rho])
        for _ in range(sub):
            k1 = deriv(s, d)
            k2 = deriv(s + 0.5 * hs * k1, d)
            k3 = deriv(s + 0.5 * hs * k2, d)
            k4 = deriv(s + hs * k3, d)
            s = s + hs / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return np.array(rows)


def _run(name: str, vehicle, data: np.ndarray, **options):
    obs = create(name, vehicle, lane_heading_at="cg", lipschitz_y_lane=30.0, lipschitz_psi_lane=5.0, **options)
    return obs, obs.run(data[:, 0], data[:, 1:6])


# ---- TS model --------------------------------------------------------------------------------------

def test_vertex_coefficients_match_digest_table() -> None:
    obs = create("ts_yacine", SEED_CAR, **SEED_RANGE)
    model = obs.ts_model
    assert (model.mf_Npr + model.mr_Npr) == (SEED_STIFFNESS_NPR[0], SEED_STIFFNESS_NPR[1],
                                             SEED_STIFFNESS_NPR[2], SEED_STIFFNESS_NPR[3])
    table = {(0, 0): (-606.667, 162.400, 99.2665, -621.134, 280.000, 188.264),
             (0, 1): (-500.000, 8.800, 5.3790, -485.936, 280.000, 188.264),
             (1, 0): (-546.667, 228.400, 139.6088, -576.758, 220.000, 147.922),
             (1, 1): (-440.000, 74.800, 45.7213, -441.560, 220.000, 147.922)}
    for i, (l, j, k) in enumerate(RULES):
        A, B = model.vertex(i)
        v = model.vx_range_mps[1 - l]
        a1, a2, a3, a4, b1, b2 = table[(j, k)]
        np.testing.assert_allclose([A[2, 0], A[2, 1], A[3, 0], A[3, 1], B[2] / v, B[3] / v],
                                   [a1, a2, a3, a4, b1, b2], rtol=2e-5)
        assert A[0, 1] == -v and A[2, 2] == A[3, 3] == pytest.approx(-v / 0.1)


def test_weights_rebuild_the_model_exactly() -> None:
    """Sum h_i (A_i, B_i) equals the physical (A, B) inside the sector box (exact sector form)."""
    model = create("ts_yacine", SEDAN).ts_model
    rng = np.random.default_rng(3)
    w = np.zeros(8)
    for _ in range(50):
        vx = rng.uniform(*model.vx_range_mps)
        ff = rng.uniform(model.mf_Npr[1], model.mf_Npr[0])
        fr = rng.uniform(model.mr_Npr[1], model.mr_Npr[0])
        h = model.weights(vx, ff, fr)
        assert h.min() >= 0.0 and h.sum() == pytest.approx(1.0, abs=1e-12)
        A, B = model.matrices(vx, ff, fr)
        np.testing.assert_allclose(sum(h[i] * model.vertex(i)[0] for i in range(8)), A, rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(sum(h[i] * model.vertex(i)[1] for i in range(8)), B, rtol=1e-10, atol=1e-9)
        for order in ("corrected", "as_printed"):
            m1 = ((vx - model.vx_range_mps[0]) / (model.vx_range_mps[1] - model.vx_range_mps[0]),
                  (ff - model.mf_Npr[1]) / (model.mf_Npr[0] - model.mf_Npr[1]),
                  (fr - model.mr_Npr[1]) / (model.mr_Npr[0] - model.mr_Npr[1]))
            rule_weights(*m1, order == "as_printed", w)
            np.testing.assert_allclose(w, model.weights(vx, ff, fr, order), rtol=1e-12, atol=1e-15)


def test_magic_formula_sectors_for_other_vehicles() -> None:
    obs = create("ts_yacine", SEDAN)
    assert obs.sector_source == "magic_formula"
    fc, rc = axle_curves(SEDAN)
    fmin, fmax = sector_bounds(fc.B, fc.C, fc.E, fc.D, 0.14)
    assert obs.ts_model.mf_Npr == (fmax, fmin)
    assert fmax == pytest.approx(SEDAN.cornering_stiffness_f_Npr, rel=1e-6)  # f(0) = B C D
    # f is even and decreasing in |alpha| for these shapes: the minimum is at the edge.
    assert fmin == pytest.approx(secant_slope(0.14, fc.B, fc.C, fc.E, fc.D), rel=1e-9)
    assert secant_slope(-0.05, fc.B, fc.C, fc.E, fc.D) == secant_slope(0.05, fc.B, fc.C, fc.E, fc.D)
    assert create("ts_yacine", SEED_CAR).sector_source == "seed"
    explicit = create("ts_yacine", SEDAN, tire_sectors=(1.2e5, 6e4, 1.4e5, 5e4))
    assert explicit.ts_model.mr_Npr == (1.4e5, 5e4)


@pytest.mark.parametrize("options", [{"vx_range_mps": (0.0, 17.0)}, {"tire_sectors": (1.0, 2.0, 3.0, 1.0)},
                                     {"rule_order": "swapped"}, {"lane_heading_at": "rear"},
                                     {"differentiator_order": 9}, {"decay_alpha": 0.0}, {"tire_sectors": "x"}])
def test_bad_options_are_input_errors(options: dict) -> None:
    with pytest.raises(InputError):
        create("ts_yacine", SEDAN, **options)


# ---- Theorem 1 -------------------------------------------------------------------------------------

@pytest.mark.parametrize(("vehicle", "options"), [(SEED_CAR, SEED_RANGE), (SEED_CAR, {}), (SEDAN, {})])
def test_theorem1_design_is_certified(vehicle, options: dict) -> None:
    d = create("ts_yacine", vehicle, **options).design()
    assert d.certified, d.reason
    assert np.asarray(d.gains["L"]).shape == (8, 4)
    assert d.margins["theorem1_max_eig_vertices"] <= -1e-7 and d.margins["theorem1_max_eig_grid"] <= -1e-7
    assert d.margins["closed_loop_max_real_eig"] <= -0.0005          # at least alpha / 2
    assert d.margins["slowest_vertex_real_eig"] < -0.5                # digest: about -1.1


def test_lyapunov_function_decreases_across_exact_discrete_steps() -> None:
    """exp(Phi h) for any convex premise weights keeps V = e^T P e decreasing (common P, exact ZOH)."""
    obs = create("ts_yacine", SEDAN)
    d = obs.design()
    P = np.asarray(d.P)
    s = d.gains["state_scale"][0]
    S, Si = np.diag([1, 1, s, s]), np.diag([1, 1, 1 / s, 1 / s])
    L = obs.gains()
    rng = np.random.default_rng(1)
    for _ in range(40):
        w = rng.dirichlet(np.ones(8))
        Phi = sum(w[i] * (obs._Av[i] - np.outer(L[i], C_OUT[0])) for i in range(8))
        for h in (1e-3, 1e-2, 0.1):
            E = S @ scipy.linalg.expm(Phi * h) @ Si
            e = rng.normal(size=4)
            assert (E @ e) @ P @ (E @ e) < e @ P @ e


def test_kernel_matches_scipy_and_its_python_twin() -> None:
    rng = np.random.default_rng(2)
    for scale in (0.1, 5.0, 300.0):
        M = rng.normal(size=(5, 5)) * scale / 5
        np.testing.assert_allclose(expm_taylor(M), scipy.linalg.expm(M), rtol=1e-9, atol=1e-12)
    obs = create("ts_yacine", SEDAN)
    L = obs.gains()
    xa, xb = np.array([0.3, 0.05, 1.0, -2.0]), np.array([0.3, 0.05, 1.0, -2.0])
    wa, wb = np.zeros(8), np.zeros(8)
    args = (0.01, 0.3, 0.7, 0.2, False, 0.02, 0.1, True, obs._Av, obs._Bv, L)
    ts_step(xa, *args, wa)
    ts_step.py_func(xb, *args, wb)
    np.testing.assert_allclose(xa, xb, rtol=1e-12, atol=1e-14)


# ---- own model (no noise) ---------------------------------------------------------------------------

def test_error_decays_on_own_model_with_exact_premises() -> None:
    """Digest: v_y error 1.0 -> ~0.005 within 1 s; here 1.0 -> < 0.02 (1 s) -> < 1e-3 (2 s), forces too."""
    data = own_model(SEED_CAR, t_end=3.0)
    obs, tr = _run("ts_yacine", SEED_CAR, data, **SEED_RANGE)
    assert obs.premise_source == "camera"
    e = np.abs(tr.x[:, 0] - data[:, 6])
    assert e[0] == pytest.approx(1.0)
    assert e[1000] < 0.02 and e[2000] < 1e-3 and e[2500:].max() < 5e-4
    assert np.abs(tr.x[2500:, 3] - data[2500:, 8]).max() < 10.0   # F_f [N], about 1 % of its amplitude
    assert np.abs(tr.x[2500:, 4] - data[2500:, 9]).max() < 10.0
    np.testing.assert_allclose(tr.x[2500:, 2], np.arctan2(tr.x[2500:, 0], 15.0))


def test_residual_vanishes_with_the_sampling_step() -> None:
    """The only residual is the sample-and-hold of r and the premises: O(h)."""
    worst = []
    for h, sub in ((1e-2, 20), (2e-3, 4)):
        data = own_model(SEED_CAR, t_end=3.0, h=h, sub=sub)
        _, tr = _run("ts_yacine", SEED_CAR, data)
        k = int(2.0 / h)
        worst.append(np.abs(tr.x[k:, 0] - data[k:, 6]).max())
    assert worst[0] < 5e-3 and worst[0] / worst[1] > 3.0


def test_as_printed_rule_order_keeps_the_certificate_but_biases() -> None:
    """Eq. (22) as printed swaps mu_2 / mu_3: any convex weights stay certified, the model is wrong.

    With the swap the front stiffness follows the rear membership and vice versa
    (``M_f1 mu_r1 + M_f2 mu_r2``), so the error stays wherever the two axles' slips differ.
    """
    data = own_model(SEDAN, t_end=4.0, vx=20.0, delta_amp=0.06, vy0=0.0)
    _, good = _run("ts_yacine", SEDAN, data)
    printed_obs, bad = _run("ts_yacine", SEDAN, data, rule_order="as_printed")
    assert printed_obs.design().certified
    k = 2000
    e_good = np.abs(good.x[k:, 0] - data[k:, 6]).max()
    e_bad = np.abs(bad.x[k:, 0] - data[k:, 6]).max()
    assert e_bad > 10.0 * e_good and e_bad > 5e-3


def test_curvature_exact_on_constant_curvature_road() -> None:
    data = own_model(SEDAN, t_end=3.0, rho=0.004, vy0=0.0)
    _, tr = _run("ts_yacine", SEDAN, data)
    assert np.abs(tr.x[1500:, 5] - 0.004).max() < 1e-5
    _, tr2 = _run("ts_yacine", SEDAN, own_model(SEDAN, t_end=3.0, rho=-0.01, vy0=0.0))
    assert np.abs(tr2.x[1500:, 5] + 0.01).max() < 1e-5


def test_camera_loss_falls_back_to_own_premise() -> None:
    data = own_model(SEED_CAR, t_end=3.0, h=2e-3, sub=4)
    Y = data[:, 1:6].copy()
    Y[500:900, 3:5] = np.nan                     # 0.8 s without lane markings
    obs = create("ts_yacine", SEED_CAR, lane_heading_at="cg", lipschitz_y_lane=30.0, lipschitz_psi_lane=5.0)
    obs.reset(0.0)
    sources = []
    for i in range(len(data)):
        out = obs.step(float(data[i, 0]), Y[i])
        assert np.all(np.isfinite(out.x))
        sources.append(obs.premise_source)
    assert sources[400] == "camera" and sources[800] == "observer" and sources[-1] == "camera"
    rho_held = out.x[5]
    assert rho_held == pytest.approx(0.005, abs=1e-4)
    xhat = create("ts_yacine_xhat", SEED_CAR, lane_heading_at="cg")
    tr = xhat.run(data[:, 0], Y)
    assert xhat.premise_source == "observer" and np.abs(tr.x[-200:, 0] - data[-200:, 6]).max() < 5e-3


def test_conformance_with_camera_inputs(monkeypatch: pytest.MonkeyPatch) -> None:
    """The shared conformance checks, with the camera columns the shared signal set lacks."""
    import tests.test_observers_conformance as conf

    base = conf._signals

    def with_camera(n: int = 800, h: float = 0.01):
        t, sig = base(n, h)
        sig = {**sig, "y_lane_m": 0.1 * np.sin(t), "psi_lane_rad": 0.01 * np.cos(t)}
        sig["y_lane_m"][1::3] = np.nan           # a 33 Hz camera
        sig["psi_lane_rad"][1::3] = np.nan
        return t, sig

    monkeypatch.setattr(conf, "_signals", with_camera)
    for name in ("ts_yacine", "ts_yacine_xhat"):
        conf.test_conformance(name)
        conf.test_missing_samples_never_crash(name)
        conf.test_unknown_option_and_bad_initial_state_are_input_errors(name)


# ---- MuJoCo ------------------------------------------------------------------------------------------

def test_short_mujoco_curvy_road_run_gives_finite_metrics() -> None:
    from roadtruth.harness.evaluation.estimate import run_observers
    from roadtruth.harness.evaluation.scoring import score
    from roadtruth.harness.sensors import emulate, load_sensor_config
    from roadtruth.harness.truth.scenario import load_scenario
    from roadtruth.harness.truth.simulate import simulate

    sc = dataclasses.replace(load_scenario("curvy_road"), duration_s=4.0)
    truth = simulate(sc)
    assert truth.status == "ok"
    meas = emulate(truth.frame, truth.vehicle, load_sensor_config("automotive", sc.sensor_overrides, None), 1,
                   outages=sc.outages, lane_gaps=sc.lane_gaps)
    est, runs = run_observers(meas.frame, truth.vehicle, ["ts_yacine", "kf_bicycle"])
    assert runs["ts_yacine"].status == "ok" and runs["ts_yacine"].certified
    m = score(truth.frame, est, scenario=sc.name, runs=runs, mass_kg=truth.vehicle.mass_kg)
    rows = m[m.observer == "ts_yacine"].set_index("state")
    assert set(rows.index) == {"vy_mps", "yaw_rate_radps", "beta_rad", "fy_f_N", "fy_r_N", "rho_1pm"}
    assert np.all(np.isfinite(rows["rmse"]))
    assert rows.loc["vy_mps", "rmse"] < 0.1 and rows.loc["rho_1pm", "rmse"] < 0.01


# ---- compiled loop -------------------------------------------------------------------------------------

def _ragged_camera_log(n: int = 2500) -> tuple[np.ndarray, np.ndarray]:
    """Own-model inputs (h = 2 ms) with a 25 Hz camera, a camera gap longer than the timeout, gyro and
    steering dropouts, a repeated and a jittered block of time stamps."""
    data = own_model(SEED_CAR, t_end=n * 2e-3, h=2e-3, sub=2)
    t, Y = data[:, 0].copy(), data[:, 1:6].copy()
    gen = np.random.default_rng(11)
    cam = np.arange(len(t)) % 20 == 0
    cam[1000:1300] = False
    Y[~cam, 3:5] = np.nan
    Y[gen.random(len(t)) < 0.2, 0] = np.nan
    Y[gen.random(len(t)) < 0.1, 1] = np.nan
    Y[1600:1700, 0] = np.nan   # gyro older than hold_s: open loop
    t[401] = t[400]
    t[1800:1850] += gen.uniform(-8e-4, 8e-4, 50)
    return t, Y


@pytest.mark.parametrize("name", ["ts_yacine", "ts_yacine_xhat"])
def test_run_is_one_compiled_call_and_equals_stepping_bit_for_bit(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """run() is one call of the compiled kernel step() calls per sample: the same bits through camera
    gaps (differentiators re-armed, premise falls back to the estimate), gyro and steering dropouts,
    repeated and irregular time stamps and an initial state; the premise source and the state end where
    stepping leaves them, the next step agrees, and run() again repeats itself."""
    import roadtruth.observers.takagi_sugeno_loop as loop

    t, Y = _ragged_camera_log()
    opts = {"lane_heading_at": "cg", "lipschitz_y_lane": 30.0, "lipschitz_psi_lane": 5.0, **SEED_RANGE}
    calls: list[int] = []
    kernel = loop.ts_run

    def counted(tt: np.ndarray, *args: object) -> None:
        calls.append(len(tt))
        kernel(tt, *args)

    x0 = {"vy_mps": 0.8, "yaw_rate_radps": 0.02}
    obs = create(name, SEED_CAR, **opts)
    obs.design()
    monkeypatch.setattr(loop, "ts_run", counted)
    tr = obs.run(t, Y, x0)
    assert calls == [len(t)]
    monkeypatch.undo()
    ref = create(name, SEED_CAR, **opts)
    ref.reset(float(t[0]), x0)
    sources = []
    stepped = []
    for i in range(len(t)):
        stepped.append(ref.step(float(t[i]), Y[i]).x)
        sources.append(ref.premise_source)
    assert tr.x.tobytes() == np.array(stepped).tobytes()
    assert tr.x[0, 0] == 0.8 and np.all(np.isfinite(tr.x))
    if name == "ts_yacine":
        assert sources[900] == "camera" and sources[1250] == "observer" and sources[-1] == "camera"
    else:
        assert set(sources) == {"observer"}
    assert obs.premise_source == ref.premise_source
    y_next = np.array([0.01, 0.0, 15.0, np.nan, np.nan])
    assert obs.step(float(t[-1]) + 2e-3, y_next).x.tobytes() == ref.step(float(t[-1]) + 2e-3, y_next).x.tobytes()
    assert obs.run(t, Y, x0).x.tobytes() == tr.x.tobytes()


def test_camera_premise_differs_from_the_estimate_premise() -> None:
    """On the same log the camera-premise and the estimate-premise observers start from the same state
    but weigh their rules differently: the curvature is the camera's in both, the v_y paths differ while
    the estimate has not converged (so a kernel that ignored premise_from_camera would fail here)."""
    t, Y = _ragged_camera_log()
    opts = {"lane_heading_at": "cg", "lipschitz_y_lane": 30.0, "lipschitz_psi_lane": 5.0, **SEED_RANGE}
    a = create("ts_yacine", SEED_CAR, **opts).run(t, Y).x
    b = create("ts_yacine_xhat", SEED_CAR, **opts).run(t, Y).x
    assert np.abs(a[300:700, 0] - b[300:700, 0]).max() > 1e-4
    assert a[:, 5].tobytes() == b[:, 5].tobytes()   # rho (11) does not depend on the premise
    assert np.abs(a[-100:, 5] - 0.005).max() < 1.5e-3   # 25 Hz camera: the differentiator's lag
