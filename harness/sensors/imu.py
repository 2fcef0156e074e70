"""Six-axis IMU (accelerometer + gyro) mounted at a point of the chassis.

The accelerometer measures specific force at its mounting point r (body frame, from the CG):

.. math::

    f = a_{cg} + \\dot\\omega \\times r + \\omega \\times (\\omega \\times r) - g_{body},\\qquad
    g_{body} = (g \\sin\\theta,\\; -g \\cos\\theta \\sin\\phi,\\; -g \\cos\\theta \\cos\\phi)

(``a_cg`` the inertial CG acceleration in body axes, gravity excluded; roll ``phi``, pitch ``theta``,
ISO 8855). So a car rolled by ``phi`` in a left turn reads ``ay + g sin(phi)`` (the gravity leak of
shared/notes/mujoco-car-and-tires.md §3.2), and a car at rest reads ``az = +g``. The gyro reads the
body angular velocity ``omega``. With ``anti_alias: mean`` both are averaged over each sample interval
(integrate-and-dump decimation, as the digital filter of a MEMS part); with ``sample`` they are
point samples at the sample instant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtruth.harness.files.strict_yaml import Fields
from roadtruth.harness.sensors.sampling import ANTI_ALIAS_MODES, SampleContext, parse_position
from roadtruth.harness.truth.vehicle import G

NAME = "imu"
COLUMNS: tuple[str, ...] = ("ax_mps2", "ay_mps2", "az_mps2", "roll_rate_radps", "pitch_rate_radps",
                            "yaw_rate_radps")
ERROR_GROUPS: dict[str, tuple[str, ...]] = {
    "accel": ("ax_mps2", "ay_mps2", "az_mps2"),
    "gyro": ("roll_rate_radps", "pitch_rate_radps", "yaw_rate_radps"),
}


@dataclass(frozen=True)
class ImuParams:
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # mounting point from the CG, body frame
    anti_alias: str = "mean"


def parse_params(f: Fields) -> ImuParams:
    return ImuParams(position_m=parse_position(f, "position_m", (0.0, 0.0, 0.0)),
                     anti_alias=f.string("anti_alias", "mean", choices=ANTI_ALIAS_MODES))


def specific_force(a: np.ndarray, w: np.ndarray, dw: np.ndarray, roll: np.ndarray, pitch: np.ndarray,
                   r: tuple[float, float, float]) -> np.ndarray:
    """Specific force at body point ``r`` [m/s^2], (n, 3).

    Parameters
    ----------
    a : (n, 3) CG acceleration, body frame, gravity excluded [m/s^2]
    w : (n, 3) body angular velocity [rad/s]
    dw : (n, 3) body angular acceleration [rad/s^2]
    roll, pitch : (n,) attitude [rad]
    r : mounting point, body frame [m]
    """
    rx, ry, rz = r
    wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
    # dw × r and w × (w × r) written out: np.cross on (n, 3) costs several times more.
    wr = np.column_stack((wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx))
    f = np.empty_like(a)
    f[:, 0] = a[:, 0] + (dw[:, 1] * rz - dw[:, 2] * ry) + (wy * wr[:, 2] - wz * wr[:, 1]) - G * np.sin(pitch)
    f[:, 1] = (a[:, 1] + (dw[:, 2] * rx - dw[:, 0] * rz) + (wz * wr[:, 0] - wx * wr[:, 2])
               + G * np.cos(pitch) * np.sin(roll))
    f[:, 2] = (a[:, 2] + (dw[:, 0] * ry - dw[:, 1] * rx) + (wx * wr[:, 1] - wy * wr[:, 0])
               + G * np.cos(pitch) * np.cos(roll))
    return f


def measure(ctx: SampleContext, p: ImuParams) -> dict[str, np.ndarray]:
    """Ideal IMU samples (before the channel error model): specific force and body rates, (n,) each."""
    def block(prefix: str, suffix: str) -> np.ndarray:
        cols = [ctx.column(f"{prefix}{ax}_body_{suffix}") for ax in "xyz"]
        return np.column_stack(cols if p.anti_alias == "mean" else [c[ctx.rows] for c in cols])

    w = block("w", "radps")
    roll, pitch = ctx.column("roll_rad"), ctx.column("pitch_rad")
    if p.anti_alias == "sample":
        roll, pitch = roll[ctx.rows], pitch[ctx.rows]
    f = specific_force(block("a", "mps2"), w, block("dw", "radps2"), roll, pitch, p.position_m)
    out = {}
    for i, name in enumerate(COLUMNS[:3]):
        out[name] = ctx.sampled(f[:, i], "mean") if p.anti_alias == "mean" else f[:, i]
    for i, name in enumerate(COLUMNS[3:]):
        out[name] = ctx.sampled(w[:, i], "mean") if p.anti_alias == "mean" else w[:, i]
    return out


def derive(raw: dict[str, np.ndarray], p: ImuParams, ctx: SampleContext) -> dict[str, np.ndarray]:
    return {c: raw[c] for c in COLUMNS}
