"""Radar high-gain observers of Bessafa (2024): Thms 4.3.1-4.3.4 and 4.4.1 on the radar model of sec. 5.2.

On the thesis's own relative longitudinal model (M7d): the Lyapunov function of every variant decays
at its certified rate; the dynamic extension meets its ISS bound with bounded range noise; the drag
coupling of the lead model is exact; the multi-output observer keeps range rate and lead acceleration
when the range is lost while the standard HGO's range error grows without bound; the designs certify;
the printed SHGO gains reproduce; the printed Method-2 design fails (4.40) with lambda = 1 and
certifies at its largest feasible lambda (72.36); Table 5.1's ordering on S5a as far as it holds.
On MuJoCo car_following: metrics rows for all seven variants.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable

import numpy as np
import pytest

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers.high_gain_radar import SEED_LEAD
from roadtruth.observers.high_gain_radar_design import (
    PRINTED_SHGO,
    certify_gains,
    gradient_corners,
    lipschitz_kf,
)
from roadtruth.observers.lmi import DesignStatus
from roadtruth.observers.registry import create

SEDAN = load_vehicle("sedan")
NAMES = ("hgo_radar_standard", "hgo_radar_multi", "hgo_radar_standard_printed")
CF_NAMES = (*NAMES, "hgo_radar_method1", "hgo_radar_method2", "hgo_radar_method2_printed", "hgo_radar_extension")
BOX = {"v": (0.0, 45.0), "a": (-10.0, 6.0)}

pytestmark = pytest.mark.usefixtures("isolated_design_cache")


def seed_truth(t_end: float, h: float = 0.01, sub: int = 20,
               x0: tuple[float, float, float] = (30.0, 0.5, 1.0), force_N: Callable[[float], float] | None = None,
               ego_mps: float = 18.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulate M7d (RK4, ``sub`` substeps per ``h``): lead of (1.35) with the thesis's parameters, ego at
    ``v_E = ego_mps + sin t``; ``force_N(t)`` is the lead's driving force u of (1.35) (``u/(m tau)``
    in a_L'; unknown to the observers, whose model (5.1) has no input). Returns t (n,) [s], truth
    (n, 3) (range, range rate, a_L), inputs (n, 4)."""
    m, tau, kd, dm = SEED_LEAD["mass_kg"], SEED_LEAD["tau_s"], SEED_LEAD["kd_Ns2pm2"], SEED_LEAD["dm_N"]

    def rhs(t: float, x: np.ndarray) -> np.ndarray:
        v, a = x[1] + ego_mps + math.sin(t), x[2]
        f = -(2 * kd / m) * v * a - (a + kd / m * v * v + dm / m) / tau
        if force_N is not None:
            f += force_N(t) / (m * tau)
        return np.array([x[1], a - math.cos(t), f])

    n = int(round(t_end / h)) + 1
    t = np.arange(n) * h
    X = np.zeros((n, 3))
    x = np.array(x0, dtype=float)
    X[0] = x
    dt = h / sub
    for k in range(1, n):
        for j in range(sub):
            s = t[k - 1] + j * dt
            k1 = rhs(s, x)
            k2 = rhs(s + dt / 2, x + dt / 2 * k1)
            k3 = rhs(s + dt / 2, x + dt / 2 * k2)
            k4 = rhs(s + dt, x + dt * k3)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        X[k] = x
    return t, X, np.column_stack([X[:, 0], X[:, 1], ego_mps + np.sin(t), np.cos(t)])


def track(name: str, t: np.ndarray, Y: np.ndarray, x0: dict[str, float]) -> np.ndarray:
    """Internal states (n, 3) of ``name`` started from ``x0``."""
    obs = create(name, SEDAN)
    obs.reset(float(t[0]), x0)
    out = []
    for i in range(len(t)):
        obs.step(float(t[i]), Y[i])
        out.append(obs.internal_state())
    return np.array(out)


X0_WRONG = {"range_m": 31.0, "range_rate_mps": 0.0, "lead_accel_mps2": 0.0}


@pytest.fixture(scope="module")
def truth_4s() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return seed_truth(4.0)


