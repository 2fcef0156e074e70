"""Sign and unit consistency of a mapped log, from the physics every car obeys (ISO 8855 axes).

Range checks (``replay_log.check_plausible``) catch a unit only when the driving leaves the range; a
lateral acceleration counted positive to the right, or a speed in km/h at 60 km/h, stays in range.
These checks compare channels with each other on the samples where the relation is sharp:

``ay_sign`` / ``ay_scale``
    In cornering a_y ≈ v_x r (the centripetal acceleration; β̇, roll and banking add little). Opposite
    signs in most cornering samples: a_y (or r) counted positive to the right. A slope far from 1 by a
    known factor: v_x in km/h or mph, a_y in g, read as SI.
``r_vs_delta``
    Every stable car turns the way it is steered: r and δ have the same sign in cornering (ISO 8855:
    left steer positive, left turn positive).
``speed_vs_wheels`` / ``speed_vs_gnss``
    v_x against the wheel speeds × the vehicle's wheel radius, or the GNSS speed: their median ratio is
    1 within slip and tire growth (±15 %); 3.6 is km/h read as m/s.
``beta_vs_vy``
    A sideslip reference and a lateral-velocity reference must have the same sign (β = atan(v_y/v_x)).

Cornering samples: ``v_x ≥ 5 m/s`` and ``|v_x r| ≥ 2 m/s²``; a check needs at least
``MIN_SAMPLES`` of them and is ``skipped`` (with the reason) otherwise. A result is ``ok``, ``warn``
(implausible but no known cause) or ``fail`` (opposite sign, or off by a known unit factor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

G0 = 9.80665
MIN_SAMPLES = 100
MIN_CORNER_SPEED_MPS = 5.0
MIN_CORNER_ACC_MPS2 = 2.0
OPPOSITE_FRACTION = 0.8  # at least this share of samples of the opposite sign …
OPPOSITE_CORR = -0.5  # … and a correlation below this: a flipped sign, not noise
SLOPE_OK = (0.6, 1.6)  # a_y / (v_x r) of a real car in cornering
SPEED_RATIO_OK = (0.85, 1.15)
FACTOR_TOLERANCE = 0.15  # a ratio within 15 % of a unit factor is that unit


@dataclass(frozen=True)
class CheckResult:
    """One consistency check: ``status`` ok | warn | fail | skipped, and the evidence in one line."""

    check: str
    status: str
    evidence: str

    def to_dict(self) -> dict[str, str]:
        return {"check": self.check, "status": self.status, "evidence": self.evidence}


def _known_factor(ratio: float, factors: dict[str, float]) -> str | None:
    for what, f in factors.items():
        if abs(ratio / f - 1.0) <= FACTOR_TOLERANCE:
            return what
    return None


def _sign_check(name: str, a: np.ndarray, b: np.ndarray, a_name: str, b_name: str, fix: str) -> CheckResult:
    agree = float(np.mean(np.sign(a) == np.sign(b)))
    corr = float(np.corrcoef(a, b)[0, 1]) if a.std() > 0 and b.std() > 0 else 0.0
    n = a.size
    if 1.0 - agree >= OPPOSITE_FRACTION and corr < OPPOSITE_CORR:
        return CheckResult(name, "fail", f"{a_name} has the opposite sign of {b_name} in {100 * (1 - agree):.0f} % "
                                         f"of {n} cornering samples (corr {corr:+.2f}): {fix}")
    return CheckResult(name, "ok", f"{a_name} and {b_name} agree in sign in {100 * agree:.0f} % of {n} cornering "
                                   f"samples (corr {corr:+.2f})")


def _speed_ratio(name: str, vx: np.ndarray, other: np.ndarray, other_name: str) -> CheckResult:
    ok = np.isfinite(vx) & np.isfinite(other) & (other > 3.0)
    if ok.sum() < MIN_SAMPLES:
        return CheckResult(name, "skipped", f"fewer than {MIN_SAMPLES} samples with {other_name} above 3 m/s")
    ratio = float(np.median(vx[ok] / other[ok]))
    text = f"vx_mps is {ratio:.3g} x {other_name} (median of {int(ok.sum())} samples)"
    if SPEED_RATIO_OK[0] <= ratio <= SPEED_RATIO_OK[1]:
        return CheckResult(name, "ok", text)
    cause = _known_factor(ratio, {"vx_mps in km/h read as m/s: set 'unit: km/h'": 3.6,
                                  "vx_mps in mph read as m/s: set 'unit: mph'": 2.23694,
                                  f"{other_name} in km/h read as m/s": 1 / 3.6})
    if cause:
        return CheckResult(name, "fail", f"{text}: {cause}")
    return CheckResult(name, "warn", f"{text}, expected 1 within 15 % (wrong wheel radius, unit or scale?)")


def check_consistency(frame: pd.DataFrame, wheel_radius_m: float | None = None) -> list[CheckResult]:
    """Run every check the frame's channels allow (module doc). ``frame``: ``apply_map`` output (SI)."""
    out: list[CheckResult] = []
    cols = set(frame.columns)
    get = {c: frame[c].to_numpy(dtype=float) for c in cols}
    vx, r = get.get("vx_mps"), get.get("yaw_rate_radps")
    corner = None
    if vx is not None and r is not None:
        with np.errstate(invalid="ignore"):
            corner = np.isfinite(vx) & np.isfinite(r) & (vx >= MIN_CORNER_SPEED_MPS) & (
                np.abs(vx * r) >= MIN_CORNER_ACC_MPS2)
    few = f"fewer than {MIN_SAMPLES} cornering samples (v_x >= 5 m/s, |v_x r| >= 2 m/s^2)"
    ay_flipped = False
    if "ay_mps2" in cols and corner is not None:
        ay = get["ay_mps2"]
        sel = corner & np.isfinite(ay)
        if sel.sum() < MIN_SAMPLES:
            out.append(CheckResult("ay_sign", "skipped", few))
        else:
            a, vr = ay[sel], (vx * r)[sel]
            res = _sign_check("ay_sign", a, vr, "ay_mps2", "vx*r", "ISO 8855 counts a_y positive to the left "
                              "like r: flip it with 'scale: -1' in the column map (or r, if r is the one "
                              "counted clockwise)")
            out.append(res)
            ay_flipped = res.status == "fail"
            if not ay_flipped:
                k = float(np.sum(a * vr) / np.sum(vr * vr))
                text = f"ay_mps2 is {k:.3g} x vx*r in {a.size} cornering samples (least squares)"
                if SLOPE_OK[0] <= k <= SLOPE_OK[1]:
                    out.append(CheckResult("ay_scale", "ok", text))
                else:
                    cause = _known_factor(k, {"vx_mps in km/h read as m/s: set 'unit: km/h'": 1 / 3.6,
                                              "vx_mps in mph read as m/s: set 'unit: mph'": 1 / 2.23694,
                                              "ay_mps2 in g read as m/s^2: set 'unit: g'": 1 / G0})
                    out.append(CheckResult("ay_scale", "fail" if cause else "warn",
                                           f"{text}: {cause}" if cause else f"{text}, expected about 1"))
    if "delta_rad" in cols and corner is not None:
        d = get["delta_rad"]
        sel = corner & np.isfinite(d)
        if sel.sum() < MIN_SAMPLES:
            out.append(CheckResult("r_vs_delta", "skipped", few))
        else:
            wrong = ("a_y agrees with v_x r, so flip delta_rad with 'scale: -1'" if "ay_mps2" in cols and not
                     ay_flipped else "flip the one counted clockwise with 'scale: -1'")
            out.append(_sign_check("r_vs_delta", d[sel], r[sel], "delta_rad", "yaw_rate_radps",
                                   f"a car turns the way it is steered (ISO 8855: both positive to the left); "
                                   f"{wrong}"))
    wheels = [c for c in ("omega_fl_radps", "omega_fr_radps", "omega_rl_radps", "omega_rr_radps") if c in cols]
    if vx is not None and wheels and wheel_radius_m:
        vw = np.mean([get[c] for c in wheels], axis=0) * wheel_radius_m
        out.append(_speed_ratio("speed_vs_wheels", vx, vw, "the wheel speeds x wheel radius"))
    if vx is not None and "gnss_speed_mps" in cols:
        out.append(_speed_ratio("speed_vs_gnss", vx, get["gnss_speed_mps"], "gnss_speed_mps"))
    if "beta_rad" in cols and "vy_mps" in cols:
        b, vy = get["beta_rad"], get["vy_mps"]
        sel = np.isfinite(b) & np.isfinite(vy) & (np.abs(b) > 0.005)
        if sel.sum() < MIN_SAMPLES:
            out.append(CheckResult("beta_vs_vy", "skipped", f"fewer than {MIN_SAMPLES} samples with |beta| > 0.3 deg"))
        else:
            res = _sign_check("beta_vs_vy", b[sel], vy[sel], "beta_rad", "vy_mps",
                              "beta = atan(v_y / v_x): flip the one counted clockwise with 'scale: -1'")
            out.append(CheckResult(res.check, res.status, res.evidence.replace("cornering samples", "samples")))
    return out
