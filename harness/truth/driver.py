"""Driver models: open-loop steering profiles, a preview path follower, speed control, a lead car.

A scenario's ``driver:`` and ``lead:`` blocks (docs/SCENARIOS.md) are parsed here into
frozen specs. Open-loop steering and speed targets are precomputed on the simulation time grid
(vectorised); the closed-loop parts (rate limiter, path follower, PI speed controller, time-gap
follower) are scalar ``numba`` functions called from the compiled stepping loop of
``roadtruth.harness.truth.simulate`` once per step.

Steering is the ROAD-WHEEL angle δ (positive = left), clipped to the vehicle's maximum and rate
limited to what a steering robot can do at the handwheel (``MAX_HANDWHEEL_RATE_RADPS`` / ratio).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from roadtruth.harness.errors import ScenarioError
from roadtruth.harness.files.strict_yaml import Fields
from roadtruth.harness.truth.tire import jit

STEER_TYPES = ("step", "ramp", "sine", "sweep", "sine_with_dwell", "fishhook", "constant", "path_follower")
SPEED_TYPES = ("hold", "profile", "brake", "follow_lead")

#: Steering-robot limit at the handwheel (ISO 7401 / FMVSS 126 robots reach ~1000-1200 deg/s) [rad/s].
MAX_HANDWHEEL_RATE_RADPS = math.radians(1000.0)
#: Speed controller: acceleration demand per m/s of speed error [1/s] and its integral gain [1/s^2].
SPEED_KP = 1.5
SPEED_KI = 0.3
#: Acceleration limits of the closed-loop speed controllers [m/s^2].
MAX_ACCEL_DEMAND = 4.0
MAX_DECEL_DEMAND = 8.0
#: follow_lead: speed correction per metre of gap error [1/s] (added to the lead's speed).
GAP_GAIN = 0.25
#: Brake demand fades out between these speeds: the tire model is only valid above ~3 m/s [m/s].
#: A target speed at or below this is a stop [m/s]; under HOLD_BELOW_MPS the driver then holds the
#: car on the brake with HOLD_DECEL_MPS2 of demand (a foot on the pedal at a traffic light).
STOP_TARGET_MPS = 0.05
HOLD_BELOW_MPS = 0.5
HOLD_DECEL_MPS2 = 3.0
#: Geometry of the range measurement: ego front bumper ahead of the CG by lf + this [m]; the lead car
#: is LEAD_LENGTH_M long with its CG in the middle. range_m is bumper to bumper.
FRONT_OVERHANG_M = 0.9
LEAD_LENGTH_M = 4.5


@dataclass(frozen=True)
class SteerSpec:
    """One steering input. Angles are road-wheel angles [rad]; unused fields keep their defaults."""

    type: str
    t_start_s: float = 0.0
    amplitude_rad: float = 0.0
    rise_time_s: float = 0.15
    rate_radps: float = 0.0
    max_rad: float = 0.0
    frequency_hz: float = 0.0
    cycles: float = math.inf
    f0_hz: float = 0.0
    f1_hz: float = 0.0
    sweep_duration_s: float = 0.0
    dwell_s: float = 0.0
    direction: float = 1.0  # +1 left, -1 right (fishhook)
    preview_s: float = 1.0
    gain: float = 1.0
    lane_offset_m: float = 0.0


@dataclass(frozen=True)
class SpeedSpec:
    """Longitudinal input. ``target_mps`` None = hold the initial speed."""

    type: str
    target_mps: float | None = None
    points: tuple[tuple[float, float], ...] = ()
    t_start_s: float = 0.0
    decel_mps2: float = 0.0
    time_gap_s: float = 1.5
    standstill_m: float = 5.0


@dataclass(frozen=True)
class DriverSpec:
    """The scenario's driver: a steering input and a speed input."""

    steer: SteerSpec
    speed: SpeedSpec

    @property
    def closed_loop_steer(self) -> bool:
        return self.steer.type == "path_follower"

    def steer_profile(self, t_s: np.ndarray) -> np.ndarray:
        """Open-loop road-wheel angle command on a time grid, (n,) [rad] (zeros for path_follower)."""
        return steer_profile(self.steer, np.asarray(t_s, dtype=np.float64))

    def speed_target(self, t_s: np.ndarray, initial_speed_mps: float) -> tuple[np.ndarray, np.ndarray]:
        """Target speed and its time derivative on a time grid, each (n,) [m/s], [m/s^2].

        ``brake`` holds the initial (or target) speed before ``t_start_s``; after it the stepping loop
        uses the deceleration demand instead. ``follow_lead`` returns the initial speed (unused).
        """
        t = np.asarray(t_s, dtype=np.float64)
        sp = self.speed
        if sp.type == "profile":
            pts = np.asarray(sp.points, dtype=np.float64)
            v = np.interp(t, pts[:, 0], pts[:, 1])
            slope = np.diff(pts[:, 1]) / np.maximum(np.diff(pts[:, 0]), 1e-9)
            seg = np.clip(np.searchsorted(pts[:, 0], t, side="right") - 1, 0, len(pts) - 1)
            inside = (t >= pts[0, 0]) & (t < pts[-1, 0])
            dv = np.where(inside, np.concatenate([slope, [0.0]])[seg], 0.0)
            return v, dv
        target = initial_speed_mps if sp.target_mps is None else sp.target_mps
        return np.full_like(t, target), np.zeros_like(t)


