"""Emulate the whole sensor suite over a truth frame: sampling, errors, faults, latency, one time base.

For each enabled sensor (rate ``f``, latency ``L``):

1. sample instants ``t_k = t_0 + k / f`` (truth rows; ``f`` divides the truth rate);
2. ideal values from the truth (the sensor module's physics), then the channel error model
   (:mod:`roadtruth.harness.sensors.noise`), then derived outputs;
3. value faults, then availability: a sample is lost if any of its values is NaN (the sensor had
   nothing to report), or an availability fault or a scheduled outage removes it;
4. arrival at ``t_k + L + extra delay``, placed on the first time-base row at or after it
   (``ceil``); a latency that is a multiple of the base period is therefore exact to the sample.

The frame has one row per base period (the fastest enabled rate) from the first truth time to the
last; a sensor's cells hold values only at rows where one of its samples arrives, NaN elsewhere, and
``<sensor>_valid`` is 1 exactly at those rows.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.errors import SensorConfigError
from roadtruth.harness.sensors.catalog import SENSORS, valid_column
from roadtruth.harness.sensors.config import SensorConfig, SensorSuiteConfig, rate_divides
from roadtruth.harness.sensors.faults import FAULT_KINDS, apply_value_fault, availability_loss, extra_delay
from roadtruth.harness.sensors.noise import apply_channel_errors, stream
from roadtruth.harness.sensors.sampling import SampleContext
from roadtruth.harness.truth.vehicle import VehicleParams

_ROW_EPS = 1e-6  # fraction of a base period forgiven when placing an arrival on the grid


@dataclass(frozen=True, eq=False)
class Measurements:
    """Emulated measurements on one time base. ``frame`` starts with ``t_s``; ``rate_hz`` is its rate."""

    frame: pd.DataFrame
    rate_hz: float
    config: SensorSuiteConfig


def _truth_time(truth: pd.DataFrame) -> tuple[np.ndarray, float]:
    if "t_s" not in truth.columns:
        raise SensorConfigError("truth frame has no t_s column", source="truth frame")
    t = truth["t_s"].to_numpy(dtype=np.float64)
    if t.size < 2 or not np.all(np.isfinite(t)):
        raise SensorConfigError("truth frame needs at least two rows of finite t_s", source="truth frame")
    d = np.diff(t)
    dt = float(np.median(d))
    if dt <= 0 or np.max(np.abs(d - dt)) > 1e-6 * max(dt, 1e-3) + 1e-9:
        raise SensorConfigError("truth t_s is not uniformly spaced", source="truth frame")
    return t, dt


def _outage_mask(outage: Any, ctx: SampleContext) -> np.ndarray:
    """(n,) bool: samples removed by a scheduled outage (time window and/or x-range zone)."""
    t0 = getattr(outage, "t_start_s", None)
    t1 = getattr(outage, "t_end_s", None)
    mask = (ctx.t_s >= (-math.inf if t0 is None else t0)) & (ctx.t_s < (math.inf if t1 is None else t1))
    xr = getattr(outage, "x_range_m", None)
    if xr is not None:
        x0, x1 = sorted(float(v) for v in xr)
        x = ctx.at("x_m")
        with np.errstate(invalid="ignore"):
            mask &= (x >= x0) & (x <= x1)
    return mask


def _check_outages(outages: Iterable[Any]) -> list[Any]:
    out = list(outages)
    for o in out:
        name = getattr(o, "sensor", None)
        if name not in SENSORS and name != "all":
            raise SensorConfigError(f"outage names unknown sensor {name!r} (known: {', '.join(SENSORS)}, all)",
                                    source="scenario outages")
    return out


def _emulate_sensor(cfg: SensorConfig, ctx: SampleContext, seed: int, outages: Sequence[Any],
                    t0: float, base_hz: float, n_base: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One sensor -> (arrival rows (m,), output columns (m,) each) for the delivered samples."""
    mod = SENSORS[cfg.name]
    raw = mod.measure(ctx, cfg.params)
    for group, channels in mod.ERROR_GROUPS.items():
        errors = cfg.errors[group]
        if not errors.is_ideal:
            for ch in channels:
                raw[ch] = apply_channel_errors(raw[ch], errors, cfg.rate_hz, seed, (cfg.name, ch))
    values = mod.derive(raw, cfg.params, ctx)
    n = ctx.t_s.size
    lost = np.zeros(n, dtype=bool)
    blanked: list[tuple[tuple[str, ...], np.ndarray]] = []  # partial faults: (channels, mask)
    delay = np.zeros(n)
    ordinal: Counter[str] = Counter()
    for fault in cfg.faults:
        rng = stream(seed, cfg.name, "fault", f"{fault.kind}#{ordinal[fault.kind]}")
        ordinal[fault.kind] += 1
        scope = FAULT_KINDS[fault.kind].scope
        if scope == "value":
            apply_value_fault(fault, values, ctx.t_s, rng)
        elif scope == "availability":
            lost |= availability_loss(fault, ctx.t_s, rng)
        elif scope == "partial":
            group = mod.ERROR_GROUPS.get(fault.channel or "", ())
            chans = tuple(c for c in group if c in mod.COLUMNS) or (str(fault.channel),)
            blanked.append((chans, rng.random(n) < fault.params["p"]))
        else:
            delay += extra_delay(fault, ctx.t_s, rng)
    for outage in outages:
        if outage.sensor in (cfg.name, "all"):
            lost |= _outage_mask(outage, ctx)
    finite = np.logical_and.reduce([np.isfinite(values[c]) for c in mod.COLUMNS])
    for chans, mask in blanked:  # after the all-or-nothing check: the sample still arrives
        for c in chans:
            values[c] = np.where(mask, np.nan, values[c])
    arrival = np.ceil((ctx.t_s + cfg.latency_s + delay - t0) * base_hz - _ROW_EPS).astype(np.int64)
    keep = np.flatnonzero(finite & ~lost & (arrival < n_base))
    rows = arrival[keep]
    if delay.any() and rows.size:
        # Out-of-order or bunched arrivals: one row holds one sample, the newest (largest t_k).
        order = np.lexsort((ctx.t_s[keep], rows))
        keep, rows = keep[order], rows[order]
        last = np.r_[rows[1:] != rows[:-1], True]
        keep, rows = keep[last], rows[last]
    return rows, {c: values[c][keep] for c in mod.COLUMNS}