@pytest.mark.parametrize("name", NAMES)
def test_designs_certify_and_are_rechecked_independently(name: str) -> None:
    obs = create(name, SEDAN)
    d = obs.design()
    assert d.status is DesignStatus.CERTIFIED and d.certified, d.reason
    P, K, N = np.array(d.P), d.gain("K"), d.gain("N")
    Y, Z = d.gain("Y").reshape(1, 3), d.gain("Z").reshape(1, 3)
    np.testing.assert_allclose(K, np.linalg.solve(P, Y.T).reshape(3), rtol=1e-9)
    np.testing.assert_allclose(N, np.linalg.solve(P, Z.T).reshape(3), rtol=1e-9, atol=1e-12)
    A = np.diag([1.0, 1.0], k=1)
    C = np.array([[1.0, 0.0, 0.0]])
    e2 = np.array([[0.0, 1.0, 0.0]])
    lam, sigma = d.margins["lambda"], d.margins["sigma"]
    xis = (0.0, sigma ** -2) if name == "hgo_radar_multi" else (0.0,)
    for xi2 in xis:  # LMI (4.57) / (4.20), without the noise block (a Schur complement of it)
        M = P @ A - C.T @ Y - xi2 * Z.T @ e2
        assert np.linalg.eigvalsh(M + M.T + lam * np.eye(3)).max() < 0.0
    kf = lipschitz_kf(gradient_corners(SEED_LEAD, BOX["v"], BOX["a"]))
    assert kf == pytest.approx(d.margins["k_f"]) and 2.0 < kf < 2.1  # ~1/tau (digest M7)
    theta0 = 2 * kf * np.linalg.eigvalsh(P).max() / lam
    assert d.margins["theta"] > theta0 and d.margins["kappa_per_s"] > 0
    # the running gains are T(theta) K and T(theta) N / theta^3 (corrected Thm 4.3.4, digest sec. 6)
    L, Mz = obs.gains()
    th = d.margins["theta"]
    np.testing.assert_allclose(L, [th * K[0], th ** 2 * K[1], th ** 3 * K[2]], rtol=1e-12)
    if name == "hgo_radar_multi":
        np.testing.assert_allclose(Mz, [N[0] / th ** 2, N[1] / th, N[2]], rtol=1e-12)
        assert Mz[1] > 0 and Mz[2] > 0  # the range-rate channel is really used (Remark 4.3.1)
    else:
        assert not np.any(Mz)


def test_printed_shgo_gain_reproduces() -> None:
    P, Y = np.array(PRINTED_SHGO["P"]), np.array(PRINTED_SHGO["Y"])
    np.testing.assert_allclose(np.linalg.solve(P, Y), PRINTED_SHGO["K"], rtol=2e-4)
    d = create("hgo_radar_standard_printed", SEDAN).design()
    assert d.margins["theta0"] == pytest.approx(35.6, abs=0.1)  # digest: 35.28 with k_f = 1.9964
    assert d.margins["theta0"] < PRINTED_SHGO["theta"]


def test_printed_method2_fails_theta_condition_with_lambda_one() -> None:
    """sec. 5.2.2(b): theta = 30.37 cannot satisfy (4.40) at lambda = 1 (theta_0 ~ 1500, digest sec. 6)."""
    P = np.array([[294.6169, -85.2035, -111.2819], [-85.2035, 105.2495, -49.4222],
                  [-111.2819, -49.4222, 211.9653]])
    Y = np.array([[104.6494, 350.2155, -29.3206]])
    Z = np.array([[2.9269, 1.6601, 2.0146]])
    corners = gradient_corners(SEED_LEAD, BOX["v"], BOX["a"])
    kf = lipschitz_kf(corners)
    bad = certify_gains("method2_printed", P, Y, Z, np.array([[1e9]]), 1.0, 1.0, kf, corners, 30.3704, {})
    assert bad.status is DesignStatus.REJECTED and "theta_0" in bad.reason
    assert bad.margins["theta0"] > 1400
    # the LMI itself holds (digest: up to lambda ~ 72): only the theta condition fails
    assert bad.margins["thm_lmi_max_eig_vertices"] < 0


@pytest.mark.parametrize("name", ["hgo_radar_standard", "hgo_radar_multi"])
def test_certified_decay_rate_on_seed_model(name: str, truth_4s: tuple) -> None:
    t, X, Y = truth_4s
    d = create(name, SEDAN).design()
    th, P = d.margins["theta"], np.array(d.P)
    eps = (X - track(name, t, Y, X0_WRONG)) / np.array([th, th ** 2, th ** 3])
    V = np.einsum("ij,jk,ik->i", eps, P, eps)
    kappa, kappa_v = d.margins["kappa_per_s"], d.margins["kappa_vertex_per_s"]
    assert kappa_v > kappa > 0
    early = t <= 2.0   # before the discretisation floor (V ~ 1e-13)
    assert np.all(V[early] <= V[0] * np.exp(-kappa * t[early]))
    fast = t <= 0.6
    assert np.all(V[fast] <= V[0] * np.exp(-kappa_v * t[fast]))
    # the peaking bound (4.59) with w = 0
    e = X - track(name, t, Y, X0_WRONG)
    bound = th ** 2 * np.sqrt(np.linalg.cond(P)) * np.linalg.norm(e[0]) * np.exp(-kappa * t / 2)
    assert np.all(np.linalg.norm(e, axis=1)[early] <= bound[early])
    late = t >= 1.0
    assert np.abs(e[late, :2]).max() < 1e-4 and np.abs(e[late, 2]).max() < 2e-3


