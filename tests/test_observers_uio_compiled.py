"""The compiled loop of the generalized UIO equals its plain-Python step() reference.

``GeneralizedUIO.run_compiled`` is one numba kernel (:mod:`observers.uio_generalized_loop`) that integrates
each frozen affine step with a Padé exponential acting on the state; ``step()`` keeps the Taylor
exponential of the full augmented matrix. Both are exact to rounding, so the estimates must agree to
1e-9 of each state's scale (they agree to ~1e-11): on a MuJoCo run with emulated automotive sensors,
and on synthetic inputs with dropouts, an outage longer than ``hold_s`` (prediction branch), heading
wraps of the integrated gyro, a repeated and an irregular time stamp, with both differentiators.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.linalg import expm

from harness.vehicle import load_vehicle
from observers.registry import create
from observers.uio_generalized import GeneralizedUIO
from observers.uio_generalized_design import basis
from observers.uio_generalized_loop import affine_step_pade, balanced_constants

SEDAN = load_vehicle("sedan")
NAMES = ("uio_generalized", "uio_generalized_yaw_moment")
RTOL = 1e-9

pytestmark = pytest.mark.usefixtures("isolated_design_cache")


def _stepped(obs: GeneralizedUIO, t: np.ndarray, Y: np.ndarray,
             x0: dict[str, float] | None = None) -> np.ndarray:
    obs.reset(float(t[0]), x0)
    return np.array([obs.step(float(t[i]), Y[i]).x for i in range(len(t))])


def _assert_close(got: np.ndarray, want: np.ndarray) -> None:
    """Equal to ``RTOL`` of each column's own scale (a small beta next to a large r counts)."""
    assert got.shape == want.shape
    assert np.array_equal(np.isnan(got), np.isnan(want))
    scale = np.nanmax(np.abs(want), axis=0)
    err = np.nanmax(np.abs(got - want), axis=0)
    assert np.all(err <= RTOL * scale), (err / scale)


