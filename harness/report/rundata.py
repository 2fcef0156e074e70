"""Reading a run folder back: what the report (and ``compare``) may rely on, and nothing else.

The report never re-simulates and never recomputes metrics: it reads ``run.json``, ``metrics.csv``
and, per scenario, ``truth.csv``, ``estimates.csv``, ``events.json`` and ``scenario.json``. Each table
may be CSV or Parquet (``--format``; ``harness/files/table_io.py``), and ``estimates`` wide (one row per time
step, ``<observer>.<state>`` columns) or long (runs written before the wide form): readers get the long
frame either way.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.errors import InputError
from roadtruth.harness.files.strict_yaml import short_repr
from roadtruth.harness.files.table_io import (
    BOUND_SUFFIXES,
    estimate_columns,
    estimates_long,
    format_of,
    is_wide,
    read_table,
    state_columns,
    table_columns,
    table_path,
    write_csv_table,
)


class RunFolderError(InputError):
    """A run folder is missing, lacks the files a run writes, or holds a file that is malformed or
    points outside the folder."""


#: Folders of a run that are not scenarios (written by the render stage).
RESERVED_FOLDERS: tuple[str, ...] = ("frames", "videos")
#: Longest scenario folder name written.
MAX_FOLDER_NAME = 100
#: Largest JSON file of a run folder read [bytes] (a run.json of a 144-case sweep is ~1 MB).
MAX_JSON_BYTES = 64_000_000
#: A wide estimates table up to this size [bytes] is read once for all of a scenario's figures: a
#: CSV file of at most this size (its numbers take about as much memory as the file), a Parquet
#: table whose numbers (rows x columns x 8 bytes) take at most this. A larger one (a long log) is
#: read one state's columns at a time (a CSV parser reads the whole file for any of its columns;
#: Parquet reads only those columns, but column by column costs ~1 ms a column, which a
#: default-suite page of 96 figures felt).
WHOLE_TABLE_BYTES = 32_000_000


def inside_folder(root: Path, path: Path, *, source: str | None = None) -> Path:
    """``path`` with symlinks resolved; ``RunFolderError`` if that leaves ``root``.

    ``root`` must already be resolved. A crafted name (``../../etc``), an absolute path or a symlink
    pointing elsewhere is refused rather than read.
    """
    resolved = Path(path).resolve()
    if resolved != root and not resolved.is_relative_to(root):
        raise RunFolderError(f"{str(path)!r} points outside the run folder", source=source or str(root))
    return resolved


def _read_json(path: Path, kind: type, what: str) -> Any:
    try:
        if path.stat().st_size > MAX_JSON_BYTES:
            raise RunFolderError(f"larger than {MAX_JSON_BYTES:,} bytes", source=str(path))
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise RunFolderError(f"invalid JSON ({e.msg} at line {e.lineno})", source=str(path)) from None
    except UnicodeDecodeError:
        raise RunFolderError("not a UTF-8 text file", source=str(path)) from None
    except OSError as e:
        raise RunFolderError(f"unreadable ({e.strerror or type(e).__name__})", source=str(path)) from None
    if not isinstance(data, kind):
        raise RunFolderError(f"expected a JSON {what}, got {type(data).__name__}", source=str(path))
    return data


def read_metrics(run_dir: Path) -> pd.DataFrame:
    """``metrics.csv`` of a run folder, validated (raises RunFolderError naming the file)."""
    from roadtruth.harness.evaluation.metrics_file import read_metrics_file

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise RunFolderError("not a run folder (does not exist)", source=str(run_dir))
    path = table_path(run_dir, "metrics")
    if path is None:
        raise RunFolderError("missing metrics.csv (not a roadtruth run folder?)", source=str(run_dir))
    inside_folder(run_dir.resolve(), path)
    # The validation compare and check apply (columns, numbers, flags, no duplicate rows).
    m = read_metrics_file(path, error=RunFolderError)
    m["state"] = m["state"].fillna("")
    return m


def read_run_json(run_dir: Path) -> dict[str, Any]:
    """``run.json`` of a run folder as a dict ({} when the folder has none)."""
    run_dir = Path(run_dir)
    path = run_dir / "run.json"
    if not path.is_file():
        return {}
    inside_folder(run_dir.resolve(), path)
    return _read_json(path, dict, "object")


# What the report reads of run.json: key -> accepted types (None = null). Other keys pass unchecked.
_RUN_KEYS: dict[str, tuple[type | None, ...]] = {
    "command": (str,), "suite": (str, None), "scenarios": (list,), "observers": (list,),
    "observer_runs": (dict,), "render": (dict, None), "versions": (dict,), "timings_s": (dict,),
    "git_revision": (str, None), "wall_s": (int, float, None), "seed": (int, None), "jobs": (int, None),
}
_ENTRY_KEYS: dict[str, tuple[type | None, ...]] = {
    "name": (str,), "status": (str,), "description": (str, None), "tags": (list,), "render": (dict, None),
    "timings_s": (dict,), "vehicle": (str, None), "duration_s": (int, float, None), "seed": (int, None),
}
_RENDER_KEYS: dict[str, tuple[type | None, ...]] = {
    "frames": (list,), "video": (str, None), "reason": (str, None),
}


def _check_keys(data: dict[str, Any], spec: dict[str, tuple[type | None, ...]], source: str, where: str) -> None:
    for key, kinds in spec.items():
        if key not in data:
            continue
        v = data[key]
        ok = (v is None and None in kinds) or any(
            k is not None and isinstance(v, k) and not (isinstance(v, bool) and k in (int, float)) for k in kinds)
        if not ok:
            names = " or ".join("null" if k is None else {dict: "object", list: "list", str: "string",
                                                           int: "number", float: "number"}[k] for k in kinds)
            raise RunFolderError(f"must be {names}, got {type(v).__name__}", source=source, field=f"{where}{key}")


def check_run_json(run: dict[str, Any], root: Path, source: str) -> None:
    """Raise ``RunFolderError`` unless ``run`` has the shape the report reads and every file it
    names (rendered frames, videos) lies inside the run folder ``root`` (resolved)."""
    _check_keys(run, _RUN_KEYS, source, "")
    for i, entry in enumerate(run.get("scenarios", [])):
        where = f"scenarios[{i}]"
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
            raise RunFolderError("each entry must be an object with a string name", source=source, field=where)
        _check_keys(entry, _ENTRY_KEYS, source, f"{where}.")
        scenario_folder(root, entry["name"], source=source)
        render = entry.get("render") or {}
        _check_keys(render, _RENDER_KEYS, source, f"{where}.render.")
        files = [f.get("file") if isinstance(f, dict) else f for f in render.get("frames", [])]
        if render.get("video"):
            files.append(render["video"])
        for j, rel in enumerate(files):
            if not isinstance(rel, str) or not rel:
                raise RunFolderError("each frame must be an object with a file name", source=source,
                                     field=f"{where}.render.frames[{j}]")
            inside_folder(root, root / rel, source=source)
    for i, obs in enumerate(run.get("observers", [])):
        if not isinstance(obs, dict):
            raise RunFolderError("each entry must be an object", source=source, field=f"observers[{i}]")
    for scen, per_obs in run.get("observer_runs", {}).items():
        if not isinstance(per_obs, dict) or not all(isinstance(r, dict) for r in per_obs.values()):
            raise RunFolderError("must map observer names to objects", source=source,
                                 field=f"observer_runs.{scen}")


def scenario_folder(root: Path, name: str, *, source: str | None = None) -> Path:
    """The folder of scenario ``name`` in the run folder ``root`` (resolved), refusing any name
    that is not one plain folder name or that resolves (through a symlink) outside ``root``."""
    if (not name or name in (".", "..") or "/" in name or "\\" in name or "\x00" in name
            or Path(name).is_absolute()):
        raise RunFolderError(f"scenario name {name[:80]!r} is not a folder name of this run", source=source or str(root))
    return inside_folder(root, root / name, source=source)


@dataclass(frozen=True)
class ScenarioFiles:
    """The saved outputs of one scenario of a run (each read lazily, once).

    ``root`` is the resolved run folder: every file is read only if it resolves inside it.
    """

    name: str
    folder: Path
    root: Path | None = None

    def _path(self, filename: str) -> Path | None:
        path = self.folder / filename
        if not path.is_file():
            return None
        if self.root is not None:
            inside_folder(self.root, path)
        return path

    def _table(self, name: str, required: tuple[str, ...], text: tuple[str, ...] = (),
               columns: list[str] | None = None) -> pd.DataFrame:
        """The table ``name`` of the scenario (``name.csv`` or ``name.parquet``), only ``columns`` of
        it if given; every column read but ``text`` must hold numbers (empty = NaN)."""
        found = table_path(self.folder, name)
        path = self._path(found.name) if found is not None else None
        if path is None:
            return pd.DataFrame()
        try:
            frame = read_table(path, columns=columns)
        except pd.errors.EmptyDataError:
            raise RunFolderError("empty file (no header)", source=str(path)) from None
        except (ValueError, pd.errors.ParserError, UnicodeDecodeError, OSError) as e:
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            kind = "Parquet" if format_of(path) == "parquet" else "CSV"
            raise RunFolderError(f"unreadable {kind} ({first})", source=str(path)) from None
        for col in required:
            if col not in frame.columns:
                has = ", ".join(map(str, frame.columns[:12]))
                raise RunFolderError(f"missing column (has: {has})", source=str(path), field=col)
        for col, dtype in frame.dtypes.items():
            if col in text or dtype.kind in "biuf":
                continue
            values = pd.to_numeric(frame[col], errors="coerce")
            bad = values.isna() & frame[col].notna()
            if bad.any():
                i = int(np.argmax(bad.to_numpy()))
                raise RunFolderError(f"not a number on line {i + 2} (got {short_repr(frame[col].iloc[i])})",
                                     source=str(path), field=str(col))
            frame[col] = values
        return frame

    def _csv(self, filename: str, required: tuple[str, ...], text: tuple[str, ...] = ()) -> pd.DataFrame:
        """Kept for callers that name the file: ``_table`` of its stem."""
        return self._table(Path(filename).stem, required, text)

    def _json(self, filename: str, default: Any) -> Any:
        path = self._path(filename)
        if path is None:
            return default
        kind, what = (list, "list") if isinstance(default, list) else (dict, "object")
        return _read_json(path, kind, what)

    @cached_property
    def truth(self) -> pd.DataFrame:
        return self._table("truth", required=("t_s",))

    @cached_property
    def estimates(self) -> pd.DataFrame:
        """Long ``t_s, observer, state, value, lo, hi, var`` whether the file is wide or long."""
        table = self._estimates_table
        return table if table.empty or not is_wide(table) else estimates_long(table)

    @cached_property
    def _estimates_header(self) -> list[str] | None:
        """The column names of the estimates table (None when the scenario has none), read without
        its rows."""
        found = table_path(self.folder, "estimates")
        path = self._path(found.name) if found is not None else None  # never read outside the folder
        if path is None:
            return None
        if format_of(path) == "csv":
            names = _csv_header(path)
            if names is not None:
                return names
        try:
            return table_columns(path)
        except pd.errors.EmptyDataError:
            raise RunFolderError("empty file (no header)", source=str(path)) from None
        except (ValueError, pd.errors.ParserError, UnicodeDecodeError, OSError) as e:
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            kind = "Parquet" if format_of(path) == "parquet" else "CSV"
            raise RunFolderError(f"unreadable {kind} ({first})", source=str(path)) from None

    def _is_long(self) -> bool:
        header = self._estimates_header or []
        return "observer" in header or "state" in header  # a run written before the wide form

    @cached_property
    def _estimates_table(self) -> pd.DataFrame:
        """The estimates table as written: wide, or long for a run written before the wide form."""
        if self._estimates_header is None:
            return pd.DataFrame()
        if self._is_long():
            return self._long_table
        return self._table("estimates", required=("t_s",))

    @cached_property
    def _long_table(self) -> pd.DataFrame:
        return self._table("estimates", required=("t_s", "observer", "state", "value"), text=("observer", "state"))

    def estimates_of(self, state: str) -> pd.DataFrame:
        """The long rows of one state (``observer``/``state`` categorical): what one figure plots.

        Of a wide table only that state's columns (and the shared ``t_s``, ``segment``) are read
        from the file, and the table is never held whole: a long log's wide table of every
        observer's every state is hundreds of MB as a frame, one state's columns a few percent of it.
        """
        header = self._estimates_header
        if header is None:
            return pd.DataFrame()
        if self._is_long():
            return estimates_long(self._long_table, states=[state], categorical=True)
        table = self._table("estimates", required=("t_s",), columns=state_columns(header, [state]))
        return estimates_long(table, states=[state], categorical=True)

    def series_of(self, state: str) -> list[ObserverSeries]:
        """Each observer's series of one state (:class:`ObserverSeries`): what one figure draws.
        Of a wide table only that state's columns are read, and no long frame is built."""
        header = self._estimates_header
        if header is None:
            return []
        if self._is_long():
            return observer_series(estimates_long(self._long_table, states=[state], categorical=True), state)
        whole = self._whole_table
        if whole is not None:
            return wide_series({"t_s": whole["t_s"], **{c: whole[c] for c in self._whole_table_states.get(state, [])}},
                               state)
        return wide_series(self._state_columns(state_columns(header, [state])), state)

    @cached_property
    def _whole_table_states(self) -> dict[str, list[str]]:
        """state -> the estimate columns (values, bounds, variances) of that state in the whole
        table, grouped once (not once per figure)."""
        out: dict[str, list[str]] = {}
        for (_, state), cols in estimate_columns(list(self._whole_table or {})).items():
            out.setdefault(state, []).extend(cols.values())
        return out

    @cached_property
    def _whole_table(self) -> dict[str, np.ndarray] | None:
        """Every column of a wide estimates table of at most ``WHOLE_TABLE_BYTES`` as float arrays,
        read once (CSV with ``_table``'s checks), or None for a larger table, and for a Parquet
        table with a column that does not hold numbers (each figure's own read then names it)."""
        found = table_path(self.folder, "estimates")
        path = self._path(found.name) if found is not None else None
        if path is None or "t_s" not in (self._estimates_header or []):
            return None
        if format_of(path) == "parquet":
            import pyarrow.parquet as pq

            try:
                meta = pq.ParquetFile(path).metadata
                if meta.num_rows * meta.num_columns * 8 > WHOLE_TABLE_BYTES:
                    return None
                return read_numeric_columns(path, self._estimates_header or [], at_once=True)
            except (ValueError, OSError) as e:
                first = str(e).splitlines()[0] if str(e) else type(e).__name__
                raise RunFolderError(f"unreadable Parquet ({first})", source=str(path)) from None
        if path.stat().st_size > WHOLE_TABLE_BYTES:
            return None
        frame = self._table("estimates", required=("t_s",))
        # One conversion of the frame's float block: each column is then a contiguous row of it.
        rows = np.ascontiguousarray(frame.to_numpy(dtype=float).T)
        return {str(c): rows[i] for i, c in enumerate(frame.columns)}

    def _state_columns(self, columns: list[str]) -> dict[str, np.ndarray]:
        """``columns`` of the wide estimates table as float arrays. Numeric Parquet columns are taken
        from pyarrow as they are (no pandas frame: that copy doubled one figure's memory); anything
        else goes through ``_table``'s checks, which name a column that does not hold numbers."""
        found = table_path(self.folder, "estimates")
        path = self._path(found.name) if found is not None else None
        if path is not None and format_of(path) == "parquet" and "t_s" in columns:
            try:
                arrays = read_numeric_columns(path, columns)
            except (ValueError, OSError) as e:
                first = str(e).splitlines()[0] if str(e) else type(e).__name__
                raise RunFolderError(f"unreadable Parquet ({first})", source=str(path)) from None
            if arrays is not None:
                return arrays
        frame = self._table("estimates", required=("t_s",), columns=columns)
        return {str(c): frame[c].to_numpy(float) for c in frame.columns}

    @cached_property
    def events(self) -> list[dict[str, Any]]:
        raw = self._json("events.json", [])
        return [e for e in raw if isinstance(e, dict) and _finite(e.get("t_s"))]

    @cached_property
    def info(self) -> dict[str, Any]:
        return self._json("scenario.json", {})


