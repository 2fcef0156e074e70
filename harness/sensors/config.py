"""Sensor-suite configuration: shipped presets, user YAML files, overrides and faults, all validated.

A preset file (``harness/sensors/presets/<name>.yaml``, or any YAML path) is::

    name: automotive
    description: ...
    base: ideal            # optional: start from another preset and override it
    sensors:
      imu:
        enabled: true
        rate_hz: 100
        latency_s: 0.01
        position_m: [0.3, 0.0, 0.2]     # sensor-specific parameters (see each sensor module)
        accel: {noise_density: 0.0012, bias_std: 0.05, resolution: 0.001, range: 40}
        gyro: {noise_density: 0.00017}
        faults: [{fault: dropout, p: 0.001}]

Each error block (``accel``, ``gyro``, ``position`` …) takes the keys of
:class:`roadtruth.harness.sensors.noise.ChannelErrors`. Overrides are a mapping of the same shape as
``sensors:`` merged into it (mappings merge, other values replace). Any unknown sensor, key or fault,
a negative figure, or rates that do not divide the fastest one raise :class:`SensorConfigError`.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path
from typing import Any

from roadtruth.harness.errors import SensorConfigError
from roadtruth.harness.files.parsed_files import ParsedFiles
from roadtruth.harness.files.strict_yaml import Fields, load_mapping
from roadtruth.harness.sensors.catalog import SENSORS
from roadtruth.harness.sensors.faults import FAULT_KINDS, FaultSpec, parse_fault_list, parse_faults
from roadtruth.harness.sensors.noise import ChannelErrors, parse_channel_errors

DEFAULT_PRESET = "automotive"


@dataclass(frozen=True)
class SensorConfig:
    """One sensor: rate [Hz], latency [s], error blocks, sensor-specific parameters, faults."""

    name: str
    enabled: bool
    rate_hz: float
    latency_s: float
    errors: dict[str, ChannelErrors]
    params: Any
    faults: tuple[FaultSpec, ...] = ()


@dataclass(frozen=True)
class SensorSuiteConfig:
    """The whole suite. ``sensors`` holds every known sensor (disabled ones too), in output order."""

    name: str
    source: str
    sensors: dict[str, SensorConfig]
    description: str = ""

    def enabled(self) -> list[str]:
        return [n for n, s in self.sensors.items() if s.enabled]

    @property
    def base_rate_hz(self) -> float:
        """The fastest enabled rate: the time base of the measurements frame."""
        return max(self.sensors[n].rate_hz for n in self.enabled())

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-safe data for run.json (infinite window ends become the string ``"inf"``)."""
        def clean(v: Any) -> Any:
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            if isinstance(v, (list, tuple)):
                return [clean(x) for x in v]
            if isinstance(v, float) and not math.isfinite(v):
                return str(v)
            return v
        return clean(dataclasses.asdict(self))


def presets_dir() -> Path:
    return Path(str(files("roadtruth.harness") / "sensors" / "presets"))


def available_presets() -> list[str]:
    return sorted(p.stem for p in presets_dir().glob("*.yaml"))


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) else v
    return out


def _check_sensor_keys(data: Mapping[str, Any], source: str, field: str) -> None:
    if not isinstance(data, Mapping):
        raise SensorConfigError(f"must be a mapping of sensor names (got {data!r})", source=source, field=field)
    for k in data:
        if k not in SENSORS:
            raise SensorConfigError(f"unknown sensor {k!r} (known: {', '.join(SENSORS)})", source=source,
                                    field=f"{field}.{k}" if field else str(k))


def _preset_file(preset: str | Path) -> Path:
    p = Path(preset)
    if p.suffix.lower() in (".yaml", ".yml"):
        return p
    candidate = presets_dir() / f"{preset}.yaml"
    if not candidate.is_file():
        raise SensorConfigError(f"unknown sensor preset {str(preset)!r} (available: {', '.join(available_presets())}"
                                " or a YAML file)", source="--sensors")
    return candidate


#: Parsed preset files (a sweep builds the same suite for every case; an edited file is read again).
_PARSED = ParsedFiles()


def _preset_mapping(path: Path) -> dict[str, Any]:
    """The top-level mapping of a preset file (a private copy: callers may change it)."""
    return copy.deepcopy(_PARSED.get(path, lambda: load_mapping(path, SensorConfigError)))


def _read_preset(preset: str | Path, depth: int = 0) -> tuple[dict[str, Any], str, str, str]:
    """(sensors mapping with ``base`` resolved, name, description, source path)."""
    path = _preset_file(preset)
    src = str(path)
    f = Fields(_preset_mapping(path), source=src, error=SensorConfigError)
    name = f.string("name", path.stem)
    description = f.string("description", "")
    base = f.string("base", None)
    sensors = f.raw("sensors")
    f.done()
    _check_sensor_keys(sensors, src, "sensors")
    if base is not None:
        if depth > 4:
            raise SensorConfigError("presets nest too deep (a base cycle?)", source=src, field="base")
        base_sensors, _, _, _ = _read_preset(base, depth + 1)
        sensors = _merge(base_sensors, sensors)
    return dict(sensors), name, description, src


