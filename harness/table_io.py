"""The one place that writes and reads the tables of a run folder, as CSV or Parquet.

Every table a command writes (``truth``, ``measurements``, ``estimates``, ``metrics``, ``segments``,
``stress``, ``summary``, ``check``, ``compare``) goes through :func:`write_table`, and every reader
finds it with :func:`table_path` whatever format it was written in. ``run.json`` records the format
(``table_format``).

CSV (the default) is byte-for-byte what ``pandas.DataFrame.to_csv`` writes with
``float_format=FLOAT_FORMAT`` (``%.10g``), ``na_rep=""`` and ``\\n`` line ends, so the same seed gives
the same bytes; it is produced column by column and in blocks of rows (:data:`CSV_BLOCK_ROWS`),
about 2.5× faster than ``to_csv`` and without holding the whole text in memory. pyarrow's own CSV
writer is faster still, but it prints shortest round-trip floats (17 digits, quoted headers), not
``%.10g``, so it is not used: its files would not match.

Parquet (``--format parquet``) keeps float64 exactly, is written with fixed options (zstd,
dictionary-encoded text, no statistics that depend on the writing time), so it too gives the same
bytes for the same seed with the same pyarrow version.

Estimates are written in *wide* form: one row per time step, a column ``<observer>.<state>`` per
state and ``<observer>.<state>_lo``, ``_hi``, ``_var`` where the observer gives bounds or a
covariance (observer names are identifiers, so the first ``.`` separates observer and state). Other
columns (``t_s``, a replay's ``segment``) are shared by all observers. :func:`estimates_long` turns it
back into the long ``t_s, observer, state, value, lo, hi, var`` frame scoring and the report use, and
still reads the long files of older runs.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

#: Output table formats (``--format``).
FORMATS: tuple[str, ...] = ("csv", "parquet")
DEFAULT_FORMAT = "csv"
SUFFIXES: dict[str, str] = {"csv": ".csv", "parquet": ".parquet"}
#: Rows formatted at a time by the CSV writer (bounds the text held in memory to a few MB per column).
CSV_BLOCK_ROWS = 20_000
#: Suffixes of the bound and covariance columns of a wide estimates table.
BOUND_SUFFIXES: tuple[str, ...] = ("lo", "hi", "var")
LONG_COLUMNS: tuple[str, ...] = ("t_s", "observer", "state", "value", "lo", "hi", "var")


def check_format(fmt: str) -> str:
    """``fmt`` if it is an output format, else ``InputError`` naming ``--format``."""
    from harness.errors import InputError

    if fmt not in FORMATS:
        raise InputError(f"unknown table format {fmt!r} (choose {' or '.join(FORMATS)})", field="--format")
    return fmt


def table_file(folder: Path, name: str, fmt: str = DEFAULT_FORMAT) -> Path:
    """``folder/name.csv`` or ``folder/name.parquet``."""
    return Path(folder) / f"{name}{SUFFIXES[check_format(fmt)]}"


def table_path(folder: Path, name: str) -> Path | None:
    """The table ``name`` of ``folder`` in whichever format it was written (CSV first), or None."""
    for fmt in FORMATS:
        p = Path(folder) / f"{name}{SUFFIXES[fmt]}"
        if p.is_file():
            return p
    return None


def format_of(path: Path) -> str:
    """The format of a table file from its suffix (``.parquet``/``.pq`` = parquet, else csv)."""
    return "parquet" if Path(path).suffix.lower() in (".parquet", ".pq") else "csv"


# ---- writing ---------------------------------------------------------------------------------------

def _float_format() -> str:
    from harness.report.rundata import FLOAT_FORMAT

    return FLOAT_FORMAT


def _quote(text: str) -> str:
    # csv.QUOTE_MINIMAL, as pandas uses it: quote a field holding the delimiter, a quote or a line end.
    if any(ch in text for ch in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text


def _cells(column: pd.Series, fmt: str) -> list[str] | None:
    """One column as CSV cells (None: a dtype this writer does not format like pandas does)."""
    kind = column.dtype.kind
    values = column.tolist()
    if kind == "f":
        f = fmt.__mod__
        return ["" if v != v else f(v) for v in values]  # v != v: NaN
    if kind in "iub":
        return [str(v) for v in values]
    if kind in "OUT":
        out: list[str] = []
        for v in values:
            if v is None or (isinstance(v, float) and v != v):
                out.append("")
            elif isinstance(v, str):
                out.append(_quote(v))
            else:
                return None  # numbers or objects inside a text column: leave them to pandas
        return out
    return None


def _csv_text(frame: pd.DataFrame, fmt: str, header: bool) -> str | None:
    """``frame`` as CSV text identical to ``to_csv`` (None if a column needs pandas itself)."""
    if not frame.columns.is_unique or len(frame.columns) == 0:
        return None
    cols = []
    for name in frame.columns:
        cells = _cells(frame[name], fmt)
        if cells is None:
            return None
        cols.append(cells)
    lines: list[str] = []
    if header:
        lines.append(",".join(_quote(str(c)) for c in frame.columns))
    if len(frame.columns) == 1:
        # A lone empty field is written as "" by the csv module (an empty line would be no row).
        lines.extend(c if c != "" else '""' for c in cols[0])
    else:
        lines.extend(map(",".join, zip(*cols, strict=True)))
    return "\n".join(lines) + "\n" if lines else ""


def write_csv_table(frame: pd.DataFrame, path: Path) -> None:
    """``frame`` as CSV: the fixed float format (``%.10g``), NaN an empty cell, ``\\n`` line ends."""
    fmt = _float_format()
    with open(path, "w", encoding="utf-8", newline="") as fh:
        for start in range(0, max(len(frame), 1), CSV_BLOCK_ROWS):
            block = frame.iloc[start:start + CSV_BLOCK_ROWS]
            text = _csv_text(block, fmt, header=start == 0)
            if text is None:
                text = block.to_csv(index=False, float_format=fmt, na_rep="", lineterminator="\n",
                                    header=start == 0, quoting=csv.QUOTE_MINIMAL)
            fh.write(text)


def _arrow_table(frame: pd.DataFrame) -> Any:
    import pyarrow as pa

    # No pandas index and no pandas metadata block: the file holds the columns and nothing that
    # depends on the pandas version that wrote it.
    return pa.Table.from_pandas(frame, preserve_index=False).replace_schema_metadata(None)


_PARQUET_OPTIONS: dict[str, Any] = {"compression": "zstd", "use_dictionary": True, "write_statistics": False}


def write_parquet_table(frame: pd.DataFrame, path: Path) -> None:
    """``frame`` as Parquet (float64 kept exactly; fixed writer options, so identical input gives
    identical bytes)."""
    import pyarrow.parquet as pq

    pq.write_table(_arrow_table(frame), path, **_PARQUET_OPTIONS)


def write_table(frame: pd.DataFrame, folder: Path, name: str, fmt: str = DEFAULT_FORMAT) -> Path:
    """Write ``frame`` as ``folder/name.<csv|parquet>``; returns the path written."""
    path = table_file(folder, name, fmt)
    (write_parquet_table if fmt == "parquet" else write_csv_table)(frame, path)
    return path


class TableWriter:
    """A table written block by block (a replay writes each segment as soon as it is done).

    Every block must have the same columns in the same order (and, for Parquet, the same dtypes);
    the bytes are those :func:`write_table` would write for the concatenated blocks in CSV, and one
    row group per block in Parquet. Use as a context manager; nothing is left open on an error.
    """

    def __init__(self, folder: Path, name: str, fmt: str = DEFAULT_FORMAT) -> None:
        self.path = table_file(folder, name, fmt)
        self.fmt = fmt
        self.columns: list[str] | None = None
        self._fh: io.TextIOBase | None = None
        self._pq: Any = None

    def __enter__(self) -> TableWriter:
        return self

    def write(self, frame: pd.DataFrame) -> None:
        if self.columns is None:
            self.columns = [str(c) for c in frame.columns]
        elif [str(c) for c in frame.columns] != self.columns:
            raise ValueError(f"{self.path.name}: a block has other columns than the first one")
        if self.fmt == "parquet":
            import pyarrow.parquet as pq

            table = _arrow_table(frame)
            if self._pq is None:
                self._pq = pq.ParquetWriter(self.path, table.schema, **_PARQUET_OPTIONS)
            self._pq.write_table(table)
            return
        fmt = _float_format()
        if self._fh is None:
            self._fh = open(self.path, "w", encoding="utf-8", newline="")  # noqa: SIM115 (closed in close())
            header = True
        else:
            header = False
        for start in range(0, max(len(frame), 1), CSV_BLOCK_ROWS):
            block = frame.iloc[start:start + CSV_BLOCK_ROWS]
            text = _csv_text(block, fmt, header=header and start == 0)
            if text is None:
                text = block.to_csv(index=False, float_format=fmt, na_rep="", lineterminator="\n",
                                    header=header and start == 0)
            self._fh.write(text)

    def close(self) -> None:
        if self._pq is not None:
            self._pq.close()
            self._pq = None
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---- reading ---------------------------------------------------------------------------------------

def read_table(path: Path, **csv_options: Any) -> pd.DataFrame:
    """A table file as a frame (``csv_options`` go to ``pandas.read_csv``; Parquet ignores them)."""
    if format_of(path) == "parquet":
        return pd.read_parquet(path)
    return pd.read_csv(path, **csv_options)


def read_table_as_text(path: Path) -> pd.DataFrame:
    """Every cell as text (what the strict metrics reader validates): CSV cells as written; Parquet
    values as ``str(value)`` with a missing value as ``""``."""
    if format_of(path) == "csv":
        return pd.read_csv(path, dtype=str, keep_default_na=False, na_filter=False)
    frame = pd.read_parquet(path)
    out = pd.DataFrame(index=frame.index)
    for col in frame.columns:
        s = frame[col]
        out[str(col)] = ["" if (v is None or (isinstance(v, float) and v != v)) else
                         (repr(v) if isinstance(v, float) else str(v)) for v in s.tolist()]
    return out


# ---- wide estimates -----------------------------------------------------------------------------------

def estimates_wide(long: pd.DataFrame, shared: Sequence[str] = ()) -> pd.DataFrame:
    """The long estimates frame (``t_s, observer, state, value, lo, hi, var``) in wide form.

    One row per time step of the union of the observers' times; ``<observer>.<state>`` per state and
    ``_lo``/``_hi``/``_var`` columns only where the observer gives them (any finite value). Columns
    of ``shared`` (e.g. ``segment``) are per time step and carried once. Observers keep the order in
    which they appear.
    """
    shared = [c for c in shared if c in long.columns]
    if long.empty:
        return pd.DataFrame({"t_s": pd.Series(dtype=float), **{c: pd.Series(dtype=float) for c in shared}})
    keys = ["t_s", *shared]
    groups = list(long.groupby(["observer", "state"], sort=False))
    first = groups[0][1]
    base = first[keys].reset_index(drop=True)
    same = all(len(g) == len(base) and np.array_equal(g["t_s"].to_numpy(), base["t_s"].to_numpy())
               for _, g in groups)
    if not same:  # observers on different time bases: the union of times, NaN where one has none
        base = long[keys].drop_duplicates().sort_values(keys, kind="stable").reset_index(drop=True)
    columns: dict[str, np.ndarray] = {}
    for (obs, state), g in groups:
        if same:
            cols = {"value": g["value"].to_numpy(float)}
            cols.update({s: g[s].to_numpy(float) for s in BOUND_SUFFIXES if s in g})
        else:
            merged = base.merge(g[[*keys, "value", *[s for s in BOUND_SUFFIXES if s in g]]], on=keys, how="left")
            cols = {c: merged[c].to_numpy(float) for c in merged.columns if c not in keys}
        columns[f"{obs}.{state}"] = cols["value"]
        for s in BOUND_SUFFIXES:
            v = cols.get(s)
            if v is not None and np.isfinite(v).any():
                columns[f"{obs}.{state}_{s}"] = v
    return pd.concat([base, pd.DataFrame(columns)], axis=1)


def estimate_columns(columns: Iterable[str]) -> dict[tuple[str, str], dict[str, str]]:
    """(observer, state) -> {"value"|"lo"|"hi"|"var": column} of a wide estimates table's columns."""
    found: dict[tuple[str, str], dict[str, str]] = {}
    names = [str(c) for c in columns]
    for c in names:
        if "." not in c:
            continue
        obs, rest = c.split(".", 1)
        kind = "value"
        for s in BOUND_SUFFIXES:
            if rest.endswith(f"_{s}") and f"{obs}.{rest[: -len(s) - 1]}" in names:
                rest, kind = rest[: -len(s) - 1], s
                break
        found.setdefault((obs, rest), {})[kind] = c
    return {k: v for k, v in found.items() if "value" in v}