@dataclass(frozen=True)
class LeadSpec:
    """A kinematic lead car on the road centre line. ``speed_points``: ((t_s, v_mps), ...)."""

    initial_gap_m: float
    speed_points: tuple[tuple[float, float], ...]

    def speed(self, t_s: np.ndarray) -> np.ndarray:
        """Lead speed on a time grid (piecewise linear, held constant outside the points) [m/s]."""
        pts = np.asarray(self.speed_points, dtype=np.float64)
        return np.interp(np.asarray(t_s, dtype=np.float64), pts[:, 0], pts[:, 1])

    def path_coordinate(self, t_s: np.ndarray, lf_m: float) -> np.ndarray:
        """Lead CG path coordinate s(t) [m] for an ego car starting at s = 0 with CG-to-front ``lf_m``.

        The lead's rear bumper starts ``initial_gap_m`` ahead of the ego front bumper; s integrates
        the piecewise-linear speed exactly (trapezoids are exact for linear pieces between samples).
        """
        t = np.asarray(t_s, dtype=np.float64)
        v = self.speed(t)
        s0 = lf_m + FRONT_OVERHANG_M + self.initial_gap_m + 0.5 * LEAD_LENGTH_M
        if len(t) < 2:
            return np.full_like(t, s0)
        inc = 0.5 * (v[1:] + v[:-1]) * np.diff(t)
        return s0 + np.concatenate([[0.0], np.cumsum(inc)])


# ---- parsing ----------------------------------------------------------------------------------

def _deg(f: Fields, key: str, default: Any = ..., lo: float = -90.0, hi: float = 90.0) -> float:
    return math.radians(f.number(key, default, lo=lo, hi=hi))


