"""Canonical signal names and units (ISO 8855: x forward, y left, z up; angles CCW seen from above).

Every stage speaks these names: truth columns, observer inputs/states, replay column maps and scoring.
The unit is in the name (``_m``, ``_mps``, ``_rad``, ``_radps``, ``_N`` …). See CONTRACT.md.
"""

from __future__ import annotations

WHEELS: tuple[str, ...] = ("fl", "fr", "rl", "rr")

# name -> (unit, meaning)
CANONICAL: dict[str, tuple[str, str]] = {
    "t_s": ("s", "time"),
    "x_m": ("m", "CG position x (world)"),
    "y_m": ("m", "CG position y (world)"),
    "psi_rad": ("rad", "yaw angle"),
    "vx_mps": ("m/s", "CG longitudinal velocity (heading frame)"),
    "vy_mps": ("m/s", "CG lateral velocity (heading frame)"),
    "beta_rad": ("rad", "sideslip at the CG, atan2(vy, vx)"),
    "yaw_rate_radps": ("rad/s", "yaw rate r"),
    "yaw_acc_radps2": ("rad/s^2", "yaw acceleration"),
    "ax_mps2": ("m/s^2", "CG longitudinal acceleration (heading frame, no gravity)"),
    "ay_mps2": ("m/s^2", "CG lateral acceleration (heading frame, no gravity)"),
    "roll_rad": ("rad", "roll angle"),
    "pitch_rad": ("rad", "pitch angle"),
    "roll_rate_radps": ("rad/s", "roll rate"),
    "delta_rad": ("rad", "mean front road-wheel steering angle"),
    "delta_fl_rad": ("rad", "front-left road-wheel angle"),
    "delta_fr_rad": ("rad", "front-right road-wheel angle"),
    "alpha_f_rad": ("rad", "front axle slip angle"),
    "alpha_r_rad": ("rad", "rear axle slip angle"),
    "fy_f_N": ("N", "front axle lateral force (tire frame)"),
    "fy_r_N": ("N", "rear axle lateral force (tire frame)"),
    "rho_1pm": ("1/m", "road curvature at the vehicle"),
    "y_lane_m": ("m", "lateral offset from the lane centre at look-ahead l_s"),
    "psi_lane_rad": ("rad", "heading relative to the lane at look-ahead l_s"),
    "range_m": ("m", "range to the lead vehicle"),
    "range_rate_mps": ("m/s", "range rate to the lead vehicle"),
    "lead_accel_mps2": ("m/s^2", "lead vehicle's longitudinal acceleration along its path, dv_lead/dt"),
}
for _w in WHEELS:
    CANONICAL[f"fz_{_w}_N"] = ("N", f"normal load, {_w}")
    CANONICAL[f"fy_{_w}_N"] = ("N", f"lateral tire force (tire frame), {_w}")
    CANONICAL[f"fx_{_w}_N"] = ("N", f"longitudinal tire force (tire frame), {_w}")
    CANONICAL[f"alpha_{_w}_rad"] = ("rad", f"slip angle, {_w}")
    CANONICAL[f"kappa_{_w}"] = ("1", f"longitudinal slip ratio, {_w}")
    CANONICAL[f"mu_{_w}"] = ("1", f"road friction coefficient under the wheel, {_w}")
    CANONICAL[f"omega_{_w}_radps"] = ("rad/s", f"wheel spin rate, {_w}")

#: States an observer may estimate (scored against truth columns of the same name).
ESTIMABLE: tuple[str, ...] = (
    "beta_rad", "vy_mps", "vx_mps", "yaw_rate_radps", "alpha_f_rad", "alpha_r_rad",
    "fy_f_N", "fy_r_N", "rho_1pm", "y_lane_m", "psi_lane_rad", "range_m", "range_rate_mps",
    "lead_accel_mps2", "roll_rad", "ax_mps2", "ay_mps2", "x_m", "y_m", "psi_rad",
    *(f"mu_{w}" for w in WHEELS), *(f"fy_{w}_N" for w in WHEELS), *(f"fx_{w}_N" for w in WHEELS),
)


def unit_of(name: str) -> str:
    """Unit of a canonical signal, e.g. ``unit_of("beta_rad") == "rad"``. Raises KeyError if unknown."""
    return CANONICAL[name][0]


def is_canonical(name: str) -> bool:
    return name in CANONICAL