def _parse_sensor(name: str, data: Mapping[str, Any] | None, source: str) -> SensorConfig:
    mod = SENSORS[name]
    prefix = f"sensors.{name}"
    if data is None:  # not mentioned in the file: off
        f = Fields({}, source=source, error=SensorConfigError, prefix=prefix)
        return SensorConfig(name, False, 1.0, 0.0, {g: ChannelErrors() for g in mod.ERROR_GROUPS},
                            mod.parse_params(f))
    f = Fields(data, source=source, error=SensorConfigError, prefix=prefix)
    enabled = f.boolean("enabled", True)
    rate = f.number("rate_hz", lo=0.0, lo_open=True, hi=1e5)
    latency = f.number("latency_s", 0.0, lo=0.0, hi=10.0)
    errors = {g: parse_channel_errors(f.sub(g, {})) for g in mod.ERROR_GROUPS}
    params = mod.parse_params(f)
    faults = parse_fault_list(f.raw("faults", []), source=source, sensor=name, prefix=f"{prefix}.faults")
    f.done()
    return SensorConfig(name, enabled, rate, latency, errors, params, faults)


def _check_fault_targets(faults: Sequence[FaultSpec], sensors: Mapping[str, SensorConfig], source: str) -> None:
    for fault in faults:
        if fault.sensor not in SENSORS:
            raise SensorConfigError(f"unknown sensor {fault.sensor!r} (known: {', '.join(SENSORS)})",
                                    source=source, field=fault.label())
        if not sensors[fault.sensor].enabled:
            raise SensorConfigError(f"sensor {fault.sensor!r} is disabled in this suite; enable it to fault it",
                                    source=source, field=fault.label())
        cols = SENSORS[fault.sensor].COLUMNS
        groups = [g for g, chans in SENSORS[fault.sensor].ERROR_GROUPS.items() if set(chans) <= set(cols)]
        if fault.kind == "channel_dropout" and fault.channel in groups:
            continue
        if fault.channel is not None and fault.channel not in cols:
            raise SensorConfigError(f"sensor {fault.sensor!r} has no channel {fault.channel!r} (channels: "
                                    f"{', '.join(cols)})", source=source, field=fault.label())
        if fault.kind not in FAULT_KINDS:  # pragma: no cover - make_fault already refuses these
            raise SensorConfigError(f"unknown fault {fault.kind!r}", source=source, field=fault.label())


def rate_divides(base_hz: float, rate_hz: float) -> bool:
    """True when ``base_hz / rate_hz`` is a whole number (to rounding)."""
    q = base_hz / rate_hz
    return abs(q - round(q)) <= 1e-9 * max(1.0, q) and round(q) >= 1


def load_sensor_config(preset: str | Path = DEFAULT_PRESET, overrides: Mapping[str, Any] | None = None,
                       faults: str | Sequence[Any] | None = None,
                       source: str = "sensor overrides") -> SensorSuiteConfig:
    """Build a validated sensor suite.

    Parameters
    ----------
    preset : a shipped preset name (``ideal``, ``automotive``, ``consumer``) or a YAML file path.
    overrides : mapping ``{sensor: {key: value, ...}}`` merged onto the preset's ``sensors:``.
    faults : extra faults: a CLI string (``"gnss:dropout=0.2,imu:bias_step=0.3"``), a YAML file path,
        or a list of FaultSpec / mappings ``{sensor, fault, ...}``; appended to the preset's.
    source : names the overrides in error messages (e.g. the scenario file).

    Raises
    ------
    SensorConfigError
        Unknown preset, sensor, key or fault; a value out of range; no sensor enabled; a rate that
        does not divide the fastest enabled rate.
    """
    sensors_data, name, description, preset_src = _read_preset(preset)
    src = preset_src
    if overrides:
        _check_sensor_keys(overrides, source, "")
        sensors_data = _merge(sensors_data, overrides)
        src = f"{preset_src} + {source}"
    sensors = {n: _parse_sensor(n, sensors_data.get(n), src) for n in SENSORS}
    for s in sensors.values():
        if s.enabled:  # a switched-off sensor keeps its preset faults, unused
            _check_fault_targets(s.faults, sensors, src)
    fault_source = faults if isinstance(faults, str) and faults.lower().endswith((".yaml", ".yml")) else (
        "--faults" if isinstance(faults, str) else source)
    extra = parse_faults(faults, source=fault_source)
    _check_fault_targets(extra, sensors, fault_source)
    for fault in extra:
        s = sensors[fault.sensor]
        sensors[fault.sensor] = dataclasses.replace(s, faults=(*s.faults, fault))
    suite = SensorSuiteConfig(name=name, source=src, sensors=sensors, description=description)
    on = suite.enabled()
    if not on:
        raise SensorConfigError("no sensor is enabled", source=src, field="sensors")
    base = suite.base_rate_hz
    for n in on:
        if not rate_divides(base, sensors[n].rate_hz):
            raise SensorConfigError(f"rate {sensors[n].rate_hz:g} Hz does not divide the fastest sensor rate "
                                    f"{base:g} Hz (the measurement time base)", source=src,
                                    field=f"sensors.{n}.rate_hz")
    return suite


def sensor_config_from_cli(sensors: str | None, faults: str | None) -> SensorSuiteConfig:
    """``--sensors PRESET|file.yaml`` and ``--faults SPEC|file.yaml`` -> a suite (default preset if None)."""
    return load_sensor_config(sensors or DEFAULT_PRESET, faults=faults)
