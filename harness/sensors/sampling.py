"""What a sensor sees of the truth: the sample instants, truth columns at those instants, and the
boxcar anti-alias mean over a sample interval.

Sensors never see MuJoCo: they read a truth DataFrame (one row per simulation step, uniform ``dt``)
through a :class:`SampleContext`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from roadtruth.harness.errors import SensorConfigError
from roadtruth.harness.files.strict_yaml import Fields
from roadtruth.harness.truth.vehicle import VehicleParams

ANTI_ALIAS_MODES: tuple[str, ...] = ("mean", "sample")


@dataclass(frozen=True, eq=False)
class SampleContext:
    """The truth as one sensor samples it.

    Attributes
    ----------
    sensor : name of the sensor (for error messages).
    truth : the truth frame at the simulation rate (ARCHITECTURE "Truth" columns).
    rows : (n,) int array, truth row of each sample instant.
    t_s : (n,) float array, sample instants [s].
    rate_hz : sensor sample rate [Hz].
    truth_dt_s : simulation step [s].
    vehicle : the vehicle parameter set.
    seed : the run seed (for a sensor's own random draws, through ``noise.stream``).
    lane_gaps : (s0_m, s1_m) stretches of path without lane markings.
    """

    sensor: str
    truth: pd.DataFrame
    rows: np.ndarray
    t_s: np.ndarray
    rate_hz: float
    truth_dt_s: float
    vehicle: VehicleParams
    seed: int = 0
    lane_gaps: tuple[tuple[float, float], ...] = ()
    _cache: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def window_rows(self) -> int:
        """Truth rows per sample interval (the boxcar length of the anti-alias mean)."""
        return max(1, int(round(1.0 / (self.rate_hz * self.truth_dt_s))))

    def column(self, name: str) -> np.ndarray:
        """A truth column at the simulation rate, (N,) float64."""
        if name not in self._cache:
            if name not in self.truth.columns:
                raise SensorConfigError(f"truth frame has no column {name!r}, which sensor {self.sensor!r} needs",
                                        source="truth frame")
            self._cache[name] = self.truth[name].to_numpy(dtype=np.float64)
        return self._cache[name]

    def at(self, name: str) -> np.ndarray:
        """A truth column at the sample instants, (n,) float64."""
        return self.column(name)[self.rows]

    def window_mean(self, values: np.ndarray) -> np.ndarray:
        """Boxcar mean of a full-rate (N,) array over each sample interval (t_k - T, t_k] -> (n,).

        The first samples average over the rows available. This is the decimation filter of a
        digital MEMS sensor (integrate-and-dump); it delays a ramp by (T - dt)/2.
        """
        csum = np.concatenate(([0.0], np.cumsum(values, dtype=np.float64)))
        hi = self.rows + 1
        lo = np.maximum(hi - self.window_rows, 0)
        return (csum[hi] - csum[lo]) / (hi - lo)

    def sampled(self, values: np.ndarray, anti_alias: str) -> np.ndarray:
        """Values of a full-rate (N,) array at the samples: boxcar mean or point sample -> (n,)."""
        return self.window_mean(values) if anti_alias == "mean" else values[self.rows]

    def in_lane_gap(self) -> np.ndarray:
        """(n,) bool: the vehicle's path coordinate lies inside a lane-marking gap."""
        s = self.at("s_m")
        gap = np.zeros(s.shape, dtype=bool)
        for s0, s1 in self.lane_gaps:
            gap |= (s >= min(s0, s1)) & (s <= max(s0, s1))
        return gap


def parse_position(f: Fields, key: str, default: Sequence[float]) -> tuple[float, float, float]:
    """A body-frame mounting position relative to the CG, ``[x, y, z]`` [m], each within ±10 m."""
    v = f.raw(key, list(default))
    if not isinstance(v, (list, tuple)) or len(v) != 3 or not all(
            isinstance(c, (int, float)) and not isinstance(c, bool) for c in v):
        raise f.fail(key, f"must be a list of three numbers [x, y, z] in metres (got {v!r})")
    if any(not np.isfinite(c) or abs(c) > 10.0 for c in v):
        raise f.fail(key, f"each coordinate must be finite and within ±10 m (got {v!r})")
    return float(v[0]), float(v[1]), float(v[2])


def body_to_heading(roll: np.ndarray, pitch: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate body-frame vectors (n, 3) into the heading frame: R_y(pitch) R_x(roll) v -> (n, 3).

    The heading frame is the body frame with roll and pitch removed (ISO 8855 intermediate axes).
    """
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    y1 = cr * y - sr * z
    z1 = sr * y + cr * z
    return np.column_stack((cp * x + sp * z1, y1, -sp * x + cp * z1))


def heading_to_body(roll: np.ndarray, pitch: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`body_to_heading`: R_x(roll)^T R_y(pitch)^T v -> (n, 3)."""
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    x1 = cp * x - sp * z
    z1 = sp * x + cp * z
    return np.column_stack((x1, cr * y + sr * z1, -sr * y + cr * z1))


def cross_const(w: np.ndarray, r: Sequence[float]) -> np.ndarray:
    """w × r for rows w (n, 3) and one constant vector r (3,) -> (n, 3)."""
    return np.cross(w, np.asarray(r, dtype=np.float64)[None, :])
