"""The cache of finished stress cases: what a case's result depends on, and its rows on disk.

A sweep stores every finished case (its ``stress.csv`` rows) under a key that hashes everything that
determines them, so a rerun of a killed sweep resumes where it stopped and a wider sweep (more seeds,
one more μ) recomputes only the cases it does not share:

* the content of the prepared scenario (friction override applied; its file location left out),
  the vehicle parameters, the sensor suite with its faults, the case's seed;
* the observers by name plus the source file of each observer class (plug-ins included), and the
  observer options given (``--observer-options``, ``-O``);
* the source of the installed roadtruth packages (every file of ``harness``, ``observers``,
  ``mjcf``: code, shipped scenarios, vehicles, sensor presets) and the versions of Python and of the
  packages that change results (MuJoCo, NumPy, SciPy, pandas, numba, cvxpy).

Anything the key cannot describe exactly (an object of an unknown type) makes the case uncacheable:
it is computed, never guessed. Cases with an error (a crashed stage, an observer ``error: …``) are
not stored, so a rerun retries them. The columns that place a case in its sweep (``case``,
``seed_index``, the ``friction`` / ``faults`` labels, ``seed``) are rewritten from the current sweep on
load; every other cell is stored losslessly (JSON floats round-trip exactly), so ``stress.csv`` and
``summary.csv`` have the same bytes whether a case was computed or loaded. Entries are content-checked
files of :mod:`roadtruth.harness.files.disk_cache` (folder ``stress-cases``).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import hashlib
import inspect
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.files.disk_cache import cache_folder, read_entry, write_entry

CACHE_KIND = "stress-cases"
#: Bump when the stored layout or the meaning of a key changes.
ENTRY_FORMAT = 1
#: Columns that say where a case sits in its sweep, not what it computed.
POSITION_COLUMNS: tuple[str, ...] = ("case", "seed_index", "friction", "faults", "seed")
#: The roadtruth packages whose files are part of every key.
PACKAGES: tuple[str, ...] = ("roadtruth", "roadtruth.harness", "roadtruth.observers", "roadtruth.mjcf")
_SKIP_SUFFIXES = (".pyc", ".nbi", ".nbc", ".tmp")


class Uncacheable(TypeError):
    """A value the key cannot describe exactly; the case is computed and not cached."""


# ---- canonical hashing ---------------------------------------------------------------------------

def _feed(h: Any, obj: Any, exclude: frozenset[str] = frozenset()) -> None:
    """Feed a type-tagged, order-stable encoding of ``obj`` into the hash ``h``."""
    if obj is None or isinstance(obj, bool | int | str):
        h.update(f"{type(obj).__name__}:{obj!r};".encode())
    elif isinstance(obj, float):
        h.update(f"float:{obj!r};".encode())  # repr is exact; nan and -0.0 stay distinct from 0.0
    elif isinstance(obj, np.generic):
        _feed(h, obj.item())
    elif isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        if a.dtype == object:
            _feed(h, a.tolist())
        else:
            h.update(f"ndarray:{a.dtype.str}:{a.shape};".encode())
            h.update(a.tobytes())
    elif isinstance(obj, enum.Enum):
        h.update(f"enum:{type(obj).__qualname__}.{obj.name};".encode())
    elif isinstance(obj, Path):
        h.update(f"path:{obj};".encode())
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        h.update(f"dc:{type(obj).__module__}.{type(obj).__qualname__}{{".encode())
        for f in dataclasses.fields(obj):
            if f.name not in exclude:
                h.update(f"{f.name}=".encode())
                _feed(h, getattr(obj, f.name))
        h.update(b"}")
    elif isinstance(obj, Mapping):
        h.update(f"map:{len(obj)}{{".encode())
        for k in sorted(obj, key=repr):
            _feed(h, k)
            _feed(h, obj[k])
        h.update(b"}")
    elif isinstance(obj, list | tuple):
        h.update(f"{type(obj).__name__}:{len(obj)}[".encode())
        for x in obj:
            _feed(h, x)
        h.update(b"]")
    elif isinstance(obj, set | frozenset):
        _feed(h, sorted(obj, key=repr))
    else:
        raise Uncacheable(f"cannot key a {type(obj).__qualname__}")


def content_digest(obj: Any, exclude: frozenset[str] = frozenset()) -> str:
    """SHA-256 of the canonical encoding of ``obj`` (dataclasses, mappings, sequences, arrays, scalars).

    ``exclude`` names top-level dataclass fields to leave out. Raises :class:`Uncacheable` for any
    other type rather than hashing an unstable ``repr``.
    """
    h = hashlib.sha256()
    _feed(h, obj, exclude)
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 over the relative path and bytes of every file of the installed roadtruth packages."""
    import importlib

    h = hashlib.sha256()
    for pkg in PACKAGES:
        root = Path(inspect.getfile(importlib.import_module(pkg))).parent
        for p in sorted(root.rglob("*")):
            if p.is_file() and "__pycache__" not in p.parts and not p.name.endswith(_SKIP_SUFFIXES):
                h.update(f"{pkg}/{p.relative_to(root).as_posix()}\0".encode())
                h.update(p.read_bytes())
    return h.hexdigest()


