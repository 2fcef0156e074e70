"""Analytic roll statics: hand-checkable limits of the roll gradient, load transfer, lift and rollover
thresholds, and an independent check of the model form against a virtual-work linearisation."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from roadtruth.harness.truth.suspension_statics import (
    banked_neutral_speed,
    load_transfer,
    roll_statics,
    rollover_threshold_with_roll,
    slide_inclination,
    static_stability_factor,
    wheel_lift,
)
from roadtruth.harness.truth.vehicle import G, VehicleParams, load_vehicle


@pytest.fixture(scope="module")
def sedan() -> VehicleParams:
    return load_vehicle("sedan")


def _with(v: VehicleParams, *, tire_k: float | None = None, **susp: float) -> VehicleParams:
    """The set with suspension fields replaced (roll centres set even before the field exists)."""
    s = v.suspension
    known = {k: val for k, val in susp.items() if k in {f.name for f in dataclasses.fields(s)}}
    s = dataclasses.replace(s, **known)
    for k, val in susp.items():
        if k not in known:
            object.__setattr__(s, k, val)
    tires = v.tires if tire_k is None else dataclasses.replace(v.tires, radial_stiffness_Npm=tire_k)
    return v.with_overrides(suspension=s, tires=tires)


def _rigid(v: VehicleParams, **susp: float) -> VehicleParams:
    return _with(v, tire_k=5e6 * 1e6, stiffness_f_Npm=1e12, stiffness_r_Npm=1e12, **susp)


def test_roll_stiffness_is_springs_plus_twice_the_bar_in_series_with_tires(sedan) -> None:
    rs = roll_statics(sedan)
    t, s = sedan.track_f_m, sedan.suspension
    ks = t**2 / 2 * (s.stiffness_f_Npm + 2 * s.arb_f_Npm)  # the bar acts on the travel DIFFERENCE
    kt = t**2 / 2 * sedan.tires.radial_stiffness_Npm
    assert rs.front.suspension_roll_stiffness_Nmprad == pytest.approx(ks, rel=1e-12)
    assert rs.front.roll_stiffness_Nmprad == pytest.approx(1.0 / (1.0 / ks + 1.0 / kt), rel=1e-12)
    assert rs.roll_stiffness_Nmprad > rs.front.roll_stiffness_Nmprad  # the rear adds, never subtracts


def test_sprung_mass_and_cg(sedan) -> None:
    rs = roll_statics(sedan)
    assert rs.sprung_mass_kg == pytest.approx(sedan.mass_kg - 4 * sedan.unsprung_mass_kg)
    assert rs.front.sprung_mass_kg + rs.rear.sprung_mass_kg == pytest.approx(rs.sprung_mass_kg, rel=1e-12)
    # The corners hang below the CG: the sprung CG is above the car's.
    h_u = sedan.wheel_radius_m - rs.front.static_wheel_load_N / sedan.tires.radial_stiffness_Npm
    assert rs.front.wheel_centre_height_m == pytest.approx(h_u)
    whole = (rs.sprung_mass_kg * rs.sprung_cg_height_m + rs.front.unsprung_mass_kg * rs.front.wheel_centre_height_m
             + rs.rear.unsprung_mass_kg * rs.rear.wheel_centre_height_m) / sedan.mass_kg
    assert whole == pytest.approx(sedan.h_cg_m, rel=1e-12) and rs.sprung_cg_height_m > sedan.h_cg_m


def test_zero_roll_centres_make_all_sprung_transfer_elastic(sedan) -> None:
    v = _with(sedan, roll_centre_f_m=0.0, roll_centre_r_m=0.0)
    rs, lt = roll_statics(v), load_transfer(v)
    assert lt.front.geometric == 0.0 and lt.rear.geometric == 0.0
    assert rs.roll_axis_height_m == 0.0 and rs.roll_arm_m == pytest.approx(rs.sprung_cg_height_m)
    # Textbook: phi' = m_s h_s / (K - m_s g h_s), by hand.
    k = rs.roll_stiffness_Nmprad
    ms, hs = rs.sprung_mass_kg, rs.sprung_cg_height_m
    assert rs.textbook_roll_gradient_radpmps2 == pytest.approx(ms * hs / (k - ms * G * hs), rel=1e-12)
    # The elastic parts split by roll stiffness.
    ratio = lt.front.elastic * sedan.track_f_m / (lt.rear.elastic * sedan.track_r_m)
    assert ratio == pytest.approx(rs.front.roll_stiffness_Nmprad / rs.rear.roll_stiffness_Nmprad, rel=1e-12)


def test_roll_centre_at_the_sprung_cg_gives_no_roll_and_only_geometric_transfer(sedan) -> None:
    h = roll_statics(_rigid(sedan)).sprung_cg_height_m  # rigid tires: the wheel centres sit at R
    v = _rigid(sedan, roll_centre_f_m=h, roll_centre_r_m=h)
    rs, lt = roll_statics(v), load_transfer(v)
    assert rs.roll_arm_m == pytest.approx(0.0, abs=1e-12)
    assert rs.textbook_roll_gradient_radpmps2 == pytest.approx(0.0, abs=1e-15)
    assert lt.front.elastic == pytest.approx(0.0, abs=1e-9) and lt.rear.elastic == pytest.approx(0.0, abs=1e-9)
    assert lt.front.geometric == pytest.approx(rs.front.sprung_mass_kg * h / sedan.track_f_m, rel=1e-12)


def test_symmetric_car_splits_elastic_transfer_by_stiffness(sedan) -> None:
    sym = _with(sedan.with_overrides(lf_m=1.3, lr_m=1.3), arb_f_Npm=30000.0, arb_r_Npm=10000.0,
                roll_centre_f_m=0.0, roll_centre_r_m=0.0)
    rs, lt = roll_statics(sym), load_transfer(sym)
    assert rs.front.sprung_mass_kg == pytest.approx(rs.rear.sprung_mass_kg)
    kf, kr = rs.front.roll_stiffness_Nmprad, rs.rear.roll_stiffness_Nmprad
    assert kf > kr
    assert lt.front.elastic / lt.rear.elastic == pytest.approx(kf / kr, rel=1e-12)
    assert lt.front.model > lt.rear.model  # the stiffer axle takes more, in the model too
    lift = wheel_lift(sym)
    assert lift.first == "front" and lift.front_mps2 < lift.rear_mps2


def test_rigid_car_transfer_sums_to_m_ay_h(sedan) -> None:
    v = _rigid(sedan, roll_centre_f_m=0.07, roll_centre_r_m=0.13)
    rs, lt = roll_statics(v), load_transfer(v)
    assert abs(rs.roll_gradient_radpmps2) < 1e-9 and abs(rs.textbook_roll_gradient_radpmps2) < 1e-9
    moment = lt.front.textbook * v.track_f_m + lt.rear.textbook * v.track_r_m
    model = lt.front.model * v.track_f_m + lt.rear.model * v.track_r_m
    assert moment == pytest.approx(v.mass_kg * v.h_cg_m, rel=1e-6)
    assert model == pytest.approx(v.mass_kg * v.h_cg_m, rel=1e-6)
    # Rigid: the unsprung corners' own transfer m_u h_u / t is the textbook's third part.
    assert lt.front.unsprung == pytest.approx(2 * v.unsprung_mass_kg * rs.front.wheel_centre_height_m / v.track_f_m)


def test_weight_shift_amplifies_roll(sedan) -> None:
    """The m_s g h' term: a softer car rolls more than in proportion (and diverges at K = m_s g h')."""
    rs = roll_statics(sedan)
    no_shift = rs.sprung_mass_kg * rs.roll_arm_m / rs.roll_stiffness_Nmprad
    assert rs.textbook_roll_gradient_radpmps2 > no_shift * 1.03
    soft = _with(sedan, stiffness_f_Npm=1500.0, stiffness_r_Npm=1500.0, arb_f_Npm=0.0, arb_r_Npm=0.0)
    rs_soft = roll_statics(soft)
    assert rs_soft.roll_stiffness_Nmprad < rs_soft.sprung_mass_kg * G * rs_soft.roll_arm_m
    assert rs_soft.textbook_roll_gradient_radpmps2 < 0.0  # no stable roll equilibrium: it falls over


def _virtual_work_roll_gradient(v: VehicleParams) -> float:
    """dphi/da_y of the multibody layout by brute force: Hessian of the exact potential (chassis roll,
    heave, pitch and the four slide travels; springs, bars, tire springs, gravity) and the virtual
    work of the lateral loads, both by finite differences of the exact 3D kinematics."""
    m, mu = v.mass_kg, v.unsprung_mass_kg
    ms, L, kt, s = m - 4 * mu, v.wheelbase_m, v.tires.radial_stiffness_Npm, v.suspension
    fz0 = np.array([m * G * v.lr_m / L / 2] * 2 + [m * G * v.lf_m / L / 2] * 2)
    d0 = fz0 / kt
    hu = v.wheel_radius_m - d0
    xs, side = np.array([v.lf_m, v.lf_m, -v.lr_m, -v.lr_m]), np.array([1.0, -1.0, 1.0, -1.0])
    t = np.array([v.track_f_m] * 2 + [v.track_r_m] * 2)
    hrc = np.array([getattr(s, "roll_centre_f_m", 0.0)] * 2 + [getattr(s, "roll_centre_r_m", 0.0)] * 2)
    th = np.arctan(2 * hrc / t)
    ka = np.array([s.stiffness_f_Npm] * 2 + [s.stiffness_r_Npm] * 2) * np.cos(th) ** 2
    kb = np.array([s.arb_f_Npm, s.arb_r_Npm]) * np.cos(th[[0, 2]]) ** 2
    zc = hu - v.h_cg_m
    off = -mu * np.array([xs.sum(), 0.0, zc.sum()]) / ms
    qref = -(fz0 - mu * G) * np.cos(th) / ka

    def pose(c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        phi, zb, pitch, q = c[0], c[1], c[2], c[3:]
        cr, sr, cp, sp = math.cos(phi), math.sin(phi), math.cos(pitch), math.sin(pitch)
        rot = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]]) @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
        o = np.array([0.0, 0.0, v.h_cg_m + zb])
        wc = np.array([o + rot @ np.array([xs[i], side[i] * (t[i] / 2 + q[i] * math.sin(th[i])),
                                           zc[i] + q[i] * math.cos(th[i])]) for i in range(4)])
        return o + rot @ off, wc, rot

    def potential(c: np.ndarray) -> float:
        cg, wc, _ = pose(c)
        q = c[3:]
        e = ms * G * cg[2] + mu * G * wc[:, 2].sum() + 0.5 * np.sum(ka * (q - qref) ** 2)
        e += 0.5 * kb[0] * (q[0] - q[1]) ** 2 + 0.5 * kb[1] * (q[2] - q[3]) ** 2
        return e + 0.5 * np.sum(kt * (d0 + hu - wc[:, 2]) ** 2)  # contact under the wheel centre

    def lateral_work(c: np.ndarray) -> float:
        cg, wc, rot = pose(c)
        fy = np.array([m * v.lr_m / L / 2] * 2 + [m * v.lf_m / L / 2] * 2)  # per unit a_y
        contact = np.array([wc[i, 1] + (rot @ np.array([0.0, 0.0, -hu[i]]))[1] for i in range(4)])
        return float(np.sum(fy * contact) - ms * cg[1] - mu * wc[:, 1].sum())

    n, eps = 7, 1e-5
    e = np.eye(n) * eps
    hess = np.array([[(potential(e[a] + e[b]) - potential(e[a] - e[b]) - potential(-e[a] + e[b])
                       + potential(-e[a] - e[b])) / (4 * eps**2) for b in range(n)] for a in range(n)])
    load = np.array([(lateral_work(e[j]) - lateral_work(-e[j])) / (2 * eps) for j in range(n)])
    return float(np.linalg.solve(hess, load)[0])


@pytest.mark.parametrize("h_f, h_r", [(0.0, 0.0), (0.06, 0.11), (0.3, 0.25)])
def test_model_roll_gradient_equals_a_virtual_work_linearisation(sedan, h_f: float, h_r: float) -> None:
    v = _with(sedan, roll_centre_f_m=h_f, roll_centre_r_m=h_r)
    exact = _virtual_work_roll_gradient(v)
    assert roll_statics(v).roll_gradient_radpmps2 == pytest.approx(exact, rel=2e-4), (h_f, h_r)


def test_model_and_textbook_agree_for_low_roll_centres(sedan) -> None:
    v = _with(sedan, roll_centre_f_m=0.0, roll_centre_r_m=0.0)
    rs = roll_statics(v)
    assert rs.roll_gradient_radpmps2 == pytest.approx(rs.textbook_roll_gradient_radpmps2, rel=0.02)


def test_wheel_lift_is_static_load_over_transfer(sedan) -> None:
    lift, lt, rs = wheel_lift(sedan), load_transfer(sedan), roll_statics(sedan)
    assert lift.front_mps2 == pytest.approx(rs.front.static_wheel_load_N / lt.front.model, rel=1e-12)
    assert lift.lift_mps2 == min(lift.front_mps2, lift.rear_mps2)
    # The sedan's front is heavier loaded but takes more of the transfer (stiffer front bar): it lifts first.
    assert lift.first == "front"
    # Higher CG, earlier lift.
    assert wheel_lift(sedan.with_overrides(h_cg_m=0.8)).lift_mps2 < lift.lift_mps2


def test_stability_factor_and_roll_allowance(sedan) -> None:
    assert static_stability_factor(sedan) == pytest.approx(1.6 / (2 * 0.55), rel=1e-12)
    rs = roll_statics(sedan)
    r_phi = rs.roll_gradient_radpmps2 * G
    expected = static_stability_factor(sedan) / (1 + r_phi * (1 - rs.roll_axis_height_m / sedan.h_cg_m))
    assert rollover_threshold_with_roll(sedan) == pytest.approx(expected, rel=1e-12)
    assert rollover_threshold_with_roll(sedan) < static_stability_factor(sedan)  # roll only lowers it


def test_slide_inclination_and_banked_speed() -> None:
    assert slide_inclination(0.1, 1.6) == pytest.approx(math.atan(0.125))
    assert slide_inclination(0.0, 1.6) == 0.0
    v = banked_neutral_speed(100.0, math.radians(10.0))
    assert v == pytest.approx(math.sqrt(G * 100.0 * math.tan(math.radians(10.0))))
    # At that speed the centripetal and weight components in the road plane cancel.
    b = math.radians(10.0)
    assert v**2 / 100.0 * math.cos(b) == pytest.approx(G * math.sin(b), rel=1e-12)
    with pytest.raises(ValueError):
        banked_neutral_speed(0.0, 0.1)
