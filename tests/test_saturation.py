"""An observer's status says whether its estimate is usable: pinned on a declared bound -> saturated,
missing -> no estimate; measured over the scored window only, with error > diverged > saturated > ok."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
import pandas as pd
import pytest

from roadtruth.harness.evaluation import scoring

BOUND = 0.5


@dataclass(frozen=True)
class Run:
    status: str = "ok"
    us_per_step: float = 1.0
    certified: bool | None = False
    design_reason: str = ""
    n_steps: int = 0


T = np.round(np.arange(0.0, 10.0, 0.001), 9)  # truth at 1 kHz


def truth() -> pd.DataFrame:
    # A sideslip large enough that a good estimate beats the trivial estimate 0 (else "unusable").
    return pd.DataFrame({"t_s": T, "beta_rad": 0.3 * np.sin(T), "yaw_rate_radps": np.zeros_like(T)})


def estimates(beta: np.ndarray, observer: str = "filt") -> pd.DataFrame:
    """Long estimates of ``beta_rad`` and a harmless second state at 100 Hz."""
    t = T[::10]
    rows = []
    for state, value in (("beta_rad", beta), ("yaw_rate_radps", np.zeros(t.size))):
        rows.append(pd.DataFrame({"t_s": t, "observer": observer, "state": state, "value": value,
                                  "lo": np.nan, "hi": np.nan}))
    return pd.concat(rows, ignore_index=True)


def pinned(fraction: float, value: float = BOUND) -> np.ndarray:
    """A good estimate that sits on ``value`` for the first ``fraction`` of the record."""
    t = T[::10]
    beta = 0.3 * np.sin(t) + 0.01 * np.cos(t)
    beta[t < fraction * 10.0] = value
    return beta


def status_of(metrics: pd.DataFrame, observer: str = "filt") -> set[str]:
    return set(metrics.loc[metrics["observer"] == observer, "status"])


def percent(status: str, prefix: str) -> float:
    assert status.startswith(prefix), status
    m = re.search(r"\(?([\d.]+) % of the time\)$", status)
    assert m, status
    return float(m.group(1))


def run_score(beta: np.ndarray, *, run: Run = Run(), **kw) -> pd.DataFrame:
    return scoring.score(truth(), estimates(beta), scenario="s", runs={"filt": run},
                         state_bounds={"filt": {"beta_rad": (-BOUND, BOUND)}}, **kw)


@pytest.mark.parametrize("side", [BOUND, -BOUND])
def test_an_estimate_pinned_on_its_bound_for_20_percent_is_saturated(side):
    m = run_score(pinned(0.20, side))
    (st,) = status_of(m)  # every row of the observer carries the observer's status
    assert st.startswith("saturated (")
    assert percent(st, "saturated") == pytest.approx(20.0, abs=1.0)
    # the metrics are still there to look at, the status says they are not usable
    assert m["rmse"].notna().all()


def test_two_percent_on_the_bound_stays_ok():
    assert status_of(run_score(pinned(0.02))) == {"ok"}


def test_close_to_but_off_the_bound_is_not_saturated():
    # Half the time at 0.4995 rad is a bad estimate ("unusable" on that state), but it is not pinned.
    statuses = status_of(run_score(pinned(0.5, BOUND * (1 - 1e-3))))
    assert not any(s.startswith("saturated") for s in statuses), statuses
    assert "ok" in statuses


def test_nan_gaps_are_no_estimate():
    beta = pinned(0.0)
    t = T[::10]
    beta[(t >= 3.0) & (t < 5.0)] = np.nan  # 20 % of the record
    (st,) = status_of(run_score(beta))
    assert percent(st, "diverged (no estimate for") == pytest.approx(20.0, abs=1.0)
    beta = pinned(0.0)
    beta[(t >= 3.0) & (t < 3.2)] = np.nan  # 2 %
    assert status_of(run_score(beta)) == {"ok"}


def test_only_the_scored_window_counts():
    t = T[::10]
    beta = pinned(0.0)
    beta[t >= 8.0] = BOUND  # pinned only after the car spun out at 8 s
    m = run_score(beta, scored_until_s=8.0)
    assert status_of(m) == {"ok"}
    # 1 s pinned in a 5 s window is 20 % of the scored time, not 10 % of the record
    beta = pinned(0.0)
    beta[(t >= 4.0) & (t < 5.0)] = BOUND
    (st,) = status_of(run_score(beta, scored_until_s=5.0))
    assert percent(st, "saturated") == pytest.approx(20.0, abs=1.0)


@pytest.mark.parametrize("status", ["diverged", "error: ValueError: boom", "skipped: missing ay_mps2"])
def test_worse_statuses_are_kept(status):
    m = run_score(pinned(0.5), run=Run(status=status))
    assert status_of(m) == {status}


def test_missing_beats_saturated():
    beta = pinned(0.3)
    t = T[::10]
    beta[(t >= 5.0) & (t < 7.0)] = np.nan
    (st,) = status_of(run_score(beta))
    assert st.startswith("diverged (no estimate for")


def test_bound_fraction_is_time_weighted():
    t = np.array([0.0, 1.0, 1.5, 4.0])
    a = scoring.align(t, np.zeros(4), pd.DataFrame({"t_s": t, "value": [BOUND, 0.0, -BOUND, 0.0]}),
                      "beta_rad", 0.01)
    # rows stand for 1.0, 0.5, 2.5 and (mean step) 4/3 s: on the bound 1.0 + 2.5 of 5.333 s
    assert scoring.bound_fraction(a, (-BOUND, BOUND)) == pytest.approx(3.5 / (4.0 + 4.0 / 3.0))
    assert math.isnan(scoring.bound_fraction(scoring.align(t[:0], np.zeros(0), pd.DataFrame(
        {"t_s": [0.0], "value": [0.0]}), "beta_rad", 0.01), (-BOUND, BOUND)))


@pytest.mark.parametrize("name", ["ekf_bicycle", "ukf_bicycle"])
def test_the_kalman_filters_declare_the_bound_they_project_onto(name):
    """Drive the real filter into its sideslip projection: it lands exactly on its declared bound, and
    scoring (with the bound taken from the observer's class) says ``saturated``, not ``ok``."""
    from roadtruth.harness.truth.vehicle import load_vehicle
    from roadtruth.observers.registry import create, observer_class

    lo, hi = observer_class(name).state_bounds["beta_rad"]
    assert (lo, hi) == (-0.5, 0.5)
    obs = create(name, load_vehicle("sedan"))
    t = np.round(np.arange(0.0, 4.0, 0.01), 9)
    n = t.size
    # slow car, large measured yaw rate and lateral acceleration: the model cannot explain them and
    # the projection |v_y| <= tan(beta_max) v_x holds the sideslip on its edge
    Y = np.column_stack([np.zeros(n), np.full(n, 3.0), np.full(n, 2.0), np.full(n, 15.0)])
    track = obs.run(t, Y)
    beta = track.x[:, track.states.index("beta_rad")]
    assert np.max(np.abs(beta)) == pytest.approx(hi, abs=1e-12)
    assert np.mean(np.abs(np.abs(beta) - hi) < 1e-9) > 0.9
    tf = pd.DataFrame({"t_s": t, **{s: np.zeros(n) for s in track.states}})
    m = scoring.score(tf, track.to_frame(), scenario="s", runs={name: Run()})
    (st,) = set(m["status"])
    assert percent(st, "saturated") > 90.0


def test_an_instance_with_another_beta_max_declares_it():
    from roadtruth.harness.truth.vehicle import load_vehicle
    from roadtruth.observers.registry import create

    obs = create("ekf_bicycle", load_vehicle("sedan"), beta_max_rad=0.3)
    assert obs.state_bounds == {"beta_rad": (-0.3, 0.3)}


def test_every_declared_bound_names_an_estimated_state_inside_the_absurd_limits():
    """A bound on a state the observer does not estimate would never be checked; one wider than the
    absurd limit of ``roadtruth.harness.evaluation.estimate`` would leave a band where neither check sees a runaway."""
    from roadtruth.harness.evaluation.estimate import ABSURD_LIMITS
    from roadtruth.observers.registry import available_observers, observer_class

    declared = {n: observer_class(n).state_bounds for n in available_observers() if observer_class(n).state_bounds}
    assert {"ekf_bicycle", "ukf_bicycle"} <= set(declared)
    for name, bounds in declared.items():
        for state, (lo, hi) in bounds.items():
            assert state in observer_class(name).states, (name, state)
            assert lo < hi, (name, state)
            if state in ABSURD_LIMITS:
                assert max(abs(lo), abs(hi)) <= ABSURD_LIMITS[state], (name, state)