def _observer_source(name: str) -> str:
    """Module and source bytes of an observer class (a plug-in outside roadtruth changes keys too)."""
    from roadtruth.observers.registry import observer_class

    cls = observer_class(name)
    try:
        src = Path(inspect.getsourcefile(cls) or "").read_bytes()
    except (TypeError, OSError):
        raise Uncacheable(f"observer {name!r} has no readable source") from None
    return f"{cls.__module__}.{cls.__qualname__}:" + hashlib.sha256(src).hexdigest()


class CaseKeys:
    """Cache keys of stress cases; scenario, sensor and observer digests are computed once per sweep."""

    def __init__(self) -> None:
        from roadtruth.harness.report.rundata import versions

        self._base = {"format": ENTRY_FORMAT, "code": code_fingerprint(), "versions": versions()}
        self._scenario: dict[tuple[str, str | None], str] = {}
        self._sensors: dict[tuple[str, str | None], str] = {}
        self._observers: dict[str, str] = {}

    def key(self, scenario: str, friction: str | None, faults: str | None, seed: int,
            observers: tuple[str, ...], options: Mapping[str, Mapping[str, Any]] | None = None) -> str | None:
        """The key of one case, or None when some input cannot be keyed exactly (then: no caching).

        ``options``: the checked observer options (observer -> {option: value}); they change results.
        """
        from roadtruth.harness.jobs.pipeline import prepare_scenario, sensor_config

        try:
            if (scenario, friction) not in self._scenario:
                sc = prepare_scenario(scenario, None, friction)
                self._scenario[(scenario, friction)] = content_digest(
                    (content_digest(sc, exclude=frozenset({"path"})), sc.vehicle_params()))
            if (scenario, faults) not in self._sensors:
                sc = prepare_scenario(scenario, None, None)
                self._sensors[(scenario, faults)] = content_digest(sensor_config(sc, None, faults))
            for o in observers:
                if o not in self._observers:
                    self._observers[o] = _observer_source(o)
        except Uncacheable:
            return None
        key: dict[str, Any] = {**self._base, "scenario": self._scenario[(scenario, friction)],
                               "sensors": self._sensors[(scenario, faults)], "seed": int(seed),
                               "observers": [(o, self._observers[o]) for o in observers]}
        if options:  # only when given, so a sweep without options keeps its keys
            key["observer_options"] = {str(o): dict(v) for o, v in options.items() if v}
        try:
            return content_digest(key)
        except Uncacheable:
            return None


# ---- rows on disk --------------------------------------------------------------------------------

def _cell(x: Any) -> Any:
    if isinstance(x, np.generic):
        x = x.item()
    if x is None or isinstance(x, bool | int | float | str):
        return x
    raise Uncacheable(f"cannot store a {type(x).__qualname__} cell")


def rows_to_entry(rows: pd.DataFrame) -> dict[str, Any]:
    """A JSON-ready, lossless form of a case's rows: column names, dtypes and values."""
    cols = []
    for name in rows.columns:
        s = rows[name]
        if s.dtype.kind not in "biufO":
            raise Uncacheable(f"column {name!r} has dtype {s.dtype}")
        values = [_cell(x) for x in s.tolist()]
        cols.append({"name": str(name), "dtype": s.dtype.str if s.dtype.kind != "O" else "object",
                     "values": values})
    return {"format": ENTRY_FORMAT, "n_rows": len(rows), "columns": cols}


