"""GNSS receiver: antenna position, horizontal speed and course over ground.

The antenna sits at ``antenna_m`` (body frame, from the CG), so its position and velocity carry
the lever arm through attitude and rotation:

.. math::

    p_a = p_{cg} + R_z(\\psi) R_y(\\theta) R_x(\\phi)\\, r,\\qquad
    v_a = v_{cg} + R_z(\\psi) R_y(\\theta) R_x(\\phi)\\, (\\omega \\times r).

Errors are applied to the world-frame position (``position`` block: white noise plus a
Gauss–Markov or random-walk error, the slowly wandering error of a stand-alone receiver) and to the
world-frame velocity components (``velocity`` block, Doppler-derived). Speed and course are then
computed from the noisy velocity, ``speed = |v|``, ``course = atan2(v_y, v_x)`` in (-pi, pi] (world
frame, anticlockwise from +x; not unwrapped), so the course is as noisy at low speed as a real
receiver's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtruth.harness.files.strict_yaml import Fields
from roadtruth.harness.sensors.sampling import SampleContext, body_to_heading, parse_position

NAME = "gnss"
COLUMNS: tuple[str, ...] = ("gnss_x_m", "gnss_y_m", "gnss_speed_mps", "gnss_course_rad")
ERROR_GROUPS: dict[str, tuple[str, ...]] = {
    "position": ("gnss_x_m", "gnss_y_m"),
    "velocity": ("gnss_vx_world_mps", "gnss_vy_world_mps"),
}


@dataclass(frozen=True)
class GnssParams:
    antenna_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # antenna position from the CG, body frame


def parse_params(f: Fields) -> GnssParams:
    return GnssParams(antenna_m=parse_position(f, "antenna_m", (0.0, 0.0, 0.0)))


def measure(ctx: SampleContext, p: GnssParams) -> dict[str, np.ndarray]:
    """Ideal antenna position and world-frame horizontal velocity, (n,) each."""
    roll, pitch, psi = ctx.at("roll_rad"), ctx.at("pitch_rad"), ctx.at("psi_rad")
    n = roll.size
    r = np.broadcast_to(np.asarray(p.antenna_m), (n, 3))
    w = np.column_stack([ctx.at(f"w{a}_body_radps") for a in "xyz"])
    r_h = body_to_heading(roll, pitch, r)
    v_h = np.column_stack((ctx.at("vx_mps"), ctx.at("vy_mps"), ctx.at("vz_mps")))
    v_h = v_h + body_to_heading(roll, pitch, np.cross(w, r))
    c, s = np.cos(psi), np.sin(psi)
    return {
        "gnss_x_m": ctx.at("x_m") + c * r_h[:, 0] - s * r_h[:, 1],
        "gnss_y_m": ctx.at("y_m") + s * r_h[:, 0] + c * r_h[:, 1],
        "gnss_vx_world_mps": c * v_h[:, 0] - s * v_h[:, 1],
        "gnss_vy_world_mps": s * v_h[:, 0] + c * v_h[:, 1],
    }


def derive(raw: dict[str, np.ndarray], p: GnssParams, ctx: SampleContext) -> dict[str, np.ndarray]:
    vx, vy = raw["gnss_vx_world_mps"], raw["gnss_vy_world_mps"]
    return {"gnss_x_m": raw["gnss_x_m"], "gnss_y_m": raw["gnss_y_m"],
            "gnss_speed_mps": np.hypot(vx, vy), "gnss_course_rad": np.arctan2(vy, vx)}
