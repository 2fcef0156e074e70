"""Readers of measurement formats that hold several time bases: ASAM MDF4 and ROS 2 MCAP bags.

Both are read into one table with a ``time`` column [s] and one column per signal, so that a column
map treats them like a CSV file.

Column names
    *MDF4* (``.mf4``/``.mdf``, via ``asammdf``): the channel name (``GyroZ``). A name that occurs in
    several channel groups is ``name@<group index>`` in each (``Speed@0``, ``Speed@2``).
    The channel's unit string from the file is kept (``units``) and checked against the map.
    *MCAP* (``.mcap``, or a ROS 2 bag folder holding ``metadata.yaml`` and ``.mcap`` files, via ``mcap``
    and ``mcap-ros2-support``): ``<topic>.<field>.<field>`` (``/imu/data.angular_velocity.z``,
    ``/vehicle/speed.data``); numeric arrays up to 16 elements as ``field[i]``; strings, byte arrays
    and the ``header`` are left out. ROS messages are in SI with x forward, y left, z up (REP 103),
    which is ISO 8855's vehicle frame. A message's time is its ``header.stamp`` when its type has one
    (non-zero), else the time it was logged.

One time base
    Each MDF4 channel group and each MCAP topic is a stream with its own time stamps. The table is on
    the time stamps of the stream with the most samples among those the column map uses; every other
    stream is held at its latest sample at or before each of those times (zero-order hold, as a
    controller reading the bus would see it) and is NaN before its first sample.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.errors import LogError

MAX_ARRAY_ELEMENTS = 16
TIME_COLUMN = "time"

Stream = tuple[np.ndarray, dict[str, np.ndarray]]  # (time [s], column -> values), one time base


def _sorted_stream(t: np.ndarray, cols: dict[str, np.ndarray]) -> Stream:
    """Sort a stream by time and keep the last sample of repeated time stamps."""
    order = np.argsort(t, kind="stable")
    t = t[order]
    keep = np.append(t[1:] != t[:-1], True)
    return t[keep], {k: v[order][keep] for k, v in cols.items()}


def merge_streams(streams: list[Stream], wanted: set[str] | None = None) -> pd.DataFrame:
    """One table on the time stamps of the longest stream that holds a ``wanted`` column (the longest
    of all when none does or ``wanted`` is None); the others zero-order held (module doc)."""
    streams = [s for s in streams if s[0].size and s[1]]
    if not streams:
        return pd.DataFrame()
    used = [s for s in streams if wanted and wanted & set(s[1])] or streams
    base_t = max(used, key=lambda s: s[0].size)[0]
    out: dict[str, np.ndarray] = {TIME_COLUMN: base_t}
    for t, cols in streams:
        if t is base_t:
            out.update(cols)
            continue
        j = np.searchsorted(t, base_t, side="right") - 1  # latest sample at or before each base time
        ok = j >= 0
        for name, v in cols.items():
            held = np.full(base_t.size, np.nan)
            held[ok] = v[j[ok]]
            out[name] = held
    return pd.DataFrame(out)


# ---- MDF4 ----------------------------------------------------------------------------------------

def read_mdf(path: Path, wanted: set[str] | None = None) -> tuple[pd.DataFrame, dict[str, str]]:
    """An MDF4 file as one table (module doc) and the unit string of each column from the file.

    ``wanted``: the log columns the column map uses (None: every channel); it picks the time base.
    """
    from asammdf import MDF  # imported here: a heavy import only MDF4 users pay

    try:
        mdf = MDF(str(path))
    except Exception as exc:  # asammdf raises many types on a file that is not MDF
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise LogError(f"unreadable as MDF4: {msg}", source=str(path)) from None
    with mdf:
        signals = [s for s in mdf.iter_channels() if s.samples.dtype.kind in "biuf" and s.samples.ndim == 1]
    counts: dict[str, int] = {}
    for s in signals:
        counts[s.name] = counts.get(s.name, 0) + 1
    groups: dict[int, tuple[np.ndarray, dict[str, np.ndarray]]] = {}
    units: dict[str, str] = {}
    for s in signals:
        name = s.name if counts[s.name] == 1 else f"{s.name}@{s.group_index}"
        t, cols = groups.setdefault(s.group_index, (np.asarray(s.timestamps, dtype=float), {}))
        cols[name] = np.asarray(s.samples, dtype=float)
        if s.unit:
            units[name] = str(s.unit)
    streams = [_sorted_stream(t, cols) for t, cols in groups.values()]
    return merge_streams(streams, wanted), units


# ---- MCAP / ROS 2 --------------------------------------------------------------------------------

def _flatten(prefix: str, v: Any, out: dict[str, float]) -> None:
    if isinstance(v, bool):
        out[prefix] = float(v)
    elif isinstance(v, int | float):
        out[prefix] = float(v)
    elif isinstance(v, list | tuple):
        if len(v) <= MAX_ARRAY_ELEMENTS and all(isinstance(x, int | float) for x in v):
            for i, x in enumerate(v):
                out[f"{prefix}[{i}]"] = float(x)
    elif hasattr(v, "__slots__"):
        for k in v.__slots__:
            _flatten(f"{prefix}.{k}", getattr(v, k), out)
    # strings, bytes and anything else are not signals


def _stamp_s(msg: Any) -> float | None:
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is None:
        return None
    sec, nsec = getattr(stamp, "sec", 0), getattr(stamp, "nanosec", 0)
    return None if sec == 0 and nsec == 0 else sec + nsec * 1e-9


def _mcap_files(path: Path) -> list[Path]:
    if path.is_dir():
        found = sorted(path.glob("*.mcap"))
        if not found:
            if list(path.glob("*.db3")):
                raise LogError("ROS 2 bag in sqlite3 storage: convert it to MCAP "
                               "(ros2 bag convert, storage_id: mcap)", source=str(path))
            raise LogError("folder holds no .mcap file (a ROS 2 bag folder has metadata.yaml and *.mcap)",
                           source=str(path))
        return found
    return [path]


def read_mcap(path: Path, wanted: set[str] | None = None) -> tuple[pd.DataFrame, dict[str, str]]:
    """An MCAP file (or ROS 2 bag folder) of ROS 2 messages as one table (module doc).

    ``wanted``: the log columns the column map uses (None: every topic); only their topics are decoded.
    """
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    topics = None if wanted is None else sorted({c.split(".", 1)[0] for c in wanted if c.startswith("/")})
    rows: dict[str, tuple[list[float], list[dict[str, float]]]] = {}
    for f in _mcap_files(path):
        try:
            with f.open("rb") as fh:
                reader = make_reader(fh, decoder_factories=[DecoderFactory()])
                for _schema, channel, message, ros_msg in reader.iter_decoded_messages(topics=topics or None):
                    flat: dict[str, float] = {}
                    for k in getattr(ros_msg, "__slots__", ()):
                        if k != "header":
                            _flatten(f"{channel.topic}.{k}", getattr(ros_msg, k), flat)
                    stamp = _stamp_s(ros_msg)
                    times, values = rows.setdefault(channel.topic, ([], []))
                    times.append(stamp if stamp is not None else message.log_time * 1e-9)
                    values.append(flat)
        except LogError:
            raise
        except Exception as exc:  # mcap raises its own types and struct/EOF errors on a corrupt file
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise LogError(f"unreadable as MCAP (ROS 2): {msg}", source=str(f)) from None
    streams: list[Stream] = []
    for times, values in rows.values():
        names = sorted({k for v in values for k in v})
        cols = {n: np.array([v.get(n, np.nan) for v in values], dtype=float) for n in names}
        streams.append(_sorted_stream(np.asarray(times, dtype=float), cols))
    return merge_streams(streams, wanted), {}