def _parse_steer(f: Fields) -> SteerSpec:
    kind = f.string("type", choices=STEER_TYPES)
    if kind == "path_follower":
        spec = SteerSpec(type=kind, preview_s=f.number("preview_s", 1.0, lo=0.05, hi=10.0),
                         gain=f.number("gain", 1.0, lo=0.0, hi=10.0),
                         lane_offset_m=f.number("lane_offset_m", 0.0, lo=-20.0, hi=20.0))
        f.done()
        return spec
    t0 = f.number("t_start_s", lo=0.0)
    if kind == "step":
        spec = SteerSpec(kind, t0, _deg(f, "amplitude_deg"), rise_time_s=f.number("rise_time_s", 0.15, lo=0.0, hi=10.0))
    elif kind == "constant":
        spec = SteerSpec(kind, t0, _deg(f, "amplitude_deg"), rise_time_s=0.0)
    elif kind == "ramp":
        spec = SteerSpec(kind, t0, rate_radps=_deg(f, "rate_degps", lo=-1000.0, hi=1000.0),
                         max_rad=_deg(f, "max_deg", lo=0.0, hi=90.0))
        if spec.rate_radps == 0.0:
            raise f.fail("rate_degps", "must not be zero (got 0)")
    elif kind == "sine":
        cyc = f.number("cycles", None, lo=0.0, lo_open=True)
        spec = SteerSpec(kind, t0, _deg(f, "amplitude_deg"), frequency_hz=f.number("frequency_hz", lo=0.0, hi=50.0, lo_open=True),
                         cycles=math.inf if cyc is None else cyc)
    elif kind == "sweep":
        spec = SteerSpec(kind, t0, _deg(f, "amplitude_deg"), f0_hz=f.number("f0_hz", lo=0.0, hi=50.0),
                         f1_hz=f.number("f1_hz", lo=0.0, hi=50.0),
                         sweep_duration_s=f.number("sweep_duration_s", lo=0.0, lo_open=True))
    elif kind == "sine_with_dwell":
        spec = SteerSpec(kind, t0, _deg(f, "amplitude_deg"), frequency_hz=f.number("frequency_hz", 0.7, lo=0.0, hi=50.0, lo_open=True),
                         dwell_s=f.number("dwell_s", 0.5, lo=0.0, hi=100.0))
    else:  # fishhook
        spec = SteerSpec(kind, t0, _deg(f, "amplitude_deg", lo=0.0, hi=90.0),
                         rate_radps=_deg(f, "rate_degps", lo=0.0, hi=1000.0),
                         dwell_s=f.number("dwell_s", lo=0.0, hi=100.0),
                         direction=1.0 if f.string("direction", "left", choices=("left", "right")) == "left" else -1.0)
        if spec.rate_radps <= 0.0:
            raise f.fail("rate_degps", "must be > 0 (got 0)")
    f.done()
    return spec


def _points(f: Fields, key: str, *, v_lo: float = 0.0) -> tuple[tuple[float, float], ...]:
    raw = f.items(key)
    if not raw:
        raise f.fail(key, "must hold at least one [t_s, v_mps] pair (got [])")
    out: list[tuple[float, float]] = []
    for p in raw:
        ok = (isinstance(p, list) and len(p) == 2
              and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in p))
        if not ok:
            raise f.fail(key, f"each point must be [t_s, v_mps] numbers (got {p!r})")
        t, v = float(p[0]), float(p[1])
        if out and t <= out[-1][0]:
            raise f.fail(key, f"times must increase (got {t:g} after {out[-1][0]:g})")
        if v < v_lo or v > 150.0:
            raise f.fail(key, f"speeds must be in [{v_lo:g}, 150] m/s (got {v:g})")
        out.append((t, v))
    return tuple(out)


def _parse_speed(f: Fields) -> SpeedSpec:
    kind = f.string("type", choices=SPEED_TYPES)
    if kind == "hold":
        spec = SpeedSpec(kind, target_mps=f.number("target_mps", None, lo=0.0, hi=150.0))
    elif kind == "profile":
        spec = SpeedSpec(kind, points=_points(f, "points"))
    elif kind == "brake":
        spec = SpeedSpec(kind, t_start_s=f.number("t_start_s", lo=0.0),
                         decel_mps2=f.number("decel_mps2", lo=0.0, hi=15.0, lo_open=True))
    else:
        spec = SpeedSpec(kind, time_gap_s=f.number("time_gap_s", 1.5, lo=0.1, hi=10.0),
                         standstill_m=f.number("standstill_m", 5.0, lo=0.0, hi=100.0))
    f.done()
    return spec


def parse_driver(data: dict[str, Any] | None, source: str) -> DriverSpec:
    """Check a scenario's ``driver:`` block and build a ``DriverSpec``.

    Both parts are optional: no ``steer`` = straight ahead (constant 0), no ``speed`` = hold the
    initial speed. Raises ``ScenarioError`` naming ``source`` and the field.
    """
    f = Fields(data if data is not None else {}, source=source, error=ScenarioError, prefix="driver")
    steer = _parse_steer(f.sub("steer")) if f.has("steer") else SteerSpec("constant")
    speed = _parse_speed(f.sub("speed")) if f.has("speed") else SpeedSpec("hold")
    f.done()
    return DriverSpec(steer=steer, speed=speed)


