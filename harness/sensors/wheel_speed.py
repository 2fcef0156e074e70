"""ABS wheel-speed sensors (toothed tone ring) and the reference speed derived from them.

Each wheel's angle is the integral of its true spin rate; a tone ring with ``ticks_per_rev`` edges
per revolution quantizes it. Two read-outs, as in ECUs:

* ``count``: edges counted in a window ``window_s`` ending at the sample,
  ``omega = (c(t) - c(t - T_w)) * 2 pi / (N T_w)`` — a resolution of ``2 pi / (N T_w)``, coarse
  at low speed;
* ``period``: time between the first and the last edge in the window, time-stamped with
  ``timer_resolution_s``; at least the last edge interval is used (so at crawling speed the value is
  old), and with no edge for ``timeout_s`` the wheel reads 0 (below the sensor's minimum speed).

``ticks_per_rev: 0`` gives the exact spin rate. The sign follows the true direction of rotation
(active sensors with direction detection). The reference speed ``vx_mps`` is what an ESC computes:
the mean of the non-driven wheels' (or all wheels') measured rates times the loaded radius.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadtruth.harness.files.strict_yaml import Fields
from roadtruth.harness.sensors.noise import stream
from roadtruth.harness.sensors.sampling import SampleContext
from roadtruth.harness.signals import WHEELS

NAME = "wheel_speed"
OMEGA = tuple(f"omega_{w}_radps" for w in WHEELS)
COLUMNS: tuple[str, ...] = (*OMEGA, "vx_mps")
ERROR_GROUPS: dict[str, tuple[str, ...]] = {"wheel": OMEGA}
METHODS = ("count", "period")
REFERENCES = ("nondriven", "all")


@dataclass(frozen=True)
class WheelSpeedParams:
    ticks_per_rev: int = 0          # tone-ring edges per revolution; 0 = exact spin rate
    method: str = "period"          # count | period
    window_s: float = 0.0           # counting/timing window; 0 = one sample period
    timer_resolution_s: float = 0.0  # edge time-stamp resolution (period method); 0 = exact
    timeout_s: float = 0.5          # no edge for this long -> 0 (period method)
    reference: str = "nondriven"    # wheels averaged for vx_mps
    radius_m: float = 0.0           # loaded radius for vx_mps; 0 = the vehicle's wheel radius


def parse_params(f: Fields) -> WheelSpeedParams:
    return WheelSpeedParams(
        ticks_per_rev=f.number("ticks_per_rev", 0, lo=0, hi=10000, integer=True),
        method=f.string("method", "period", choices=METHODS),
        window_s=f.number("window_s", 0.0, lo=0.0, hi=10.0),
        timer_resolution_s=f.number("timer_resolution_s", 0.0, lo=0.0, hi=0.01),
        timeout_s=f.number("timeout_s", 0.5, lo=0.0, lo_open=True, hi=60.0),
        reference=f.string("reference", "nondriven", choices=REFERENCES),
        radius_m=f.number("radius_m", 0.0, lo=0.0, hi=2.0),
    )


def _count(theta: np.ndarray, ctx: SampleContext, pitch: float, w_rows: int) -> np.ndarray:
    """Counting read-out from the signed wheel angle (N,) [rad] -> (n,) [rad/s]."""
    c = np.floor(theta / pitch)
    lo = np.maximum(ctx.rows - w_rows, 0)
    span = (ctx.rows - lo) * ctx.truth_dt_s
    full = (ctx.rows - w_rows) >= 0
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (c[ctx.rows] - c[lo]) * pitch / span
    # Before the first full window there is no count yet: no sample (not a made-up 0).
    return np.where(full, out, np.nan)


def _period(theta: np.ndarray, t: np.ndarray, ctx: SampleContext, p: WheelSpeedParams, pitch: float,
            window: float) -> np.ndarray:
    """Edge-timing read-out from the unsigned travelled angle (N,) [rad] -> (n,) [rad/s] (>= 0)."""
    c = np.floor(theta / pitch).astype(np.int64)
    levels = np.arange(c[0] + 1, c[-1] + 1)
    if levels.size < 2:
        return np.where(ctx.t_s - t[0] < p.timeout_s, np.nan, 0.0)
    # theta is non-decreasing, so the edge at level L lies in the truth step ending at the first row
    # with c >= L; interpolate the crossing time linearly inside that step.
    i = np.searchsorted(c, levels, side="left")
    th0, th1 = theta[i - 1], theta[i]
    edges = t[i - 1] + (levels * pitch - th0) / (th1 - th0) * (t[i] - t[i - 1])
    if p.timer_resolution_s > 0:
        edges = np.floor(edges / p.timer_resolution_s) * p.timer_resolution_s
    tk = ctx.t_s
    j1 = np.searchsorted(edges, tk, side="right") - 1
    j0 = np.minimum(np.searchsorted(edges, tk - window, side="right"), j1 - 1)
    ok = (j0 >= 0) & (j1 >= 1)
    j0c, j1c = np.clip(j0, 0, None), np.clip(j1, 0, None)
    dt = edges[j1c] - edges[j0c]
    ok &= (dt > 0) & (tk - edges[j1c] <= p.timeout_s)
    with np.errstate(invalid="ignore", divide="ignore"):
        omega = (j1c - j0c) * pitch / dt
    # No edge for timeout_s: the wheel reads 0 (below minimum speed) -- except while the sensor has
    # not yet seen an edge pair since power-up and the timeout has not run out: no sample then.
    starting = (j0 < 0) & (tk - t[0] < p.timeout_s)
    return np.where(ok, omega, np.where(starting, np.nan, 0.0))


def measure(ctx: SampleContext, p: WheelSpeedParams) -> dict[str, np.ndarray]:
    """Wheel spin rates as the tone-ring read-out gives them, (n,) each [rad/s]."""
    out: dict[str, np.ndarray] = {}
    t = ctx.column("t_s")
    window = p.window_s if p.window_s > 0 else 1.0 / ctx.rate_hz
    w_rows = max(1, int(round(window / ctx.truth_dt_s)))
    pitch = 2.0 * math.pi / p.ticks_per_rev if p.ticks_per_rev else 0.0
    for col in OMEGA:
        omega = ctx.column(col)
        if not p.ticks_per_rev:
            out[col] = omega[ctx.rows]
            continue
        # The tone ring's position at t = 0 is unknown: a random phase per wheel (own stream).
        phase = stream(ctx.seed, NAME, col, "tooth_phase").uniform(0.0, pitch)
        if p.method == "count":
            step = np.concatenate(([0.0], 0.5 * (omega[1:] + omega[:-1]) * np.diff(t)))
            out[col] = _count(phase + np.cumsum(step), ctx, pitch, w_rows)
        else:
            a = np.abs(omega)
            step = np.concatenate(([0.0], 0.5 * (a[1:] + a[:-1]) * np.diff(t)))
            mag = _period(phase + np.cumsum(step), t, ctx, p, pitch, window)
            out[col] = np.where(omega[ctx.rows] < 0, -mag, mag)
    return out


def reference_wheels(layout: str, reference: str) -> tuple[str, ...]:
    """Wheels whose mean gives the reference speed: the non-driven axle, or all four (AWD/``all``)."""
    if reference == "all" or layout == "awd":
        return WHEELS
    return ("fl", "fr") if layout == "rwd" else ("rl", "rr")


def derive(raw: dict[str, np.ndarray], p: WheelSpeedParams, ctx: SampleContext) -> dict[str, np.ndarray]:
    radius = p.radius_m if p.radius_m > 0 else ctx.vehicle.wheel_radius_m
    wheels = reference_wheels(ctx.vehicle.drivetrain.layout, p.reference)
    vx = np.mean([raw[f"omega_{w}_radps"] for w in wheels], axis=0) * radius
    return {**{c: raw[c] for c in OMEGA}, "vx_mps": vx}
