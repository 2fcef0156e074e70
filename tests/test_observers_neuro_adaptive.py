"""Neuro-adaptive observers of Bessafa (2024, ch. 3) on their own design model (3.27) with input (3.30).

The truth is the design model simulated here (RK4, 1 ms, the input's breakpoints on the grid); the
observers get the position only and the known input u, and start from x_hat = (0, 18, 0.5, 0)
against x(0) = (0, 20, 0) (the thesis gives no initial conditions).

The four observers run one compiled kernel shared by step(), run() and run_model(): stepping one
sample at a time equals run() bit for bit (estimates, weights, history stack, latch) through radar
dropouts and outages, a repeated and an irregular time stamp, from x0 and on MuJoCo car following,
and read-only logs do not compile a second copy of the kernel.
"""

from __future__ import annotations

import numpy as np
import pytest

from roadtruth.observers import neuro_adaptive as na
from roadtruth.observers import neuro_adaptive_design as nad
from roadtruth.observers.lmi import DesignStatus, SolverSettings, solve_lmi

DT = 1e-3
X0 = (0.0, 20.0, 0.0)
Z0 = np.array([0.0, 18.0, 0.5, 0.0])
#: Windows 5-10 s after each change of (3.30): where "steady state" is read.
WINDOWS = ((5.0, 10.0), (15.0, 20.0), (25.0, 30.0), (35.0, 40.0), (45.0, 50.0), (55.0, 60.0))


@pytest.fixture(scope="module")
def s3a() -> dict[str, np.ndarray]:
    t = np.round(np.arange(0.0, 60.0 + DT / 2, DT), 9)
    x, f = nad.simulate_m7c(t, X0, nad.s3a_input, substeps=1)
    u = np.array([nad.s3a_input(float(tt)) for tt in t])
    return {"t": t, "x": x, "f": f, "u": u}


def _run(cls: type, s3a: dict[str, np.ndarray], **opts: object) -> na.LearningTrack:
    return cls(None, **opts).run_model(s3a["t"], s3a["x"][:, 0], s3a["u"], Z0)


def _steady(tr: na.LearningTrack, s3a: dict[str, np.ndarray]) -> np.ndarray:
    """Largest |error| of (p, v, a, x_4) over the steady windows."""
    err = np.abs(np.column_stack([tr.z[:, :3] - s3a["x"], tr.z[:, 3] - s3a["f"]]))
    t = s3a["t"]
    return np.max([err[(t >= a) & (t <= b)].max(axis=0) for a, b in WINDOWS], axis=0)


def test_design_model_is_the_printed_one() -> None:
    # f of (3.27) at v = 20 m/s, a = 0: -(1/tau)(K_d v^2 / m + d_m / m) = -2 (120 + 100) / 1850
    assert nad.m7c_f(20.0, 0.0) == pytest.approx(-2.0 * 220.0 / 1850.0, rel=1e-12)
    assert nad.m7c_f(20.0, 1.0) == pytest.approx(-2 * 0.3 / 1850 * 20 - 2.0 * (1 + 120 / 1850 + 100 / 1850))
    assert [nad.s3a_input(t) for t in (5.0, 15.0, 25.0, 30.0, 45.0, 54.0)] == pytest.approx(
        [0.5, 1.0, 5 / 3 - 25 / 30, 0.75, 1.0, 11 / 6 - 0.9])


def test_lmi_3_12_infeasible_as_printed() -> None:
    """lambda = 1e5 with P <= diag(1e-2, ..., 1e-5): infeasible (the (4,4) entry is 2 P_34 + lambda)."""
    import cvxpy as cp

    def build() -> tuple:
        P, Y = cp.Variable((4, 4), symmetric=True), cp.Variable((1, 4))
        M = P @ nad.A_EXT - nad.C_EXT.T @ Y
        cons = [P >> 0, P << nad.D_PRINTED, M + M.T + nad.LAMBDA_PRINTED * np.eye(4) << 0]
        return cp.Problem(cp.Minimize(0), cons), {"P": P}
    assert solve_lmi(build, SolverSettings()).status == "infeasible"