def test_range_dropout_multi_keeps_rate_and_accel_standard_drifts() -> None:
    """Range lost from the start (Fig 5.9's situation): only the range rate channel remains."""
    t, X, Y = seed_truth(10.0)
    Y = Y.copy()
    Y[:, 0] = np.nan
    e_std = X - track("hgo_radar_standard", t, Y, X0_WRONG)
    e_mul = X - track("hgo_radar_multi", t, Y, X0_WRONG)
    i5, i10 = int(np.searchsorted(t, 5.0)), len(t) - 1
    # SHGO: open loop; the range-rate error stays (integrator chain), the range error grows linearly
    assert abs(e_std[i10, 1]) > 0.5
    assert abs(e_std[i10, 0]) > 5.0 and abs(e_std[i10, 0]) - abs(e_std[i5, 0]) > 3.0
    # generalized HGO: range rate and lead acceleration converge, the range error freezes
    assert abs(e_mul[i10, 1]) < 1e-3 and abs(e_mul[i10, 2]) < 1e-3
    assert abs(e_mul[i10, 0] - e_mul[i5, 0]) < 0.01 and abs(e_mul[i10, 0]) < 1.0


@pytest.mark.parametrize("name", NAMES)
def test_radar_inputs_conformance(name: str) -> None:
    """The conformance suite has no radar columns; the same checks with them."""
    rng = np.random.default_rng(3)
    t, X, Y = seed_truth(3.0, sub=2)
    Y = Y + rng.normal(0, 1e-3, Y.shape)
    Y[np.arange(len(t)) % 5 != 0, :2] = np.nan   # radar at 20 Hz
    Y[:30] = np.nan
    Y[rng.random(Y.shape) < 0.2] = np.nan
    Y[150:220] = np.nan
    a, b = create(name, SEDAN), create(name, SEDAN)
    ta, tb = a.run(t, Y), b.run(t, Y)
    assert ta.states == ("range_m", "range_rate_mps", "lead_accel_mps2")
    assert ta.x.tobytes() == tb.x.tobytes() and a.run(t, Y).x.tobytes() == ta.x.tobytes()
    assert np.all(np.isfinite(ta.x)) and np.isfinite(a.lead_accel_mps2())
    # before the first range sample: the placeholder initial state, exactly; then the measured range
    first = int(np.flatnonzero(np.isfinite(Y[:, 0]))[0])
    assert first > 0 and ta.x.shape == (len(t), 3) and np.all(ta.x[:first] == 0.0)
    a_e = Y[first, 3] if np.isfinite(Y[first, 3]) else 0.0
    assert ta.x[first, 0] == Y[first, 0] and ta.x[first, 2] == a_e  # a_L starts at the ego's a_E
    allnan = create(name, SEDAN).run(t[:50], np.full((50, 4), np.nan))
    assert allnan.x.shape == (50, 3) and np.all(allnan.x == 0.0)
    full = create(name, SEDAN).run(t, Y, X0_WRONG)  # with x0 it starts from x0 at t0
    assert tuple(full.x[0]) == (31.0, 0.0, 0.0)
    a.reset(float(t[0]))
    for i in range(first + 40):
        np.testing.assert_array_equal(a.step(float(t[i]), Y[i]).x, ta.x[i])


def test_options_are_checked() -> None:
    with pytest.raises(InputError, match="unknown option"):
        create("hgo_radar_multi", SEDAN, no_such_option=1)
    with pytest.raises(InputError):
        create("hgo_radar_multi", SEDAN, theta_factor=0.5)
    with pytest.raises(InputError):
        create("hgo_radar_standard", SEDAN, lead_speed_range_mps=(10.0, 5.0))
    with pytest.raises(InputError):
        create("hgo_radar_standard", SEDAN).reset(0.0, {"no_such_state": 1.0})


