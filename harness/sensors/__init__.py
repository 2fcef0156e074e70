"""Sensor emulators: IMU, wheel speeds, steering angle, GNSS, lane camera, radar, optical ground speed.

Public API (see docs/SENSORS.md and ARCHITECTURE "Measurements"):

* :func:`load_sensor_config` — a validated :class:`SensorSuiteConfig` from a preset or YAML file,
  overrides and faults (:func:`sensor_config_from_cli` for ``--sensors`` / ``--faults``);
* :func:`emulate` — truth frame -> :class:`Measurements` (frame on one time base, NaN = no sample);
* :func:`parse_faults` — the ``--faults`` syntax.

Sensors never see MuJoCo: they read the truth DataFrame only. The table of sensors is
:data:`roadtruth.harness.sensors.catalog.SENSORS` (one module per sensor).
"""

from roadtruth.harness.sensors.catalog import SENSORS, output_columns, valid_column
from roadtruth.harness.sensors.config import (
    DEFAULT_PRESET,
    SensorConfig,
    SensorSuiteConfig,
    available_presets,
    load_sensor_config,
    sensor_config_from_cli,
)
from roadtruth.harness.sensors.faults import FAULT_KINDS, FaultSpec, parse_faults
from roadtruth.harness.sensors.noise import ChannelErrors
from roadtruth.harness.sensors.suite import Measurements, emulate

__all__ = [
    "DEFAULT_PRESET", "FAULT_KINDS", "SENSORS", "ChannelErrors", "FaultSpec", "Measurements", "SensorConfig",
    "SensorSuiteConfig", "available_presets", "emulate", "load_sensor_config", "output_columns",
    "parse_faults", "sensor_config_from_cli", "valid_column",
]
