"""What the simulated car did that no observer can be blamed for: truth events with their times.

Detected vectorised on the finished truth frame (never inside the compiled stepping loop), so the
thresholds below can change without touching the simulation. Each event is a :class:`TruthEvent`
``(t_s, kind, detail)``; ``kind`` is one of :data:`KINDS`:

``spun out``
    The car is in a spin: ``|beta| > SPIN_BETA_RAD`` while the speed is above ``SPIN_MIN_SPEED_MPS``,
    or, where the driver follows the road, the heading is more than ``SPIN_HEADING_RAD`` off the
    road's heading.
``left the road``
    Where the driver follows the road: the CG is further from the centre line than half the lane width
    plus half the vehicle's track (the whole car is outside its lane).
``wheel lift``
    A wheel's normal load stays below ``WHEEL_LIFT_LOAD_FRACTION`` of its static load for at least
    ``WHEEL_LIFT_MIN_DURATION_S`` (one event per wheel and lift).
``rolled over``
    The simulator's roll guard tripped (roll past 80 degrees; the frame ends there).
``tire beyond its data``
    A wheel's slip angle, slip ratio, inclination or load leaves the range its tire property file
    declares (ALPMIN/ALPMAX, KPUMIN/KPUMAX, CAMMIN/CAMMAX, FZMIN/FZMAX): the forces there are the
    formula's extrapolation, not the tire's measured data (``detect_tire_range``).
``stopped``
    The speed falls below ``STOPPED_SPEED_MPS`` after having been above ``MOVED_SPEED_MPS`` (each stop
    of a stop-and-go drive). At rest sideslip is undefined (NaN in the truth), so those samples are
    not scored, and an observer silent there is not counted as missing.

Road-relative checks need a road the car is asked to follow: with an open-loop steering profile the
road is only a nominal straight line (a step steer drives a circle off it by design), so they apply
only when the driver is a path follower.

Scoring stops at the first event of :data:`ENDS_SCORING` (a spin-out or a roll-over): what follows is
the car going backwards or on its roof, not an observer's error. No margin is taken before it
(``SCORING_MARGIN_S = 0``): the truth is valid up to the limit, and the run-up to it (a growing
sideslip) is exactly the regime the observers claim to estimate; a margin would only move the limit.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.signals import WHEELS

#: |sideslip| past which the car is spinning [rad]. The stable region of a passenger car's
#: beta-beta' phase plane ends well below 20 deg even on dry asphalt (Inagaki, Kshiro & Yamamoto,
#: 1995, AVEC '94 / JSAE Review), so 20 deg is past recovery on any surface; no shipped manoeuvre on
#: its own friction comes near it (peak |beta| 8.3 deg, sine with dwell).
SPIN_BETA_RAD = math.radians(20.0)
#: Heading off the road past which the car has spun [rad]: NHTSA's spin-out criterion for its ESC
#: tests (heading >= 90 deg from the intended one; Forkenbrock, Elsasser & O'Harra, 2005, ESV paper
#: 05-0221), applied relative to the road the driver follows.
SPIN_HEADING_RAD = math.radians(90.0)
#: Below this speed sideslip is geometry, not a loss of control (a car turning on the spot has any
#: beta); the tire model's own lower limit of a scenario's initial speed [m/s].
SPIN_MIN_SPEED_MPS = 3.0
#: Fraction of the static wheel load under which a wheel counts as lifted (the radial tire spring
#: gives exactly 0 N off the ground; 5 % leaves room for the damper's pull at the instant of lift).
WHEEL_LIFT_LOAD_FRACTION = 0.05
#: A lift must last this long [s]: shorter is a wheel hop over a bump, not a tip-up.
WHEEL_LIFT_MIN_DURATION_S = 0.1
#: Speed under which the car has stopped [m/s], and the speed it must have had before [m/s].
STOPPED_SPEED_MPS = 0.3
MOVED_SPEED_MPS = 1.0
#: Scored time ends this long before the first event of ENDS_SCORING [s] (see module docstring).
SCORING_MARGIN_S = 0.0

KINDS: tuple[str, ...] = ("spun out", "left the road", "wheel lift", "rolled over", "stopped",
                          "tire beyond its data")
ENDS_SCORING: frozenset[str] = frozenset({"spun out", "rolled over"})


@dataclass(frozen=True)
class TruthEvent:
    """One thing the car did: time [s], ``kind`` (one of ``KINDS``) and a short ``detail``."""

    t_s: float
    kind: str
    detail: str = ""

    @property
    def label(self) -> str:
        """The event as the report's time line shows it, e.g. ``spun out (|β| > 20°)``."""
        return f"{self.kind} ({self.detail})" if self.detail else self.kind

    def to_dict(self) -> dict[str, Any]:
        return {"t_s": float(self.t_s), "kind": self.kind, "detail": self.detail, "label": self.label}


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (exclusive) indices of the runs of True in a 1-D bool array."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def _first(mask: np.ndarray) -> int | None:
    hit = np.flatnonzero(mask)
    return int(hit[0]) if hit.size else None