def parse_lead(data: dict[str, Any], source: str) -> LeadSpec:
    """Check a scenario's ``lead:`` block (``initial_gap_m``, ``speed_points``) into a ``LeadSpec``."""
    f = Fields(data, source=source, error=ScenarioError, prefix="lead")
    spec = LeadSpec(initial_gap_m=f.number("initial_gap_m", lo=0.0, hi=1000.0, lo_open=True),
                    speed_points=_points(f, "speed_points"))
    f.done()
    return spec


# ---- open-loop profiles (vectorised) ----------------------------------------------------------

def steer_profile(spec: SteerSpec, t: np.ndarray) -> np.ndarray:
    """Road-wheel angle command δ(t) of an open-loop profile, (n,) [rad], before limits.

    sine_with_dwell follows FMVSS 126: a sine of ``frequency_hz`` whose third quarter-period peak is
    held for ``dwell_s``, then the last quarter period back to zero. fishhook follows the NHTSA
    manoeuvre: ramp to ``direction*A`` at ``rate``, hold ``dwell_s``, ramp to ``-direction*A``, hold.
    """
    tau = t - spec.t_start_s
    on = tau >= 0.0
    tau = np.maximum(tau, 0.0)
    a = spec.amplitude_rad
    k = spec.type
    if k == "path_follower":
        return np.zeros_like(t)
    if k in ("step", "constant"):
        frac = np.ones_like(t) if spec.rise_time_s <= 0.0 else np.clip(tau / spec.rise_time_s, 0.0, 1.0)
        return np.where(on, a * frac, 0.0)
    if k == "ramp":
        return np.where(on, np.sign(spec.rate_radps) * np.minimum(np.abs(spec.rate_radps) * tau, spec.max_rad), 0.0)
    if k == "sine":
        active = on & (tau * spec.frequency_hz <= spec.cycles)
        return np.where(active, a * np.sin(2.0 * np.pi * spec.frequency_hz * tau), 0.0)
    if k == "sweep":
        T = spec.sweep_duration_s
        phase = 2.0 * np.pi * (spec.f0_hz * tau + 0.5 * (spec.f1_hz - spec.f0_hz) / T * tau**2)
        return np.where(on & (tau <= T), a * np.sin(phase), 0.0)
    if k == "sine_with_dwell":
        f = spec.frequency_hz
        t_dwell = 0.75 / f
        t_end = 1.0 / f + spec.dwell_s
        tau_sine = np.where(tau < t_dwell, tau, np.maximum(tau - spec.dwell_s, t_dwell))
        out = a * np.sin(2.0 * np.pi * f * tau_sine)
        return np.where(on & (tau <= t_end), out, 0.0)
    # fishhook
    s, r = spec.direction * a, spec.rate_radps
    t1 = a / r
    t2 = t1 + spec.dwell_s
    out = np.where(tau < t1, spec.direction * r * tau,
                   np.where(tau < t2, s, s - spec.direction * r * (tau - t2)))
    out = np.where(spec.direction * out < -a, -s, out)
    return np.where(on, out, 0.0)


# ---- closed-loop parts (compiled; called once per step from roadtruth.harness.truth.simulate) -----------------

@jit
def rate_limit(previous: float, command: float, max_rate: float, max_angle: float, dt: float) -> float:
    """Clip ``command`` to ±``max_angle`` and move at most ``max_rate*dt`` from ``previous`` [rad]."""
    c = min(max(command, -max_angle), max_angle)
    step = max_rate * dt
    return min(max(c, previous - step), previous + step)


@jit
def ackermann_angles(delta: float, wheelbase: float, track: float, ackermann: float) -> tuple[float, float]:
    """Left and right road-wheel angles whose MEAN is exactly ``delta`` [rad].

    Full Ackermann (``ackermann`` = 1) satisfies cot δ_out − cot δ_in = track/L up to third order in
    δ; both angles are shifted by the same amount so that (δ_l + δ_r)/2 = δ holds exactly, which
    keeps the logged mean road-wheel angle equal to the steering command.
    """
    if abs(delta) < 1e-9:
        return delta, delta
    radius = wheelbase / math.tan(delta)  # signed: > 0 turning left
    dl = math.atan(wheelbase / (radius - 0.5 * track))
    dr = math.atan(wheelbase / (radius + 0.5 * track))
    mean = 0.5 * (dl + dr)
    return delta + ackermann * (dl - mean), delta + ackermann * (dr - mean)


