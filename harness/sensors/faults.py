"""Composable sensor faults: what they are, how they are written, and what they do to a sample stream.

Three kinds of fault act on a sensor's samples, in this order:

* **value faults** change transmitted values, in the order given: ``bias_step`` (a constant added
  inside a time window), ``spike`` (with probability ``p`` per sample and channel, ±``magnitude``),
  ``freeze`` (the output holds its last value, or a given ``value``, inside a window);
* **availability faults** remove samples (NaN, ``<sensor>_valid = 0``): ``dropout`` (independent,
  probability ``p``), ``burst`` (Gilbert–Elliott two-state Markov chain: good -> bad with ``p_enter``
  per sample, mean bad run ``mean_len`` samples, loss probability ``loss_good`` / ``loss_bad`` in
  each state), ``outage`` (a scheduled time window);
* **timing faults** add delay: ``delay`` (``extra_s`` plus uniform ``[0, jitter_s)`` per sample inside a
  window). Samples then arrive late, possibly out of order; two samples arriving at one row keep
  the newer.

A missing sample is never replaced by a value: faults never turn a NaN into a number.
Every fault draws from its own stream keyed by (sensor, kind, ordinal among that sensor's faults of
that kind), so adding a fault never changes another's draws. CLI syntax: see :func:`parse_faults`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from roadtruth.harness.errors import SensorConfigError
from roadtruth.harness.files.strict_yaml import Fields, load_mapping

REQUIRED = object()


@dataclass(frozen=True)
class FaultKind:
    scope: str                      # value | availability | timing
    params: dict[str, tuple[Any, float, float]]  # name -> (default or REQUIRED, lo, hi)
    primary: str | None             # parameter set by the ``kind=NUMBER`` shorthand
    per_channel: bool               # may be restricted to one channel


INF = math.inf
WINDOW = {"t_start_s": (0.0, 0.0, INF), "t_end_s": (INF, 0.0, INF)}
FAULT_KINDS: dict[str, FaultKind] = {
    "dropout": FaultKind("availability", {"p": (REQUIRED, 0.0, 1.0)}, "p", False),
    "burst": FaultKind("availability", {"p_enter": (REQUIRED, 0.0, 1.0), "mean_len": (5.0, 1.0, 1e9),
                                        "loss_good": (0.0, 0.0, 1.0), "loss_bad": (1.0, 0.0, 1.0)},
                       "p_enter", False),
    # Removes only the named channel (or group of channels, e.g. gnss.position) from a sample; the
    # sample itself still arrives (the receiver keeps reporting velocity without a position fix).
    "channel_dropout": FaultKind("partial", {"p": (REQUIRED, 0.0, 1.0)}, "p", True),
    "outage": FaultKind("availability", {"t_start_s": (REQUIRED, 0.0, INF), "t_end_s": (REQUIRED, 0.0, INF)},
                        None, False),
    "bias_step": FaultKind("value", {"size": (REQUIRED, -INF, INF), **WINDOW}, "size", True),
    "spike": FaultKind("value", {"p": (REQUIRED, 0.0, 1.0), "magnitude": (REQUIRED, 0.0, INF)}, "p", True),
    "freeze": FaultKind("value", {"t_start_s": (REQUIRED, 0.0, INF), "t_end_s": (INF, 0.0, INF),
                                  "value": (None, -INF, INF)}, "t_start_s", True),
    "delay": FaultKind("timing", {"extra_s": (REQUIRED, 0.0, 10.0), "jitter_s": (0.0, 0.0, 10.0), **WINDOW},
                       "extra_s", False),
}


@dataclass(frozen=True)
class FaultSpec:
    """One fault on one sensor (optionally one output channel of it)."""

    sensor: str
    kind: str
    params: dict[str, float | None] = field(default_factory=dict)
    channel: str | None = None

    def label(self) -> str:
        where = f"{self.sensor}.{self.channel}" if self.channel else self.sensor
        args = ",".join(f"{k}={v:g}" for k, v in self.params.items() if v is not None)
        return f"{where}:{self.kind}({args})"


def make_fault(sensor: str, kind: str, params: Mapping[str, Any], channel: str | None, *,
               source: str, field_name: str) -> FaultSpec:
    """Check a fault's kind and parameters (ranges, required ones, windows) and build it."""
    if kind not in FAULT_KINDS:
        raise SensorConfigError(f"unknown fault {kind!r} (known: {', '.join(FAULT_KINDS)})",
                                source=source, field=field_name)
    fk = FAULT_KINDS[kind]
    if channel is None and fk.scope == "partial":
        raise SensorConfigError(f"fault {kind!r} needs a channel (SENSOR.CHANNEL:{kind}=P)",
                                source=source, field=field_name)
    if channel is not None and not fk.per_channel:
        raise SensorConfigError(f"fault {kind!r} acts on whole samples; it takes no channel (got {channel!r})",
                                source=source, field=field_name)
    f = Fields(dict(params), source=source, error=SensorConfigError, prefix=field_name)
    values: dict[str, float | None] = {}
    for name, (default, lo, hi) in fk.params.items():
        raw = f.raw(name, ... if default is REQUIRED else default)
        if raw is None:
            values[name] = None
            continue
        if isinstance(raw, str) and raw.strip().lower() in ("inf", "+inf"):
            raw = INF
        if isinstance(raw, bool) or not isinstance(raw, (int, float)) or math.isnan(raw):
            raise f.fail(name, f"must be a number (got {raw!r})")
        if not (lo <= raw <= hi) or (math.isinf(raw) and name != "t_end_s"):
            raise f.fail(name, f"must be >= {lo:g} and <= {hi:g} (got {raw!r})")
        values[name] = float(raw)
    f.done()
    if "t_end_s" in values and values["t_end_s"] is not None and values["t_end_s"] < values["t_start_s"]:
        raise SensorConfigError(f"t_end_s {values['t_end_s']:g} is before t_start_s {values['t_start_s']:g}",
                                source=source, field=field_name)
    return FaultSpec(sensor=sensor, kind=kind, params=values, channel=channel)