def _column(frame: pd.DataFrame, name: str) -> np.ndarray | None:
    return frame[name].to_numpy(dtype=float) if name in frame.columns else None


def detect_spin(t: np.ndarray, beta: np.ndarray, speed: np.ndarray,
                heading_off_road: np.ndarray | None = None) -> TruthEvent | None:
    """The first spin-out: ``|beta| > SPIN_BETA_RAD`` above ``SPIN_MIN_SPEED_MPS``, or the heading
    more than ``SPIN_HEADING_RAD`` off the road (``heading_off_road`` [rad], wrapped; None: no road)."""
    by_beta = (np.abs(beta) > SPIN_BETA_RAD) & (speed > SPIN_MIN_SPEED_MPS)
    k_beta = _first(by_beta)
    k_head = _first(np.abs(heading_off_road) > SPIN_HEADING_RAD) if heading_off_road is not None else None
    if k_beta is None and k_head is None:
        return None
    if k_head is None or (k_beta is not None and k_beta <= k_head):
        return TruthEvent(float(t[k_beta]), "spun out", f"|β| > {math.degrees(SPIN_BETA_RAD):.0f}°")
    return TruthEvent(float(t[k_head]), "spun out",
                      f"heading {math.degrees(SPIN_HEADING_RAD):.0f}° off the road")


def detect_wheel_lift(t: np.ndarray, fz: np.ndarray, fz_static_N: Sequence[float]) -> list[TruthEvent]:
    """Every lift of a wheel: ``fz[:, i] < WHEEL_LIFT_LOAD_FRACTION * fz_static_N[i]`` for at least
    ``WHEEL_LIFT_MIN_DURATION_S``. ``fz``: (n, 4) loads [N] in ``WHEELS`` order; the event time is the
    start of the lift."""
    out: list[TruthEvent] = []
    if t.size == 0:
        return out
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    for i, w in enumerate(WHEELS):
        low = fz[:, i] < WHEEL_LIFT_LOAD_FRACTION * float(fz_static_N[i])
        starts, ends = _runs(low)
        for a, b in zip(starts, ends, strict=True):
            # a run of samples a..b-1 stands for the time t[a] .. t[b-1] + dt
            if t[b - 1] + dt - t[a] >= WHEEL_LIFT_MIN_DURATION_S - 1e-9:
                out.append(TruthEvent(float(t[a]), "wheel lift", w))
    return out