def read_numeric_columns(path: Path, columns: Sequence[str], *, at_once: bool = False) -> dict[str, np.ndarray] | None:
    """``columns`` of a Parquet table as float64 numpy arrays in ``columns`` order, or None if one of
    them does not hold numbers (the caller then reads it as a frame and says which).

    Read one column at a time on one thread and copied out of pyarrow's memory pool: decoding one
    state's 45 columns of a 550 s log at once grew the process by 4-5 times their 19 MB (buffers
    the pool keeps after the read); column by column it grows by about the data itself.
    ``at_once`` reads them in one call instead (faster for a small table, where memory is no issue).
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    file = pq.ParquetFile(path)
    schema = file.schema_arrow
    for name in columns:
        if schema.get_field_index(name) < 0:
            raise ValueError(f"no column {name!r}")
        kind = schema.field(name).type
        if not (pa.types.is_floating(kind) or pa.types.is_integer(kind)):
            return None
    out = {}
    if at_once:
        table = file.read(columns=list(columns))
        for name in columns:
            out[str(name)] = np.array(table.column(name).to_numpy(), dtype=float)
        del table
    else:
        for name in columns:
            out[str(name)] = np.array(file.read(columns=[name], use_threads=False).column(0).to_numpy(), dtype=float)
    pa.default_memory_pool().release_unused()
    return out


def _csv_header(path: Path) -> list[str] | None:
    """The column names of a CSV file from its first line (what ``table_columns`` gives, without
    setting up pandas' parser), or None when pandas would rename some (empty or repeated names) or
    the line cannot be read: the caller then asks pandas."""
    import csv

    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            names = next(csv.reader(f), None)
    except (OSError, UnicodeDecodeError, csv.Error):
        return None
    if not names or any(not n for n in names) or len(set(names)) != len(names):
        return None
    return names


@dataclass(frozen=True)
class ObserverSeries:
    """One observer's estimate of one state over time: what one figure draws for it. Arrays of equal
    length, ``t_s`` [s] non-decreasing, ``value``/``lo``/``hi`` in the state's SI unit (NaN where an
    observer gives no bound); samples where value and bounds were all missing are left out."""

    observer: str
    t_s: np.ndarray
    value: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


def observer_series(estimates: pd.DataFrame, state: str) -> list[ObserverSeries]:
    """The series of ``state`` in a long estimates frame, one per observer in order of appearance."""
    rows = estimates[estimates["state"] == state] if len(estimates) else estimates
    out = []
    for obs, g in rows.groupby("observer", sort=False):
        g = g.sort_values("t_s", kind="stable")
        t = g["t_s"].to_numpy(float)
        lo = g["lo"].to_numpy(float) if "lo" in g else np.full(t.size, np.nan)
        hi = g["hi"].to_numpy(float) if "hi" in g else np.full(t.size, np.nan)
        out.append(ObserverSeries(str(obs), t, g["value"].to_numpy(float), lo, hi))
    return out


def wide_series(table: dict[str, np.ndarray], state: str) -> list[ObserverSeries]:
    """The series of ``state`` in a wide estimates table given as its columns, one per observer in
    column order: the series :func:`observer_series` gives of ``estimates_long(table)``, without
    building that frame (a long log's one state in long form is ~100 MB; these arrays are the
    table's columns themselves where no sample is dropped)."""
    if "t_s" not in table:
        return []
    t_all = np.asarray(table["t_s"], dtype=float)
    out = []
    for (obs, st), cols in estimate_columns(table).items():
        if st != state:
            continue
        arrays = {k: np.asarray(table[cols[k]], dtype=float) if k in cols else None
                  for k in ("value", *BOUND_SUFFIXES)}
        keep = ~np.isnan(arrays["value"])  # as estimates_long: a value or any bound (±inf counts)
        for k in BOUND_SUFFIXES:
            if arrays[k] is not None:
                keep |= ~np.isnan(arrays[k])
        if not keep.any():
            continue
        nan = np.full(t_all.size, np.nan)
        t, v, lo, hi = t_all, arrays["value"], arrays["lo"], arrays["hi"]
        lo, hi = nan if lo is None else lo, nan if hi is None else hi
        if not keep.all():
            t, v, lo, hi = t[keep], v[keep], lo[keep], hi[keep]
        if t.size > 1 and (np.diff(t) < 0).any():  # the long frame's stable sort by time
            order = np.argsort(t, kind="stable")
            t, v, lo, hi = t[order], v[order], lo[order], hi[order]
        out.append(ObserverSeries(str(obs), t, v, lo, hi))
    return out


def _finite(x: Any) -> bool:
    return isinstance(x, int | float) and math.isfinite(x)


def state_order(state: str) -> tuple[int, str]:
    """Sort key of states on a page: the canonical order of the estimable signals, then by name."""
    from roadtruth.harness.signals import ESTIMABLE

    return (ESTIMABLE.index(state) if state in ESTIMABLE else len(ESTIMABLE), state)


@dataclass(frozen=True)
class RunData:
    """A whole run folder: metrics, run description and per-scenario files.

    ``load`` refuses (``RunFolderError``, exit 2) a folder that is not a run, a malformed
    ``run.json`` or ``metrics.csv``, and any scenario name or file path that leads outside the folder.
    """

    folder: Path
    metrics: pd.DataFrame
    run: dict[str, Any]

    @classmethod
    def load(cls, run_dir: Path) -> RunData:
        run_dir = Path(run_dir)
        metrics = read_metrics(run_dir)
        if not (run_dir / "run.json").is_file():
            raise RunFolderError("missing run.json (not a roadtruth run folder?)", source=str(run_dir))
        run = read_run_json(run_dir)
        root = run_dir.resolve()
        check_run_json(run, root, str(run_dir / "run.json"))
        for name in metrics["scenario"].astype(str).unique():
            scenario_folder(root, name, source=str(run_dir / "metrics.csv"))
        return cls(folder=run_dir, metrics=metrics, run=run)

    @cached_property
    def memo(self) -> dict[Any, Any]:
        """Results derived from this run that several sections need (e.g. one state's ranks: the
        summary's cards and the leaderboard), computed once per page build. Values must not be mutated."""
        return {}

    @cached_property
    def records(self) -> list[dict[str, Any]]:
        """The rows of ``metrics`` as dicts of plain Python values, in file order (what the tables
        iterate: a pandas filter per state, scenario or cell cost more than the rest of the page)."""
        return self.metrics.to_dict("records")

    @cached_property
    def scenario_names(self) -> list[str]:
        listed = [s["name"] for s in self.run.get("scenarios", []) if isinstance(s, dict) and "name" in s]
        return list(dict.fromkeys([*listed, *self.metrics["scenario"].astype(str).unique().tolist()]))

    @cached_property
    def observer_names(self) -> list[str]:
        return list(dict.fromkeys(self.metrics["observer"].astype(str).tolist()))

    @cached_property
    def states(self) -> list[str]:
        return sorted((s for s in self.metrics["state"].astype(str).unique() if s), key=state_order)

    @cached_property
    def scored_states(self) -> list[str]:
        """States with at least one scored row (others had no truth/reference to compare with)."""
        m = self.metrics
        ok = m["status"].astype(str).str.startswith("ok") & m["rmse"].notna()
        scored = set(m.loc[ok, "state"])
        return [s for s in self.states if s in scored]

    @cached_property
    def row_statuses(self) -> dict[tuple[str, str], list[str]]:
        """``(scenario, observer)`` -> the statuses of its metrics rows, in file order. One pass over
        the table: filtering the frame per run cost more than the rest of the page's tables."""
        m = self.metrics
        out: dict[tuple[str, str], list[str]] = {}
        for key in zip(m["scenario"].astype(str).tolist(), m["observer"].astype(str).tolist(),
                       m["status"].astype(str).tolist(), strict=True):
            out.setdefault(key[:2], []).append(key[2])
        return out

    def run_status(self, scenario: str, observer: str) -> str:
        """The status of one observer run: ``ok`` if any of its states was scored, else the first
        reason (a state without truth is a state-level skip, not a failed run)."""
        rows = self.row_statuses.get((scenario, observer), [])
        runs = self.run.get("observer_runs", {})
        r = runs.get(scenario, {}).get(observer) if isinstance(runs, dict) else None
        if isinstance(r, dict) and r.get("status"):
            return str(r["status"])
        if not rows:
            return "absent"
        return "ok" if any(s.startswith("ok") for s in rows) else rows[0]

    def scenario(self, name: str) -> ScenarioFiles:
        root = self.folder.resolve()
        scenario_folder(root, name)
        return ScenarioFiles(name=name, folder=self.folder / name, root=root)

    def scenario_entry(self, name: str) -> dict[str, Any]:
        """The scenario's entry in run.json (status, seeds, render results), or {}."""
        for s in self.run.get("scenarios", []):
            if isinstance(s, dict) and s.get("name") == name:
                return s
        return {}


# ---- writing (the pipeline's side of the same format) --------------------------------------------

#: Every float in a run's CSV files is written with this format, so the same seed gives the same bytes.
FLOAT_FORMAT = "%.10g"


def scenario_folder_name(name: str) -> str:
    """A scenario's folder name in a run: ``[A-Za-z0-9_.-]`` only (anything else becomes ``_``), no
    leading dot, at most ``MAX_FOLDER_NAME`` characters; never empty."""
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", name).lstrip(".")[:MAX_FOLDER_NAME]
    return safe or "scenario"


def new_scenario_folder(run_dir: Path, name: str) -> tuple[str, Path]:
    """Create a scenario's own folder in ``run_dir``; returns (folder name, path).

    The name is ``scenario_folder_name(name)``, with ``-2``, ``-3`` … appended when a folder of that
    name exists already (two scenario files of one name) or is reserved (``frames``, ``videos``). The
    folder is created exclusively, so two scenarios never share one, and always inside ``run_dir``.
    """
    base = scenario_folder_name(name)
    root = Path(run_dir).resolve()
    for k in range(1, 10_000):
        label = base if k == 1 else f"{base[:MAX_FOLDER_NAME - 6]}-{k}"
        if label in RESERVED_FOLDERS:
            continue
        folder = scenario_folder(root, label)
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        return label, Path(run_dir) / label
    raise RunFolderError(f"no free folder name for scenario {base!r}", source=str(run_dir))


def write_csv(frame: pd.DataFrame, path: Path) -> None:
    """A frame as CSV with the fixed float format; NaN is an empty cell (``roadtruth.harness.files.table_io``: the
    same bytes as ``to_csv(float_format=FLOAT_FORMAT)``, written faster and in blocks)."""
    write_csv_table(frame, path)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.generic):
        return _jsonable(x.item())
    if isinstance(x, float) and not math.isfinite(x):
        return None  # JSON has no inf/NaN; None reads as "unbounded"/"unknown"
    if isinstance(x, Path):
        return str(x)
    return x


