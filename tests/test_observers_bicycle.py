"""Bicycle model forms, the closed-form 2x2 ZOH, and the two model-only baselines."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers.bicycle import alpha_model, ay_output, beta_r_model, expm2_zoh, vy_r_model
from roadtruth.observers.registry import create

SEDAN = load_vehicle("sedan")


def _zoh_reference(A: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    M = np.zeros((4, 4))
    M[:2, :2], M[:2, 2:] = A, np.eye(2)
    X = expm(M * h)
    return X[:2, :2], X[:2, 2:]


@pytest.mark.parametrize("A", [
    [[-3.0, 1.0], [-20.0, -4.0]],          # complex pair
    [[-5.0, 0.0], [0.0, -5.0]],            # repeated
    [[-5.0, 1e-9], [0.0, -5.0 + 1e-9]],    # nearly repeated
    [[-2000.0, 3.0], [1.0, -1.0]],         # stiff
    [[0.0, 1.0], [0.0, 0.0]],              # nilpotent, singular
    [[0.0, 0.0], [0.0, 0.0]],
    [[1e-7, 2e-7], [-1e-7, 3e-8]],         # tiny
    [[0.5, 2.0], [1.0, -0.3]],             # unstable, real
    [[-40.0, -20.0], [-1.0, -35.0]],       # bicycle-like
])
@pytest.mark.parametrize("h", [1e-3, 0.01, 0.1])
def test_expm2_zoh_matches_scipy(A: list[list[float]], h: float) -> None:
    A_ = np.array(A)
    E, G = expm2_zoh(*A_.reshape(-1), h)
    E_ref, G_ref = _zoh_reference(A_, h)
    np.testing.assert_allclose(np.array(E).reshape(2, 2), E_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.array(G).reshape(2, 2), G_ref, rtol=1e-9, atol=1e-12 * h)


def test_model_forms_agree_by_chain_rule() -> None:
    """(3.16) and (3.18) equal the time derivatives of beta = vy/vx and of the linear slip angles."""
    rng = np.random.default_rng(1)
    lf, lr = SEDAN.lf_m, SEDAN.lr_m
    for _ in range(20):
        vx, ax = rng.uniform(5, 40), rng.uniform(-6, 6)
        vy, r, delta, ddelta = rng.normal(0, 0.5), rng.normal(0, 0.3), rng.normal(0, 0.05), rng.normal(0, 0.2)
        A, B = vy_r_model(SEDAN, vx)
        vy_dot, r_dot = A @ [vy, r] + B * delta
        Ab, Bb = beta_r_model(SEDAN, vx, ax)
        np.testing.assert_allclose(Ab @ [vy / vx, r] + Bb * delta, [vy_dot / vx - vy * ax / vx**2, r_dot],
                                   rtol=1e-12, atol=1e-12)
        af = delta - (vy + lf * r) / vx
        ar = -(vy - lr * r) / vx
        daf = ddelta - (vy_dot + lf * r_dot) / vx + (vy + lf * r) * ax / vx**2
        dar = -(vy_dot - lr * r_dot) / vx + (vy - lr * r) * ax / vx**2
        Aa, Ba = alpha_model(SEDAN, vx, ax)
        np.testing.assert_allclose(Aa @ [af, ar] + Ba @ [delta, ddelta, r], [daf, dar], rtol=1e-10, atol=1e-12)


def _truth_piecewise(vx: float, delta: np.ndarray, h: float, x0: np.ndarray) -> np.ndarray:
    A, B = vy_r_model(SEDAN, vx)
    M = np.zeros((3, 3))
    M[:2, :2], M[:2, 2] = A, B
    Ed = expm(M * h)
    X = [x0]
    for k in range(1, len(delta)):  # delta[k] acts over (t_{k-1}, t_k], as the observers hold it
        X.append(Ed[:2, :2] @ X[-1] + Ed[:2, 2] * delta[k])
    return np.array(X)


def test_open_loop_error_is_the_model_transition() -> None:
    h, n, vx = 0.01, 400, 18.0
    t = np.arange(n) * h
    delta = 0.03 * np.sign(np.sin(2 * np.pi * 0.7 * t))
    x0 = np.array([0.4, 0.1])
    truth = _truth_piecewise(vx, delta, h, x0)
    obs = create("open_loop_bicycle", SEDAN)
    tr = obs.run(t, np.column_stack([delta, np.full(n, vx)]))
    err = truth - tr.x[:, :2]
    A, _ = vy_r_model(SEDAN, vx)
    expected = np.array([expm(A * tk) @ x0 for tk in t])
    np.testing.assert_allclose(err, expected, rtol=1e-8, atol=1e-10)


def test_kinematic_error_stays_constant_and_bias_drifts() -> None:
    h, n, vx = 0.01, 1001, 20.0
    t = np.arange(n) * h
    A, B = vy_r_model(SEDAN, vx)

    def steer(tt: float | np.ndarray) -> float | np.ndarray:
        return 0.02 * np.sin(2 * np.pi * 0.3 * tt)

    sol = solve_ivp(lambda tt, x: A @ x + B * steer(tt), (0, t[-1]), [0.3, 0.0], t_eval=t, rtol=1e-11, atol=1e-13)
    truth, delta = sol.y.T, steer(t)
    c, d = ay_output(SEDAN, vx)
    ay = truth @ c + d * delta
    obs = create("kinematic_vy", SEDAN)
    Y = np.column_stack([ay, truth[:, 1], np.full(n, vx)])
    err = truth[:, 0] - obs.run(t, Y).x[:, 0]
    assert np.max(np.abs(err - 0.3)) < 5e-4  # trapezoid rule: O(h^2) drift, no decay, no growth
    bias = 0.05
    err_b = truth[:, 0] - obs.run(t, Y + [bias, 0.0, 0.0]).x[:, 0]
    np.testing.assert_allclose(err - err_b, bias * t, atol=1e-9)


def _ragged_inputs(n: int, k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A 100 Hz log with the awkward parts of real ones: leading NaN, 20 % dropouts, a 1 s outage,
    a repeated, a jittered and a shifted block of time stamps; columns ordered as the observer's inputs."""
    gen = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    vx = 20.0 + 4.0 * np.sin(2 * np.pi * t / 12.0)
    delta = 0.04 * np.sin(2 * np.pi * 0.5 * t)
    r = 0.2 * np.sin(2 * np.pi * 0.5 * t - 0.3)
    ay = vx * r + 0.3 * np.cos(2 * np.pi * 0.5 * t)
    Y = np.column_stack({2: [delta, vx], 3: [ay, r, vx]}[k])
    Y[:3] = np.nan
    Y[gen.random(Y.shape) < 0.2] = np.nan
    Y[600:700] = np.nan
    t = t.copy()
    t[300] = t[299]
    t[400:420] += gen.uniform(-0.004, 0.004, 20)
    t[1000:] += 0.0037
    return t, Y


