"""Forward radar (77 GHz ACC class): range and range rate to the lead vehicle.

No target (range NaN in the truth), or a target outside ``[min_range_m, max_range_m]``, gives no
sample (NaN, ``radar_valid = 0``). Range and range rate carry the ``range`` and ``range_rate``
error blocks (FMCW range and Doppler are measured separately, so their errors are independent).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtruth.harness.files.strict_yaml import Fields
from roadtruth.harness.sensors.sampling import SampleContext

NAME = "radar"
COLUMNS: tuple[str, ...] = ("range_m", "range_rate_mps")
ERROR_GROUPS: dict[str, tuple[str, ...]] = {"range": ("range_m",), "range_rate": ("range_rate_mps",)}


@dataclass(frozen=True)
class RadarParams:
    min_range_m: float = 0.5
    max_range_m: float = 200.0


def parse_params(f: Fields) -> RadarParams:
    p = RadarParams(min_range_m=f.number("min_range_m", 0.5, lo=0.0, hi=100.0),
                    max_range_m=f.number("max_range_m", 200.0, lo=1.0, hi=1000.0))
    if p.max_range_m <= p.min_range_m:
        raise f.fail("max_range_m", f"must exceed min_range_m (got {p.max_range_m:g} <= {p.min_range_m:g})")
    return p


def measure(ctx: SampleContext, p: RadarParams) -> dict[str, np.ndarray]:
    """Ideal range and range rate, (n,) each; NaN where there is no target in the field of view."""
    rng, rate = ctx.at("range_m"), ctx.at("range_rate_mps")
    with np.errstate(invalid="ignore"):
        seen = (rng >= p.min_range_m) & (rng <= p.max_range_m)
    return {"range_m": np.where(seen, rng, np.nan), "range_rate_mps": np.where(seen, rate, np.nan)}


def derive(raw: dict[str, np.ndarray], p: RadarParams, ctx: SampleContext) -> dict[str, np.ndarray]:
    return {c: raw[c] for c in COLUMNS}