def write_json(data: Any, path: Path) -> None:
    path.write_text(json.dumps(_jsonable(data), indent=1, default=str) + "\n")


def events_list(events: Any) -> list[dict[str, Any]]:
    """Truth/scenario events ((t_s, label) pairs or dicts) as ``[{"t_s", "label"}]`` sorted by time."""
    out = []
    for e in events or ():
        if isinstance(e, dict):
            t, label = e.get("t_s"), e.get("label", "")
        else:
            t, label = e[0], e[1] if len(e) > 1 else ""
        if _finite(t) or isinstance(t, np.floating):
            out.append({"t_s": float(t), "label": str(label)})
    return sorted(out, key=lambda e: e["t_s"])


def scenario_info(sc: Any, veh: Any, *, max_road_points: int = 1500) -> dict[str, Any]:
    """What the report shows about a scenario: description, friction patches, road centre line."""
    patches = [{"name": p.name, "surface": p.surface, "mu": p.mu, "vertices": np.asarray(p.vertices),
                "t_start_s": p.t_start_s, "t_end_s": p.t_end_s} for p in sc.friction.patches]
    road = None
    if getattr(sc, "road", None) is not None:
        samples = np.asarray(sc.road.samples)
        step = max(1, len(samples) // max_road_points)
        road = {"x_m": np.round(samples[::step, 1], 3), "y_m": np.round(samples[::step, 2], 3),
                "lane_width_m": sc.road.lane_width_m}
    return {
        "name": sc.name, "description": sc.description, "tags": list(sc.tags),
        "standard": getattr(sc, "standard", ""), "vehicle": veh.name, "duration_s": sc.duration_s,
        "initial_speed_mps": sc.initial_speed_mps, "sensors": sc.sensors,
        "friction": {"mu_default": sc.friction.mu_default, "patches": patches},
        "road": road, "lead": sc.lead is not None,
        "outages": [{"sensor": o.sensor, "t_start_s": o.t_start_s, "t_end_s": o.t_end_s} for o in sc.outages],
        "lane_gaps": [list(g) for g in sc.lane_gaps],
    }


def versions() -> dict[str, str | None]:
    """Versions of roadtruth and the packages that change results."""
    import platform
    from importlib.metadata import PackageNotFoundError, version

    out: dict[str, str | None] = {"python": platform.python_version()}
    for pkg in ("roadtruth", "mujoco", "numpy", "scipy", "pandas", "numba", "cvxpy"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = None
    return out


def git_revision() -> str | None:
    """roadtruth's own git revision (``+dirty`` with local changes), or None when not run from a checkout.

    Asked of the folder holding the installed package, and only trusted when that folder lies in a git
    work tree whose top has a ``pyproject.toml`` naming roadtruth: an installed copy inside the user's
    own repository (a virtual environment in their project) must not report their revision, and
    neither the working folder nor ``GIT_DIR``-style variables of the caller are consulted.
    """
    import os
    import subprocess
    import tomllib

    package_dir = Path(__file__).resolve().parents[2]
    env = {k: v for k, v in os.environ.items() if not k.startswith("GIT_")}

    def git(*args: str) -> str | None:
        try:
            r = subprocess.run(["git", "-C", str(package_dir), *args], capture_output=True, text=True,
                               timeout=5, check=False, env=env, stdin=subprocess.DEVNULL)
        except (OSError, subprocess.SubprocessError):
            return None
        return r.stdout.strip() if r.returncode == 0 else None

    top = git("rev-parse", "--show-toplevel")
    if not top:
        return None
    try:
        project = tomllib.loads((Path(top) / "pyproject.toml").read_text(encoding="utf-8")).get("project", {})
    except (OSError, ValueError):
        return None
    if not isinstance(project, dict) or project.get("name") != "roadtruth":
        return None
    rev = git("rev-parse", "HEAD")
    if not rev:
        return None
    dirty = git("status", "--porcelain", "--untracked-files=no")
    return rev + ("+dirty" if dirty else "")
