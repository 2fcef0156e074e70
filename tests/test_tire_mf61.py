"""MF 6.1 kernel against an independent evaluation of the book's equations (Pacejka 2012, 4.E1–4.E78).

The reference below is written from the equation list, reads the coefficients BY NAME from the file's
parameters (not the kernel's vector), works in the file's ISO convention and converts at the edges
(α_ISO = −α, γ_ISO = −γ). It exists only here, to test the compiled kernel.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadtruth.harness.truth.tire_file import NONZERO_DEFAULTS, read_tire_file, shipped_tire_path
from roadtruth.harness.truth.tire_mf61 import (
    camber_stiffness,
    cornering_stiffness,
    longitudinal_stiffness,
    mf61_forces,
    mf61_pure_forces,
)

TIR = shipped_tire_path("mf61_205_60R15")


@pytest.fixture(scope="module")
def tire():
    return read_tire_file(TIR)


def _p(tire):
    """Coefficient lookup by name with the MF-Tyre 6.1 defaults (0, scaling 1, PKY4 = 2)."""
    params = tire.parameters
    return lambda name: float(params.get(name, NONZERO_DEFAULTS.get(name, 0.0)))


def _sign(x):
    return float(x > 0) - float(x < 0)


def reference(tire, fz, kappa, alpha, gamma, lmu_x=1.0, lmu_y=1.0, *, combined=True):
    """Independent plain-Python MF 6.1 (F_x, F_y, M_z), roadtruth convention in and out."""
    p = _p(tire)
    a_iso, g_iso = -alpha, -gamma
    Fz0p = p("LFZO") * p("FNOMIN")                                   # 4.E1
    dfz = (fz - Fz0p) / Fz0p                                         # 4.E2a
    dpi = (p("INFLPRES") - p("NOMPRES")) / p("NOMPRES")              # 4.E2b
    a_st = math.tan(a_iso)                                           # 4.E3 (V_cx > 0)
    g_st = math.sin(g_iso)                                           # 4.E4
    cos_pa = math.cos(a_iso)                                         # 4.E6
    LMUX, LMUY = p("LMUX") * lmu_x, p("LMUY") * lmu_y                # 4.E7 without speed dependence
    LMUXp = 10 * LMUX / (1 + 9 * LMUX)                               # 4.E8
    LMUYp = 10 * LMUY / (1 + 9 * LMUY)

    def mf(x, B, C, D, E):
        return D * math.sin(C * math.atan(B * x - E * (B * x - math.atan(B * x))))

    def fx0_of(k):
        SHx = (p("PHX1") + p("PHX2") * dfz) * p("LHX")               # 4.E17
        kx = k + SHx                                                 # 4.E10
        Cx = p("PCX1") * p("LCX")                                    # 4.E11
        mux = (p("PDX1") + p("PDX2") * dfz) * (1 + p("PPX3") * dpi + p("PPX4") * dpi ** 2) * (1 - p("PDX3") * g_st ** 2) * LMUX
        Dx = mux * fz                                                # 4.E12–13
        Ex = min((p("PEX1") + p("PEX2") * dfz + p("PEX3") * dfz ** 2) * (1 - p("PEX4") * _sign(kx)) * p("LEX"), 1.0)
        Kxk = fz * (p("PKX1") + p("PKX2") * dfz) * math.exp(p("PKX3") * dfz) * (1 + p("PPX1") * dpi + p("PPX2") * dpi ** 2) * p("LKX")
        Bx = Kxk / (Cx * Dx + 1e-6)                                  # 4.E16
        SVx = fz * (p("PVX1") + p("PVX2") * dfz) * p("LVX") * LMUXp  # 4.E18
        return mf(kx, Bx, Cx, Dx, Ex) + SVx, Kxk

    def fy0_of(g):
        Kya = (p("PKY1") * Fz0p * (1 + p("PPY1") * dpi) * (1 - p("PKY3") * abs(g))
               * math.sin(p("PKY4") * math.atan(fz / ((p("PKY2") + p("PKY5") * g ** 2) * (1 + p("PPY2") * dpi) * Fz0p))) * p("LKY"))
        Kyg0 = fz * (p("PKY6") + p("PKY7") * dfz) * (1 + p("PPY5") * dpi) * p("LKYC")   # 4.E30
        SVyg = fz * (p("PVY3") + p("PVY4") * dfz) * g * p("LKYC") * LMUYp              # 4.E28
        Kyap = Kya + 1e-6 * _sign(Kya)
        SHy = (p("PHY1") + p("PHY2") * dfz) * p("LHY") + (Kyg0 * g - SVyg) / Kyap     # 4.E27
        SVy = fz * (p("PVY1") + p("PVY2") * dfz) * p("LVY") * LMUYp + SVyg             # 4.E29
        ay = a_st + SHy                                                                # 4.E20
        Cy = p("PCY1") * p("LCY")                                                      # 4.E21
        muy = (p("PDY1") + p("PDY2") * dfz) * (1 + p("PPY3") * dpi + p("PPY4") * dpi ** 2) * (1 - p("PDY3") * g ** 2) * LMUY
        Dy = muy * fz                                                                  # 4.E22–23
        Ey = min((p("PEY1") + p("PEY2") * dfz) * (1 + p("PEY5") * g ** 2 - (p("PEY3") + p("PEY4") * g) * _sign(ay)) * p("LEY"), 1.0)
        By = Kya / (Cy * Dy + 1e-6)                                                    # 4.E26
        return mf(ay, By, Cy, Dy, Ey) + SVy, dict(Kya=Kyap, SHy=SHy, SVy=SVy, By=By, Cy=Cy, muy=muy)

    fx0, Kxk = fx0_of(kappa)
    fy0, y = fy0_of(g_st)
    fy0_g0 = fy0_of(0.0)[0]
    if combined:
        Bxa = (p("RBX1") + p("RBX3") * g_st ** 2) * math.cos(math.atan(p("RBX2") * kappa)) * p("LXAL")   # 4.E54
        Cxa, Exa, SHxa = p("RCX1"), min(p("REX1") + p("REX2") * dfz, 1.0), p("RHX1")
        a_s = a_st + SHxa
        Gxa = (math.cos(Cxa * math.atan(Bxa * a_s - Exa * (Bxa * a_s - math.atan(Bxa * a_s))))
               / math.cos(Cxa * math.atan(Bxa * SHxa - Exa * (Bxa * SHxa - math.atan(Bxa * SHxa)))))
        fx = Gxa * fx0                                                                  # 4.E50
        Byk = (p("RBY1") + p("RBY4") * g_st ** 2) * math.cos(math.atan(p("RBY2") * (a_st - p("RBY3")))) * p("LYKA")
        Cyk, Eyk = p("RCY1"), min(p("REY1") + p("REY2") * dfz, 1.0)
        SHyk = p("RHY1") + p("RHY2") * dfz
        ks = kappa + SHyk
        Gyk = (math.cos(Cyk * math.atan(Byk * ks - Eyk * (Byk * ks - math.atan(Byk * ks))))
               / math.cos(Cyk * math.atan(Byk * SHyk - Eyk * (Byk * SHyk - math.atan(Byk * SHyk)))))
        DVyk = y["muy"] * fz * (p("RVY1") + p("RVY2") * dfz + p("RVY3") * g_st) * math.cos(math.atan(p("RVY4") * a_st))
        SVyk = DVyk * math.sin(p("RVY5") * math.atan(p("RVY6") * kappa)) * p("LVYKA")  # 4.E66
        fy = Gyk * fy0 + SVyk                                                           # 4.E58
        kx_eq = Kxk / y["Kya"] * kappa
    else:
        fx, fy, Gyk, kx_eq = fx0, fy0, 1.0, 0.0
    # aligning moment
    R0 = p("UNLOADED_RADIUS")
    SHt = p("QHZ1") + p("QHZ2") * dfz + (p("QHZ3") + p("QHZ4") * dfz) * g_st         # 4.E35
    at = a_st + SHt                                                                    # 4.E34
    ar = a_st + y["SHy"] + y["SVy"] / y["Kya"]                                         # 4.E37–38
    at_eq = math.sqrt(at ** 2 + kx_eq ** 2) * _sign(at)                                # 4.E77
    ar_eq = math.sqrt(ar ** 2 + kx_eq ** 2) * _sign(ar)                                # 4.E78
    Bt = (p("QBZ1") + p("QBZ2") * dfz + p("QBZ3") * dfz ** 2) * (1 + p("QBZ4") * g_st + p("QBZ5") * abs(g_st)) * p("LKY") / LMUY
    Ct = p("QCZ1")
    Dt = fz * (R0 / Fz0p) * (p("QDZ1") + p("QDZ2") * dfz) * (1 - p("PPZ1") * dpi) * p("LTR") * (1 + p("QDZ3") * abs(g_st) + p("QDZ4") * g_st ** 2)
    Et = min((p("QEZ1") + p("QEZ2") * dfz + p("QEZ3") * dfz ** 2) * (1 + (p("QEZ4") + p("QEZ5") * g_st) * (2 / math.pi) * math.atan(Bt * Ct * at)), 1.0)
    t = Dt * math.cos(Ct * math.atan(Bt * at_eq - Et * (Bt * at_eq - math.atan(Bt * at_eq)))) * cos_pa   # 4.E73
    Br = p("QBZ9") * p("LKY") / LMUY + p("QBZ10") * y["By"] * y["Cy"]                  # 4.E45
    Dr = fz * R0 * ((p("QDZ6") + p("QDZ7") * dfz) * p("LRES") + ((p("QDZ8") + p("QDZ9") * dfz) * (1 + p("PPZ2") * dpi)
                    + (p("QDZ10") + p("QDZ11") * dfz) * abs(g_st)) * g_st * p("LKZC")) * LMUY * cos_pa            # 4.E47
    Mzr = Dr * math.cos(math.atan(Br * ar_eq)) * cos_pa                                # 4.E75
    if not combined:
        return fx, fy, -t * fy0_g0 + Mzr                                               # 4.E31–32
    s = R0 * (p("SSZ1") + p("SSZ2") * fy / Fz0p + (p("SSZ3") + p("SSZ4") * dfz) * g_st) * p("LS")   # 4.E76
    return fx, fy, -t * (Gyk * fy0_g0) + Mzr + s * fx                                  # 4.E71–72, 4.E74


def _samples(tire, n=40, seed=7):
    rng = np.random.default_rng(seed)
    fz = rng.uniform(max(tire.fzmin_N, 500.0), 8000.0, n)
    kappa = rng.uniform(-0.3, 0.3, n)
    alpha = rng.uniform(-0.3, 0.3, n)
    gamma = rng.uniform(-0.1, 0.1, n)
    return [tuple(float(v) for v in row) for row in zip(fz, kappa, alpha, gamma, strict=True)]


def test_pure_slip_equals_independent_evaluation(tire):
    for fz, kappa, alpha, gamma in _samples(tire):
        got = mf61_pure_forces(tire.coef, fz, kappa, alpha, gamma, 20.0, 1.0, 1.0)
        want = reference(tire, fz, kappa, alpha, gamma, combined=False)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9, err_msg=f"fz={fz} k={kappa} a={alpha} g={gamma}")


def test_combined_slip_equals_independent_evaluation(tire):
    for fz, kappa, alpha, gamma in _samples(tire, seed=11):
        for lmu in (1.0, 0.4):
            got = mf61_forces(tire.coef, fz, kappa, alpha, gamma, 20.0, lmu, lmu)
            want = reference(tire, fz, kappa, alpha, gamma, lmu, lmu)
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9, err_msg=f"fz={fz} k={kappa} a={alpha} g={gamma}")


def test_braking_lowers_side_force(tire):
    """G_yκ < 1: at a given α, braking (κ < 0) or driving lowers |F_y| below the pure-slip value."""
    fz, alpha = 4000.0, math.radians(4.0)
    fy_pure = mf61_pure_forces(tire.coef, fz, 0.0, alpha, 0.0, 20.0, 1.0, 1.0)[1]
    for kappa in (-0.2, -0.05, 0.05, 0.2):
        fy = mf61_forces(tire.coef, fz, kappa, alpha, 0.0, 20.0, 1.0, 1.0)[1]
        assert 0.0 < fy < 0.95 * fy_pure, (kappa, fy, fy_pure)
    assert mf61_forces(tire.coef, fz, 0.0, alpha, 0.0, 20.0, 1.0, 1.0)[1] == pytest.approx(fy_pure, rel=1e-12)


def test_camber_thrust_sign_and_magnitude(tire):
    """γ = +2° (top toward +y) at α = 0 pushes toward +y for this file (PKY6 < 0 in ISO)."""
    fz, g = 4000.0, math.radians(2.0)
    fy0 = mf61_forces(tire.coef, fz, 0.0, 0.0, 0.0, 20.0, 1.0, 1.0)[1]
    fy = mf61_forces(tire.coef, fz, 0.0, 0.0, g, 20.0, 1.0, 1.0)[1]
    assert fy == pytest.approx(reference(tire, fz, 0.0, 0.0, g)[1], rel=1e-9)
    thrust = fy - fy0
    assert thrust > 0.0
    # magnitude: the file's camber stiffness K_yγ0 = F_z (PKY6 + PKY7 dfz) within the curve's nonlinearity
    assert thrust == pytest.approx(camber_stiffness(tire, fz) * g, rel=0.05)
    assert camber_stiffness(tire, fz) == pytest.approx(-fz * tire.parameters["PKY6"], rel=1e-12)  # dfz = 0 at FNOMIN
    mirrored = mf61_forces(tire.coef, fz, 0.0, 0.0, -g, 20.0, 1.0, 1.0)[1] - fy0
    assert mirrored < 0.0


def test_aligning_moment_follows_the_files_curve(tire):
    fz = 4000.0
    alphas = np.radians(np.linspace(0.25, 20.0, 80))
    mz = np.array([mf61_forces(tire.coef, fz, 0.0, a, 0.0, 20.0, 1.0, 1.0)[2] for a in alphas])
    fy = np.array([mf61_forces(tire.coef, fz, 0.0, a, 0.0, 20.0, 1.0, 1.0)[1] for a in alphas])
    assert np.all(mz[:8] < 0.0)  # α > 0 (F_y > 0): M_z turns the wheel toward its velocity
    trail = -mz[0] / fy[0]
    assert 0.01 < trail < 0.06  # pneumatic trail of a car tire at small slip [m]
    i_peak = int(np.argmin(mz))
    crossing = np.flatnonzero(np.diff(np.sign(mz)) > 0)
    assert crossing.size == 1 and crossing[0] > i_peak  # one zero crossing, beyond the |M_z| peak
    assert alphas[crossing[0]] < alphas[int(np.argmax(fy))] + math.radians(5.0)  # near the F_y peak, as typical
    mz_neg = np.array([mf61_forces(tire.coef, fz, 0.0, -a, 0.0, 20.0, 1.0, 1.0)[2] for a in alphas[:8]])
    assert np.all(mz_neg > 0.0)


def test_friction_factor_scales_the_peak_not_the_stiffness(tire):
    fz = 4000.0
    alphas = np.radians(np.linspace(0.0, 25.0, 400))
    peak = {lm: max(mf61_forces(tire.coef, fz, 0.0, a, 0.0, 20.0, 1.0, lm)[1] for a in alphas) for lm in (1.0, 0.5)}
    offset = {lm: mf61_forces(tire.coef, fz, 0.0, 0.0, 0.0, 20.0, 1.0, lm)[1] for lm in (1.0, 0.5)}
    assert (peak[0.5] - offset[0.5]) / (peak[1.0] - offset[1.0]) == pytest.approx(0.5, rel=0.03)
    # slope at the curve's own origin α_y = 0 (α = S_Hy, γ = 0) is K_yα, independent of lmu_y
    dfz = (fz - tire.fnomin_N) / tire.fnomin_N
    a0 = tire.parameters["PHY1"] + tire.parameters["PHY2"] * dfz  # roadtruth α = −α_ISO with α_ISO = −S_Hy
    h = 1e-6
    slopes = {}
    for lm in (1.0, 0.5):
        fp = mf61_forces(tire.coef, fz, 0.0, math.atan(math.tan(a0) + h), 0.0, 20.0, 1.0, lm)[1]
        fm = mf61_forces(tire.coef, fz, 0.0, math.atan(math.tan(a0) - h), 0.0, 20.0, 1.0, lm)[1]
        slopes[lm] = (fp - fm) / (2 * h)
    assert slopes[0.5] == pytest.approx(slopes[1.0], rel=1e-6)
    assert slopes[1.0] == pytest.approx(cornering_stiffness(tire, fz), rel=1e-6)
    # longitudinal: same at κ_x = 0 (κ = −S_Hx)
    k0 = -(tire.parameters["PHX1"] + tire.parameters["PHX2"] * dfz)
    kslope = {lm: (mf61_pure_forces(tire.coef, fz, k0 + h, 0.0, 0.0, 20.0, lm, 1.0)[0]
                   - mf61_pure_forces(tire.coef, fz, k0 - h, 0.0, 0.0, 20.0, lm, 1.0)[0]) / (2 * h) for lm in (1.0, 0.5)}
    assert kslope[0.5] == pytest.approx(kslope[1.0], rel=1e-6)
    assert kslope[1.0] == pytest.approx(longitudinal_stiffness(tire, fz), rel=1e-6)


def test_no_load_no_force_and_finite_at_standstill(tire):
    for fz in (0.0, -100.0):
        assert mf61_forces(tire.coef, fz, 0.1, 0.1, 0.05, 20.0, 1.0, 1.0) == (0.0, 0.0, 0.0)
        assert mf61_pure_forces(tire.coef, fz, 0.1, 0.1, 0.05, 20.0, 1.0, 1.0) == (0.0, 0.0, 0.0)
    for vx in (0.0, 1e-9, -1e-9):
        assert all(math.isfinite(v) for v in mf61_forces(tire.coef, 4000.0, 0.1, 0.1, 0.05, vx, 1.0, 1.0))
    # vx only gives the rolling direction: same forces at any forward speed
    assert mf61_forces(tire.coef, 4000.0, 0.1, 0.1, 0.05, 0.0, 1.0, 1.0) == mf61_forces(tire.coef, 4000.0, 0.1, 0.1, 0.05, 30.0, 1.0, 1.0)


def test_slip_sign_convention(tire):
    fx, fy, _ = mf61_forces(tire.coef, 4000.0, 0.05, math.radians(3.0), 0.0, 20.0, 1.0, 1.0)
    assert fx > 0.0 and fy > 0.0
    fx, fy, _ = mf61_forces(tire.coef, 4000.0, -0.05, -math.radians(3.0), 0.0, 20.0, 1.0, 1.0)
    assert fx < 0.0 and fy < 0.0