def test_certification_of_both_variants() -> None:
    d = nad.design("lmi", 1e-3, SolverSettings())
    assert d.status is DesignStatus.CERTIFIED and d.certified
    lam = d.margins["lambda_max_certifiable"]
    # largest certifiable lambda under P <= D: 1.75e-5, below the bound 2 sqrt(D_33 D_44) for any gains
    assert 1.74e-5 < lam < 1.76e-5 < 2 * np.sqrt(1e-9)
    assert -4.6 < d.margins["slowest_pole_radps"] < -3.0 and d.margins["fastest_pole_radps"] < -800
    p = nad.design("printed", 1e-3, SolverSettings())
    assert p.status is DesignStatus.REJECTED and not p.certified
    assert 1.9e-7 < p.margins["lambda_max_certifiable"] < 2.1e-7 and p.margins["lambda_claimed"] == 1e5
    assert p.margins["fastest_pole_radps"] == pytest.approx(-36386.17, abs=0.1)
    assert p.gain("K")[0] == 3.169e7


def test_exact_discretisation_matches_fine_rk4() -> None:
    g = nad.L_PRINTED
    A = nad.A_EXT - g.reshape(4, 1) @ nad.C_EXT
    h = 1e-3
    Phi, G0, G1 = na.exact_discretisation(A, h)
    z0, r0, r1 = np.array([0.3, -1.0, 2.0, 0.5]), np.array([1.0, 2.0, -3.0, 4.0]), np.array([-2.0, 1.0, 0.5, 3.0])
    z, m = z0.copy(), 20000  # RK4 at 5e-8 s: 0.0018 * |pole|, well inside its stability region
    hs = h / m
    fn = lambda s, z: A @ z + r0 + r1 * s  # noqa: E731
    for k in range(m):
        s = k * hs
        k1 = fn(s, z)
        k2 = fn(s + hs / 2, z + hs / 2 * k1)
        k3 = fn(s + hs / 2, z + hs / 2 * k2)
        k4 = fn(s + hs, z + hs * k3)
        z = z + hs / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose(Phi @ z0 + G0 @ r0 + G1 @ r1, z, rtol=1e-9, atol=1e-12)


def test_unknown_term_converges_on_s3a(s3a: dict[str, np.ndarray]) -> None:
    """The LMI design: x_4 -> f(x); position and speed to the thesis's 1e-6, a and x_4 not."""
    tr = _run(na.NeuroAdaptiveCL, s3a)
    e = _steady(tr, s3a)
    assert abs(tr.z[0, 3] - s3a["f"][0]) > 0.2                 # starts far (f(x(0)) = -0.238)
    assert e[0] < 2e-8 and e[1] < 2e-6                          # p (the 1 ms first-order hold), v
    assert 5e-7 < e[2] < 2e-5 and 1e-6 < e[3] < 1e-4            # a, x_4: above the thesis's 1e-6
    # the floor is the disturbance dx_4/dt through the chain: e_4 ~ (l_3 / K) |df/dt|, |df/dt| <= 1.6e-4
    err4 = np.abs(tr.z[:, 3] - s3a["f"])
    t = s3a["t"]
    conv = t[np.nonzero(err4[t <= 10] > 1e-2)[0][-1] + 1]
    assert 2.0 < conv < 3.5                                     # the thesis's "< 0.1 s" does not hold


def test_printed_gains_converge_too(s3a: dict[str, np.ndarray]) -> None:
    e = _steady(_run(na.NeuroAdaptiveCLPrinted, s3a), s3a)
    assert e[0] < 2e-9 and e[1] < 1e-6 and e[2] < 1.5e-5 and e[3] < 1e-4


def test_history_stack_min_singular_value_never_decreases(s3a: dict[str, np.ndarray]) -> None:
    tr = _run(na.NeuroAdaptiveCL, s3a)
    assert np.all(np.diff(tr.smin) >= 0.0)
    assert tr.smin[0] == 0.0 and tr.smin[-1] > 0.3
    # the network learned something: its weights moved and it approximates f to ~0.05 m/s^3
    t = s3a["t"]
    assert np.abs(tr.W[-1]).max() > 1.0
    assert np.abs(tr.f_nn - s3a["f"])[t > 15].max() < 0.06


