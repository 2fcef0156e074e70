"""Optical ground-speed sensor (Kistler Correvit class): longitudinal and lateral velocity over ground.

The sensor head is fixed to the body at ``position_m`` (from the CG) and measures the velocity of
that point in body axes, projected on its x and y axes:

.. math::  v_s = R_x(\\phi)^T R_y(\\theta)^T v_{cg,heading} + \\omega \\times r .

So a head behind the CG reads ``vy - r_x * yaw_rate``-type lateral velocity, and a high head
picks up roll rate — the reason the real device ships a point-transformation setting. It is a
reference instrument for test vehicles, off in every preset; switch it on with an override.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtruth.harness.files.strict_yaml import Fields
from roadtruth.harness.sensors.sampling import (
    ANTI_ALIAS_MODES,
    SampleContext,
    heading_to_body,
    parse_position,
)

NAME = "ogs"
COLUMNS: tuple[str, ...] = ("ogs_vx_mps", "ogs_vy_mps")
ERROR_GROUPS: dict[str, tuple[str, ...]] = {"velocity": COLUMNS}


@dataclass(frozen=True)
class OpticalSpeedParams:
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    anti_alias: str = "mean"


def parse_params(f: Fields) -> OpticalSpeedParams:
    return OpticalSpeedParams(position_m=parse_position(f, "position_m", (0.0, 0.0, 0.0)),
                              anti_alias=f.string("anti_alias", "mean", choices=ANTI_ALIAS_MODES))


def measure(ctx: SampleContext, p: OpticalSpeedParams) -> dict[str, np.ndarray]:
    """Ideal body-axis velocity of the sensor head, (n,) each [m/s]."""
    names = ("vx_mps", "vy_mps", "vz_mps", "roll_rad", "pitch_rad", "wx_body_radps", "wy_body_radps",
             "wz_body_radps")
    if p.anti_alias == "mean":
        cols = {n: ctx.column(n) for n in names}
    else:
        cols = {n: ctx.at(n) for n in names}
    v_h = np.column_stack((cols["vx_mps"], cols["vy_mps"], cols["vz_mps"]))
    w = np.column_stack((cols["wx_body_radps"], cols["wy_body_radps"], cols["wz_body_radps"]))
    v = heading_to_body(cols["roll_rad"], cols["pitch_rad"], v_h) + np.cross(w, np.asarray(p.position_m))
    return {c: (ctx.window_mean(v[:, i]) if p.anti_alias == "mean" else v[:, i]) for i, c in enumerate(COLUMNS)}


def derive(raw: dict[str, np.ndarray], p: OpticalSpeedParams, ctx: SampleContext) -> dict[str, np.ndarray]:
    return {c: raw[c] for c in COLUMNS}
