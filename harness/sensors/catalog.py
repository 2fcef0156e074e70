"""The table of sensors: name -> module. A sensor module provides ``NAME``, ``COLUMNS`` (output
columns, without ``<name>_valid``), ``ERROR_GROUPS`` (error block -> raw channels), a frozen params
dataclass with ``parse_params(fields)``, ``measure(ctx, params) -> raw channels`` and
``derive(raw, params, ctx) -> output columns``. Adding a sensor = one module + one line here.
"""

from __future__ import annotations

from types import ModuleType

from roadtruth.harness.sensors import gnss, imu, lane_camera, optical_speed, radar, steering, wheel_speed

#: In output order (the column order of the measurements frame).
SENSORS: dict[str, ModuleType] = {m.NAME: m for m in (imu, wheel_speed, steering, gnss, lane_camera, radar,
                                                      optical_speed)}


def valid_column(sensor: str) -> str:
    return f"{sensor}_valid"


def output_columns(sensor: str) -> tuple[str, ...]:
    """The measurement columns of one sensor, its ``<sensor>_valid`` flag last."""
    return (*SENSORS[sensor].COLUMNS, valid_column(sensor))