def test_truth_lead_acceleration_is_the_exact_slope_of_the_speed_profile() -> None:
    from roadtruth.harness.truth.scenario import load_scenario
    from roadtruth.harness.truth.simulate import simulate

    sc = dataclasses.replace(load_scenario("car_following"), duration_s=6.0)
    f = simulate(sc).frame
    t, a = f["t_s"].to_numpy(), f["lead_accel_mps2"].to_numpy()
    # speed points (0, 20) (1.5, 20) (4, 25) (5.5, 25) (8, 15): slopes 0, 2, 0, -4 m/s^2
    want = np.select([t < 1.5 - 1e-9, t < 4.0 - 1e-9, t < 5.5 - 1e-9], [0.0, 2.0, 0.0], -4.0)
    np.testing.assert_array_equal(a, want)
    v = f["lead_v_mps"].to_numpy()
    inside = (np.abs(t - 1.5) > 0.01) & (np.abs(t - 4.0) > 0.01) & (np.abs(t - 5.5) > 0.01)
    np.testing.assert_allclose(np.gradient(v, t)[inside][1:-1], a[inside][1:-1], atol=1e-6)
    no_lead = simulate(dataclasses.replace(load_scenario("step_steer"), duration_s=0.2)).frame
    assert no_lead["lead_accel_mps2"].isna().all()


@pytest.fixture(scope="module")
def car_following_run(tmp_path_factory: pytest.TempPathFactory) -> tuple:
    """``roadtruth run --scenario car_following --observer <the three> --no-render`` (automotive sensors)."""
    import pandas as pd

    from roadtruth.harness.jobs.pipeline import run_suite

    out = run_suite(scenarios=["car_following"], observers=list(CF_NAMES), out=tmp_path_factory.mktemp("cf") / "r",
                    render=False, progress=False)
    truth = pd.read_csv(out / "car_following" / "truth.csv")
    return pd.read_csv(out / "metrics.csv"), truth


def test_car_following_scores_lead_acceleration(car_following_run: tuple) -> None:
    metrics, truth = car_following_run
    a_true = truth["lead_accel_mps2"].to_numpy()
    assert np.all(np.isfinite(a_true)) and a_true.min() == -4.0 and a_true.max() == 2.0
    rms_a = float(np.sqrt(np.mean(a_true ** 2)))  # error of the constant guess a_L = 0
    for name in CF_NAMES:
        rows = metrics[metrics["observer"] == name].set_index("state")
        assert list(rows.index) == ["range_m", "range_rate_mps", "lead_accel_mps2"]
        assert rows["certified"].all(), rows
        # The verdicts say what happened: the range is usable, the lead acceleration is worse than
        # assuming a_L = 0 ("unusable", with the ratio of the two RMS errors)
        assert rows.loc["range_m", "status"] == "ok", rows["status"]
        acc = rows.loc["lead_accel_mps2"]
        ratio = float(re.match(r"unusable \(RMS error ([\d.]+)×", acc["status"]).group(1))
        assert ratio == pytest.approx(acc["rmse"] / rms_a, rel=0.05, abs=0.05), acc["status"]
        assert np.isfinite(acc["rmse"]) and acc["n_scored"] == rows.loc["range_m", "n_scored"] == 10001
        # scored from the first sample (t = 0): the placeholder 0 held until the first radar sample
        # (50 ms latency) is the range's largest error, ~30 m, and its p95 stays a radar-noise figure
        assert abs(rows.loc["range_m", "max_abs"] - 30.0) < 0.1 and rows.loc["range_m", "p95_abs"] < 0.4
        # with 0.1 m range noise the high gains (theta ~ 40, L3 ~ 1e5 s^-3) swamp a_L: worse than a_L = 0;
        # Method 2's large range-rate gain (M3 ~ 2e4 against L3 ~ 1.2e5) makes it 1.6x, the others > 10x
        assert acc["rmse"] > (1.3 if name == "hgo_radar_method2" else 10) * rms_a, name
    acc = metrics[metrics["state"] == "lead_accel_mps2"].set_index("observer")["rmse"]
    # Table 5.1's ordering on the MuJoCo truth: Method 2 far below the SHGO, Method 1 (theta / alpha) above
    assert acc["hgo_radar_method2"] < acc["hgo_radar_standard"] / 10 < acc["hgo_radar_method1"] / 10
    assert acc["hgo_radar_extension"] > acc["hgo_radar_method1"]   # theta ~ 130 on a 4th-order chain