def detect_events(frame: pd.DataFrame, *, fz_static_N: Sequence[float] | None = None, road: Any = None,
                  half_track_m: float = 0.0, divergence: tuple[float, str] | None = None
                  ) -> tuple[TruthEvent, ...]:
    """All truth events of a frame, sorted by time.

    Parameters
    ----------
    frame : truth frame (``t_s, vx_mps, vy_mps, beta_rad`` and, where present, ``x_m, y_m, s_m,
        fz_<wheel>_N``).
    fz_static_N : (4,) static wheel loads [N] for wheel lift (None: the median of the first 5 % of
        the record, where the car runs straight at its initial speed).
    road : the ``roadtruth.harness.truth.road.Road`` the driver follows, or None (no road-relative checks).
    half_track_m : half the vehicle's track [m], the margin past the lane edge for ``left the road``.
    divergence : ``(t_s, cause)`` where the simulator stopped, or None; cause ``rolled over`` is an event.
    """
    t = _column(frame, "t_s")
    events: list[TruthEvent] = []
    if t is not None and t.size:
        vx, vy = _column(frame, "vx_mps"), _column(frame, "vy_mps")
        beta = _column(frame, "beta_rad")
        if beta is None and vx is not None and vy is not None:
            beta = np.arctan2(vy, vx)
        speed = np.hypot(vx, vy) if vx is not None and vy is not None else np.full(t.size, np.inf)
        heading_off = None
        offset = None
        x, y, s = _column(frame, "x_m"), _column(frame, "y_m"), _column(frame, "s_m")
        if road is not None and x is not None and y is not None:
            proj = road.project(x, y, s_hint_m=s if s is not None and np.isfinite(s).all() else None)
            psi = _column(frame, "psi_rad")
            if psi is not None:
                d = psi - proj["psi_rad"]
                heading_off = np.arctan2(np.sin(d), np.cos(d))
            offset = proj["e_left_m"]
        if beta is not None:
            spin = detect_spin(t, beta, speed, heading_off)
            if spin is not None:
                events.append(spin)
        if offset is not None:
            edge = 0.5 * float(road.lane_width_m) + float(half_track_m)
            k = _first(np.abs(offset) > edge)
            if k is not None:
                side = "left" if offset[k] > 0 else "right"
                events.append(TruthEvent(float(t[k]), "left the road", f"{abs(offset[k]):.1f} m {side} of the centre line"))
        cols = [f"fz_{w}_N" for w in WHEELS]
        if all(c in frame.columns for c in cols):
            fz = frame[cols].to_numpy(dtype=float)
            static = (np.asarray(fz_static_N, dtype=float) if fz_static_N is not None
                      else np.median(fz[: max(1, t.size // 20)], axis=0))
            events.extend(detect_wheel_lift(t, fz, static))
        if vx is not None and vy is not None:
            events.extend(TruthEvent(float(t[k]), "stopped") for k in _stops(speed))
    if divergence is not None and divergence[1] == "rolled over":
        events.append(TruthEvent(float(divergence[0]), "rolled over"))
    return tuple(sorted(events, key=lambda e: (e.t_s, KINDS.index(e.kind))))


def detect_tire_range(frame: pd.DataFrame, ranges: dict[str, tuple[float, float]]) -> list[TruthEvent]:
    """First time each wheel leaves the range its tire file was fitted over (one event per wheel).

    ``ranges``: ``alpha_rad``, ``kappa``, ``gamma_rad`` and ``fz_N`` -> (lo, hi) in roadtruth's signs.
    While rolling only (|v_x| >= 1 m/s): the slips of a tire at rest are its deflection, not data.
    """
    out: list[TruthEvent] = []
    t = frame["t_s"].to_numpy()
    rolling = np.abs(frame["vx_mps"].to_numpy()) >= MOVED_SPEED_MPS
    for w in WHEELS:
        bad = np.zeros(t.size, dtype=bool)
        why = ""
        for quantity, (lo, hi) in ranges.items():
            col = f"{quantity.split('_')[0]}_{w}" + (f"_{quantity.split('_', 1)[1]}" if "_" in quantity else "")
            if col not in frame.columns:
                continue
            x = frame[col].to_numpy()
            out_k = rolling & ((x < lo) | (x > hi))
            k = _first(out_k)
            if k is not None and (not bad.any() or k < _first(bad)):
                why = f"{w}: {quantity} {x[k]:.3g} outside the file's [{lo:.3g}, {hi:.3g}]"
            bad |= out_k
        k = _first(bad)
        if k is not None:
            out.append(TruthEvent(float(t[k]), "tire beyond its data", why))
    return out


def _stops(speed: np.ndarray) -> list[int]:
    """Indices where the speed falls below STOPPED_SPEED_MPS after being above MOVED_SPEED_MPS since
    the previous stop (every stop of a stop-and-go drive, none for a car standing still)."""
    out: list[int] = []
    k = 0
    n = speed.size
    while k < n:
        moved = np.flatnonzero(speed[k:] > MOVED_SPEED_MPS)
        if not moved.size:
            break
        k += int(moved[0])
        slow = np.flatnonzero(speed[k:] < STOPPED_SPEED_MPS)
        if not slow.size:
            break
        k += int(slow[0])
        out.append(k)
    return out


def scoring_end_s(events: Iterable[TruthEvent]) -> float | None:
    """Where scoring stops [s]: the first spin-out or roll-over minus ``SCORING_MARGIN_S``; None if
    the car did neither."""
    ends = [e.t_s for e in events if e.kind in ENDS_SCORING]
    return min(ends) - SCORING_MARGIN_S if ends else None


def truth_status(events: Iterable[TruthEvent], sim_status: str = "ok") -> str:
    """One line saying what the car did: ``ok``, or the first event of each kind in time order
    (``spun out at t=3.41 s; left the road at t=3.90 s``), or the simulator's own failure
    (``diverged: …``, ``error: …``) when it stopped for a reason that is not an event."""
    first: dict[str, TruthEvent] = {}
    for e in sorted(events, key=lambda e: e.t_s):
        first.setdefault(e.kind, e)
    parts = [f"{e.kind} at t={e.t_s:.2f} s" for e in first.values()]
    if sim_status != "ok" and "rolled over" not in first:
        parts.append(sim_status)
    return "; ".join(parts) if parts else "ok"


def status_of(truth: Any) -> str:
    """:func:`truth_status` of a ``Truth`` (or of a stand-in without events, e.g. a failed simulation)."""
    return truth_status(getattr(truth, "truth_events", ()) or (), str(getattr(truth, "status", "ok")))


def scored_until_of(truth: Any) -> float | None:
    """:func:`scoring_end_s` of a ``Truth`` (None for a stand-in without events)."""
    return scoring_end_s(getattr(truth, "truth_events", ()) or ())
