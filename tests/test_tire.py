"""Magic Formula tire kernel: compiled vs NumPy twin, slope, peak, friction scaling, combined slip, lag."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadtruth.harness.truth.tire import (
    combined_slip_forces,
    peak_slip,
    radial_load_kernel,
    relax_kernel,
    relax_reference,
    shape_array,
    tire_forces_kernel,
    tire_forces_reference,
)
from roadtruth.harness.truth.vehicle import load_vehicle


@pytest.fixture(scope="module")
def sedan():
    return load_vehicle("sedan")


def test_kernel_equals_numpy_reference(sedan) -> None:
    rng = np.random.default_rng(7)
    n = 4000
    alpha = rng.uniform(-0.5, 0.5, n)
    kappa = rng.uniform(-1.2, 1.0, n)
    fz = rng.uniform(-500.0, 9000.0, n)
    mu = rng.uniform(0.05, 1.5, n)
    shape = np.ascontiguousarray(np.tile(shape_array(sedan.tires.front, sedan.tires.rear), (n // 4, 1)))
    fz0 = np.full(n, 3800.0)
    for ls in (0.0, 0.2):
        fx, fy = np.empty(n), np.empty(n)
        tire_forces_kernel(alpha, kappa, fz, mu, shape, fz0, ls, fx, fy)
        rx, ry = tire_forces_reference(alpha, kappa, fz, mu, shape, fz0, ls)
        np.testing.assert_allclose(fx, rx, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(fy, ry, rtol=1e-12, atol=1e-9)
    assert np.all(fx[fz <= 0] == 0.0) and np.all(fy[fz <= 0] == 0.0)


@pytest.mark.parametrize("mu", [1.0, 0.6, 0.3, 0.1])
def test_small_slip_slope_is_BCD_and_kept_when_mu_changes(sedan, mu: float) -> None:
    t, fz = sedan.tires.front, 4000.0
    a = 1e-5
    _, fy = combined_slip_forces(t, a, 0.0, fz, mu)
    fx, _ = combined_slip_forces(t, 0.0, a, fz, mu)
    assert fy[0] / a == pytest.approx(t.By * t.Cy * fz, rel=1e-4)
    assert fx[0] / a == pytest.approx(t.Bx * t.Cx * fz, rel=1e-4)


@pytest.mark.parametrize("mu", [1.0, 0.5, 0.1])
def test_peak_force_is_mu_fz_at_mu_times_peak_slip(sedan, mu: float) -> None:
    t, fz = sedan.tires.rear, 3500.0
    alpha = np.linspace(0.0, 0.6, 6001)
    _, fy = combined_slip_forces(t, alpha, 0.0, fz, mu)
    assert fy.max() == pytest.approx(mu * fz, rel=1e-5)
    a_peak = math.atan(mu * peak_slip(t.By, t.Cy, t.Ey))  # the lateral slip is tan(alpha)
    assert alpha[np.argmax(fy)] == pytest.approx(a_peak, abs=2e-4)
    kappa = np.linspace(0.0, 0.5, 5001)
    fx, _ = combined_slip_forces(t, 0.0, kappa, fz, mu)
    assert fx.max() == pytest.approx(mu * fz, rel=1e-5)


def test_forces_are_odd_in_slip(sedan) -> None:
    t = sedan.tires.front
    fx1, fy1 = combined_slip_forces(t, 0.05, 0.0, 4000.0)
    fx2, fy2 = combined_slip_forces(t, -0.05, 0.0, 4000.0)
    assert fy1[0] > 0 and fy2[0] == pytest.approx(-fy1[0], rel=1e-12) and fx1[0] == 0.0


def test_combined_slip_lowers_lateral_force_under_braking(sedan) -> None:
    t = sedan.tires.front
    kappas = np.array([0.0, -0.02, -0.05, -0.1, -0.3])
    fx, fy = combined_slip_forces(t, math.radians(4.0), kappas, 4000.0)
    assert np.all(np.diff(fy) < 0.0)  # more braking slip, less side force
    assert np.all(fx[1:] < 0.0)
    assert np.all(np.hypot(fx, fy) <= 4000.0 * (1 + 1e-9))  # inside the friction circle


def test_load_sensitivity_lowers_peak_but_not_slope(sedan) -> None:
    t = sedan.tires.front
    alpha = np.linspace(0.0, 0.6, 3001)
    _, fy = combined_slip_forces(t, alpha, 0.0, 6000.0, fz_static_N=4000.0, load_sensitivity=0.2)
    assert fy.max() == pytest.approx(6000.0 * (1.0 - 0.2 * 0.5), rel=1e-4)
    _, fy0 = combined_slip_forces(t, 1e-5, 0.0, 6000.0, fz_static_N=4000.0, load_sensitivity=0.2)
    assert fy0[0] / 1e-5 == pytest.approx(t.By * t.Cy * 6000.0, rel=1e-4)


def test_relaxation_is_a_first_order_lag_with_time_constant_sigma_over_v() -> None:
    sigma, vx, dt = 0.3, 20.0, 0.001
    tau = sigma / vx
    a, n = 0.0, int(round(tau / dt))
    for _ in range(n):
        a = relax_kernel(a, 0.05, vx, sigma, dt)
    assert a == pytest.approx(0.05 * (1 - math.exp(-1)), rel=1e-9)  # 63 % after one time constant
    assert relax_kernel(0.01, 0.05, vx, 0.0, dt) == 0.05  # no relaxation length: no lag
    ref = relax_reference(np.array([0.0, 0.01]), np.array([0.05, 0.05]), np.array([vx, 5.0]), sigma, dt)
    assert ref[0] == relax_kernel(0.0, 0.05, vx, sigma, dt)
    assert ref[1] == relax_kernel(0.01, 0.05, 5.0, sigma, dt)


def test_radial_load_spring_damper_never_pulls() -> None:
    assert radial_load_kernel(0.01, 0.0, 250000.0, 300.0) == pytest.approx(2500.0)
    assert radial_load_kernel(0.01, 0.5, 250000.0, 300.0) == pytest.approx(2650.0)
    assert radial_load_kernel(-0.01, 0.0, 250000.0, 300.0) == 0.0
    assert radial_load_kernel(0.001, -10.0, 250000.0, 300.0) == 0.0