# ---- Methods 1 and 2 (Thm 4.3.2, 4.3.3), the printed Method 2, the dynamic extension (Thm 4.4.1) ----

NEW = ("hgo_radar_method1", "hgo_radar_method2", "hgo_radar_method2_printed", "hgo_radar_extension")
A3 = np.diag([1.0, 1.0], k=1)
C3 = np.array([[1.0, 0.0, 0.0]])
E23 = np.array([[0.0, 1.0, 0.0]])


@pytest.mark.parametrize("name", NEW)
def test_new_designs_certify(name: str) -> None:
    d = create(name, SEDAN).design()
    assert d.status is DesignStatus.CERTIFIED and d.certified, d.reason
    assert d.margins["kappa_per_s"] > 0 and d.margins["decay_lmi_max_eig_vertices"] <= 0


def test_method1_theta_and_m_bounds() -> None:
    """Thm 4.3.2: LMI (4.26) = (4.20), theta > 2 k_f lambda_max(P) / (alpha lambda) (4.27a), ||M|| <= (4.33)."""
    obs = create("hgo_radar_method1", SEDAN)
    d = obs.design()
    P, K, lam, kf = np.array(d.P), d.gain("K"), d.margins["lambda"], d.margins["k_f"]
    Y = d.gain("Y").reshape(1, 3)
    G = P @ A3 - C3.T @ Y
    assert np.linalg.eigvalsh(G + G.T + lam * np.eye(3)).max() < 0
    pmax, alpha, th = np.linalg.eigvalsh(P).max(), 0.5, d.margins["theta"]
    assert d.margins["alpha"] == alpha
    assert th == pytest.approx(2.0 * 2 * kf * pmax / (alpha * lam), rel=1e-9)   # theta_factor 2 x (4.27a)
    L, M = obs.gains()
    bound = (1 - alpha) * lam / (2 * 1.0 * pmax * th)                             # (4.33), n = 3, k_h = 1
    assert np.linalg.norm(M) == pytest.approx(0.9 * bound, rel=1e-9) and M[0] == M[1] == 0.0 < M[2]
    assert th < d.margins["theta_b"]                                               # (4.27b)
    np.testing.assert_allclose(L, [th * K[0], th ** 2 * K[1], th ** 3 * K[2]], rtol=1e-12)
    kappa = (th * lam - 2 * kf * pmax - 2 * th ** 2 * np.linalg.norm(M) * pmax) / pmax
    assert d.margins["kappa_per_s"] == pytest.approx(kappa, rel=1e-9)
    # the thesis's drawback, measured: the range-rate gain is ~1e-9 of the range gain on a_L
    assert M[2] / L[2] < 1e-8


def test_method2_lmi_439_and_corrected_m() -> None:
    """Thm 4.3.3: (4.39) at Sigma(sigma, w) = sigma w_2 e_2^T, w_2 in {0, 1}; theta_0 < theta <= sigma (4.40);
    M = T(theta) P^-1 Z^T (the printed M = P^-1 Z^T drops T(theta))."""
    obs = create("hgo_radar_method2", SEDAN)
    d = obs.design()
    P, lam, sigma, th = np.array(d.P), d.margins["lambda"], d.margins["sigma"], d.margins["theta"]
    Y, Z = d.gain("Y").reshape(1, 3), d.gain("Z").reshape(1, 3)
    for w2 in (0.0, 1.0):
        G = P @ A3 - C3.T @ Y - sigma * w2 * Z.T @ E23
        assert np.linalg.eigvalsh(G + G.T + lam * np.eye(3)).max() < 0
    theta0 = 2 * d.margins["k_f"] * np.linalg.eigvalsh(P).max() / lam
    assert theta0 < th <= sigma == 40.0
    _, M = obs.gains()
    np.testing.assert_allclose(M, np.array([th, th ** 2, th ** 3]) * np.linalg.solve(P, Z.T).ravel(), rtol=1e-12)
    assert Z[0, 1] >= 1.0 - 1e-6 and M[2] > 1e3   # Remark 4.3.1: the range rate really drives a_L


