"""Lane-keeping camera (Mobileye class): lateral offset, heading error and curvature of the lane.

The truth gives the lane geometry at the look-ahead ``l_s`` (``y_lane_m``, ``psi_lane_rad``,
``rho_1pm``); the camera reports it with noise (``offset``, ``heading``, ``curvature`` error
blocks). Where the path has no lane markings (the scenario's ``lane_gaps``, tested on the vehicle's
path coordinate ``s_m``), where there is no road (``s_m`` NaN), or beyond ``max_offset_m`` from the
lane centre (lost lock), there is no sample: NaN and ``camera_valid = 0``. Random loss of lock is a
fault (``camera:dropout=…`` or ``burst``), which the presets switch on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtruth.harness.files.strict_yaml import Fields
from roadtruth.harness.sensors.sampling import SampleContext

NAME = "camera"
COLUMNS: tuple[str, ...] = ("y_lane_m", "psi_lane_rad", "rho_1pm")
ERROR_GROUPS: dict[str, tuple[str, ...]] = {
    "offset": ("y_lane_m",), "heading": ("psi_lane_rad",), "curvature": ("rho_1pm",),
}


@dataclass(frozen=True)
class LaneCameraParams:
    max_offset_m: float = 3.0  # lock is lost beyond this lateral offset from the lane centre


def parse_params(f: Fields) -> LaneCameraParams:
    return LaneCameraParams(max_offset_m=f.number("max_offset_m", 3.0, lo=0.0, lo_open=True, hi=50.0))


def measure(ctx: SampleContext, p: LaneCameraParams) -> dict[str, np.ndarray]:
    """Ideal lane geometry at the look-ahead, (n,) each; NaN where the camera sees no lane."""
    y, psi, rho = ctx.at("y_lane_m"), ctx.at("psi_lane_rad"), ctx.at("rho_1pm")
    with np.errstate(invalid="ignore"):
        blind = ctx.in_lane_gap() | np.isnan(ctx.at("s_m")) | ~(np.abs(y) <= p.max_offset_m)
    return {c: np.where(blind, np.nan, v) for c, v in zip(COLUMNS, (y, psi, rho), strict=True)}


def derive(raw: dict[str, np.ndarray], p: LaneCameraParams, ctx: SampleContext) -> dict[str, np.ndarray]:
    return {c: raw[c] for c in COLUMNS}
