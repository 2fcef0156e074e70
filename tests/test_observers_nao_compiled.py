"""The neural adaptive observers of Nguyen: step() and run() execute one compiled kernel and agree bit for bit.

``step()`` and ``run()`` of ``nao_nguyen``, ``nao_nguyen_stepwise`` and ``nao_nguyen_ensemble`` call
the same numba kernel (network, sensitivity gradient, Adam, the ensemble queue and the teacher UIO)
with one sample or the whole log, on state arrays carried between calls. The observers learn online
(Adam on a gradient through 1282 parameters), so state that is not carried exactly between two
step() calls (a dropped latch, a reset sensitivity, a lost queue snapshot) does not stay small: it
changes the trained network and through it the estimates. The tests assert the estimates, the loss
trace, the trained parameters, the ensemble queue and the teacher's state are *bit-equal* between
stepping and run(), on a MuJoCo fishhook with automotive sensors and on a synthetic run with
dropouts, a full outage, a repeated and an irregular time stamp, from the default and from a given
initial state, and that run() leaves the observer where stepping leaves it (the next step agrees).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers.base import ScalarLoopObserver
from roadtruth.observers.neural_adaptive_nguyen import NeuralAdaptiveNguyen, init_theta
from roadtruth.observers.registry import create

SEDAN = load_vehicle("sedan")
NAMES = ("nao_nguyen", "nao_nguyen_stepwise", "nao_nguyen_ensemble")
INPUTS = NeuralAdaptiveNguyen.inputs


@pytest.fixture(scope="module")
def fishhook() -> tuple[np.ndarray, np.ndarray]:
    """``(t, Y)`` of a 6 s MuJoCo fishhook through the scenario's automotive sensors (seed 6)."""
    from roadtruth.harness.sensors import load_sensor_config
    from roadtruth.harness.sensors.suite import emulate
    from roadtruth.harness.truth.scenario import load_scenario
    from roadtruth.harness.truth.simulate import simulate

    sc = replace(load_scenario("fishhook"), duration_s=6.0)
    truth = simulate(sc)
    meas = emulate(truth.frame, SEDAN, load_sensor_config(sc.sensors, sc.sensor_overrides, None), 6,
                   outages=sc.outages, lane_gaps=sc.lane_gaps).frame
    return meas["t_s"].to_numpy(dtype=float), meas[list(INPUTS)].to_numpy(dtype=float)


def _synthetic() -> tuple[np.ndarray, np.ndarray]:
    """12 s at 100 Hz: speed ramp, two-tone steering, noise, 15 % dropouts per column, a 1 s outage
    of everything, nothing in the first 70 ms, a repeated and an irregular time stamp, one 30 ms step
    (three Euler sub-steps) and a gyro gap longer than the hold time (learning frozen, then resumed)."""
    n, h = 1200, 0.01
    t = np.arange(n) * h
    vx = 14.0 + 4.0 * np.sin(2 * np.pi * t / 8.0)
    delta = 0.05 * np.sin(2 * np.pi * 0.4 * t) + 0.02 * np.sin(2 * np.pi * 1.3 * t)
    r = vx * delta / 2.8
    Y = np.column_stack([vx, r, np.gradient(vx, h), delta])
    gen = np.random.default_rng(11)
    Y = Y + gen.normal(0.0, 1e-3, Y.shape) * np.abs(Y).clip(1e-2, None)
    Y[:7] = np.nan
    Y[gen.random(Y.shape) < 0.15] = np.nan
    Y[600:700] = np.nan
    Y[820:850, 1] = np.nan
    t[900] = t[899]
    t[1000:] += 0.0037
    t[1100:] += 0.02
    return t, Y


