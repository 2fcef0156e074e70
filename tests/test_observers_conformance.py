"""Every registered observer: determinism, finite outputs, canonical names, NaN handling, options."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from roadtruth.harness.errors import InputError
from roadtruth.harness.signals import ESTIMABLE
from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers import registry
from roadtruth.observers.base import ScalarLoopObserver
from roadtruth.observers.registry import ObserverRegistryError, available_observers, create, observer_info

SEDAN = load_vehicle("sedan")
NAMES = available_observers()


pytestmark = pytest.mark.usefixtures("isolated_design_cache")


def _signals(n: int = 800, h: float = 0.01) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    t = np.arange(n) * h
    vx = 12.0 + 0.5 * t
    delta = 0.04 * np.sin(2 * np.pi * 0.5 * t)
    r = vx * delta / 2.8
    # Lane camera (look-ahead 0.5 m) on a straight road: heading relative to the lane = yaw angle;
    # sampled at ~33 Hz like a real camera, NaN between samples.
    psi = np.cumsum(r) * h
    y_lane = np.cumsum(vx * np.sin(psi)) * h + 0.5 * np.sin(psi)
    camera = (np.arange(n) % 3) == 0
    sig = {"delta_rad": delta, "vx_mps": vx, "yaw_rate_radps": r, "ay_mps2": r * vx,
           "ax_mps2": np.full(n, 0.5), "psi_lane_rad": np.where(camera, psi, np.nan),
           "y_lane_m": np.where(camera, y_lane, np.nan), "rho_1pm": np.where(camera, 0.0, np.nan),
           # Radar to a lead car pulling away at 0.5 m/s, 20 Hz.
           "range_m": np.where(np.arange(n) % 5 == 0, 30.0 + 0.5 * t, np.nan),
           "range_rate_mps": np.where(np.arange(n) % 5 == 0, 0.5, np.nan)}
    # GNSS at 10 Hz (position of the car on its yaw path, speed).
    gnss = (np.arange(n) % 10) == 0
    sig.update({"gnss_x_m": np.where(gnss, np.cumsum(vx * np.cos(psi)) * h, np.nan),
                "gnss_y_m": np.where(gnss, np.cumsum(vx * np.sin(psi)) * h, np.nan),
                "gnss_speed_mps": np.where(gnss, vx, np.nan)})
    return t, sig


def _inputs(name: str, rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    t, sig = _signals()
    cls = registry.observer_class(name)
    Y = np.column_stack([sig[c] for c in cls.inputs])
    if rng is not None:
        Y = Y + rng.normal(0, 1e-3, Y.shape)
    return t, Y


def test_builtins_are_registered() -> None:
    for name in ("open_loop_bicycle", "kinematic_vy", "kf_bicycle", "ekf_bicycle", "ukf_bicycle", "lpv_wang",
                 "lpv_wang_hinf", "lpv_wang_printed", "lpv_wang_hinf_printed"):
        assert name in NAMES


def _finite_once_started(x: np.ndarray, *, must_start: bool) -> bool:
    """Leading NaN rows are "not started yet" (no measurement so far, e.g. a camera differentiator
    settling); from the first finite row on, every value must be finite."""
    started = np.all(np.isfinite(x), axis=1)
    if not started.any():
        return not must_start and bool(np.all(np.isnan(x)))
    return bool(np.all(started[int(np.argmax(started)):]))


@pytest.mark.parametrize("name", NAMES)
def test_conformance(name: str) -> None:
    cls = registry.observer_class(name)
    assert set(cls.states) <= set(ESTIMABLE) and len(set(cls.states)) == len(cls.states)
    assert cls.citation
    t, Y = _inputs(name, np.random.default_rng(0))
    a, b = create(name, SEDAN), create(name, SEDAN)
    ta, tb = a.run(t, Y), b.run(t, Y)
    assert ta.x.shape == (len(t), len(cls.states))
    assert ta.x.tobytes() == tb.x.tobytes()  # same input -> same bytes
    assert a.run(t, Y).x.tobytes() == ta.x.tobytes()  # run() resets
    assert _finite_once_started(ta.x, must_start=True)
    assert np.all(np.isfinite(ta.x[len(t) // 2:]))  # started well before the end of 10 s of data
    if cls.has_covariance:
        assert ta.var is not None and np.all(np.isfinite(ta.var)) and np.all(ta.var >= 0)
    if cls.has_bounds:
        assert ta.lo is not None and ta.hi is not None
        ok = np.isfinite(ta.x)
        assert np.all(ta.lo[ok] <= ta.x[ok] + 1e-12) and np.all(ta.x[ok] <= ta.hi[ok] + 1e-12)
    # step() gives what run() gives
    a.reset(float(t[0]))
    for i in range(5):
        out = a.step(float(t[i]), Y[i])
        np.testing.assert_array_equal(out.x, ta.x[i])
        if cls.has_covariance:
            assert out.cov is not None and out.cov.shape == (len(cls.states),) * 2
            np.testing.assert_allclose(np.diag(out.cov), ta.var[i], rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize("name", NAMES)
def test_missing_samples_never_crash(name: str) -> None:
    rng = np.random.default_rng(5)
    t, Y = _inputs(name)
    Y = Y.copy()
    Y[:30] = np.nan                           # nothing at first
    Y[rng.random(Y.shape) < 0.3] = np.nan     # random gaps per column
    Y[400:500, :] = np.nan                    # a 1 s outage
    cls = registry.observer_class(name)
    tr = create(name, SEDAN).run(t, Y)
    allnan = create(name, SEDAN).run(t[:50], np.full((50, Y.shape[1]), np.nan))
    assert not np.isinf(tr.x).any() and not np.isinf(allnan.x).any()
    if cls.withholds_estimates:  # NaN = no estimate where the inputs give none; never a made-up value
        return
    assert _finite_once_started(tr.x, must_start=True)
    assert _finite_once_started(allnan.x, must_start=False)


@pytest.mark.parametrize("name", NAMES)
def test_unknown_option_and_bad_initial_state_are_input_errors(name: str) -> None:
    with pytest.raises(InputError, match="unknown option"):
        create(name, SEDAN, no_such_option=1)
    obs = create(name, SEDAN)
    if isinstance(obs, ScalarLoopObserver):
        with pytest.raises(InputError):
            obs.reset(0.0, {"no_such_state": 1.0})


def test_registry_rejects_duplicates_and_unknown_names() -> None:
    existing = registry.observer_class("kf_bicycle")

    class Impostor(existing):  # type: ignore[misc, valid-type]
        pass

    with pytest.raises(ObserverRegistryError, match="already registered"):
        registry.register(Impostor)
    with pytest.raises(InputError, match="unknown observer"):
        create("no_such_observer", SEDAN)
    info = {d["name"]: d for d in observer_info()}
    assert info["lpv_wang"]["states"][0] == "alpha_f_rad" and info["kf_bicycle"]["covariance"]
    assert set(info["open_loop_bicycle"]) >= {"name", "citation", "inputs", "states", "bounds"}


def test_broken_plugin_only_warns(monkeypatch: pytest.MonkeyPatch) -> None:
    class BrokenEntryPoint:
        name, value = "broken", "nowhere:Nothing"

        def load(self) -> None:
            raise ImportError("no module named nowhere")

    class GoodEntryPoint:
        name, value = "good", "roadtruth.observers.open_loop:KinematicVy"

        def load(self) -> type:
            return registry.observer_class("kinematic_vy")

    monkeypatch.setattr(registry, "entry_points", lambda group: [BrokenEntryPoint(), GoodEntryPoint()])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        loaded = registry.load_plugins()
    assert loaded == ["good"]
    assert any("broken" in str(w.message) for w in caught)
