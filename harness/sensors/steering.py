"""Steering-angle sensor on the steering column, and the road-wheel angle a production car derives.

The sensor reads the handwheel angle ``handwheel = ratio * delta + offset`` (``offset`` is the
``handwheel`` error block's ``bias``: a mis-centred wheel or sensor), quantized to its resolution.
The ECU divides by the nominal ratio, ``delta_rad = handwheel / ratio``, so the offset and the
resolution show through in the road-wheel angle exactly as in a car (compliance and Ackermann are
not in this ratio either: ``delta_rad`` of the truth is the mean front road-wheel angle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtruth.harness.files.strict_yaml import Fields
from roadtruth.harness.sensors.sampling import SampleContext

NAME = "steering"
COLUMNS: tuple[str, ...] = ("handwheel_rad", "delta_rad")
ERROR_GROUPS: dict[str, tuple[str, ...]] = {"handwheel": ("handwheel_rad",)}


@dataclass(frozen=True)
class SteeringParams:
    ratio: float = 0.0  # handwheel / road-wheel angle; 0 = the vehicle's steering ratio


def parse_params(f: Fields) -> SteeringParams:
    return SteeringParams(ratio=f.number("ratio", 0.0, lo=0.0, hi=40.0))


def _ratio(p: SteeringParams, ctx: SampleContext) -> float:
    return p.ratio if p.ratio > 0 else ctx.vehicle.steering.ratio


def measure(ctx: SampleContext, p: SteeringParams) -> dict[str, np.ndarray]:
    """Ideal handwheel angle, (n,) [rad]."""
    return {"handwheel_rad": _ratio(p, ctx) * ctx.at("delta_rad")}


def derive(raw: dict[str, np.ndarray], p: SteeringParams, ctx: SampleContext) -> dict[str, np.ndarray]:
    hw = raw["handwheel_rad"]
    return {"handwheel_rad": hw, "delta_rad": hw / _ratio(p, ctx)}