def is_wide(frame: pd.DataFrame) -> bool:
    """True when ``frame`` is a wide estimates table (no ``observer``/``state`` columns)."""
    return "observer" not in frame.columns and "state" not in frame.columns


def estimates_long(frame: pd.DataFrame, observers: Sequence[str] | None = None) -> pd.DataFrame:
    """A wide estimates table (or an old long one, passed through) as the long frame.

    Rows where the value and its bounds are all missing are left out (an observer that did not run
    on a stretch, e.g. a skipped replay segment). ``observers`` restricts the result to those.
    """
    if not is_wide(frame):
        if observers is not None and "observer" in frame.columns:
            frame = frame[frame["observer"].isin(list(observers))]
        return frame
    spec = estimate_columns(frame.columns)
    prefixed = {c for cols in spec.values() for c in cols.values()}
    shared = [c for c in frame.columns if c not in prefixed]
    base = frame[shared]
    parts = []
    for (obs, state), cols in spec.items():
        if observers is not None and obs not in observers:
            continue
        part = {c: base[c].to_numpy() for c in shared}
        part["observer"] = np.full(len(frame), obs, dtype=object)
        part["state"] = np.full(len(frame), state, dtype=object)
        for kind in ("value", *BOUND_SUFFIXES):
            part[kind] = frame[cols[kind]].to_numpy(float) if kind in cols else np.full(len(frame), np.nan)
        df = pd.DataFrame(part)
        keep = df[["value", *BOUND_SUFFIXES]].notna().any(axis=1)
        parts.append(df[keep.to_numpy()])
    extra = [c for c in shared if c != "t_s"]
    order = [*LONG_COLUMNS, *extra]
    if not parts:
        return pd.DataFrame({c: pd.Series(dtype=object if c in ("observer", "state") else float) for c in order})
    out = pd.concat(parts, ignore_index=True)
    return out[[c for c in order if c in out.columns]]


