"""run_observers: long format, statuses, failure isolation."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from roadtruth.harness.errors import InputError
from roadtruth.harness.evaluation.estimate import ESTIMATE_COLUMNS, run_observers
from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers import registry
from roadtruth.observers.base import ScalarLoopObserver

SEDAN = load_vehicle("sedan")


pytestmark = pytest.mark.usefixtures("isolated_design_cache")


def _frame(n: int = 500, h: float = 0.01) -> pd.DataFrame:
    t = np.arange(n) * h
    vx = np.full(n, 15.0)
    delta = 0.03 * np.sin(2 * np.pi * 0.4 * t)
    r = vx * delta / 2.8
    f = pd.DataFrame({"t_s": t, "delta_rad": delta, "vx_mps": vx, "yaw_rate_radps": r, "ay_mps2": r * vx,
                      "ax_mps2": 0.0, "imu_valid": 1})
    f.loc[1::2, "ay_mps2"] = np.nan  # accelerometer at half rate
    return f


class _Exploding(ScalarLoopObserver):
    """Raises after a while."""

    name = "test_exploding"
    citation = "test"
    inputs = ("yaw_rate_radps",)
    states = ("yaw_rate_radps",)

    def _initial_state(self) -> list[float]:
        return [0.0]

    def _advance(self, t_s: float, y: list[float]) -> None:
        if t_s > 1.0:
            raise RuntimeError("boom")

    def _values(self) -> list[float]:
        return [0.0]


class _Runaway(_Exploding):
    """Grows without bound."""

    name = "test_runaway"

    def _advance(self, t_s: float, y: list[float]) -> None:
        self._z[0] = math.exp(2.0 * t_s)

    def _values(self) -> list[float]:
        return [self._z[0]]


@pytest.fixture()
def test_observers():
    for cls in (_Exploding, _Runaway):
        registry.register(cls)
    yield
    for cls in (_Exploding, _Runaway):
        registry.unregister(cls.name)


def test_long_format_and_statuses() -> None:
    f = _frame()
    names = ["kf_bicycle", "lpv_wang", "kinematic_vy"]
    est, runs = run_observers(f, SEDAN, names)
    assert list(est.columns) == list(ESTIMATE_COLUMNS)
    assert all(runs[n].status == "ok" and runs[n].n_steps == len(f) for n in names)
    assert runs["lpv_wang"].certified and not runs["kf_bicycle"].certified
    assert runs["kf_bicycle"].us_per_step > 0
    kf = est[est.observer == "kf_bicycle"]
    assert set(kf.state) == set(registry.observer_class("kf_bicycle").states)
    assert kf["var"].notna().all() and kf["lo"].isna().all()
    assert est[est.observer == "lpv_wang"]["var"].isna().all()
    assert len(est) == len(f) * (5 + 4 + 2)
    beta = kf[kf.state == "beta_rad"]
    np.testing.assert_array_equal(beta.t_s.to_numpy(), f.t_s.to_numpy())


def test_missing_input_column_skips_only_that_observer() -> None:
    f = _frame().drop(columns=["ay_mps2"])
    f["ax_mps2"] = np.nan
    est, runs = run_observers(f, SEDAN, ["kf_bicycle", "open_loop_bicycle", "lpv_wang"])
    assert runs["kf_bicycle"].status == "skipped: missing ay_mps2"
    assert runs["lpv_wang"].status == "skipped: missing ax_mps2"  # an all-NaN column counts as missing
    assert runs["open_loop_bicycle"].status == "ok"
    assert set(est.observer) == {"open_loop_bicycle"}


def test_failures_are_isolated(test_observers) -> None:
    est, runs = run_observers(_frame(), SEDAN, ["test_exploding", "test_runaway", "open_loop_bicycle"])
    assert runs["test_exploding"].status == "error: RuntimeError: boom"
    assert runs["test_runaway"].status == "diverged" and "yaw_rate_radps" in runs["test_runaway"].detail
    assert runs["open_loop_bicycle"].status == "ok"
    assert "test_exploding" not in set(est.observer)


def test_failed_design_is_an_error_status_not_a_crash() -> None:
    _, runs = run_observers(_frame(), SEDAN, ["lpv_wang", "kinematic_vy"],
                            options={"lpv_wang": {"decay_rate_radps": 500.0}})
    assert not runs["lpv_wang"].certified
    assert runs["lpv_wang"].status.startswith("error: DesignFailed")
    assert runs["kinematic_vy"].status == "ok"


def test_bad_requests_are_input_errors() -> None:
    with pytest.raises(InputError, match="unknown observer"):
        run_observers(_frame(), SEDAN, ["kf_bicycle", "nope"])
    with pytest.raises(InputError, match="unknown option"):
        run_observers(_frame(), SEDAN, ["kf_bicycle"], options={"kf_bicycle": {"typo": 1}})
    with pytest.raises(InputError, match="t_s"):
        run_observers(_frame().drop(columns=["t_s"]), SEDAN, ["kf_bicycle"])


def test_nan_is_no_estimate_and_inf_is_divergence() -> None:
    """Leading NaN = not started (fine); NaN later = a numerical failure unless the observer withholds
    estimates without input; ±inf is always a divergence."""
    from roadtruth.harness.evaluation.estimate import _diverged

    t = np.arange(100) * 0.01
    x = np.ones((100, 2))
    x[:10] = np.nan
    assert _diverged(x, t, ("vy_mps", "beta_rad")) is None
    gap = x.copy()
    gap[50:60] = np.nan
    assert "non-finite estimate at t=0.500" in _diverged(gap, t, ("vy_mps", "beta_rad"))
    assert _diverged(gap, t, ("vy_mps", "beta_rad"), withholds=True) is None
    blown = x.copy()
    blown[70, 1] = np.inf
    assert "infinite estimate at t=0.700" in _diverged(blown, t, ("vy_mps", "beta_rad"), withholds=True)
    assert _diverged(np.full((100, 2), np.nan), t, ("vy_mps", "beta_rad")) == "no finite estimate at all"