def test_printed_method2_certifies_with_its_largest_lambda() -> None:
    """sec. 5.2.2(b) prints no lambda. (4.39) holds with the printed P, Y, Z for lambda up to 72.36 (at
    sigma = theta = 30.37); there theta_0 = 21.1 < 30.37 and the design certifies, decay LMI included.
    With lambda = 1 (the CARLA reading, sec. 5.2.3) theta_0 ~ 1500 and it is rejected."""
    d = create("hgo_radar_method2_printed", SEDAN).design()
    assert d.certified, d.reason
    assert d.margins["lambda_max_feasible"] == pytest.approx(72.36, abs=0.01)
    assert d.margins["theta0"] == pytest.approx(21.12, abs=0.01) and d.margins["theta"] == 30.3704  # k_f 2.02
    np.testing.assert_allclose(d.gain("K"), [4.7563, 9.3042, 4.5281], atol=2e-4)   # printed K reproduces
    # the printed ||M|| = 1.5338 is neither reading of M: corrected T(theta) P^-1 Z^T or printed P^-1 Z^T
    assert d.margins["m_norm"] == pytest.approx(1817.2, abs=0.5)
    assert d.margins["m_norm_as_printed_formula"] == pytest.approx(0.1321, abs=1e-4)
    lam1 = create("hgo_radar_method2_printed", SEDAN, m2_lambda=1.0, use_cache=False).design()
    assert lam1.status is DesignStatus.REJECTED and lam1.margins["theta0"] == pytest.approx(1528, abs=1)


@pytest.mark.parametrize("name", ["hgo_radar_method1", "hgo_radar_method2", "hgo_radar_method2_printed"])
def test_methods_decay_at_certified_rate_on_seed_model(name: str, truth_4s: tuple) -> None:
    t, X, Y = truth_4s
    d = create(name, SEDAN).design()
    th, P = d.margins["theta"], np.array(d.P)
    e = X - track(name, t, Y, X0_WRONG)
    eps = e / np.array([th, th ** 2, th ** 3])
    V = np.einsum("ij,jk,ik->i", eps, P, eps)
    kappa = d.margins["kappa_per_s"]
    early = t <= 1.5   # before the discretisation floor
    assert np.all(V[early] <= V[0] * np.exp(-kappa * t[early]))
    assert np.all(V[t <= 0.4] <= V[0] * np.exp(-d.margins["kappa_vertex_per_s"] * t[t <= 0.4]))
    late = t >= 1.0
    assert np.abs(e[late, :2]).max() < 1e-4 and np.abs(e[late, 2]).max() < 2e-3


def extension_track(t: np.ndarray, Y: np.ndarray, x0: dict[str, float], **opts: float) -> tuple[np.ndarray, np.ndarray]:
    obs = create("hgo_radar_extension", SEDAN, **opts)
    obs.reset(float(t[0]), x0)
    xs, nus = [], []
    for i in range(len(t)):
        obs.step(float(t[i]), Y[i])
        xs.append(obs.internal_state())
        nus.append(obs.integrator_error())
    return np.array(xs), np.array(nus)


def test_extension_design_is_thm_441() -> None:
    obs = create("hgo_radar_extension", SEDAN)
    d = obs.design()
    P, K, lam, kf = np.array(d.P), d.gain("K"), d.margins["lambda"], d.margins["k_f"]
    alpha, varpi, th, beta = d.margins["alpha"], d.margins["varpi"], d.margins["theta"], d.margins["beta"]
    Axi = np.zeros((4, 4))
    Axi[0, 1], Axi[1, 2], Axi[2, 3] = alpha, 1.0, 1.0
    Cxi = np.array([[1.0, 0.0, 0.0, 0.0]])
    Zr = (P @ K).reshape(1, 4)                  # K = P^-1 Z^T
    top = Axi.T @ P + P @ Axi - Cxi.T @ Zr - Zr.T @ Cxi + lam * np.eye(4)
    S = d.margins["s_max_eig"]
    lmi = np.block([[top, P @ Cxi.T], [(P @ Cxi.T).T, -S * np.ones((1, 1))]])   # (4.84), I_{n+1}
    assert np.linalg.eigvalsh(lmi).max() < 0
    pmax = np.linalg.eigvalsh(P).max()
    assert th == pytest.approx(2.0 * 2 * pmax * (kf + varpi) / lam, rel=1e-9)   # 2 x (4.96)
    assert beta ** 2 * th ** 3 == pytest.approx(varpi, rel=1e-9)
    assert d.margins["kappa_per_s"] == pytest.approx((th * lam - 2 * pmax * (kf + varpi)) / pmax, rel=1e-9)
    L, a, b = obs.extension_gains()
    np.testing.assert_allclose(L, K * th ** np.arange(1, 5), rtol=1e-12)
    assert a == alpha and b == beta