@jit
def path_point(samples: np.ndarray, ds: float, s: float, offset: float) -> tuple[float, float, float]:
    """Point of the road at path coordinate ``s`` shifted ``offset`` to the left, and the road heading.

    Beyond the sampled road the last (or first) sample is extrapolated along its heading.
    """
    n = samples.shape[0]
    f = (s - samples[0, 0]) / ds
    if f <= 0.0:
        i, w, extra = 0, 0.0, f * ds
    elif f >= n - 1:
        i, w, extra = n - 2, 1.0, (f - (n - 1)) * ds
    else:
        i = int(f)
        w, extra = f - i, 0.0
    x = (1.0 - w) * samples[i, 1] + w * samples[i + 1, 1]
    y = (1.0 - w) * samples[i, 2] + w * samples[i + 1, 2]
    dpsi = samples[i + 1, 3] - samples[i, 3]
    psi = samples[i, 3] + w * dpsi
    x += extra * math.cos(psi) - offset * math.sin(psi)
    y += extra * math.sin(psi) + offset * math.cos(psi)
    return x, y, psi


@jit
def path_follower(samples: np.ndarray, ds: float, s_car: float, x: float, y: float, psi: float, vx: float,
                  preview_s: float, gain: float, lane_offset: float, wheelbase: float,
                  understeer_gradient: float) -> float:
    """Road-wheel angle of a preview (pure-pursuit) driver aiming at the lane centre [rad].

    The aim point lies ``max(vx*preview_s, 3 m)`` ahead along the road; δ = gain·atan(2 L sin η / l_d)
    with η the aim bearing in the car frame (Coulter 1992, pure pursuit), plus the understeer
    feed-forward K·vx²·κ_aim so that steady cornering does not drift outwards.
    """
    look = max(vx * preview_s, 3.0)
    px, py, _ = path_point(samples, ds, s_car + look, lane_offset)
    dx, dy = px - x, py - y
    ld = max(math.hypot(dx, dy), 1e-3)
    eta = math.atan2(dy, dx) - psi
    eta = math.atan2(math.sin(eta), math.cos(eta))
    curv = 2.0 * math.sin(eta) / ld
    return gain * (math.atan(wheelbase * curv) + understeer_gradient * vx * vx * curv)


@jit
def speed_controller(mode: int, t: float, vx: float, v_target: float, dv_target: float, integral: float,
                     brake_t0: float, brake_decel: float, dt: float) -> tuple[float, float]:
    """Longitudinal acceleration demand [m/s^2] and the updated integrator state [m].

    mode 0 = track ``v_target`` (PI with feed-forward of its slope); a stop target (≤ STOP_TARGET_MPS)
    reached below HOLD_BELOW_MPS holds the car with −HOLD_DECEL_MPS2 and resets the integrator;
    mode 1 = brake: PI before ``brake_t0``, then the constant demand −``brake_decel`` (no ABS) down to
    standstill and on (the brakes then hold the car). The integrator is clamped (anti-windup).
    """
    if mode == 1 and t >= brake_t0:
        return -brake_decel, integral
    if v_target <= STOP_TARGET_MPS and vx < HOLD_BELOW_MPS:
        return -HOLD_DECEL_MPS2, 0.0
    err = v_target - vx
    integral = min(max(integral + err * dt, -MAX_ACCEL_DEMAND / SPEED_KI), MAX_ACCEL_DEMAND / SPEED_KI)
    a = dv_target + SPEED_KP * err + SPEED_KI * integral
    return min(max(a, -MAX_DECEL_DEMAND), MAX_ACCEL_DEMAND), integral


@jit
def follow_lead_target(v_lead: float, range_m: float, vx: float, time_gap_s: float, standstill_m: float) -> float:
    """Target speed of the time-gap follower: lead speed + GAP_GAIN × (range − desired gap) [m/s]."""
    desired = standstill_m + time_gap_s * vx
    return max(v_lead + GAP_GAIN * (range_m - desired), 0.0)