def rows_from_entry(entry: Mapping[str, Any]) -> pd.DataFrame:
    """Rebuild the rows of :func:`rows_to_entry` (same columns, dtypes and values)."""
    if entry.get("format") != ENTRY_FORMAT:
        raise ValueError("other entry format")
    n = int(entry["n_rows"])
    data: dict[str, pd.Series] = {}
    for col in entry["columns"]:
        values = list(col["values"])
        if len(values) != n:
            raise ValueError("column length")
        dtype = object if col["dtype"] == "object" else np.dtype(col["dtype"])
        data[str(col["name"])] = pd.Series(values, dtype=dtype)
    return pd.DataFrame(data, index=pd.RangeIndex(n))


def is_cacheable(rows: pd.DataFrame, traceback: str | None) -> bool:
    """Only clean results are stored: no traceback and no ``error`` status anywhere in the case."""
    if traceback or rows.empty:
        return False
    for col in ("status", "truth_status"):
        if col in rows and any(str(v).startswith("error") for v in rows[col].tolist()):
            return False
    return True


def load_case(key: str, position: Mapping[str, Any], folder: Path | None = None) -> pd.DataFrame | None:
    """The stored rows of ``key`` with the position columns set from ``position``, or None."""
    entry = read_entry(folder or cache_folder(CACHE_KIND), key)
    if not isinstance(entry, dict):
        return None
    try:
        rows = rows_from_entry(entry)
    except (KeyError, TypeError, ValueError):
        return None
    for col, value in position.items():
        if col in rows:
            rows[col] = value  # broadcast: int64 for ints, object for labels, as run_case builds them
    return rows


def store_case(key: str, rows: pd.DataFrame, folder: Path | None = None) -> bool:
    """Store a finished case's rows; False when it cannot be stored (never raises for disk trouble)."""
    try:
        entry = rows_to_entry(rows)
    except Uncacheable:
        return False
    return write_entry(folder or cache_folder(CACHE_KIND), key, entry)


# ---- the cases of a sweep -----------------------------------------------------------------------

def case_keys(cases: list[Any]) -> dict[int, str]:
    """Cache key of every ``roadtruth.harness.jobs.stress.StressCase`` that can be keyed exactly, by case index."""
    from roadtruth.harness.jobs.stress import NO_FAULTS, SCENARIO_FRICTION

    ck = CaseKeys()
    keys = {}
    for c in cases:
        k = ck.key(c.scenario, None if c.friction == SCENARIO_FRICTION else c.friction,
                   None if c.faults == NO_FAULTS else c.faults, c.seed, c.observers,
                   options=c.observer_options)
        if k is not None:
            keys[c.index] = k
    return keys


def load_cached(cases: list[Any], keys: dict[int, str]) -> dict[int, Any]:
    """The ``CaseResult`` of every case an earlier sweep finished, position columns set for this sweep."""
    from roadtruth.harness.jobs.stress import CaseResult

    found: dict[int, Any] = {}
    for c in cases:
        if c.index in keys:
            rows = load_case(keys[c.index], {"case": c.index, "seed_index": c.seed_index, "friction": c.friction,
                                             "faults": c.faults, "seed": c.seed})
            if rows is not None:
                found[c.index] = CaseResult(index=c.index, rows=rows, seconds=0.0)
    return found


def store_finished(result: Any, key: str | None) -> None:
    """Store a finished ``CaseResult`` unless it errored (a rerun retries errors) or cannot be keyed."""
    if key is not None and is_cacheable(result.rows, result.traceback):
        store_case(key, result.rows)


__all__ = ["CACHE_KIND", "CaseKeys", "POSITION_COLUMNS", "Uncacheable", "case_keys", "code_fingerprint",
           "content_digest", "is_cacheable", "load_cached", "load_case", "rows_from_entry", "rows_to_entry",
           "store_case", "store_finished"]