def test_extension_decays_and_meets_iss_bound_with_bounded_range_noise() -> None:
    """Thm 4.4.1 on the thesis's model with mu_hat(0) = mu(0): without noise V = eps^T P eps decays at
    kappa; with bounded range noise |w| <= wbar the Lyapunov form of (4.87) holds,
    V(t) <= V(0) e^(-kappa t) + alpha^2 S wbar^2 / (theta^3 kappa), and so does (4.87)-(4.88) for x."""
    t, X, Y = seed_truth(3.0, h=0.002, sub=4)
    d = create("hgo_radar_extension", SEDAN).design()
    m = d.margins
    th, P, kappa, alpha = m["theta"], np.array(d.P), m["kappa_per_s"], m["alpha"]
    T = th ** np.arange(1, 5)
    Vs = {}
    for wbar in (0.0, 1e-3):
        w = np.random.default_rng(5).uniform(-wbar, wbar, len(t))
        Yn = Y.copy()
        Yn[:, 0] += w
        xh, nu = extension_track(t, Yn, X0_WRONG)
        xi_err = np.column_stack([nu, X - xh])   # mu - mu_hat with mu the measured integral (4.73)
        eps = xi_err / T
        V = np.einsum("ij,jk,ik->i", eps, P, eps)
        Vs[wbar] = V
        bound = V[0] * np.exp(-kappa * t) + alpha ** 2 * m["s_max_eig"] * wbar ** 2 / (th ** 3 * kappa)
        early = t <= 1.5 if wbar == 0.0 else t >= 0.0
        assert np.all(V[early] <= bound[early]), wbar
        nx = np.linalg.norm(X - xh, axis=1)
        assert np.all(nx <= m["iss_c0"] * np.linalg.norm(xi_err[0]) * np.exp(-kappa * t / 2) + m["iss_cw"] * wbar)
    assert np.abs(X - extension_track(t, Y, X0_WRONG)[0])[t >= 1.0].max() < 5e-3
    assert Vs[1e-3][-1] > 10 * Vs[0.0][-1]   # the noise is really fed in


def test_drag_coupling_of_the_lead_model_is_exact() -> None:
    """Started on the truth of (1.35) with a fast, hard-accelerating lead (v_L ~ 40 m/s, a_L(0) = 6 m/s^2,
    where the coupling -(2 K_d/m) v_L a_L is ~0.08 m/s^3) and fed exact data, each observer stays on the
    truth: a sign error in that term moves a_L by ~1e-2 m/s^2."""
    t, X, Y = seed_truth(1.5, h=0.001, sub=4, x0=(30.0, 2.0, 6.0), ego_mps=38.0)
    x0 = dict(zip(("range_m", "range_rate_mps", "lead_accel_mps2"), X[0], strict=True))
    for name in (*NAMES, *NEW):
        # floor: f held over the 1 ms step while a_L decays at 12 m/s^3 (0.6e-3 / 1.5e-3 for the 4th-order
        # extension); the flipped coupling gives 4.5e-3 .. 7.6e-3
        if name == "hgo_radar_extension":
            xh, tol = extension_track(t, Y, x0)[0], 2.5e-3
        else:
            xh, tol = track(name, t, Y, x0), 1.2e-3
        err = np.abs(xh - X).max(axis=0)
        assert err[2] < tol and err[1] < 6e-5, (name, err)


def s5a_force_N(t: float) -> float:
    """The lead's driving force for the S5a reproduction [N]: (3.30)'s profile in kN (see the test below)."""
    u = (0.1 * t if t < 10 else 1.0 if t < 20 else 5 / 3 - t / 30 if t < 30 else t / 40 if t < 40
         else 1.0 if t < 50 else 11 / 6 - t / 60)
    return 1000.0 * u


S5A_ORDER = ("hgo_radar_standard", "hgo_radar_method1", "hgo_radar_method2")


def s5a_errors(sigma_y: float) -> dict[str, tuple[float, float]]:
    """Mean |a_L error| [m/s^2] (whole 30 s run, and t >= 5 s) per observer on the S5a reproduction."""
    t, X, Y = seed_truth(30.0, h=0.002, sub=1, x0=(30.0, 2.0, 0.0), force_N=s5a_force_N)
    Y = Y.copy()
    Y[:, 0] += np.random.default_rng(0).normal(0.0, sigma_y, len(t))
    out = {}
    for name in S5A_ORDER:
        e = np.abs(track(name, t, Y, X0_WRONG)[:, 2] - X[:, 2])
        out[name] = (float(e.mean()), float(e[t >= 5.0].mean()))
    return out


