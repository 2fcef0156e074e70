"""Magic Formula 6.1 steady-state tire forces and aligning moment from a .tir file (compiled kernel).

Equations: Pacejka, *Tire and Vehicle Dynamics*, 3rd ed. 2012, sec. 4.3.2, eqs. (4.E1)–(4.E78), the
MF-Tyre 6.1 set (Besselink, Schmeitz and Pacejka 2010) without turn slip (all ζ_i = 1) and without the
speed dependence of friction (LMUV): λ*_μ = λ_μ, λ'_μ = A_μ λ*_μ/(1 + (A_μ − 1) λ*_μ), A_μ = 10 (4.E7–8).
MF 6.2 files are evaluated with the same force and moment equations (6.2 adds loaded-radius,
overturning/rolling-moment and contact-patch models that the truth does not take from the file).

Conventions. The file's coefficients are in the ISO W-axis convention (x forward, y left, z up; slip
angle α_ISO > 0 gives F_y < 0, so PKY1 < 0; inclination γ_ISO > 0 is a rotation about +x, i.e. the top
of the wheel toward −y). Roadtruth's arguments (docs/PHYSICS.md, CONTRACT.md) are mapped as

    α_ISO = −α,    γ_ISO = −γ,    κ_ISO = κ,    F_x, F_y, M_z unchanged (same axes).

So α > 0 gives F_y > 0, γ > 0 (top toward +y) gives camber thrust toward +y, and M_z < 0 at small
α > 0 (pneumatic trail). Inside, α* = tan α_ISO · sgn V_cx (4.E3), γ* = sin γ_ISO (4.E4) and
cos'α = sgn V_cx · cos α (4.E6 with V_c = |V_cx|/cos α and ε_V → 0); V_cx = 0 counts as rolling
forward, so a standstill caller gets the forces of the slips it passes (no low-speed logic here).

Road friction and the vehicle's grip enter as ``lmu_x``, ``lmu_y`` multiplying LMUX, LMUY: they scale
the peaks D_x, D_y (and M_zr, the Mz slope factors through λ*_μy) while the slip stiffnesses K_xκ,
K_yα do not depend on them (B = K/(C D)), as in MF 6.1. F_z ≤ 0 gives all zero.

Layout: ``_pure`` / ``_combined`` are the compiled equations (ISO inside), ``mf61_forces`` and
``mf61_pure_forces`` the compiled entry points (roadtruth convention) the stepping loop calls, and
``cornering_stiffness`` / ``longitudinal_stiffness`` / ``camber_stiffness`` plain-Python wrappers.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.tire import jit
from roadtruth.harness.truth.tire_file import MF61_NAMES, N_MF61_COEF, TireFile

# Indices into the coefficient vector (layout roadtruth.harness.truth.tire_file.MF61_NAMES; checked below).
(FNOMIN, R0, LFZO, LCX, LMUX, LEX, LKX, LHX, LVX, LCY, LMUY, LEY, LKY, LKYC, LKZC, LHY, LVY, LTR, LRES,
 LXAL, LYKA, LVYKA, LS,
 PCX1, PDX1, PDX2, PDX3, PEX1, PEX2, PEX3, PEX4, PKX1, PKX2, PKX3, PHX1, PHX2, PVX1, PVX2, PPX1, PPX2,
 PPX3, PPX4, RBX1, RBX2, RBX3, RCX1, REX1, REX2, RHX1,
 PCY1, PDY1, PDY2, PDY3, PEY1, PEY2, PEY3, PEY4, PEY5, PKY1, PKY2, PKY3, PKY4, PKY5, PKY6, PKY7, PHY1,
 PHY2, PVY1, PVY2, PVY3, PVY4, PPY1, PPY2, PPY3, PPY4, PPY5, RBY1, RBY2, RBY3, RBY4, RCY1, REY1, REY2,
 RHY1, RHY2, RVY1, RVY2, RVY3, RVY4, RVY5, RVY6,
 QBZ1, QBZ2, QBZ3, QBZ4, QBZ5, QBZ9, QBZ10, QCZ1, QDZ1, QDZ2, QDZ3, QDZ4, QDZ6, QDZ7, QDZ8, QDZ9, QDZ10,
 QDZ11, QEZ1, QEZ2, QEZ3, QEZ4, QEZ5, QHZ1, QHZ2, QHZ3, QHZ4, SSZ1, SSZ2, SSZ3, SSZ4, PPZ1, PPZ2,
 DPI) = range(N_MF61_COEF)
assert DPI == MF61_NAMES.index("DPI") and PCY1 == MF61_NAMES.index("PCY1") and QBZ1 == MF61_NAMES.index("QBZ1")

#: Guards of the MF-Tyre equations against division by zero (ε_x, ε_y, ε_K).
EPS = 1e-6
#: A_μ of the degressive friction scaling λ'_μ (4.E8).
A_MU = 10.0


@jit
def _sgn(x: float) -> float:
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0


@jit
def _mf(x: float, B: float, C: float, D: float, E: float) -> float:
    """D sin(C atan(B x − E (B x − atan B x)))."""
    bx = B * x
    return D * math.sin(C * math.atan(bx - E * (bx - math.atan(bx))))


@jit
def _cos_atan(x: float) -> float:
    """cos(atan x) = 1/√(1 + x²), without the two transcendental calls."""
    return 1.0 / math.sqrt(1.0 + x * x)


@jit
def _cos_mf(x: float, B: float, C: float, E: float) -> float:
    """cos(C atan(B x − E (B x − atan B x))): the combined-slip weighting shape (4.E52, 4.E62)."""
    bx = B * x
    return math.cos(C * math.atan(bx - E * (bx - math.atan(bx))))


@jit
def _kya(c: np.ndarray, fz: float, gs: float) -> float:
    """Cornering stiffness K_yα [N/rad], ISO sign (4.E25); gs = γ*."""
    fz0 = c[LFZO] * c[FNOMIN]
    dpi = c[DPI]
    return (c[PKY1] * fz0 * (1.0 + c[PPY1] * dpi) * (1.0 - c[PKY3] * abs(gs))
            * math.sin(c[PKY4] * math.atan(fz / ((c[PKY2] + c[PKY5] * gs * gs) * (1.0 + c[PPY2] * dpi) * fz0)))
            * c[LKY])


@jit
def _kxk(c: np.ndarray, fz: float) -> float:
    """Longitudinal slip stiffness K_xκ [N] (4.E15)."""
    fz0 = c[LFZO] * c[FNOMIN]
    dfz = (fz - fz0) / fz0
    dpi = c[DPI]
    return fz * (c[PKX1] + c[PKX2] * dfz) * math.exp(c[PKX3] * dfz) * (1.0 + c[PPX1] * dpi + c[PPX2] * dpi * dpi) * c[LKX]


@jit
def _kyg0(c: np.ndarray, fz: float) -> float:
    """Camber stiffness K_yγ0 [N/rad], ISO sign (4.E30)."""
    fz0 = c[LFZO] * c[FNOMIN]
    dfz = (fz - fz0) / fz0
    return fz * (c[PKY6] + c[PKY7] * dfz) * (1.0 + c[PPY5] * c[DPI]) * c[LKYC]


@jit
def _fy0(c: np.ndarray, fz: float, a_s: float, gs: float, lmuy: float) -> tuple[float, float, float, float, float, float]:
    """Pure lateral force (4.E19–4.E30), ISO. Returns (F_y0, μ_y, B_y, C_y, K_yα, S_Hy + S_Vy/K'_yα)."""
    fz0 = c[LFZO] * c[FNOMIN]
    dfz = (fz - fz0) / fz0
    dpi = c[DPI]
    lmuy_p = A_MU * lmuy / (1.0 + (A_MU - 1.0) * lmuy)
    kya = _kya(c, fz, gs)
    kya_p = kya + EPS * (1.0 if kya >= 0.0 else -1.0)
    svyg = fz * (c[PVY3] + c[PVY4] * dfz) * gs * c[LKYC] * lmuy_p
    shy = (c[PHY1] + c[PHY2] * dfz) * c[LHY] + (_kyg0(c, fz) * gs - svyg) / kya_p
    svy = fz * (c[PVY1] + c[PVY2] * dfz) * c[LVY] * lmuy_p + svyg
    ay = a_s + shy
    cy = c[PCY1] * c[LCY]
    muy = (c[PDY1] + c[PDY2] * dfz) * (1.0 + c[PPY3] * dpi + c[PPY4] * dpi * dpi) * (1.0 - c[PDY3] * gs * gs) * lmuy
    dy = muy * fz
    ey = min((c[PEY1] + c[PEY2] * dfz) * (1.0 + c[PEY5] * gs * gs - (c[PEY3] + c[PEY4] * gs) * _sgn(ay)) * c[LEY], 1.0)
    by = kya / (cy * dy + EPS)
    return _mf(ay, by, cy, dy, ey) + svy, muy, by, cy, kya, shy + svy / kya_p


@jit
def _fx0(c: np.ndarray, fz: float, kappa: float, gs: float, lmux: float) -> float:
    """Pure longitudinal force (4.E9–4.E18)."""
    fz0 = c[LFZO] * c[FNOMIN]
    dfz = (fz - fz0) / fz0
    dpi = c[DPI]
    lmux_p = A_MU * lmux / (1.0 + (A_MU - 1.0) * lmux)
    kx = kappa + (c[PHX1] + c[PHX2] * dfz) * c[LHX]
    svx = fz * (c[PVX1] + c[PVX2] * dfz) * c[LVX] * lmux_p
    cx = c[PCX1] * c[LCX]
    mux = (c[PDX1] + c[PDX2] * dfz) * (1.0 + c[PPX3] * dpi + c[PPX4] * dpi * dpi) * (1.0 - c[PDX3] * gs * gs) * lmux
    dx = mux * fz
    ex = min((c[PEX1] + c[PEX2] * dfz + c[PEX3] * dfz * dfz) * (1.0 - c[PEX4] * _sgn(kx)) * c[LEX], 1.0)
    bx = _kxk(c, fz) / (cx * dx + EPS)
    return _mf(kx, bx, cx, dx, ex) + svx


@jit
def _trail_and_residual(c: np.ndarray, fz: float, a_s: float, gs: float, cos_a: float, sgn_vx: float, lmuy: float,
                        by: float, cy: float, alpha_r: float, kx_equiv: float) -> tuple[float, float]:
    """Pneumatic trail t (4.E33–4.E44, 4.E73) and residual moment M_zr (4.E36, 4.E45–4.E47).

    ``alpha_r`` = α* + S_Hf (4.E37–38); ``kx_equiv`` = (K_xκ/K'_yα) κ, zero for pure slip, turns α_t, α_r
    into the equivalent slips α_t,eq, α_r,eq (4.E77–78).
    """
    fz0 = c[LFZO] * c[FNOMIN]
    dfz = (fz - fz0) / fz0
    dpi = c[DPI]
    r0 = c[R0]
    sht = c[QHZ1] + c[QHZ2] * dfz + (c[QHZ3] + c[QHZ4] * dfz) * gs
    at = a_s + sht
    bt = max((c[QBZ1] + c[QBZ2] * dfz + c[QBZ3] * dfz * dfz) * (1.0 + c[QBZ4] * gs + c[QBZ5] * abs(gs)) * c[LKY] / lmuy, 0.0)
    ct = c[QCZ1]
    dt = (fz * (r0 / fz0) * (c[QDZ1] + c[QDZ2] * dfz) * (1.0 - c[PPZ1] * dpi) * c[LTR] * sgn_vx
          * (1.0 + c[QDZ3] * abs(gs) + c[QDZ4] * gs * gs))
    et = min((c[QEZ1] + c[QEZ2] * dfz + c[QEZ3] * dfz * dfz)
             * (1.0 + (c[QEZ4] + c[QEZ5] * gs) * (2.0 / math.pi) * math.atan(bt * ct * at)), 1.0)
    at_eq = math.sqrt(at * at + kx_equiv * kx_equiv) * _sgn(at)
    ar_eq = math.sqrt(alpha_r * alpha_r + kx_equiv * kx_equiv) * _sgn(alpha_r)
    bta = bt * at_eq
    t = dt * math.cos(ct * math.atan(bta - et * (bta - math.atan(bta)))) * cos_a
    br = c[QBZ9] * c[LKY] / lmuy + c[QBZ10] * by * cy
    dr = (fz * r0 * ((c[QDZ6] + c[QDZ7] * dfz) * c[LRES]
                     + ((c[QDZ8] + c[QDZ9] * dfz) * (1.0 + c[PPZ2] * dpi) + (c[QDZ10] + c[QDZ11] * dfz) * abs(gs))
                     * gs * c[LKZC]) * lmuy * sgn_vx * cos_a)
    mzr = dr * _cos_atan(br * ar_eq) * cos_a
    return t, mzr


@jit
def _iso_inputs(alpha: float, gamma: float, vx: float) -> tuple[float, float, float, float]:
    """Roadtruth (α, γ, v_x) → ISO α*, γ*, cos'α and sgn V_cx (V_cx = 0 counts as forward)."""
    sgn_vx = 1.0 if vx >= 0.0 else -1.0
    a_iso = -alpha
    return math.tan(a_iso) * sgn_vx, math.sin(-gamma), math.cos(a_iso) * sgn_vx, sgn_vx


@jit
def mf61_pure_forces(coef: np.ndarray, fz: float, kappa: float, alpha: float, gamma: float, vx: float,
                     lmu_x: float, lmu_y: float) -> tuple[float, float, float]:
    """Pure-slip (F_x0(κ), F_y0(α), M_z0(α)) [N, N, N m] in roadtruth's convention (no combined-slip reduction).

    M_z0 = −t_0 F'_y0 + M_zr0 (4.E31–32) with F'_y0 the pure lateral force at γ = 0 (MF-Tyre 6.1: camber
    acts on M_z through M_zr and S_Ht only, as in (4.E74)).
    """
    if fz <= 0.0:
        return 0.0, 0.0, 0.0
    a_s, gs, cos_a, sgn_vx = _iso_inputs(alpha, gamma, vx)
    lmux = coef[LMUX] * lmu_x
    lmuy = coef[LMUY] * lmu_y
    fx0 = _fx0(coef, fz, kappa, gs, lmux)
    fy0, _muy, by, cy, _kya_v, shf = _fy0(coef, fz, a_s, gs, lmuy)
    fy0_g0 = fy0 if gs == 0.0 else _fy0(coef, fz, a_s, 0.0, lmuy)[0]
    t, mzr = _trail_and_residual(coef, fz, a_s, gs, cos_a, sgn_vx, lmuy, by, cy, a_s + shf, 0.0)
    return fx0, fy0, -t * fy0_g0 + mzr


@jit
def mf61_forces(coef: np.ndarray, fz: float, kappa: float, alpha: float, gamma: float, vx: float,
                lmu_x: float, lmu_y: float) -> tuple[float, float, float]:
    """Combined-slip (F_x, F_y, M_z) [N, N, N m] of one MF 6.1 tire, roadtruth convention.

    Parameters: ``coef`` = ``TireFile.coef``; normal load ``fz`` [N]; slip ratio ``kappa`` [1]; slip angle
    ``alpha`` [rad] (> 0 gives F_y > 0); inclination ``gamma`` [rad] (> 0 = top toward +y); ``vx``
    longitudinal contact-point speed [m/s] (only its direction is used); ``lmu_x``, ``lmu_y`` friction
    factors multiplying LMUX, LMUY (road μ × the vehicle's grip).

    F_x = G_xα F_x0 (4.E50–57), F_y = G_yκ F_y0 + S_Vyκ (4.E58–67),
    M_z = −t F'_y + M_zr + s F_x (4.E71–78) with F'_y = G_yκ F_y0(γ = 0).
    """
    if fz <= 0.0:
        return 0.0, 0.0, 0.0
    c = coef
    a_s, gs, cos_a, sgn_vx = _iso_inputs(alpha, gamma, vx)
    lmux = c[LMUX] * lmu_x
    lmuy = c[LMUY] * lmu_y
    fz0 = c[LFZO] * c[FNOMIN]
    dfz = (fz - fz0) / fz0
    fx0 = _fx0(c, fz, kappa, gs, lmux)
    fy0, muy, by, cy, kya, shf = _fy0(c, fz, a_s, gs, lmuy)
    # F_x, combined (4.E50–57)
    shxa = c[RHX1]
    bxa = (c[RBX1] + c[RBX3] * gs * gs) * _cos_atan(c[RBX2] * kappa) * c[LXAL]
    cxa = c[RCX1]
    exa = min(c[REX1] + c[REX2] * dfz, 1.0)
    gxa = _cos_mf(a_s + shxa, bxa, cxa, exa) / _cos_mf(shxa, bxa, cxa, exa)
    fx = gxa * fx0
    # F_y, combined (4.E58–67)
    shyk = c[RHY1] + c[RHY2] * dfz
    byk = (c[RBY1] + c[RBY4] * gs * gs) * _cos_atan(c[RBY2] * (a_s - c[RBY3])) * c[LYKA]
    cyk = c[RCY1]
    eyk = min(c[REY1] + c[REY2] * dfz, 1.0)
    ks = kappa + shyk
    gyk = _cos_mf(ks, byk, cyk, eyk) / _cos_mf(shyk, byk, cyk, eyk)
    dvyk = muy * fz * (c[RVY1] + c[RVY2] * dfz + c[RVY3] * gs) * _cos_atan(c[RVY4] * a_s)
    svyk = dvyk * math.sin(c[RVY5] * math.atan(c[RVY6] * kappa)) * c[LVYKA]
    fy = gyk * fy0 + svyk
    # M_z, combined (4.E71–78)
    kya_p = kya + EPS * (1.0 if kya >= 0.0 else -1.0)
    kx_equiv = _kxk(c, fz) / kya_p * kappa
    t, mzr = _trail_and_residual(c, fz, a_s, gs, cos_a, sgn_vx, lmuy, by, cy, a_s + shf, kx_equiv)
    # F'_y0 at γ = 0 (4.E74); the same as F_y0 when the wheel is upright
    fy_prime = gyk * (fy0 if gs == 0.0 else _fy0(c, fz, a_s, 0.0, lmuy)[0])
    s = c[R0] * (c[SSZ1] + c[SSZ2] * (fy / fz0) + (c[SSZ3] + c[SSZ4] * dfz) * gs) * c[LS]
    mz = -t * fy_prime + mzr + s * fx
    return fx, fy, mz


# ---- slopes at zero slip (setup time, plain Python) ------------------------------------------------------

def cornering_stiffness(tirefile: TireFile, fz: float) -> float:
    """Cornering stiffness dF_y/dα at γ = 0 [N/rad], roadtruth sign (> 0): −K_yα of (4.E25).

    This is the Magic Formula's slip stiffness B_y C_y D_y (the slope through the curve's shifted origin),
    independent of the friction factors.
    """
    return -float(_kya(tirefile.coef, float(fz), 0.0)) if fz > 0.0 else 0.0


def longitudinal_stiffness(tirefile: TireFile, fz: float) -> float:
    """Longitudinal slip stiffness dF_x/dκ [N], K_xκ of (4.E15)."""
    return float(_kxk(tirefile.coef, float(fz))) if fz > 0.0 else 0.0


def camber_stiffness(tirefile: TireFile, fz: float) -> float:
    """Camber stiffness dF_y/dγ at α = 0 [N/rad], roadtruth sign (γ > 0 = top toward +y): −K_yγ0 of (4.E30)."""
    return -float(_kyg0(tirefile.coef, float(fz))) if fz > 0.0 else 0.0
