"""The search space of ``roadtruth falsify``: bounded parameters and the scenario each point builds.

A point of the space is a dict ``{parameter: value}``. Each parameter perturbs one part of a base
scenario, and :func:`build_candidate` turns a point into the three inputs of a normal run: the
scenario mapping (as a scenario YAML holds it), the vehicle mapping (as a vehicle YAML holds it)
and a ``--faults`` string. So the worst case is written out as a ready scenario file.

Parameters (every one optional; a space file names the ones to search):

=========================== ======= ==============================================================
name                        unit    what it changes
=========================== ======= ==============================================================
``patch_mu``                1       μ of a friction patch laid on the road (added after the
                                    scenario's own patches, so it wins where they overlap)
``patch_start_m``           m       where the patch starts, along the road from the car's start
``patch_length_m``          m       its length along the road
``patch_side``              —       ``both`` (the whole lane), ``left`` or ``right`` half (split-μ)
``patch_t_start_s``         s       the patch exists from this time on (a μ step in time)
``speed_mps``               m/s     initial speed (and the held target speed, if the driver holds one)
``steer_amplitude_deg``     deg     ``driver.steer.amplitude_deg``
``steer_frequency_hz``      Hz      ``driver.steer.frequency_hz``
``steer_dwell_s``           s       ``driver.steer.dwell_s``
``mass_scale``              1       vehicle mass × this
``cg_shift_m``              m       CG moved forward by this (l_f − d, l_r + d; wheelbase kept)
``cornering_stiffness_scale`` 1     both axles' lateral Magic Formula stiffness factor B × this
``fault:SENSOR[.CH]:KIND``  as the  the main number of a ``--faults`` item (docs/SENSORS.md), e.g.
                            fault   ``fault:gnss:dropout``, ``fault:imu.ay_mps2:bias_step``
``fault:SENSOR:KIND:PARAM``         another parameter of that item, e.g. ``fault:camera:burst:mean_len``
=========================== ======= ==============================================================

A space file::

    parameters:
      patch_mu: {low: 0.1, high: 1.0, nominal: 1.0}
      patch_start_m: {low: 10, high: 40}          # no nominal: "where", not "how much"
      patch_side: {choices: [both, left, right]}
      speed_mps: {low: 10, high: 25}
      "fault:gnss:dropout": {low: 0.0, high: 0.8, nominal: 0.0}
      mass_scale: 1.1                               # a fixed value (not searched)

``nominal`` is the unperturbed value; the parameters that have one define the *distance* of a point
from the nominal scenario, ``sqrt(Σ ((x − nominal) / (high − low))²)`` over the searched numeric
parameters (a categorical parameter adds 1 when it differs from its nominal). The smallest perturbation
that breaks a property is the violating case with the least distance.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.harness.files.strict_yaml import Fields, load_mapping, short_repr

PATCH_SIDES = ("both", "left", "right")
#: How far the patch reaches past the lane edge on each side [m], so that a wheel drifting a little
#: out of the lane is still on it (the sedan's half track is 0.8 m, half a 3.5 m lane 1.75 m).
PATCH_MARGIN_M = 1.5
#: Most vertices along one edge of a patch polygon (enough to follow an arc, few for the compiled loop).
PATCH_EDGE_POINTS = 24
BUILTIN: dict[str, str] = {
    "patch_mu": "1", "patch_start_m": "m", "patch_length_m": "m", "patch_side": "", "patch_t_start_s": "s",
    "speed_mps": "m/s", "steer_amplitude_deg": "deg", "steer_frequency_hz": "Hz", "steer_dwell_s": "s",
    "mass_scale": "1", "cg_shift_m": "m", "cornering_stiffness_scale": "1",
}
PATCH_KEYS = ("patch_mu", "patch_start_m", "patch_length_m", "patch_side", "patch_t_start_s")


class SpaceError(InputError):
    """A falsification space file (or a parameter in it) is invalid."""


@dataclass(frozen=True)
class Parameter:
    """One parameter: searched in [low, high] (or over ``choices``), or fixed at ``fixed``."""

    name: str
    low: float = math.nan
    high: float = math.nan
    nominal: float | str | None = None
    choices: tuple[str, ...] = ()
    fixed: float | str | None = None

    @property
    def searched(self) -> bool:
        return self.fixed is None

    @property
    def categorical(self) -> bool:
        return bool(self.choices)

    def to_dict(self) -> dict[str, Any]:
        if not self.searched:
            return {"fixed": self.fixed}
        if self.categorical:
            return {"choices": list(self.choices), "nominal": self.nominal}
        return {"low": self.low, "high": self.high, "nominal": self.nominal}


@dataclass(frozen=True)
class Space:
    """The parameters, in the order the space gives them (that order fixes the sampler's draws)."""

    parameters: tuple[Parameter, ...]
    source: str

    @property
    def searched(self) -> tuple[Parameter, ...]:
        return tuple(p for p in self.parameters if p.searched)

    def fixed_values(self) -> dict[str, Any]:
        return {p.name: p.fixed for p in self.parameters if not p.searched}

    def nominal_point(self) -> dict[str, Any] | None:
        """Every searched parameter at its nominal (one without: the middle of its range, its first
        choice), or None if no parameter has a nominal."""
        if all(p.nominal is None for p in self.searched):
            return None

        def value(p: Parameter) -> Any:
            if p.nominal is not None:
                return p.nominal
            return p.choices[0] if p.categorical else 0.5 * (p.low + p.high)

        return {**{p.name: value(p) for p in self.searched}, **self.fixed_values()}

    def distance(self, point: dict[str, Any]) -> float:
        """Normalised distance of a point from the nominal (the parameters with a nominal only)."""
        total = 0.0
        for p in self.searched:
            if p.nominal is None or p.name not in point:
                continue
            if p.categorical:
                total += 0.0 if point[p.name] == p.nominal else 1.0
            else:
                total += ((float(point[p.name]) - float(p.nominal)) / (p.high - p.low)) ** 2
        return math.sqrt(total)

    def to_dict(self) -> dict[str, Any]:
        return {"parameters": {p.name: p.to_dict() for p in self.parameters}}


# ---- parsing -------------------------------------------------------------------------------------

def _check_name(name: str, source: str) -> None:
    if name in BUILTIN:
        return
    if name.startswith("fault:") and len(name.split(":")) in (3, 4) and all(name.split(":")[1:]):
        return
    raise SpaceError(f"unknown parameter {name!r} (known: {', '.join(BUILTIN)}, fault:SENSOR[.CHANNEL]:KIND"
                     "[:PARAM])", source=source, field=f"parameters.{name}")


def _parameter(name: str, raw: Any, source: str) -> Parameter:
    _check_name(name, source)
    field = f"parameters.{name}"
    if isinstance(raw, bool) or raw is None:
        raise SpaceError(f"must be a number, a name or a mapping (got {short_repr(raw)})", source=source, field=field)
    if isinstance(raw, int | float | str):
        if name == "patch_side" and raw not in PATCH_SIDES:
            raise SpaceError(f"must be one of {', '.join(PATCH_SIDES)} (got {short_repr(raw)})", source=source,
                             field=field)
        if name != "patch_side" and isinstance(raw, str):
            raise SpaceError(f"must be a number (got {short_repr(raw)})", source=source, field=field)
        return Parameter(name, fixed=raw if isinstance(raw, str) else float(raw))
    f = Fields(raw, source=source, error=SpaceError, prefix=field)
    if name == "patch_side":
        choices = f.items("choices")
        bad = [c for c in choices if c not in PATCH_SIDES] or ([] if choices else ["(none)"])
        if bad:
            raise f.fail("choices", f"each must be one of {', '.join(PATCH_SIDES)} (got {short_repr(bad[0])})")
        nominal = f.string("nominal", None, choices=PATCH_SIDES)
        f.done()
        return Parameter(name, choices=tuple(dict.fromkeys(choices)), nominal=nominal)
    low = f.number("low")
    high = f.number("high")
    if not high > low:
        raise f.fail("high", f"must be above low {low:g} (got {high:g})")
    nominal = f.number("nominal", None)
    if nominal is not None and not low <= nominal <= high:
        raise f.fail("nominal", f"must be inside [{low:g}, {high:g}] (got {nominal:g})")
    f.done()
    return Parameter(name, low=low, high=high, nominal=nominal)


def load_space(path: str | Path) -> Space:
    """Read and check a space YAML (see the module doc). Raises :class:`SpaceError` naming file and field."""
    src = str(path)
    f = Fields(load_mapping(path, SpaceError), source=src, error=SpaceError)
    raw = f.raw("parameters")
    f.done()
    if not isinstance(raw, dict) or not raw:
        raise SpaceError(f"must be a non-empty mapping of parameters (got {short_repr(raw)})", source=src,
                         field="parameters")
    params = tuple(_parameter(str(k), v, src) for k, v in raw.items())
    space = Space(params, src)
    if not space.searched:
        raise SpaceError("no parameter is searched (every one is fixed)", source=src, field="parameters")
    return space


def default_space(base: Any) -> Space:
    """A space for a scenario with no space file: a μ patch on the road it drives, its speed, its
    steering amplitude (if it has one) and the vehicle's mass, CG and cornering stiffness.

    The patch lies between 15 % and 65 % of the distance the car covers at its initial speed, is
    2 m to a third of that distance long, with μ from ice (0.1) up to the scenario's own μ.
    """
    distance = base.initial_speed_mps * base.duration_s
    mu0 = float(base.friction.mu_default)
    v0 = base.initial_speed_mps
    params = [
        Parameter("patch_mu", low=0.1, high=max(mu0, 0.2), nominal=max(mu0, 0.2)),
        Parameter("patch_start_m", low=round(0.15 * distance, 1), high=round(0.65 * distance, 1)),
        Parameter("patch_length_m", low=2.0, high=round(max(distance / 3.0, 4.0), 1), nominal=2.0),
        Parameter("speed_mps", low=round(max(5.0, 0.7 * v0), 2), high=round(min(60.0, 1.3 * v0), 2), nominal=v0),
    ]
    amp = getattr(base.driver.steer, "amplitude_rad", 0.0)
    if base.driver.steer.type not in ("path_follower", "ramp") and amp:
        a = math.degrees(amp)
        lo, hi = sorted((0.5 * a, 1.5 * a))
        params.append(Parameter("steer_amplitude_deg", low=round(lo, 3), high=round(hi, 3), nominal=round(a, 3)))
    params += [Parameter("mass_scale", low=0.85, high=1.15, nominal=1.0),
               Parameter("cg_shift_m", low=-0.1, high=0.1, nominal=0.0),
               Parameter("cornering_stiffness_scale", low=0.8, high=1.2, nominal=1.0)]
    return Space(tuple(params), f"default space of {base.name}")


# ---- building a candidate ------------------------------------------------------------------------

def _patch_polygon(road: Any, s0: float, length: float, side: str) -> list[list[float]]:
    """A polygon following the road from s0 over ``length`` [m], across the lane (or one half)."""
    samples = road.samples
    s = samples[:, 0]
    s1 = min(s0 + length, float(s[-1]))
    n = int(min(PATCH_EDGE_POINTS, max(2, math.ceil((s1 - s0) / 1.0) + 1)))
    ss = np.linspace(s0, s1, n)
    x = np.interp(ss, s, samples[:, 1])
    y = np.interp(ss, s, samples[:, 2])
    psi = np.interp(ss, s, np.unwrap(samples[:, 3]))
    half = road.lane_width_m / 2.0 + PATCH_MARGIN_M
    left, right = {"both": (half, -half), "left": (half, 0.0), "right": (0.0, -half)}[side]
    nx, ny = -np.sin(psi), np.cos(psi)  # unit normal to the left of the road
    edge_l = [[round(float(a), 4), round(float(b), 4)] for a, b in zip(x + left * nx, y + left * ny, strict=True)]
    edge_r = [[round(float(a), 4), round(float(b), 4)] for a, b in zip(x + right * nx, y + right * ny, strict=True)]
    return edge_l + edge_r[::-1]


def _fault_items(point: dict[str, Any]) -> str | None:
    """The ``--faults`` string of a point's ``fault:`` parameters (main numbers, then named ones)."""
    main: dict[tuple[str, str], float] = {}
    extra: dict[tuple[str, str], dict[str, float]] = {}
    for name, value in point.items():
        if not name.startswith("fault:"):
            continue
        parts = name.split(":")
        key = (parts[1], parts[2])
        if len(parts) == 3:
            main[key] = float(value)
        else:
            extra.setdefault(key, {})[parts[3]] = float(value)
    items = []
    for key in dict.fromkeys([*main, *extra]):
        sensor, kind = key
        text = f"{sensor}:{kind}" + (f"={main[key]:.6g}" if key in main else "")
        if key in extra:
            text += "(" + ",".join(f"{k}={v:.6g}" for k, v in extra[key].items()) + ")"
        items.append(text)
    return ",".join(items) or None


def _vehicle_mapping(data: dict[str, Any], point: dict[str, Any]) -> dict[str, Any] | None:
    """The base vehicle mapping with the point's perturbations, or None if it has none."""
    keys = ("mass_scale", "cg_shift_m", "cornering_stiffness_scale")
    if not any(k in point for k in keys):
        return None
    v = copy.deepcopy(data)
    if "mass_scale" in point:
        v["mass_kg"] = round(float(v["mass_kg"]) * float(point["mass_scale"]), 6)
        for k in ("yaw_inertia_kgm2", "roll_inertia_kgm2", "pitch_inertia_kgm2"):
            if k in v:  # the same body, heavier: inertias scale with the mass
                v[k] = round(float(v[k]) * float(point["mass_scale"]), 6)
    if "cg_shift_m" in point:
        d = float(point["cg_shift_m"])
        v["lf_m"] = round(float(v["lf_m"]) - d, 6)
        v["lr_m"] = round(float(v["lr_m"]) + d, 6)
    if "cornering_stiffness_scale" in point:
        k = float(point["cornering_stiffness_scale"])
        for axle in ("front", "rear"):
            tire = v["tires"][axle]
            key = "By" if "By" in tire else "cornering_stiffness_Npr"
            tire[key] = round(float(tire[key]) * k, 6)
    v["name"] = f"{v.get('name', 'vehicle')}_perturbed"
    return v


@dataclass(frozen=True)
class Candidate:
    """What a point builds: a scenario mapping, a vehicle mapping (None = the scenario's own) and faults."""

    scenario: dict[str, Any]
    vehicle: dict[str, Any] | None
    faults: str | None


def build_candidate(scenario_data: dict[str, Any], vehicle_data: dict[str, Any], base: Any,
                    point: dict[str, Any]) -> Candidate:
    """Apply a point to the base scenario's mapping (``base`` = the parsed base scenario, for its road)."""
    sc = copy.deepcopy(scenario_data)
    if "patch_mu" in point:
        s0 = float(point.get("patch_start_m", 0.25 * base.initial_speed_mps * base.duration_s))
        length = float(point.get("patch_length_m", 10.0))
        side = str(point.get("patch_side", "both"))
        patch: dict[str, Any] = {"name": "falsify_patch", "mu": round(float(point["patch_mu"]), 6),
                                 "polygon": _patch_polygon(base.road, s0, length, side)}
        if "patch_t_start_s" in point:
            patch["t_s"] = [round(float(point["patch_t_start_s"]), 6), None]
        fr = sc.get("friction") or {}
        fr = dict(fr)
        fr["patches"] = [*list(fr.get("patches") or []), patch]
        sc["friction"] = fr
    driver = sc.setdefault("driver", {}) or {}
    sc["driver"] = driver
    if "speed_mps" in point:
        v = round(float(point["speed_mps"]), 6)
        sc["initial_speed_mps"] = v
        speed = driver.get("speed")
        if isinstance(speed, dict) and speed.get("type") == "hold" and "target_mps" in speed:
            driver["speed"] = {**speed, "target_mps": v}
    steer = driver.get("steer")
    for key, field in (("steer_amplitude_deg", "amplitude_deg"), ("steer_frequency_hz", "frequency_hz"),
                       ("steer_dwell_s", "dwell_s")):
        if key in point:
            if not isinstance(steer, dict):
                raise SpaceError(f"the scenario's steering has no {field} (it has no open-loop steer block)",
                                 field=f"parameters.{key}")
            steer = {**steer, field: round(float(point[key]), 6)}
            driver["steer"] = steer
    return Candidate(sc, _vehicle_mapping(vehicle_data, point), _fault_items(point))


__all__ = ["BUILTIN", "Candidate", "PATCH_SIDES", "Parameter", "Space", "SpaceError", "build_candidate",
           "default_space", "load_space"]