def test_table_51_ordering_on_s5a() -> None:
    """Table 5.1 (mean |a_L error|): SHGO 0.4642 > Method 1 0.2961 > Method 2 0.0185. S5a as far as
    specified (sec. 5.2.2 lead parameters, y = range, z = range rate), with these choices: the lead
    driven by (3.30) in kN (unknown to the observers), ego 18 + sin t m/s, 500 Hz, 30 s, x_hat(0) off
    by (1 m, 2 m/s, 0), N(0, 6.2e-4 m) range noise (the printed equal position errors, 4.975e-4 =
    sigma sqrt(2/pi)), exact range rate. Method 2 < SHGO holds everywhere; SHGO > Method 1 holds
    only without noise after the transient: Method 1's M is bounded to ~1e-3 by (4.33), so it is a
    SHGO with theta / alpha, which amplifies noise and peaking by (1/alpha)^2 on a_L."""
    noisy, clean = s5a_errors(6.2e-4), s5a_errors(0.0)
    shgo, m1, m2 = (noisy[n][0] for n in S5A_ORDER)
    assert m2 < shgo / 5                              # Method 2 >> SHGO (printed ratio 25)
    assert m1 > 1.5 * shgo                            # reversed: Method 1 is worse with noise
    assert clean["hgo_radar_method1"][1] < 0.7 * clean["hgo_radar_standard"][1]   # ordering, no noise, t >= 5
    assert clean["hgo_radar_method2"][1] < clean["hgo_radar_standard"][1]


def test_multi_output_iss_bound_with_bounded_range_noise() -> None:
    """Thm 4.3.4 (4.57)-(4.60): with |w| <= wbar on the range, V = eps^T P eps obeys
    V(t) <= V(0) e^(-kappa t) + X wbar^2 / (theta kappa) (Young's step of the proof), and the noise is
    really felt: the late V sits well above the noise-free one."""
    t, X, Y = seed_truth(3.0, h=0.002, sub=4)
    d = create("hgo_radar_multi", SEDAN).design()
    th, P, kappa, Xn = d.margins["theta"], np.array(d.P), d.margins["kappa_per_s"], d.margins["x_max_eig"]
    late = {}
    for wbar in (0.0, 1e-3):
        Yn = Y.copy()
        Yn[:, 0] += np.random.default_rng(7).uniform(-wbar, wbar, len(t))
        eps = (X - track("hgo_radar_multi", t, Yn, X0_WRONG)) / np.array([th, th ** 2, th ** 3])
        V = np.einsum("ij,jk,ik->i", eps, P, eps)
        bound = V[0] * np.exp(-kappa * t) + Xn * wbar ** 2 / (th * kappa)
        keep = t <= 1.5 if wbar == 0.0 else t >= 0.0
        assert np.all(V[keep] <= bound[keep]), wbar
        late[wbar] = V[t >= 2.0].max()
    assert late[1e-3] > 100 * late[0.0]


def test_range_dropout_method2_keeps_rate_and_accel_method1_drifts() -> None:
    """Range lost from the start (Fig 5.9): Method 2's range-rate gain keeps range rate and a_L (the
    range freezes at its initial error); Method 1's M, bounded by (4.33) to ~6e-4, cannot: it drifts
    like the SHGO. The dynamic extension sees the range rate only through beta^2 = 4.5e-7 in mu':
    its range-rate error shrinks, slowly."""
    t, X, Y = seed_truth(10.0)
    Y = Y.copy()
    Y[:, 0] = np.nan
    i5, i10 = int(np.searchsorted(t, 5.0)), len(t) - 1
    for name in ("hgo_radar_method2", "hgo_radar_method2_printed"):
        e = X - track(name, t, Y, X0_WRONG)
        assert np.abs(e[i5:, 1]).max() < 1e-4 and np.abs(e[i5:, 2]).max() < 1e-4, name
        assert abs(e[i10, 0] - e[i5, 0]) < 1e-3 and abs(e[i10, 0] + 1.0) < 2e-3   # x_hat(0) range off by 1 m
    e1 = X - track("hgo_radar_method1", t, Y, X0_WRONG)
    assert abs(e1[i10, 1]) > 0.5 and abs(e1[i10, 0]) - abs(e1[i5, 0]) > 3.0
    ex = X - extension_track(t, Y, X0_WRONG)[0]
    assert 0.1 < abs(ex[i5, 1]) < 0.5 and abs(ex[i10, 1]) < 0.4 * abs(ex[i5, 1])