def emulate(truth_frame: pd.DataFrame, vehicle: VehicleParams, config: SensorSuiteConfig, seed: int, *,
            outages: Iterable[Any] = (), lane_gaps: Iterable[tuple[float, float]] = ()) -> Measurements:
    """Emulate every enabled sensor of ``config`` over a truth frame.

    Parameters
    ----------
    truth_frame : (N, ...) DataFrame, one row per simulation step (uniform dt), ARCHITECTURE "Truth"
        columns (only those the enabled sensors need are read).
    vehicle : VehicleParams (steering ratio, wheel radius, drive layout).
    config : SensorSuiteConfig from :func:`load_sensor_config`.
    seed : int >= 0; every sensor, channel and fault draws from its own stream under it.
    outages : objects with ``sensor`` (a sensor name or ``all``), ``t_start_s``, ``t_end_s`` and
        optionally ``x_range_m`` = (x0, x1): the sensor gives no sample while the vehicle's CG is in
        that x range (and, if times are given, inside the time window).
    lane_gaps : (s0_m, s1_m) stretches of path without lane markings (the camera is blind there).

    Returns
    -------
    Measurements
        ``frame``: ``t_s`` then, per enabled sensor in suite order, its columns and ``<sensor>_valid``
        (int8); ``rate_hz``: the time-base rate.

    Raises
    ------
    SensorConfigError
        A rate above the truth rate, a time base that does not divide the truth rate, a bad seed,
        a non-uniform truth time, an unknown outage sensor, or a truth column a sensor needs missing.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SensorConfigError(f"seed must be a whole number >= 0 (got {seed!r})", source="emulate")
    seed = int(seed)
    t, dt = _truth_time(truth_frame)
    truth_hz = 1.0 / dt
    enabled = config.enabled()
    if not enabled:
        raise SensorConfigError("no sensor is enabled", source=config.source, field="sensors")
    for name in enabled:
        rate = config.sensors[name].rate_hz
        if rate > truth_hz * (1 + 1e-9):
            raise SensorConfigError(f"rate {rate:g} Hz is above the simulation rate {truth_hz:g} Hz",
                                    source=config.source, field=f"sensors.{name}.rate_hz")
    base_hz = config.base_rate_hz
    if not rate_divides(truth_hz, base_hz):
        raise SensorConfigError(f"the fastest sensor rate {base_hz:g} Hz does not divide the simulation rate "
                                f"{truth_hz:g} Hz", source=config.source, field="sensors")
    outage_list = _check_outages(outages)
    gaps = tuple((float(a), float(b)) for a, b in lane_gaps)
    t0 = float(t[0])
    n_base = int(math.floor((t[-1] - t0) * base_hz + _ROW_EPS)) + 1
    columns: dict[str, np.ndarray] = {"t_s": t0 + np.arange(n_base) / base_hz}
    for name in enabled:
        cfg = config.sensors[name]
        step = int(round(truth_hz / cfg.rate_hz))
        rows = np.arange(0, t.size, step)
        ctx = SampleContext(sensor=name, truth=truth_frame, rows=rows, t_s=t[rows], rate_hz=cfg.rate_hz,
                            truth_dt_s=dt, vehicle=vehicle, seed=seed, lane_gaps=gaps)
        arrival, values = _emulate_sensor(cfg, ctx, seed, outage_list, t0, base_hz, n_base)
        for c, v in values.items():
            col = np.full(n_base, np.nan)
            col[arrival] = v
            columns[c] = col
        valid = np.zeros(n_base, dtype=np.int8)
        valid[arrival] = 1
        columns[valid_column(name)] = valid
    return Measurements(frame=pd.DataFrame(columns), rate_hz=base_hz, config=config)