@pytest.mark.parametrize("name", ["open_loop_bicycle", "kinematic_vy"])
def test_run_is_one_compiled_call_and_equals_stepping_bit_for_bit(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """run() advances the whole log in one call of the compiled kernel that step() calls per sample: the
    same bits through dropouts, an outage, repeated and irregular time stamps and an initial state; the
    observer ends where stepping leaves it (the next step agrees) and run() again from x0 repeats itself."""
    import roadtruth.observers.open_loop_loop as loop

    k = len(create(name, SEDAN).inputs)
    t, Y = _ragged_inputs(1500, k, 4)
    calls: list[int] = []
    kernel = loop.open_loop_run

    def counted(tt: np.ndarray, *args: object) -> None:
        calls.append(len(tt))
        kernel(tt, *args)

    x0 = {"vy_mps": 0.3}
    monkeypatch.setattr(loop, "open_loop_run", counted)
    obs = create(name, SEDAN)
    tr = obs.run(t, Y, x0)
    assert calls == [len(t)]   # one compiled call for the whole log, not a Python loop over step()
    monkeypatch.undo()
    ref = create(name, SEDAN)
    ref.reset(float(t[0]), x0)
    stepped = np.array([ref.step(float(t[i]), Y[i]).x for i in range(len(t))])
    assert tr.x.tobytes() == stepped.tobytes()
    assert tr.x[0, 0] == 0.3 and np.all(np.isfinite(tr.x)) and np.ptp(tr.x[:, 0]) > 0.05
    y_next = np.nan_to_num(Y[1400], nan=0.5)
    assert obs.step(float(t[-1]) + 0.01, y_next).x.tobytes() == ref.step(float(t[-1]) + 0.01, y_next).x.tobytes()
    assert obs.run(t, Y, x0).x.tobytes() == tr.x.tobytes()


@pytest.mark.parametrize("name", ["open_loop_bicycle", "kinematic_vy"])
def test_missing_samples_are_held(name: str) -> None:
    """NaN = no new sample: the baselines hold the latest value of each input (zero-order hold), so a
    log with dropouts gives the bits of the same log with every gap filled by the previous sample; a
    repeated time stamp takes no step."""
    import pandas as pd

    k = len(create(name, SEDAN).inputs)
    t, Y = _ragged_inputs(1500, k, 5)
    filled = pd.DataFrame(Y).ffill().to_numpy()
    a = create(name, SEDAN).run(t, Y).x
    b = create(name, SEDAN).run(t, filled).x
    assert a.tobytes() == b.tobytes()
    assert np.abs(a[:, 0]).max() > 0.05   # the inputs do drive the estimate
    assert np.array_equal(a[300, :1], a[299, :1])   # t[300] == t[299]: v_y unchanged


def test_kinematic_irregular_steps_integrate_the_trapezoid() -> None:
    """On irregular steps the kinematic estimate is the trapezoidal sum of a_y - r v_x over the actual
    time stamps (the step is the time since the last sample, not a nominal rate)."""
    gen = np.random.default_rng(8)
    t = np.cumsum(gen.uniform(0.002, 0.03, 400))
    ay, r, vx = np.sin(t), 0.1 * np.cos(t), 15.0 + t
    f = ay - r * vx
    expected = 0.1 + np.concatenate([[0.0], np.cumsum(0.5 * np.diff(t) * (f[1:] + f[:-1]))])
    est = create("kinematic_vy", SEDAN).run(t, np.column_stack([ay, r, vx]), {"vy_mps": 0.1}).x
    np.testing.assert_allclose(est[:, 0], expected, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(est[:, 1], np.arctan2(expected, vx), rtol=1e-12, atol=1e-14)


def test_bicycle_module_holds_the_model_only() -> None:
    """The model file (whose source keys the shipped LMI designs) defines no observer; the baselines are
    registered, under their names, from their own module."""
    import inspect

    import roadtruth.observers.bicycle as bicycle
    from roadtruth.observers.base import Observer
    from roadtruth.observers.registry import observer_class

    assert not [c for _, c in inspect.getmembers(bicycle, inspect.isclass) if issubclass(c, Observer)]
    for name in ("open_loop_bicycle", "kinematic_vy"):
        assert observer_class(name).__module__ == "roadtruth.observers.open_loop"
