"""Fiala brush tire: linear slopes, sliding limit, friction circle, brush trail, signs; the observers' MF fit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadtruth.harness.truth.tire_fiala import fiala_coefficients, fiala_forces
from roadtruth.harness.truth.tire_file import read_tire_file, shipped_tire_path
from roadtruth.harness.truth.tire_fit import (
    ALPHA_FIT_MAX_RAD,
    KAPPA_FIT_MAX,
    fit_axle_magic_formula,
    pure_slip_curves,
)
from roadtruth.harness.truth.tire_mf61 import cornering_stiffness, longitudinal_stiffness, mf61_forces

C_ALPHA, C_KAPPA, A, C_GAMMA = 80_000.0, 120_000.0, 0.07, 4_000.0
FZ = 4000.0


@pytest.fixture(scope="module")
def coef():
    return fiala_coefficients(C_ALPHA, C_KAPPA, A, C_GAMMA)


def test_linear_range_slopes(coef):
    h = 1e-7
    assert fiala_forces(coef, FZ, 0.0, h, 0.0, 1.0)[1] / h == pytest.approx(C_ALPHA, rel=1e-5)
    assert fiala_forces(coef, FZ, h, 0.0, 0.0, 1.0)[0] / h == pytest.approx(C_KAPPA, rel=1e-5)
    assert fiala_forces(coef, FZ, 0.0, 0.0, h, 1.0)[1] / h == pytest.approx(C_GAMMA, rel=1e-5)
    # slopes do not depend on μ (only the peak does)
    assert fiala_forces(coef, FZ, 0.0, h, 0.0, 0.3)[1] / h == pytest.approx(C_ALPHA, rel=1e-5)


def test_full_sliding_is_mu_fz(coef):
    for mu in (1.0, 0.4):
        alpha_sl = math.atan(3.0 * mu * FZ / C_ALPHA)  # sliding limit of the parabolic brush
        assert fiala_forces(coef, FZ, 0.0, 1.001 * alpha_sl, 0.0, mu)[1] == pytest.approx(mu * FZ, rel=1e-12)
        assert fiala_forces(coef, FZ, 0.0, 0.9 * alpha_sl, 0.0, mu)[1] < mu * FZ
        assert fiala_forces(coef, FZ, -1.0, 0.0, 0.0, mu)[0] == pytest.approx(-mu * FZ, rel=1e-12)  # locked wheel
        assert fiala_forces(coef, FZ, 0.5, 0.0, 0.0, mu)[0] == pytest.approx(mu * FZ, rel=1e-12)


def test_friction_circle_over_a_grid(coef):
    worst = 0.0
    for kappa in np.linspace(-1.0, 1.0, 41):
        for alpha in np.radians(np.linspace(-30.0, 30.0, 41)):
            for gamma in (-0.05, 0.0, 0.05):
                fx, fy, _ = fiala_forces(coef, FZ, float(kappa), float(alpha), gamma, 0.8)
                worst = max(worst, math.hypot(fx, fy) / (0.8 * FZ))
    assert worst <= 1.0 + 1e-12
    assert worst == pytest.approx(1.0, abs=1e-12)  # and the circle is reached
    # combined slip: braking at a given α lowers F_y
    fy_pure = fiala_forces(coef, FZ, 0.0, math.radians(2.0), 0.0, 1.0)[1]
    assert fiala_forces(coef, FZ, -0.03, math.radians(2.0), 0.0, 1.0)[1] < 0.9 * fy_pure


def test_brush_trail_and_aligning_moment(coef):
    alpha = 1e-5  # λ ≈ 7e-5: the trail is a/3 to 2e-4
    mz = fiala_forces(coef, FZ, 0.0, alpha, 0.0, 1.0)[2]
    assert mz == pytest.approx(-(A / 3.0) * C_ALPHA * math.tan(alpha), rel=1e-3)
    assert fiala_forces(coef, FZ, 0.0, -alpha, 0.0, 1.0)[2] == pytest.approx(-mz, rel=1e-12)
    alpha_sl = math.atan(3.0 * FZ / C_ALPHA)
    assert fiala_forces(coef, FZ, 0.0, alpha_sl * 0.999, 0.0, 1.0)[2] == pytest.approx(0.0, abs=1e-6 * FZ * A)
    assert fiala_forces(coef, FZ, 0.0, alpha_sl * 1.5, 0.0, 1.0)[2] == 0.0
    # |M_z| peaks inside the adhesion range, then falls to zero at the sliding limit
    alphas = np.linspace(1e-4, alpha_sl, 400)
    mzs = np.array([fiala_forces(coef, FZ, 0.0, float(a), 0.0, 1.0)[2] for a in alphas])
    assert 0.1 * alpha_sl < alphas[int(np.argmin(mzs))] < 0.5 * alpha_sl
    # camber thrust carries no trail
    assert fiala_forces(coef, FZ, 0.0, 0.0, 0.02, 1.0)[2] == 0.0


def test_sign_conventions_and_zero_load(coef):
    fx, fy, mz = fiala_forces(coef, FZ, 0.05, math.radians(2.0), 0.0, 1.0)
    assert fx > 0.0 and fy > 0.0 and mz < 0.0
    fx, fy, mz = fiala_forces(coef, FZ, -0.05, -math.radians(2.0), 0.0, 1.0)
    assert fx < 0.0 and fy < 0.0 and mz > 0.0
    assert fiala_forces(coef, FZ, 0.0, 0.0, 0.03, 1.0)[1] > 0.0  # top toward +y pushes toward +y
    assert fiala_forces(coef, 0.0, 0.1, 0.1, 0.0, 1.0) == (0.0, 0.0, 0.0)
    assert fiala_forces(coef, -5.0, 0.1, 0.1, 0.0, 1.0) == (0.0, 0.0, 0.0)
    assert fiala_forces(coef, FZ, 0.1, 0.1, 0.0, 0.0) == (0.0, 0.0, 0.0)
    assert fiala_forces(coef, FZ, 0.0, 0.0, 0.0, 1.0) == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        fiala_coefficients(-1.0, C_KAPPA, A)


def _mf(s, B, C, D, E):
    return D * np.sin(C * np.arctan(B * s - E * (B * s - np.arctan(B * s))))


def test_fit_reproduces_the_fiala_curve(coef):
    """The observers' simple MF fitted to the Fiala tire: exact slope, close curve.

    The parabolic brush's curve bends faster in the linear range and saturates with a kink at the
    sliding limit, which the Magic Formula shape cannot follow exactly: the least-squares fit is
    within 2 % of the peak in RMS and 5.5 % at worst.
    """
    for mu in (1.0, 0.5):
        fy, fx = pure_slip_curves(lambda fz, k, a, g, mu=mu: fiala_forces(coef, fz, k, a, g, mu), FZ)
        fit = fit_axle_magic_formula(fy, fx, FZ)
        assert fit.mu_y == pytest.approx(mu, rel=1e-9) and fit.mu_x == pytest.approx(mu, rel=1e-9)
        assert fit.By * fit.Cy * fit.mu_y * FZ == pytest.approx(C_ALPHA, rel=0.01)
        assert fit.Bx * fit.Cx * fit.mu_x * FZ == pytest.approx(C_KAPPA, rel=0.01)
        assert 0.5 <= min(fit.Cy, fit.Cx) and max(fit.Cy, fit.Cx) <= 3.0 and max(fit.Ey, fit.Ex) <= 1.0
        a = np.linspace(0.0, ALPHA_FIT_MAX_RAD, 300)
        k = np.linspace(0.0, KAPPA_FIT_MAX, 300)
        err_y = (_mf(a, fit.By, fit.Cy, mu * FZ, fit.Ey) - fy(a)) / (mu * FZ)
        err_x = (_mf(k, fit.Bx, fit.Cx, mu * FZ, fit.Ex) - fx(k)) / (mu * FZ)
        for err in (err_y, err_x):
            assert np.sqrt(np.mean(err ** 2)) < 0.02
            assert np.max(np.abs(err)) < 0.055


def test_fit_reproduces_the_shipped_tir_curve():
    """For the .tir file the MF shape fits to 0.1 % of the peak and keeps the file's slip stiffnesses."""
    tire = read_tire_file(shipped_tire_path("mf61_205_60R15"))
    fy, fx = pure_slip_curves(lambda fz, k, a, g: mf61_forces(tire.coef, fz, k, a, g, 20.0, 1.0, 1.0), FZ)
    fit = fit_axle_magic_formula(fy, fx, FZ)
    assert fit.By * fit.Cy * fit.mu_y * FZ == pytest.approx(cornering_stiffness(tire, FZ), rel=0.01)
    assert fit.Bx * fit.Cx * fit.mu_x * FZ == pytest.approx(longitudinal_stiffness(tire, FZ), rel=0.01)
    a = np.linspace(0.0, ALPHA_FIT_MAX_RAD, 200)
    odd = 0.5 * (fy(a) - fy(-a))
    assert np.max(np.abs(_mf(a, fit.By, fit.Cy, fit.mu_y * FZ, fit.Ey) - odd)) < 1e-3 * fit.mu_y * FZ
