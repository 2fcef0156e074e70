"""Closed-form truth frames for testing sensors (and observers) without MuJoCo.

:func:`steady_motion_truth` is a rigid car in steady planar motion: constant body-frame velocity
``(vx, vy)``, constant yaw rate ``r`` and constant roll/pitch. Then (heading frame)

.. math::

    \\psi = \\psi_0 + r t,\\qquad a = (-r v_y,\\; r v_x,\\; 0),\\qquad
    \\omega_{body} = R_x(\\phi)^T R_y(\\theta)^T (0, 0, r),\\qquad \\dot\\omega_{body} = 0,

the CG runs on a circle of radius ``|v| / r`` (a straight line when ``r = 0``), and each wheel
spins at ``(v_x - r y_w) / R`` with ``y_w = ±track/2``. Every column of the ARCHITECTURE "Truth"
contract that the sensors read is filled.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from roadtruth.harness.sensors.sampling import heading_to_body


def steady_motion_truth(duration_s: float = 10.0, dt_s: float = 0.001, *, vx_mps: float = 20.0,
                        vy_mps: float = 0.0, yaw_rate_radps: float = 0.0, roll_rad: float = 0.0,
                        pitch_rad: float = 0.0, delta_rad: float = 0.0, psi0_rad: float = 0.0,
                        range_m: float | None = None, range_rate_mps: float = 0.0,
                        wheel_radius_m: float = 0.31, track_m: float = 1.6) -> pd.DataFrame:
    """A truth frame (one row per ``dt_s``) of steady planar motion; see the module docstring.

    ``range_m`` None = no lead vehicle (range columns NaN); otherwise the range starts there and
    changes at ``range_rate_mps``. The road is the driven path itself (lane offset and heading 0,
    curvature ``r / vx``), with path coordinate ``s = |v| t``.
    """
    n = int(round(duration_s / dt_s)) + 1
    t = np.arange(n) * dt_s
    r, vx, vy = yaw_rate_radps, vx_mps, vy_mps
    psi = psi0_rad + r * t
    if r != 0.0:
        x = (vx * (np.sin(psi) - np.sin(psi0_rad)) + vy * (np.cos(psi) - np.cos(psi0_rad))) / r
        y = (-vx * (np.cos(psi) - np.cos(psi0_rad)) + vy * (np.sin(psi) - np.sin(psi0_rad))) / r
    else:
        x = (vx * np.cos(psi0_rad) - vy * np.sin(psi0_rad)) * t
        y = (vx * np.sin(psi0_rad) + vy * np.cos(psi0_rad)) * t
    ones = np.ones(n)
    roll, pitch = roll_rad * ones, pitch_rad * ones
    a_body = heading_to_body(roll, pitch, np.column_stack((-r * vy * ones, r * vx * ones, 0.0 * ones)))
    w_body = heading_to_body(roll, pitch, np.column_stack((0.0 * ones, 0.0 * ones, r * ones)))
    speed = float(np.hypot(vx, vy))
    cols: dict[str, np.ndarray] = {
        "t_s": t, "x_m": x, "y_m": y, "psi_rad": psi, "vx_mps": vx * ones, "vy_mps": vy * ones,
        "vz_mps": 0.0 * ones, "beta_rad": np.arctan2(vy, vx) * ones, "yaw_rate_radps": r * ones,
        "yaw_acc_radps2": 0.0 * ones, "ax_mps2": -r * vy * ones, "ay_mps2": r * vx * ones,
        "roll_rad": roll, "pitch_rad": pitch, "roll_rate_radps": 0.0 * ones, "delta_rad": delta_rad * ones,
        "s_m": speed * t, "y_lane_m": 0.0 * ones, "psi_lane_rad": 0.0 * ones,
        "rho_1pm": (r / vx if vx else 0.0) * ones,
        "range_m": (np.nan * ones if range_m is None else range_m + range_rate_mps * t),
        "range_rate_mps": (np.nan * ones if range_m is None else range_rate_mps * ones),
    }
    for i, ax in enumerate("xyz"):
        cols[f"a{ax}_body_mps2"] = a_body[:, i]
        cols[f"w{ax}_body_radps"] = w_body[:, i]
        cols[f"dw{ax}_body_radps2"] = 0.0 * ones
    for wheel, y_w in (("fl", track_m / 2), ("fr", -track_m / 2), ("rl", track_m / 2), ("rr", -track_m / 2)):
        cols[f"omega_{wheel}_radps"] = (vx - r * y_w) / wheel_radius_m * ones
    return pd.DataFrame(cols)
