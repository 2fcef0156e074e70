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
#: Rows formatted at a time by the CSV writer (bounds the text held in memory to a few MB per column) ...
CSV_BLOCK_ROWS = 20_000
#: ... and at most this many cells per block: a wide estimates table of 150 columns holds 50 B or so
#: of Python string per cell while a block is formatted (20,000 rows of it would be 150 MB).
CSV_BLOCK_CELLS = 400_000
#: Suffixes of the bound and covariance columns of a wide estimates table.
BOUND_SUFFIXES: tuple[str, ...] = ("lo", "hi", "var")
LONG_COLUMNS: tuple[str, ...] = ("t_s", "observer", "state", "value", "lo", "hi", "var")


def check_format(fmt: str) -> str:
    """``fmt`` if it is an output format, else ``InputError`` naming ``--format``."""
    from roadtruth.harness.errors import InputError

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
    from roadtruth.harness.report.rundata import FLOAT_FORMAT

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
        # Format every value, then blank the NaN cells: one C-level map instead of a Python test per
        # value (the formatting of ~10^7 floats is most of a long replay's CSV time).
        cells = list(map(fmt.__mod__, values))
        for i in np.flatnonzero(np.isnan(column.to_numpy())).tolist():
            cells[i] = ""
        return cells
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


def block_rows(n_columns: int) -> int:
    """Rows per CSV block for a table of ``n_columns`` columns (:data:`CSV_BLOCK_ROWS`, :data:`CSV_BLOCK_CELLS`)."""
    return max(1, min(CSV_BLOCK_ROWS, CSV_BLOCK_CELLS // max(n_columns, 1)))


def _float_csv_text(frame: pd.DataFrame, fmt: str, header: bool) -> str:
    """An all-float frame of two or more columns as CSV text: one ``%`` over the whole block (half
    the time of a ``%`` per value). ``fmt`` never prints ``nan`` inside a number, so NaN cells are
    blanked by replacing that word."""
    values = frame.to_numpy(dtype=float)
    n, k = values.shape
    line = ",".join([fmt] * k)
    body = ("\n".join([line] * n) % tuple(values.ravel().tolist())).replace("nan", "")
    head = ",".join(_quote(str(c)) for c in frame.columns) + "\n" if header else ""
    return head + body + "\n"


def _csv_text(frame: pd.DataFrame, fmt: str, header: bool) -> str | None:
    """``frame`` as CSV text identical to ``to_csv`` (None if a column needs pandas itself)."""
    if not frame.columns.is_unique or len(frame.columns) == 0:
        return None
    if len(frame.columns) > 1 and len(frame) and all(dt.kind == "f" for dt in frame.dtypes):
        return _float_csv_text(frame, fmt, header)
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
    rows = block_rows(len(frame.columns))
    with open(path, "w", encoding="utf-8", newline="") as fh:
        for start in range(0, max(len(frame), 1), rows):
            block = frame.iloc[start:start + rows]
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


_PARQUET_OPTIONS: dict[str, Any] = {"compression": "zstd", "write_statistics": False}


def _parquet_options(schema: Any) -> dict[str, Any]:
    """Fixed writer options for a table of ``schema``: dictionary encoding for the text columns
    only. Float columns rarely repeat: trying a dictionary for each made the Revs estimates table
    2.9x slower to write and 26 % larger (71 vs 56 MB) than plain encoding under zstd."""
    import pyarrow as pa

    text = [f.name for f in schema if pa.types.is_string(f.type) or pa.types.is_large_string(f.type)
            or pa.types.is_dictionary(f.type)]
    return {**_PARQUET_OPTIONS, "use_dictionary": text}


def write_parquet_table(frame: pd.DataFrame, path: Path) -> None:
    """``frame`` as Parquet (float64 kept exactly; fixed writer options, so identical input gives
    identical bytes)."""
    import pyarrow.parquet as pq

    table = _arrow_table(frame)
    pq.write_table(table, path, **_parquet_options(table.schema))


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
                self._pq = pq.ParquetWriter(self.path, table.schema, **_parquet_options(table.schema))
            self._pq.write_table(table)
            return
        fmt = _float_format()
        if self._fh is None:
            self._fh = open(self.path, "w", encoding="utf-8", newline="")  # noqa: SIM115 (closed in close())
            header = True
        else:
            header = False
        rows = block_rows(len(frame.columns))
        for start in range(0, max(len(frame), 1), rows):
            block = frame.iloc[start:start + rows]
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

def read_table(path: Path, columns: Sequence[str] | None = None, **csv_options: Any) -> pd.DataFrame:
    """A table file as a frame (``csv_options`` go to ``pandas.read_csv``; Parquet ignores them).

    ``columns`` reads only those columns, in the file's order (Parquet stores columns apart, so the
    others are never decoded; CSV parses only those cells): one state of a wide estimates table of
    many observers is a few percent of it. The values are the same as in the whole table's columns.
    """
    if format_of(path) == "parquet":
        if columns is None:
            return pd.read_parquet(path)
        wanted = set(columns)
        return pd.read_parquet(path, columns=[c for c in table_columns(path) if c in wanted])
    if columns is not None:
        csv_options = {**csv_options, "usecols": list(columns)}
    return pd.read_csv(path, **csv_options)


def read_numeric_columns(path: Path, columns: Sequence[str]) -> dict[str, np.ndarray] | None:
    """``columns`` of a Parquet table as float64 arrays (pyarrow's own buffers where no conversion
    is needed: no pandas frame, whose block copy doubles the memory), or None if one of them does
    not hold numbers (the caller then reads it as a frame and says which)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(path, columns=list(columns))
    if not all(pa.types.is_floating(f.type) or pa.types.is_integer(f.type) for f in table.schema):
        return None
    return {name: np.asarray(table.column(name).to_numpy(), dtype=float) for name in table.column_names}


def table_columns(path: Path) -> list[str]:
    """The column names of a table file in order, without reading its rows (Parquet: the schema;
    CSV: the header line)."""
    if format_of(path) == "parquet":
        import pyarrow.parquet as pq

        return [str(c) for c in pq.read_schema(path).names]
    return [str(c) for c in pd.read_csv(path, nrows=0).columns]


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


def _track_columns(track: Any) -> list[tuple[str, np.ndarray]]:
    """One track's wide columns: ``<observer>.<state>`` and its ``_lo``/``_hi``/``_var`` where the
    track gives any finite value (the columns :func:`estimates_wide` makes of its long rows)."""
    out: list[tuple[str, np.ndarray]] = []
    for j, state in enumerate(track.states):
        name = f"{track.observer}.{state}"
        out.append((name, track.x[:, j]))
        for suffix, arr in zip(BOUND_SUFFIXES, (track.lo, track.hi, track.var), strict=True):
            if arr is not None and np.isfinite(arr[:, j]).any():
                out.append((f"{name}_{suffix}", arr[:, j]))
    return out


def tracks_wide(tracks: Any) -> pd.DataFrame:
    """Observer tracks (name -> ``EstimateTrack``) as the wide estimates table: the same frame as
    :func:`estimates_wide` of their long rows, built from the arrays (no long frame in between)."""
    items = list(tracks.values())
    if not items or all(len(tr.t_s) == 0 or len(tr.states) == 0 for tr in items):
        return pd.DataFrame({"t_s": pd.Series(dtype=float)})
    t = np.asarray(items[0].t_s, dtype=float)
    if not all(len(tr.t_s) == len(t) and np.array_equal(tr.t_s, t) for tr in items):
        # Observers on different time bases (not what run_observer_tracks gives): the union of times.
        from roadtruth.harness.evaluation.estimate import long_estimates

        return estimates_wide(long_estimates(tracks))
    columns: dict[str, np.ndarray] = {"t_s": t}
    for tr in items:
        for name, arr in _track_columns(tr):
            columns[name] = np.asarray(arr, dtype=float)
    return pd.DataFrame(columns)


def state_columns(columns: Sequence[str], states: Sequence[str]) -> list[str]:
    """The columns of a wide estimates table that :func:`estimates_long` with ``states`` reads: the
    shared ones (``t_s``, ``segment``, …) and each observer's value, bound and covariance columns of
    those states, in ``columns`` order (what to read of a file for one figure)."""
    spec = estimate_columns(columns)
    prefixed = {c for cols in spec.values() for c in cols.values()}
    wanted = {c for (_, state), cols in spec.items() if state in states for c in cols.values()}
    return [str(c) for c in columns if str(c) in wanted or str(c) not in prefixed]


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


def _labels(labels: Sequence[str], lengths: Sequence[int]) -> pd.Categorical:
    """A text column holding ``labels[i]`` ``lengths[i]`` times, as a categorical.

    A categorical stores one small integer per row; an object column of the same text becomes a
    pyarrow string column in pandas 3, whose construction costs seconds on a long log's millions of
    rows (and the report's filters compare strings row by row).
    """
    cats = list(dict.fromkeys(labels))
    code = {c: i for i, c in enumerate(cats)}
    codes = np.repeat(np.array([code[c] for c in labels], dtype=np.int32), np.asarray(lengths, dtype=np.int64))
    return pd.Categorical.from_codes(codes, categories=cats)


def _long_frame(parts: list[tuple[str, str, dict[str, np.ndarray]]], shared: Sequence[str],
                categorical: bool) -> pd.DataFrame:
    """Long estimates from ``(observer, state, {column: array})`` parts, columns in ``LONG_COLUMNS``
    order then ``shared`` extras; ``observer``/``state`` categorical or plain text."""
    extra = [c for c in shared if c != "t_s"]
    order = [*LONG_COLUMNS, *extra]
    if not parts:
        return pd.DataFrame({c: pd.Series(dtype=object if c in ("observer", "state") else float) for c in order})
    lengths = [len(cols["value"]) for _, _, cols in parts]
    data: dict[str, Any] = {}
    for c in order:
        if c == "observer" or c == "state":
            labels = [p[0] if c == "observer" else p[1] for p in parts]
            data[c] = _labels(labels, lengths) if categorical else np.repeat(
                np.array(labels, dtype=object), lengths)
        elif c in parts[0][2]:
            data[c] = np.concatenate([cols[c] for _, _, cols in parts])
    return pd.DataFrame(data)


def estimates_long(frame: pd.DataFrame, observers: Sequence[str] | None = None, *,
                   states: Sequence[str] | None = None, categorical: bool = False) -> pd.DataFrame:
    """A wide estimates table (or an old long one, passed through) as the long frame.

    Rows where the value and its bounds are all missing are left out (an observer that did not run
    on a stretch, e.g. a skipped replay segment). ``observers`` and ``states`` restrict the result to
    those (the report asks for one state at a time: one figure's rows, never the whole long table);
    ``categorical`` gives ``observer``/``state`` as categoricals (:func:`_labels`).
    """
    if not is_wide(frame):
        if observers is not None and "observer" in frame.columns:
            frame = frame[frame["observer"].isin(list(observers))]
        if states is not None and "state" in frame.columns:
            frame = frame[frame["state"].isin(list(states))]
        return frame
    spec = estimate_columns(frame.columns)
    prefixed = {c for cols in spec.values() for c in cols.values()}
    shared = [c for c in frame.columns if c not in prefixed]
    base = {c: frame[c].to_numpy() for c in shared}
    parts = []
    for (obs, state), cols in spec.items():
        if (observers is not None and obs not in observers) or (states is not None and state not in states):
            continue
        arrays = {kind: frame[cols[kind]].to_numpy(float) if kind in cols else np.full(len(frame), np.nan)
                  for kind in ("value", *BOUND_SUFFIXES)}
        keep = ~np.isnan(arrays["value"])  # a row with a value or a bound (±inf counts: divergence)
        for kind in BOUND_SUFFIXES:
            keep |= ~np.isnan(arrays[kind])
        if keep.all():
            part = {**base, **arrays}
        else:
            part = {c: a[keep] for c, a in {**base, **arrays}.items()}
        parts.append((obs, state, part))
    return _long_frame(parts, shared, categorical)


class WideEstimates:
    """The estimates of several runs over time segments (a replay's run segments), kept as float
    arrays per ``<observer>.<state>`` column and segment rather than as a long frame (a long frame
    repeats time, observer and state on every value: about 4× the memory, and copies of it made a
    long log's replay peak near 2 GB).

    ``add`` takes one segment's long estimates (any observers) on that segment's times; ``columns``
    and ``write`` give the wide table over all segments (NaN where an observer did not run on one)
    without a frame copy of it, ``frame`` the same as a DataFrame, and ``long`` one observer's long
    frame with per-segment time shifts (for scoring on a stitched axis).
    """

    def __init__(self) -> None:
        self._times: dict[int, np.ndarray] = {}
        self._columns: dict[str, dict[int, np.ndarray]] = {}

    def _add_column(self, name: str, segment: int, values: np.ndarray, optional: bool) -> None:
        if optional and not np.isfinite(values).any():
            return  # a bound or covariance column only where the observer gives one (estimates_wide)
        self._columns.setdefault(name, {})[segment] = values

    def add(self, segment: int, t_s: np.ndarray, long: pd.DataFrame) -> None:
        t = np.asarray(t_s, dtype=float)
        known = self._times.setdefault(segment, t)
        if known is not t and not np.array_equal(known, t):
            raise ValueError(f"segment {segment} given on two time bases")
        if long.empty:
            return
        n = len(t)
        if n and len(long) % n == 0:
            # The frame of roadtruth.harness.evaluation.estimate.run_observers: one block of n rows per (observer, state),
            # each on the segment's times. Sliced directly; anything else goes through estimates_wide.
            obs, state, tl = (long[c].to_numpy() for c in ("observer", "state", "t_s"))
            blocks = [slice(k * n, (k + 1) * n) for k in range(len(long) // n)]
            if all(np.array_equal(tl[b], t) and (obs[b] == obs[b.start]).all() and (state[b] == state[b.start]).all()
                   for b in blocks):
                for b in blocks:
                    name = f"{obs[b.start]}.{state[b.start]}"
                    self._add_column(name, segment, long["value"].to_numpy(float)[b].copy(), False)
                    for s in BOUND_SUFFIXES:
                        if s in long.columns:
                            self._add_column(f"{name}_{s}", segment, long[s].to_numpy(float)[b].copy(), True)
                return
        wide = estimates_wide(long)
        if len(wide) != len(t) or not np.array_equal(wide["t_s"].to_numpy(float), t):
            wide = pd.DataFrame({"t_s": t}).merge(wide, on="t_s", how="left")
        for col in wide.columns:
            if col != "t_s":
                self._columns.setdefault(str(col), {})[segment] = wide[col].to_numpy(float)

    def add_times(self, segment: int, t_s: np.ndarray) -> None:
        """The times of ``segment`` [s] (rows of the table even where no observer gives an estimate)."""
        t = np.asarray(t_s, dtype=float)
        known = self._times.setdefault(segment, t)
        if known is not t and not np.array_equal(known, t):
            raise ValueError(f"segment {segment} given on two time bases")

    def add_track(self, segment: int, track: Any) -> None:
        """One observer's ``EstimateTrack`` on ``segment`` (its times are the segment's times)."""
        self.add_times(segment, track.t_s)
        for name, arr in _track_columns(track):
            self._columns.setdefault(name, {})[segment] = np.array(arr, dtype=float)  # own contiguous copy

    def _stitched(self, cols: dict[str, str], segments: list[int], shift_s: dict[int, float]) -> dict[str, np.ndarray]:
        """One state's ``t_s`` (shifted by ``shift_s[segment]``), value, bound and variance arrays over
        ``segments`` joined in order (NaN where a kind is absent on a segment)."""
        def joined(parts: list[np.ndarray]) -> np.ndarray:
            return np.concatenate(parts) if parts else np.empty(0)

        out = {"t_s": joined([self._times[seg] + shift_s.get(seg, 0.0) for seg in segments])}
        for kind in ("value", *BOUND_SUFFIXES):
            per = self._columns[cols[kind]] if kind in cols else {}
            out[kind] = joined([per[seg] if seg in per else np.full(len(self._times[seg]), np.nan) for seg in segments])
        return out

    def track(self, observer: str, shift_s: dict[int, float] | None = None) -> Any:
        """One observer's estimates over its segments as an ``EstimateTrack``, ``t_s`` shifted by
        ``shift_s[segment]`` (the rows :meth:`long` gives, as arrays; for scoring on a stitched axis).
        None if the observer has no estimates."""
        from roadtruth.observers.base import EstimateTrack

        spec = {k[1]: v for k, v in estimate_columns(self._columns).items() if k[0] == observer}
        if not spec:
            return None
        segs = [seg for seg in self._times if all(seg in self._columns[c["value"]] for c in spec.values())]
        states = {state: self._stitched(cols, segs, shift_s or {}) for state, cols in spec.items()}

        def stacked(kind: str) -> np.ndarray | None:
            if kind != "value" and not any(kind in c for c in spec.values()):
                return None
            return np.column_stack([st[kind] for st in states.values()])

        return EstimateTrack(observer, tuple(spec), next(iter(states.values()))["t_s"], stacked("value"),
                             stacked("lo"), stacked("hi"), stacked("var"))

    @property
    def observers(self) -> list[str]:
        return list(dict.fromkeys(c.split(".", 1)[0] for c in self._columns))

    def columns(self, segment_column: str | None = "segment") -> dict[str, np.ndarray]:
        """``t_s`` (+ ``segment``) and every estimate column as arrays, segments in the order they were
        added (one segment: the stored arrays themselves, no copy)."""
        segs = list(self._times)

        def joined(parts: list[np.ndarray]) -> np.ndarray:
            return parts[0] if len(parts) == 1 else np.concatenate(parts) if parts else np.empty(0)

        data: dict[str, np.ndarray] = {"t_s": joined([self._times[s] for s in segs])}
        if segment_column is not None:
            segment = [np.full(len(self._times[s]), s, dtype=np.int64) for s in segs]
            data[segment_column] = joined(segment) if segs else np.empty(0, dtype=np.int64)
        for col, per in self._columns.items():
            data[col] = joined([per[s] if s in per else np.full(len(self._times[s]), np.nan) for s in segs])
        return data

    def frame(self, segment_column: str | None = "segment") -> pd.DataFrame:
        """``t_s`` (+ ``segment``) and every estimate column, segments in the order they were added."""
        return pd.DataFrame(self.columns(segment_column))

    def write(self, folder: Path, name: str, fmt: str = DEFAULT_FORMAT, segment_column: str | None = "segment") -> Path:
        """The wide table as ``folder/name.<csv|parquet>``: the bytes :func:`write_table` writes for
        :meth:`frame`, without a frame copy of all columns (CSV in row blocks, Parquet from the arrays)."""
        return write_columns(self.columns(segment_column), folder, name, fmt)

    def long(self, observer: str, shift_s: dict[int, float] | None = None) -> pd.DataFrame:
        """One observer's long estimates over its segments, ``t_s`` shifted by ``shift_s[segment]``
        (``observer``/``state`` categorical, see :func:`_labels`)."""
        spec = {k: v for k, v in estimate_columns(self._columns).items() if k[0] == observer}
        parts = [(obs, state, self._stitched(cols, [seg for seg in self._times if seg in self._columns[cols["value"]]],
                                             shift_s or {}))
                 for (obs, state), cols in spec.items()]
        return _long_frame(parts, ("t_s",), categorical=True)

    def drop(self, observer: str) -> None:
        """Forget ``observer``'s arrays (after they are written and scored)."""
        for col in [c for c in self._columns if c.split(".", 1)[0] == observer]:
            del self._columns[col]


def write_columns(columns: dict[str, np.ndarray], folder: Path, name: str, fmt: str = DEFAULT_FORMAT) -> Path:
    """Equal-length arrays as the table ``folder/name.<csv|parquet>``, the bytes :func:`write_table`
    writes for ``pandas.DataFrame(columns)``, without building that frame: CSV in row blocks of small
    frames, Parquet from the arrays (pyarrow wraps float64 arrays without a copy)."""
    path = table_file(folder, name, fmt)
    if fmt == "parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.table({c: pa.array(a) for c, a in columns.items()})
        pq.write_table(table, path, **_parquet_options(table.schema))
        return path
    n = len(next(iter(columns.values()))) if columns else 0
    rows = block_rows(len(columns))
    with TableWriter(folder, name, fmt) as out:
        for start in range(0, max(n, 1), rows):
            out.write(pd.DataFrame({c: a[start:start + rows] for c, a in columns.items()}))
    return path


def read_estimates(folder: Path) -> pd.DataFrame:
    """The long estimates (``t_s, observer, state, value, lo, hi, var`` + shared columns) of a scenario
    folder, from ``estimates.csv`` or ``estimates.parquet``, wide or long. Raises FileNotFoundError."""
    path = table_path(folder, "estimates")
    if path is None:
        raise FileNotFoundError(f"no estimates table in {folder}")
    return estimates_long(read_table(path))