def test_baselines_on_s3a(s3a: dict[str, np.ndarray]) -> None:
    """Finding: at poles of -10 rad/s the Chakrabarty et al. observer does NOT fail on a or f; its
    'network' is an output-error integrator (weights ~ 0, no model). The CL-AEO tracks x_4 but its
    known-regressor weights are far from the true (3.27) parameters (the stack is poorly excited)."""
    ch = _run(na.NeuroAdaptiveChakrabarty, s3a)
    e = _steady(ch, s3a)
    assert e[2] < 1e-5 and e[3] < 1e-4
    assert np.abs(ch.W[-1]).max() < 1e-3
    cl = _run(na.CLAEORanXie, s3a, eps=0.05, eta1=100.0, eta2=100.0)
    e = _steady(cl, s3a)
    assert e[2] < 5e-6 and e[3] < 5e-5
    w_true = np.array([-2 * 0.3 / 1850, -2.0, -0.3 / (1850 * 0.5), -100 / (1850 * 0.5)])
    assert np.abs(cl.W[-1] - w_true).max() > 1.0
    assert np.all(np.diff(cl.smin) >= 0.0)


@pytest.fixture(scope="module")
def car_following(tmp_path_factory: pytest.TempPathFactory) -> object:
    import pandas as pd

    from roadtruth.harness.jobs.pipeline import run_suite

    out = run_suite(scenarios=["car_following"], observers=list(NAMES), out=tmp_path_factory.mktemp("na") / "r",
                    render=False, progress=False)
    return pd.read_csv(out / "metrics.csv")


NAMES = ("neuro_adaptive_cl", "neuro_adaptive_cl_printed", "cl_aeo_ran_xie", "neuro_adaptive_chakrabarty")


def test_runs_on_mujoco_car_following(car_following: object) -> None:
    m = car_following
    for name in NAMES:
        rows = m[m["observer"] == name].set_index("state")
        assert list(rows.index) == ["range_m", "range_rate_mps", "lead_accel_mps2"], name
        assert rows["status"].notna().all()
        assert bool(rows["certified"].all()) is (name == "neuro_adaptive_cl")


# ---- step() and run() share one compiled kernel ---------------------------------------------------

def _radar_log() -> tuple[np.ndarray, np.ndarray]:
    """20 s at 100 Hz of (range_m, vx_mps, ax_mps2): a lead 30 m ahead that speeds up and brakes,
    radar at 20 Hz with 10 % of its samples lost, ego speed/acceleration with 5 % dropouts, nothing
    in the first 50 ms, a 0.6 s radar outage (longer than hold_s: the open chain predicts), a
    repeated and an irregular time stamp and one 30 ms step."""
    n, h = 2000, 0.01
    t = np.arange(n) * h
    v_e = 20.0 + 2.0 * np.sin(2 * np.pi * t / 15.0)
    a_l = 1.5 * np.sin(2 * np.pi * t / 6.0) * (t > 2.0)
    v_l = 20.0 + np.cumsum(a_l) * h
    rng_m = 30.0 + np.concatenate([[0.0], np.cumsum((v_l - v_e)[:-1]) * h])
    gen = np.random.default_rng(4)
    Y = np.column_stack([rng_m + gen.normal(0.0, 0.05, n), v_e + gen.normal(0.0, 0.02, n),
                         np.gradient(v_e, h) + gen.normal(0.0, 0.05, n)])
    Y[np.arange(n) % 5 != 0, 0] = np.nan
    Y[gen.random(n) < 0.10, 0] = np.nan
    ego = Y[:, 1:]
    ego[gen.random(ego.shape) < 0.05] = np.nan
    Y[:5] = np.nan
    Y[900:960, 0] = np.nan
    t[1200] = t[1199]
    t[1400:] += 0.0037
    t[1600:] += 0.02
    return t, Y