class WideEstimates:
    """The estimates of several runs over time segments (a replay's run segments), kept as float
    arrays per ``<observer>.<state>`` column and segment rather than as a long frame (a long frame
    repeats time, observer and state on every value: about 4× the memory, and copies of it made a
    long log's replay peak near 2 GB).

    ``add`` takes one segment's long estimates (any observers) on that segment's times; ``frame``
    gives the wide table over all segments (NaN where an observer did not run on one), and
    ``long`` one observer's long frame with per-segment time shifts (for scoring on a stitched axis).
    """

    def __init__(self) -> None:
        self._times: dict[int, np.ndarray] = {}
        self._columns: dict[str, dict[int, np.ndarray]] = {}

    def add(self, segment: int, t_s: np.ndarray, long: pd.DataFrame) -> None:
        t = np.asarray(t_s, dtype=float)
        known = self._times.setdefault(segment, t)
        if known is not t and not np.array_equal(known, t):
            raise ValueError(f"segment {segment} given on two time bases")
        if long.empty:
            return
        wide = estimates_wide(long)
        if len(wide) != len(t) or not np.array_equal(wide["t_s"].to_numpy(float), t):
            wide = pd.DataFrame({"t_s": t}).merge(wide, on="t_s", how="left")
        for col in wide.columns:
            if col != "t_s":
                self._columns.setdefault(str(col), {})[segment] = wide[col].to_numpy(float)

    @property
    def observers(self) -> list[str]:
        return list(dict.fromkeys(c.split(".", 1)[0] for c in self._columns))

    def frame(self, segment_column: str | None = "segment") -> pd.DataFrame:
        """``t_s`` (+ ``segment``) and every estimate column, segments in the order they were added."""
        segs = list(self._times)
        data: dict[str, np.ndarray] = {"t_s": np.concatenate([self._times[s] for s in segs]) if segs
                                       else np.empty(0)}
        if segment_column is not None:
            data[segment_column] = np.concatenate([np.full(len(self._times[s]), s, dtype=np.int64) for s in segs]) \
                if segs else np.empty(0, dtype=np.int64)
        for col, per in self._columns.items():
            data[col] = np.concatenate([per.get(s, np.full(len(self._times[s]), np.nan)) for s in segs])
        return pd.DataFrame(data)

    def long(self, observer: str, shift_s: dict[int, float] | None = None) -> pd.DataFrame:
        """One observer's long estimates over its segments, ``t_s`` shifted by ``shift_s[segment]``."""
        shift_s = shift_s or {}
        spec = {k: v for k, v in estimate_columns(self._columns).items() if k[0] == observer}
        parts = []
        for (obs, state), cols in spec.items():
            for seg in self._times:
                if seg not in self._columns[cols["value"]]:
                    continue
                n = len(self._times[seg])
                part = {"t_s": self._times[seg] + shift_s.get(seg, 0.0),
                        "observer": np.full(n, obs, dtype=object), "state": np.full(n, state, dtype=object)}
                for kind in ("value", *BOUND_SUFFIXES):
                    part[kind] = self._columns[cols[kind]][seg] if kind in cols else np.full(n, np.nan)
                parts.append(pd.DataFrame(part))
        if not parts:
            return pd.DataFrame({c: pd.Series(dtype=object if c in ("observer", "state") else float)
                                 for c in LONG_COLUMNS})
        return pd.concat(parts, ignore_index=True)[list(LONG_COLUMNS)]


def read_estimates(folder: Path) -> pd.DataFrame:
    """The long estimates (``t_s, observer, state, value, lo, hi, var`` + shared columns) of a scenario
    folder, from ``estimates.csv`` or ``estimates.parquet``, wide or long. Raises FileNotFoundError."""
    path = table_path(folder, "estimates")
    if path is None:
        raise FileNotFoundError(f"no estimates table in {folder}")
    return estimates_long(read_table(path))