def _stepped(obs: ScalarLoopObserver, t: np.ndarray, Y: np.ndarray,
             x0: dict[str, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Estimates (n, 3) and the unknown input mu_theta (n, 2) [N] from stepping one sample at a time."""
    obs.reset(float(t[0]), x0)
    xs, mus = [], []
    for i in range(len(t)):
        xs.append(obs.step(float(t[i]), Y[i]).x)
        mus.append(obs.unknown_input_N())
    return np.array(xs), np.array(mus)


def _assert_same_state(a: NeuralAdaptiveNguyen, b: NeuralAdaptiveNguyen) -> None:
    """Everything the next step reads is equal: network, learning state, queue, teacher, latch."""
    for key in ("_x", "_theta", "_S", "_g", "_m", "_v", "_mu", "_kstate", "_klatch", "_ku", "_kfresh", "_ktl"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)
    np.testing.assert_array_equal(a.loss_trace, b.loss_trace)
    qa, qb = a.ensemble_queue(), b.ensemble_queue()
    assert len(qa) == len(qb)
    for x, y in zip(qa, qb, strict=True):
        np.testing.assert_array_equal(x, y)
    ta, tb = a.teacher(), b.teacher()
    np.testing.assert_array_equal(ta.zeta_hat(), tb.zeta_hat())
    np.testing.assert_array_equal(ta._eta, tb._eta)
    np.testing.assert_array_equal(ta._w_prev, tb._w_prev)
    assert (ta._psi_m, ta._tracking, ta._t) == (tb._psi_m, tb._tracking, tb._t)


def _check(name: str, t: np.ndarray, Y: np.ndarray, x0: dict[str, float] | None = None) -> np.ndarray:
    obs = create(name, SEDAN)
    assert type(obs).run is not ScalarLoopObserver.run and type(obs).step is not ScalarLoopObserver.step
    track = obs.run(t, Y, x0)
    mu_run = obs.unknown_input_N()
    ref = create(name, SEDAN)
    want, mus = _stepped(ref, t, Y, x0)
    # the run exercised what it must: learning happened, the network moved, estimates vary
    assert len(ref.loss_trace) > 0.5 * len(t) and ref.adam_steps >= 10
    assert np.abs(ref._theta - init_theta(0)).max() > 1e-4
    assert np.all(np.isfinite(want)) and np.ptp(want, axis=0).min() > 0.0
    if name == "nao_nguyen_ensemble":
        assert len(ref.ensemble_queue()) == 5
        # the queue holds the snapshots of the last five Adam steps: the newest is the trained network
        np.testing.assert_array_equal(ref.ensemble_queue()[-1], ref._theta)
        assert not np.array_equal(ref.ensemble_queue()[0], ref._theta)
    # bit-equal
    np.testing.assert_array_equal(track.x, want)
    np.testing.assert_array_equal(mu_run, mus[-1])
    _assert_same_state(obs, ref)
    # the teacher is the regularised UIO on the same samples: equal to the UIO run on its own
    uio = create("uio_nguyen", SEDAN)
    x_uio = uio.run(t, Y, x0).x
    np.testing.assert_array_equal(obs.teacher().zeta_hat(), uio.zeta_hat())
    # run() left the stepped state: the next step agrees (the observer's, and its teacher's)
    t_next, y_next = float(t[-1]) + 0.01, np.nan_to_num(Y[-1], nan=0.02) * 1.001
    np.testing.assert_array_equal(obs.step(t_next, y_next).x, ref.step(t_next, y_next).x)
    uio.step(t_next, y_next)
    t2, y2 = t_next + 0.01, y_next * 1.001
    np.testing.assert_array_equal(obs.teacher().step(t2, y2).x, uio.step(t2, y2).x)
    assert np.ptp(x_uio, axis=0).min() > 0.0
    return want


@pytest.mark.parametrize("name", NAMES)
def test_compiled_run_equals_stepping_on_mujoco_fishhook(name: str, fishhook) -> None:
    t, Y = fishhook
    assert np.isnan(Y).any() and not np.isnan(Y).all(axis=0).any()  # multi-rate sensors, every column present
    _check(name, t, Y)


@pytest.mark.parametrize("name", NAMES)
def test_compiled_run_equals_stepping_with_gaps(name: str) -> None:
    t, Y = _synthetic()
    want = _check(name, t, Y)
    # the outage is predicted through (NaN input = predict only), not frozen or NaN
    assert np.all(np.isfinite(want[600:700])) and np.ptp(want[600:700, 0]) > 0.0


@pytest.mark.parametrize("name", NAMES)
def test_compiled_run_from_initial_state_equals_stepping(name: str) -> None:
    t, Y = _synthetic()
    _check(name, t, Y, {"vy_mps": 0.4, "yaw_rate_radps": -0.1})


def test_variants_differ() -> None:
    """The three kernels' paths (every-50-steps Adam, every-step Adam, ensemble) are really different."""
    t, Y = _synthetic()
    x = {name: create(name, SEDAN).run(t, Y).x for name in NAMES}
    assert np.abs(x["nao_nguyen"] - x["nao_nguyen_stepwise"]).max() > 1e-4
    assert np.abs(x["nao_nguyen"] - x["nao_nguyen_ensemble"]).max() > 1e-6


def test_empty_and_all_missing_runs() -> None:
    """No rows: an empty track. Only NaN: the observer never starts and holds its initial state."""
    obs = create("nao_nguyen", SEDAN)
    assert obs.run(np.zeros(0), np.zeros((0, 4))).x.shape == (0, 3)
    t = np.arange(50) * 0.01
    Y = np.full((50, 4), np.nan)
    x = obs.run(t, Y, {"vy_mps": 0.3}).x
    want, _ = _stepped(create("nao_nguyen", SEDAN), t, Y, {"vy_mps": 0.3})
    np.testing.assert_array_equal(x, want)
    assert np.all(x[:, 0] == 0.3) and obs.loss_trace == []