def _synthetic(n: int = 2500, h: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """(t, Y) of ``(v_x, r, a_x, delta)`` with gaps; r ~ 0.45 rad/s so the integrated gyro wraps."""
    t = np.arange(n) * h
    vx = 14.0 + 4.0 * np.sin(2 * np.pi * t / 8.0)
    ax = np.gradient(vx, h)
    delta = 0.05 + 0.05 * np.sin(2 * np.pi * 0.4 * t) + 0.02 * np.sin(2 * np.pi * 1.3 * t)
    r = vx * delta / 2.8
    gen = np.random.default_rng(7)
    Y = np.column_stack([vx, r, ax, delta])
    Y = Y + gen.normal(0.0, 1e-3, Y.shape) * np.abs(Y).clip(1e-2, None)
    Y[:5] = np.nan                            # nothing at first
    Y[gen.random(Y.shape) < 0.15] = np.nan    # random dropouts per column
    Y[900:960, 1] = np.nan                    # a 0.6 s gyro outage: predicts, then re-seeds
    Y[1500:1530] = np.nan                     # everything gone for 0.3 s
    t = t.copy()
    t[1200] = t[1199]                         # a repeated time stamp (h = 0)
    t[1800:] += 0.0037                        # an irregular step
    return t, Y


def _mujoco_inputs() -> tuple[np.ndarray, np.ndarray]:
    from harness.scenario import load_scenario
    from harness.sensors import load_sensor_config
    from harness.sensors.suite import emulate
    from harness.simulate import simulate

    sc = dataclasses.replace(load_scenario("double_lane_change"), duration_s=6.0)
    truth = simulate(sc)
    meas = emulate(truth.frame, SEDAN, load_sensor_config(sc.sensors, sc.sensor_overrides, None), 1,
                   outages=sc.outages, lane_gaps=sc.lane_gaps)
    frame = meas.frame
    return frame["t_s"].to_numpy(dtype=float), frame[list(GeneralizedUIO.inputs)].to_numpy(dtype=float)


@pytest.mark.parametrize("name", NAMES)
def test_compiled_run_equals_stepping_on_mujoco(name: str) -> None:
    t, Y = _mujoco_inputs()
    obs = create(name, SEDAN)
    got = obs.run_compiled(t, Y).x
    ref = create(name, SEDAN)
    want = _stepped(ref, t, Y)
    assert len(t) > 500 and np.all(np.isfinite(want)) and np.ptp(want, axis=0).min() > 0.0
    _assert_close(got, want)
    # the loop leaves the observer where stepping leaves it: unknown input and the next step agree
    np.testing.assert_allclose(obs.unknown_input(), ref.unknown_input(), rtol=RTOL,
                               atol=RTOL * np.abs(ref.unknown_input()).max())
    nxt, nref = obs.step(float(t[-1]) + 0.01, Y[-1]).x, ref.step(float(t[-1]) + 0.01, Y[-1]).x
    _assert_close(nxt[None], nref[None])


@pytest.mark.parametrize("differentiator", ["fd_lowpass", "levant"])
@pytest.mark.parametrize("name", NAMES)
def test_compiled_run_equals_stepping_with_gaps_and_wraps(name: str, differentiator: str) -> None:
    t, Y = _synthetic()
    obs = create(name, SEDAN, differentiator=differentiator)
    got = obs.run_compiled(t, Y).x
    ref = create(name, SEDAN, differentiator=differentiator)
    want = _stepped(ref, t, Y)
    # the heading pseudo-output wrapped: the gyro integrates past pi, the observer's psi_m stays in [-pi, pi]
    assert np.all(np.isfinite(want)) and np.nansum(Y[:, 1]) * 0.01 > np.pi and abs(ref._psi_m) <= np.pi
    _assert_close(got, want)
    np.testing.assert_allclose(obs.zeta_hat(), ref.zeta_hat(), rtol=0.0, atol=RTOL * np.abs(ref.zeta_hat()).max())
    nxt, nref = obs.step(float(t[-1]) + 0.01, Y[-1]).x, ref.step(float(t[-1]) + 0.01, Y[-1]).x
    _assert_close(nxt[None], nref[None])


@pytest.mark.parametrize("name", NAMES)
def test_compiled_run_from_initial_state_equals_stepping(name: str) -> None:
    t, Y = _synthetic()
    x0 = {"vy_mps": 0.4, "yaw_rate_radps": -0.1}
    got = create(name, SEDAN).run_compiled(t, Y, x0).x
    want = _stepped(create(name, SEDAN), t, Y, x0)
    assert want[5, 0] == 0.4   # before the first sample the estimate is x0
    _assert_close(got, want)


@pytest.mark.parametrize("name", NAMES)
def test_pade_step_equals_the_matrix_exponential(name: str) -> None:
    """The compiled step is ``exp`` of the augmented matrix acting on ``(eta, 1, 0)`` (scipy as reference)."""
    obs = create(name, SEDAN)
    Fs, Gws, _, _, _ = obs.constants()
    Fb, Gb, d = balanced_constants(Fs, Gws, 17.5)
    assert np.all(np.log2(d) == np.round(np.log2(d)))  # powers of two: the similarity is exact
    n, m = Fs.shape[1], Gws.shape[2]
    work, piv = np.zeros((9, n + 2, n + 2)), np.zeros(n + 2, dtype=np.int64)
    gen = np.random.default_rng(3)
    for h in (1e-4, 0.0037, 0.01, 0.05):
        v, a = gen.uniform(5.0, 30.0), gen.uniform(-4.0, 4.0)
        z, w0 = gen.normal(0.0, 10.0, n), gen.normal(0.0, 10.0, m)
        w1 = w0 + gen.normal(0.0, 1.0, m)
        c = basis(v, a)
        F, G = np.tensordot(c, Fs, axes=1), np.tensordot(c, Gws, axes=1)
        M = np.zeros((n + 2, n + 2))
        M[:n, :n], M[:n, n], M[:n, n + 1], M[n + 1, n] = F * h, G @ w0 * h, G @ (w1 - w0) * h, 1.0
        want = (expm(M) @ np.r_[z, 1.0, 0.0])[:n]
        got = z.copy()
        affine_step_pade(got, Fb, Gb, c, w0, w1, h, d, work, piv)
        assert np.abs(got - want).max() <= 1e-13 * np.abs(want).max(), h
