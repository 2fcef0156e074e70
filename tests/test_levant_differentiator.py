"""Levant's discrete robust exact differentiator: gains, finite-time exactness, accuracy orders."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadtruth.observers.levant_differentiator import LAMBDAS, LevantDifferentiator, levant_gains


def _track(order: int, lipschitz: float, tau: float, t_end: float = 12.0, noise: float = 0.0,
           irregular: bool = False, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Differentiate f = 3 + sin t + 0.5 sin 2t (|f^(k+1)| <= 1 + 2^k) sampled every ~tau.

    Returns times (n,), first-derivative errors (n,) and zeroth-order errors (n,).
    """
    rng = np.random.default_rng(seed)
    d = LevantDifferentiator(order, lipschitz)
    t, ts, e1, e0 = 0.0, [], [], []
    while t < t_end:
        f = 3.0 + math.sin(t) + 0.5 * math.sin(2 * t)
        fn = f + (rng.uniform(-noise, noise) if noise else 0.0)
        d.update(fn, t - ts[-1] if ts else 0.0)
        ts.append(t)
        e1.append(d.z[1] - (math.cos(t) + math.cos(2 * t)))
        e0.append(d.z[0] - f)
        t += tau * (0.5 + rng.random()) if irregular else tau
    return np.array(ts), np.abs(np.array(e1)), np.abs(np.array(e0))


def test_gains_follow_levant_scaling() -> None:
    g = levant_gains(2, 8.0)
    np.testing.assert_allclose(g, (2.0 * 2.0, 2.12 * 4.0, 1.1 * 8.0), rtol=1e-12)
    assert levant_gains(1, 4.0) == pytest.approx((1.5 * 2.0, 1.1 * 4.0))
    for k, lam in LAMBDAS.items():
        assert len(lam) == k + 1 and lam[0] == 1.1
        # Homogeneity: L -> 2^(k+1) L scales gain i by 2^(i+1).
        a, b = levant_gains(k, 1.0), levant_gains(k, 2.0 ** (k + 1))
        np.testing.assert_allclose(np.array(b) / np.array(a), 2.0 ** np.arange(1, k + 2), rtol=1e-12)
    with pytest.raises(ValueError):
        levant_gains(7, 1.0)
    with pytest.raises(ValueError):
        levant_gains(2, 0.0)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_finite_time_convergence_and_accuracy_order(order: int) -> None:
    """No noise: after a transient independent of tau the error is O(L tau^k) for z_1."""
    L = 1.0 + 2.0 ** order + 1.0   # > sup |f^(k+1)|
    errs, times = [], []
    for tau in (4e-3, 2e-3, 1e-3):
        t, e1, _ = _track(order, L, tau)
        errs.append(e1[t > 6.0].max())
        times.append(t[np.argmax(e1 < 0.02)])
    # Sliding-mode convergence: the time to reach the band does not depend on the sampling step.
    assert max(times) - min(times) < 0.05 and max(times) < 3.0
    # Accuracy order k of the first derivative: halving tau divides the error by ~2^k.
    for a, b in zip(errs, errs[1:], strict=False):
        assert 0.7 * 2.0 ** order < a / b < 1.4 * 2.0 ** order
    assert errs[-1] < 40.0 * L * 1e-3 ** order


def test_exact_in_the_limit_for_second_order() -> None:
    """k = 2 (the seed's 'third-order' HOSMD): |z_i - f^(i)| <= mu L tau^(3-i) with mu < 10 (Levant 2003)."""
    L, tau = 10.0, 5e-4
    t, e1, e0 = _track(2, L, tau)
    assert e1[t > 5.0].max() < 10.0 * L * tau**2    # 2.5e-5 m/s-equivalent
    assert e0[t > 5.0].max() < 10.0 * L * tau**3


def test_irregular_sampling_converges() -> None:
    t, e1, _ = _track(2, 10.0, 2e-3, irregular=True)
    assert e1[t > 6.0].max() < 1e-3


def test_noise_accuracy_order_two_thirds() -> None:
    """Bounded noise eps: the z_1 error scales as eps^(2/3) (k = 2), i.e. x4 for eps x8."""
    worst = []
    for eps in (1e-4, 8e-4):
        runs = [_track(2, 10.0, 1e-3, t_end=10.0, noise=eps, seed=s) for s in range(3)]
        worst.append(max(e1[t > 4.0].max() for t, e1, _ in runs))
    ratio = worst[1] / worst[0]
    assert 2.5 < ratio < 6.5


def test_reset_and_first_sample() -> None:
    d = LevantDifferentiator(2, 1.0)
    d.update(5.0, 0.0)
    assert d.initialized and d.z == [5.0, 0.0, 0.0]
    d.update(5.1, 0.01)
    d.reset()
    assert not d.initialized and d.samples == 0
    assert d.accuracy_bound_noise(0.008, 1) == pytest.approx(1.0 * 0.008 ** (2 / 3))
