"""Compiled run() loops equal the plain-Python step() they were written from.

Each family below runs its whole loop in a numba kernel; ``step()`` stays the reference. The test
steps ``step()`` one sample at a time through a run with camera/radar/GNSS sample rates, random
dropouts, a full outage, a repeated and an irregular time stamp, and asserts the estimates, bounds
and variances equal ``run()``'s to 1e-12 relative, that ``run()`` leaves the observer where stepping
leaves it (the next ``step()`` agrees), and that ``run()`` from an initial state ``x0`` agrees too.
"""

from __future__ import annotations

import numpy as np
import pytest

from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers.base import ScalarLoopObserver
from roadtruth.observers.registry import available_observers, create, observer_class

SEDAN = load_vehicle("sedan")

#: Families whose run() is a compiled loop (module -> the observers it registers).
COMPILED_MODULES = ("roadtruth.observers.high_gain_radar", "roadtruth.observers.high_gain_methods", "roadtruth.observers.finite_time_interval")
COMPILED = [n for n in available_observers() if observer_class(n).__module__ in COMPILED_MODULES]

pytestmark = pytest.mark.usefixtures("isolated_design_cache")


def _signals(n: int = 1500, h: float = 0.01) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    t = np.arange(n) * h
    vx = 14.0 + 4.0 * np.sin(2 * np.pi * t / 8.0)
    ax = np.gradient(vx, h)
    delta = 0.05 * np.sin(2 * np.pi * 0.4 * t) + 0.02 * np.sin(2 * np.pi * 1.3 * t)
    r = vx * delta / 2.8
    psi = np.cumsum(r) * h
    y_lane = np.cumsum(vx * np.sin(psi)) * h + 0.5 * np.sin(psi)
    camera = np.arange(n) % 3 == 0
    radar = np.arange(n) % 5 == 0
    v_lead = 15.0 + 2.0 * np.sin(2 * np.pi * t / 6.0)
    rate = v_lead - vx
    rng_m = 25.0 + np.cumsum(rate) * h
    gnss = np.arange(n) % 10 == 0
    return t, {"delta_rad": delta, "vx_mps": vx, "yaw_rate_radps": r, "ay_mps2": r * vx, "ax_mps2": ax,
               "psi_lane_rad": np.where(camera, psi, np.nan), "y_lane_m": np.where(camera, y_lane, np.nan),
               "rho_1pm": np.where(camera, 0.0, np.nan),
               "range_m": np.where(radar, rng_m, np.nan), "range_rate_mps": np.where(radar, rate, np.nan),
               "gnss_x_m": np.where(gnss, np.cumsum(vx * np.cos(psi)) * h, np.nan),
               "gnss_y_m": np.where(gnss, np.cumsum(vx * np.sin(psi)) * h, np.nan),
               "gnss_speed_mps": np.where(gnss, vx, np.nan)}


def _inputs(name: str) -> tuple[np.ndarray, np.ndarray]:
    t, sig = _signals()
    gen = np.random.default_rng(11)
    Y = np.column_stack([sig[c] for c in observer_class(name).inputs])
    Y = Y + gen.normal(0.0, 1e-3, Y.shape) * np.abs(Y).clip(1e-2, None)
    Y[:7] = np.nan                              # nothing at first
    Y[gen.random(Y.shape) < 0.15] = np.nan      # random dropouts per column
    Y[600:700] = np.nan                         # a 1 s outage of everything
    t = t.copy()
    t[900] = t[899]                             # a repeated time stamp (h = 0)
    t[1000:] += 0.0037                          # an irregular step
    return t, Y


def _stepped(obs: ScalarLoopObserver, t: np.ndarray, Y: np.ndarray,
             x0: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """``x`` and, where the observer gives them, ``lo``/``hi``/``var`` (n, k) from stepping."""
    obs.reset(float(t[0]), x0)
    outs = [obs.step(float(t[i]), Y[i]) for i in range(len(t))]
    res = {"x": np.array([o.x for o in outs])}
    if obs.has_bounds:
        res["lo"] = np.array([o.lo for o in outs])
        res["hi"] = np.array([o.hi for o in outs])
    if obs.has_covariance:
        res["var"] = np.array([np.diag(o.cov) for o in outs])
    return res


def _close(a: np.ndarray, b: np.ndarray) -> None:
    """Equal to 1e-12 relative to each state's own scale (a small beta next to a large r counts)."""
    scale = np.nanmax(np.abs(np.atleast_2d(b)), axis=0)
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=0.0)
    assert np.all(np.abs(np.atleast_2d(a) - np.atleast_2d(b)) <= 1e-12 * scale)


def test_compiled_families_are_listed() -> None:
    assert len(COMPILED) >= 11
    for name in COMPILED:
        assert observer_class(name).run is not ScalarLoopObserver.run, name


@pytest.mark.parametrize("name", COMPILED)
def test_compiled_run_equals_stepping(name: str) -> None:
    t, Y = _inputs(name)
    obs = create(name, SEDAN)
    track = obs.run(t, Y)
    nxt = obs.step(float(t[-1]) + 0.01, Y[-1] * 1.001)  # run() left the stepped state
    ref = create(name, SEDAN)
    want = _stepped(ref, t, Y)
    assert np.all(np.isfinite(want["x"])) and np.ptp(want["x"], axis=0).min() > 0.0
    for key, value in want.items():
        got = getattr(track, key)
        assert got is not None, key
        _close(got, value)
    _close(nxt.x, ref.step(float(t[-1]) + 0.01, Y[-1] * 1.001).x)


@pytest.mark.parametrize("name", COMPILED)
def test_compiled_run_from_initial_state_equals_stepping(name: str) -> None:
    t, Y = _inputs(name)
    obs = create(name, SEDAN)
    if not obs._initial_state():
        pytest.skip("the observer's state is not settable (it needs no initial state)")
    x0 = {s: 0.5 * (i + 1) for i, s in enumerate(obs.states[:2])}
    track = obs.run(t, Y, x0)
    _close(track.x, _stepped(create(name, SEDAN), t, Y, x0)["x"])
