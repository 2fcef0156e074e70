"""The generalized UIO's run() is one compiled loop and equals stepping step() bit for bit.

``GeneralizedUIO.step()`` and ``run()`` both call the numba kernel
:func:`roadtruth.observers.uio_generalized_loop.generalized_run` (one sample, or the whole log in one call) on
the same carried state, so their estimates must be equal to the last bit: on a MuJoCo run with
emulated automotive sensors and a sensor outage, and on synthetic inputs with dropouts, an outage
longer than ``hold_s`` (prediction branch), heading wraps of the integrated gyro, a repeated and an
irregular time stamp, with both differentiators. The kernel's exact affine step is the matrix
exponential of the augmented matrix to 1e-13 (scipy's ``expm`` as reference).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.linalg import expm

import roadtruth.observers.uio_generalized as uio_module
from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers.registry import create
from roadtruth.observers.uio_generalized import GeneralizedUIO
from roadtruth.observers.uio_generalized_design import basis
from roadtruth.observers.uio_generalized_loop import affine_step_pade, balanced_constants

SEDAN = load_vehicle("sedan")
NAMES = ("uio_generalized", "uio_generalized_yaw_moment")

pytestmark = pytest.mark.usefixtures("isolated_design_cache")


def _stepped(obs: GeneralizedUIO, t: np.ndarray, Y: np.ndarray,
             x0: dict[str, float] | None = None) -> np.ndarray:
    obs.reset(float(t[0]), x0)
    return np.array([obs.step(float(t[i]), Y[i]).x for i in range(len(t))])


def _assert_bit_equal(got: np.ndarray, want: np.ndarray) -> None:
    assert got.shape == want.shape and got.dtype == want.dtype
    assert got.tobytes() == want.tobytes(), np.nanmax(np.abs(got - want), axis=0)


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
    """Emulated sensors on a MuJoCo double lane change, with a 0.3 s gap of every channel (held, then
    predicted past ``hold_s``) and random 10 % dropouts."""
    from roadtruth.harness.sensors import load_sensor_config
    from roadtruth.harness.sensors.suite import emulate
    from roadtruth.harness.truth.scenario import load_scenario
    from roadtruth.harness.truth.simulate import simulate

    sc = dataclasses.replace(load_scenario("double_lane_change"), duration_s=6.0)
    truth = simulate(sc)
    meas = emulate(truth.frame, SEDAN, load_sensor_config(sc.sensors, sc.sensor_overrides, None), 1,
                   outages=sc.outages, lane_gaps=sc.lane_gaps)
    frame = meas.frame
    t = frame["t_s"].to_numpy(dtype=float)
    Y = frame[list(GeneralizedUIO.inputs)].to_numpy(dtype=float, copy=True)
    gap = (t > 2.5) & (t < 2.8)
    Y[gap] = np.nan
    Y[np.random.default_rng(11).random(Y.shape) < 0.1] = np.nan
    return t, Y


@pytest.mark.parametrize("name", NAMES)
def test_run_is_one_compiled_call_and_equals_stepping_on_mujoco(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    t, Y = _mujoco_inputs()
    calls: list[int] = []
    kernel = uio_module.generalized_run

    def counted(tt: np.ndarray, *args: object) -> None:
        calls.append(len(tt))
        kernel(tt, *args)

    monkeypatch.setattr(uio_module, "generalized_run", counted)
    obs = create(name, SEDAN)
    got = obs.run(t, Y).x
    assert calls == [len(t)]   # the whole log in one compiled call, not a Python loop over step()
    monkeypatch.undo()
    ref = create(name, SEDAN)
    want = _stepped(ref, t, Y)
    assert len(t) > 500 and np.all(np.isfinite(want)) and np.ptp(want, axis=0).min() > 0.0
    _assert_bit_equal(got, want)
    # run() leaves the observer where stepping leaves it: unknown input and the next step agree
    _assert_bit_equal(obs.unknown_input(), ref.unknown_input())
    assert np.abs(ref.unknown_input()).max() > 0.0
    nxt, nref = obs.step(float(t[-1]) + 0.01, Y[-1]).x, ref.step(float(t[-1]) + 0.01, Y[-1]).x
    _assert_bit_equal(nxt, nref)


@pytest.mark.parametrize("differentiator", ["fd_lowpass", "levant"])
@pytest.mark.parametrize("name", NAMES)
def test_run_equals_stepping_with_gaps_and_wraps(name: str, differentiator: str) -> None:
    t, Y = _synthetic()
    obs = create(name, SEDAN, differentiator=differentiator)
    got = obs.run(t, Y).x
    ref = create(name, SEDAN, differentiator=differentiator)
    want = _stepped(ref, t, Y)
    # the heading pseudo-output wrapped: the gyro integrates past pi, the observer's psi_m stays in [-pi, pi]
    assert np.all(np.isfinite(want)) and np.nansum(Y[:, 1]) * 0.01 > np.pi and abs(ref.psi_m) <= np.pi
    _assert_bit_equal(got, want)
    _assert_bit_equal(obs.zeta_hat(), ref.zeta_hat())
    nxt, nref = obs.step(float(t[-1]) + 0.01, Y[-1]).x, ref.step(float(t[-1]) + 0.01, Y[-1]).x
    _assert_bit_equal(nxt, nref)
    # split in two calls (as a host resuming a run would) gives the same bits as one call
    split = create(name, SEDAN, differentiator=differentiator)
    first = split.run(t[:1300], Y[:1300]).x
    rest = np.array([split.step(float(t[i]), Y[i]).x for i in range(1300, len(t))])
    _assert_bit_equal(np.vstack([first, rest]), got)


@pytest.mark.parametrize("name", NAMES)
def test_run_from_initial_state_equals_stepping(name: str) -> None:
    t, Y = _synthetic()
    x0 = {"vy_mps": 0.4, "yaw_rate_radps": -0.1}
    got = create(name, SEDAN).run(t, Y, x0).x
    want = _stepped(create(name, SEDAN), t, Y, x0)
    assert want[5, 0] == 0.4 and want[5, 1] == -0.1   # before the first sample the estimate is x0
    _assert_bit_equal(got, want)


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
        # At h = 0.05 the augmented matrix has a 1-norm near 8e3: scipy's result and the compiled
        # step then each sit ~5e-14 (relative) from an extended-precision exponential, on either
        # side depending on the machine's BLAS kernels. A dropped or mis-signed Pade term is off by
        # far more than 1e-12.
        assert np.abs(got - want).max() <= 1e-12 * np.abs(want).max(), h