# ---- parsing --------------------------------------------------------------------------------------

_ITEM = re.compile(r"^\s*(?P<sensor>[A-Za-z_]\w*)(?:\.(?P<channel>[A-Za-z_]\w*))?\s*:\s*(?P<kind>[A-Za-z_]\w*)"
                   r"\s*(?:=\s*(?P<primary>[^()\s]+))?\s*(?:\((?P<args>[^()]*)\))?\s*$")


def _number(text: str, source: str, field_name: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise SensorConfigError(f"not a number: {text!r}", source=source, field=field_name) from None


def _split_top_level(spec: str) -> list[str]:
    """Split at ',' or ';' outside parentheses."""
    parts, depth, cur = [], 0, []
    for ch in spec:
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth -= 1
        if ch in ",;" and depth == 0:
            parts.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    parts.append("".join(cur))
    return [p for p in (s.strip() for s in parts) if p]


def parse_faults(spec: str | Sequence[Any] | None, source: str = "--faults") -> tuple[FaultSpec, ...]:
    """Parse faults from a CLI string, a YAML file path, or a list (of FaultSpec or mappings).

    CLI syntax (items separated by ``,`` or ``;`` outside parentheses)::

        SENSOR[.CHANNEL]:KIND[=NUMBER][(NAME=NUMBER, ...)]

    ``KIND=NUMBER`` sets the kind's main parameter (``dropout``/``spike``: ``p``; ``burst``: ``p_enter``;
    ``bias_step``: ``size``; ``freeze``: ``t_start_s``; ``delay``: ``extra_s``). Examples:
    ``gnss:dropout=0.2``, ``camera:burst(p_enter=0.02,mean_len=8)``,
    ``imu.ay_mps2:bias_step(size=0.5,t_start_s=10)``, ``gnss:outage(t_start_s=5,t_end_s=8)``.

    A YAML file holds ``faults:`` — a list of mappings ``{sensor: gnss, fault: dropout, p: 0.2}``
    (``channel:`` optional). Sensor and channel names are checked against the suite later, by
    :func:`roadtruth.harness.sensors.config.load_sensor_config`.
    """
    if spec is None:
        return ()
    if isinstance(spec, str):
        text = spec.strip()
        if text.lower().endswith((".yaml", ".yml")):
            data = load_mapping(text, SensorConfigError)
            f = Fields(data, source=text, error=SensorConfigError)
            items = f.items("faults")
            f.done()
            return parse_fault_list(items, source=text)
        out = []
        for i, item in enumerate(_split_top_level(text)):
            m = _ITEM.match(item)
            where = f"item {i + 1} {item!r}"
            if m is None:
                raise SensorConfigError("expected SENSOR[.CHANNEL]:KIND[=NUMBER][(NAME=NUMBER,...)]",
                                        source=source, field=where)
            kind = m["kind"]
            params: dict[str, Any] = {}
            if m["primary"] is not None:
                primary = FAULT_KINDS[kind].primary if kind in FAULT_KINDS else "?"
                if primary is None:
                    raise SensorConfigError(f"fault {kind!r} has no shorthand; write {kind}(NAME=NUMBER,...)",
                                            source=source, field=where)
                params[primary] = _number(m["primary"], source, where)
            for arg in (m["args"] or "").split(","):
                if not arg.strip():
                    continue
                if "=" not in arg:
                    raise SensorConfigError(f"expected NAME=NUMBER, got {arg.strip()!r}", source=source, field=where)
                k, v = (s.strip() for s in arg.split("=", 1))
                if k in params:
                    raise SensorConfigError(f"parameter {k!r} given twice", source=source, field=where)
                params[k] = _number(v, source, where)
            out.append(make_fault(m["sensor"], kind, params, m["channel"], source=source, field_name=where))
        return tuple(out)
    return parse_fault_list(spec, source=source)


def parse_fault_list(items: Sequence[Any], source: str, sensor: str | None = None,
                     prefix: str = "faults") -> tuple[FaultSpec, ...]:
    """Faults from a list of FaultSpec or mappings ``{sensor, fault, channel?, <params>}``.

    Inside a sensor's block of a preset, ``sensor`` is implied and must not be given.
    """
    if not isinstance(items, (list, tuple)):
        raise SensorConfigError(f"must be a list (got {items!r})", source=source, field=prefix)
    out = []
    for i, item in enumerate(items):
        where = f"{prefix}[{i}]"
        if isinstance(item, FaultSpec):
            out.append(make_fault(item.sensor, item.kind, {k: v for k, v in item.params.items() if v is not None},
                                  item.channel, source=source, field_name=where))
            continue
        if not isinstance(item, Mapping):
            raise SensorConfigError(f"must be a mapping (got {item!r})", source=source, field=where)
        d = dict(item)
        if sensor is None:
            if "sensor" not in d:
                raise SensorConfigError("required field is missing", source=source, field=f"{where}.sensor")
            name = d.pop("sensor")
        else:
            if "sensor" in d:
                raise SensorConfigError("the sensor is implied inside its block", source=source,
                                        field=f"{where}.sensor")
            name = sensor
        if "fault" not in d:
            raise SensorConfigError("required field is missing", source=source, field=f"{where}.fault")
        kind = d.pop("fault")
        channel = d.pop("channel", None)
        if not isinstance(name, str) or not isinstance(kind, str) or not (channel is None or isinstance(channel, str)):
            raise SensorConfigError("sensor, fault and channel must be strings", source=source, field=where)
        out.append(make_fault(name, kind, d, channel, source=source, field_name=where))
    return tuple(out)


# ---- effects -------------------------------------------------------------------------------------

def window_mask(t_s: np.ndarray, params: Mapping[str, float | None]) -> np.ndarray:
    """(n,) bool: sample instants inside ``[t_start_s, t_end_s)``."""
    return (t_s >= params["t_start_s"]) & (t_s < params["t_end_s"])


def apply_value_fault(fault: FaultSpec, values: dict[str, np.ndarray], t_s: np.ndarray,
                      rng: np.random.Generator) -> None:
    """Apply a value fault in place to the (n,) output arrays of one sensor (NaN stays NaN)."""
    p = fault.params
    channels = [fault.channel] if fault.channel else list(values)
    if fault.kind == "bias_step":
        inside = window_mask(t_s, p)
        for c in channels:
            values[c] = np.where(inside, values[c] + p["size"], values[c])
    elif fault.kind == "spike":
        for c in channels:
            hit = rng.random(t_s.size) < p["p"]
            sign = np.where(rng.random(t_s.size) < 0.5, -1.0, 1.0)
            values[c] = np.where(hit, values[c] + sign * p["magnitude"], values[c])
    elif fault.kind == "freeze":
        inside = window_mask(t_s, p)
        if not inside.any():
            return
        first = int(np.argmax(inside))
        for c in channels:
            v = values[c]
            if p["value"] is not None:
                held = p["value"]
            else:
                # The last finite value before the failure; if none, the first one inside it.
                before = np.flatnonzero(np.isfinite(v[:first]))
                after = np.flatnonzero(np.isfinite(v[first:]) & inside[first:])
                if before.size:
                    held = v[before[-1]]
                elif after.size:
                    held = v[first + after[0]]
                else:
                    continue
            values[c] = np.where(inside & np.isfinite(v), held, v)
    else:
        raise ValueError(f"not a value fault: {fault.kind}")


def gilbert_elliott_states(n: int, p_enter: float, p_exit: float, rng: np.random.Generator) -> np.ndarray:
    """States of a two-state Markov chain over ``n`` samples (True = bad), (n,) bool.

    Sojourns are geometric (mean ``1/p_enter`` good, ``1/p_exit`` bad samples); the chain starts in
    its stationary distribution, ``P(bad) = p_enter / (p_enter + p_exit)``. Built from run lengths,
    so the cost is one vectorised draw per run, not a Python loop per sample.
    """
    if n == 0 or p_enter <= 0.0:
        return np.zeros(n, dtype=bool)
    bad = rng.random() < p_enter / (p_enter + p_exit)
    runs: list[np.ndarray] = []
    total = 0
    mean_cycle = 1.0 / p_enter + 1.0 / p_exit
    while total < n:
        m = int(n / mean_cycle) + 8
        # Clip: with a tiny p a geometric draw can exceed int64; nothing beyond n is ever used.
        good_len = np.clip(rng.geometric(p_enter, size=m), 1, n)
        bad_len = np.clip(rng.geometric(p_exit, size=m), 1, n)
        pair = np.column_stack((bad_len, good_len) if bad else (good_len, bad_len)).ravel()
        runs.append(pair)
        total += int(pair.sum())
    lengths = np.concatenate(runs)
    states = np.zeros(lengths.size, dtype=bool)
    states[(0 if bad else 1)::2] = True
    return np.repeat(states, lengths)[:n]


def availability_loss(fault: FaultSpec, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n,) bool: samples this availability fault removes."""
    p, n = fault.params, t_s.size
    if fault.kind == "dropout":
        return rng.random(n) < p["p"]
    if fault.kind == "burst":
        bad = gilbert_elliott_states(n, p["p_enter"], 1.0 / p["mean_len"], rng)
        u = rng.random(n)
        return np.where(bad, u < p["loss_bad"], u < p["loss_good"])
    if fault.kind == "outage":
        return window_mask(t_s, p)
    raise ValueError(f"not an availability fault: {fault.kind}")


def extra_delay(fault: FaultSpec, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n,) extra latency [s] of a ``delay`` fault."""
    p = fault.params
    jitter = rng.random(t_s.size) * p["jitter_s"]
    return np.where(window_mask(t_s, p), p["extra_s"] + jitter, 0.0)