@pytest.fixture(scope="module")
def car_following_log() -> tuple[np.ndarray, np.ndarray]:
    """``(t, Y)`` of the MuJoCo car-following scenario through its sensors (radar on a lead car)."""
    import roadtruth as rt

    sc = rt.load_scenario("car_following")
    truth = rt.simulate(sc, seed=0)
    meas = rt.emulate(truth.frame, rt.load_vehicle(sc.vehicle), rt.load_sensor_config(sc.sensors,
                      sc.sensor_overrides), seed=0).frame
    return meas["t_s"].to_numpy(dtype=float), meas[list(na.NeuroAdaptiveCL.inputs)].to_numpy(dtype=float)


_KERNEL_STATE = ("_kz", "_kW", "_kZ", "_kLam", "_klast", "_ktl", "_kslope", "_kst")


def _step_equals_run(name: str, t: np.ndarray, Y: np.ndarray, x0: dict[str, float] | None = None) -> np.ndarray:
    from roadtruth.observers.registry import create

    obs = create(name, None)
    track = obs.run(t, Y, x0)
    ref = create(name, None)
    ref.reset(float(t[0]), x0)
    want = np.array([ref.step(float(t[i]), Y[i]).x for i in range(len(t))])
    np.testing.assert_array_equal(track.x, want)
    for key in _KERNEL_STATE:   # weights, history stack, latch: everything the next step reads
        np.testing.assert_array_equal(getattr(obs, key), getattr(ref, key), err_msg=key)
    # the run learned: weights moved, (CL variants) the history stack filled
    assert np.all(np.isfinite(want)) and np.abs(ref._kW - ref._W0).max() > 1e-6
    if name != "neuro_adaptive_chakrabarty":
        assert ref._kst[3] == ref._p and obs.last_learning.smin[-1] > 0.0
    # run() left the stepped state: the next step agrees
    t_next, y_next = float(t[-1]) + 0.05, np.nan_to_num(Y[-1], nan=20.0) * 1.001
    np.testing.assert_array_equal(obs.step(t_next, y_next).x, ref.step(t_next, y_next).x)
    return want


@pytest.mark.parametrize("name", NAMES)
def test_step_equals_run_through_gaps_and_irregular_stamps(name: str) -> None:
    t, Y = _radar_log()
    x = _step_equals_run(name, t, Y)
    assert np.all(x[:5] == 0.0) and x[5, 0] != 0.0          # starts at the first range sample
    # through the radar outage the estimate is predicted (open chain), not frozen
    assert np.ptp(x[905:960, 0]) > 0.01


@pytest.mark.parametrize("name", NAMES)
def test_step_equals_run_from_initial_state(name: str) -> None:
    t, Y = _radar_log()
    x = _step_equals_run(name, t, Y, {"range_m": 28.0, "range_rate_mps": -0.5})
    assert x[0, 0] == 28.0 and x[0, 1] == -0.5               # started from x0, not from the first sample


@pytest.mark.parametrize("name", NAMES)
def test_step_equals_run_on_mujoco_car_following(name: str, car_following_log) -> None:
    t, Y = car_following_log
    assert np.isnan(Y[:, 0]).any() and np.isfinite(Y[:, 0]).sum() > 50   # radar at its own rate
    _step_equals_run(name, t, Y)


def test_one_kernel_for_the_family() -> None:
    """All four observers, stepping, run() on read-only logs (as pandas hands them out) and run_model
    use one compiled specialisation of the one kernel of neuro_adaptive_loop (each extra one costs
    tens of seconds of numba compilation on a fresh install)."""
    from roadtruth.observers import neuro_adaptive_loop as loop
    from roadtruth.observers.registry import create

    t, Y = _radar_log()
    t, Y = t[:60], Y[:60]
    t.flags.writeable = False
    Y.flags.writeable = False
    for name in NAMES:
        obs = create(name, None)
        obs.run(t, Y)
        obs.step(float(t[-1]) + 0.01, Y[-1])
        obs.run_model(t, Y[:, 0], np.ones(len(t)), Z0)
    sig = loop.learning_run.signatures
    assert len(sig) == 1, sig
