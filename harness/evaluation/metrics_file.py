"""Reading a ``metrics.csv`` strictly: the one validation shared by ``compare`` and ``check``.

A metrics file is one row per (scenario, observer, state) (``roadtruth.harness.evaluation.scoring.COLUMNS``). Before any
command compares or judges one, :func:`read_metrics_file` checks that

* the file exists and is a readable CSV with a header and at least one row;
* the key columns ``scenario, observer, state`` and ``status`` are there (plus any the caller needs);
* ``scenario``, ``observer`` and ``status`` cells are not empty (``state`` may be: an observer that
  failed before declaring states has one row with an empty state);
* every numeric column present holds numbers (an empty cell or ``nan`` is a missing value, ``x`` is
  an error); the flag columns (``certified``, ``nees_in_band``) hold true/false or nothing;
* no (scenario, observer, state) key appears twice.

Every violation raises one ``InputError`` (or the subclass the caller passes) naming the file, the
column and the CSV line (header = line 1). Nothing is silently dropped, coerced or duplicated.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from roadtruth.harness.errors import InputError
from roadtruth.harness.evaluation.scoring import KEY_COLUMNS

#: Key columns of a metrics row.
KEYS: list[str] = list(KEY_COLUMNS)
#: Columns every metrics file must have.
REQUIRED: tuple[str, ...] = (*KEY_COLUMNS, "status")
#: Columns holding true/false flags (empty = unknown).
FLAG_COLUMNS: tuple[str, ...] = ("certified", "nees_in_band")
#: Columns holding free text (everything else ``roadtruth.harness.evaluation.scoring`` writes, and any unknown column, is
#: left as read; the known numeric columns below are checked).
TEXT_COLUMNS: tuple[str, ...] = (*KEY_COLUMNS, "status")
#: Known numeric columns (metrics, timing, counts, convergence band; ``scored_until_s`` when present).
NUMERIC_COLUMNS: tuple[str, ...] = (
    "rmse", "mae", "max_abs", "p95_abs", "bias", "conv_time_s", "coverage", "mean_width", "max_width",
    "violation_time_s", "nees_mean", "us_per_step", "conv_band", "n_scored", "scored_until_s",
)
_NA_TEXT = {"", "nan", "NaN", "NA", "N/A", "null", "None"}
_TRUE = {"true", "1", "1.0"}
_FALSE = {"false", "0", "0.0"}


class MetricsFileError(InputError):
    """A metrics.csv is missing, unreadable, or has a bad column, cell or duplicate row."""


def metrics_path(path: Path) -> Path:
    """``path`` itself when it is a file, else ``path/metrics.csv`` (a run folder)."""
    from roadtruth.harness.files.table_io import table_path

    p = Path(path)
    return (table_path(p, "metrics") or p / "metrics.csv") if p.is_dir() else p


def read_metrics_file(path: Path, *, required: tuple[str, ...] = (), finite: tuple[str, ...] = (),
                      error: type[InputError] = MetricsFileError) -> pd.DataFrame:
    """A validated metrics frame.

    Parameters
    ----------
    path : a ``metrics.csv`` or a run folder holding one.
    required : columns needed beyond ``REQUIRED`` (e.g. the metrics a regression compares).
    finite : numeric columns whose values must not be ±inf (NaN stays allowed: a missing metric).
    error : the ``InputError`` subclass to raise (``check`` uses its ``BaselineError``).

    Returns
    -------
    DataFrame
        Rows in file order; key and status columns as ``str`` (empty state = ``""``), numeric
        columns as float (NaN = missing), flag columns as ``True``/``False``/NaN (object dtype).

    Raises
    ------
    error
        One line: ``<file>: <column>: <what> on line N (got '<cell>')``.
    """
    from roadtruth.harness.files.table_io import format_of, read_table_as_text

    p = metrics_path(Path(path))
    src = str(p)
    if not p.is_file():
        where = "the folder has no metrics.csv" if p.parent.is_dir() and p.name == "metrics.csv" else \
            "file not found"
        raise error(f"{where} (expected a metrics.csv or a run folder)", source=src)
    try:
        # Every cell as text first, so that the checks below see exactly what the file holds.
        # (a metrics.parquet of ``--format parquet`` is read the same way, each value as its text)
        raw = read_table_as_text(p)
    except (ValueError, pd.errors.ParserError, UnicodeDecodeError, OSError) as e:
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise error(f"unreadable {'Parquet' if format_of(p) == 'parquet' else 'CSV'} ({first})", source=src) from None
    raw.columns = [str(c) for c in raw.columns]
    for col in dict.fromkeys((*REQUIRED, *required)):
        if col not in raw.columns:
            raise error(f"missing column (has: {', '.join(raw.columns)})", source=src, field=col)
    if raw.columns.duplicated().any():
        raise error("column given twice", source=src, field=str(raw.columns[raw.columns.duplicated()][0]))
    if raw.empty:
        raise error("no rows", source=src)

    frame = raw.copy()
    for col in ("scenario", "observer", "status"):
        text = frame[col].str.strip()
        bad = text == ""
        if bad.any():
            raise error(f"empty cell on line {_line(bad)}", source=src, field=col)
        frame[col] = text
    frame["state"] = frame["state"].str.strip()

    for col in NUMERIC_COLUMNS:
        if col not in frame.columns:
            continue
        text = frame[col].str.strip()
        missing = text.isin(_NA_TEXT)
        values = pd.to_numeric(text.where(~missing), errors="coerce")
        bad = values.isna() & ~missing
        if bad.any():
            i = int(np.argmax(bad.to_numpy()))
            raise error(f"not a number on line {i + 2} (got {raw[col].iloc[i]!r})", source=src, field=col)
        if col in finite:
            inf = values.map(lambda v: not math.isnan(v) and math.isinf(v))
            if inf.any():
                raise error(f"infinite value on line {_line(inf)}", source=src, field=col)
        frame[col] = values.astype(float)

    for col in FLAG_COLUMNS:
        if col not in frame.columns:
            continue
        text = frame[col].str.strip().str.lower()
        missing = text.isin({t.lower() for t in _NA_TEXT})
        bad = ~(missing | text.isin(_TRUE) | text.isin(_FALSE))
        if bad.any():
            i = int(np.argmax(bad.to_numpy()))
            raise error(f"not true/false on line {i + 2} (got {raw[col].iloc[i]!r})", source=src, field=col)
        frame[col] = [math.nan if m else (t in _TRUE) for m, t in zip(missing, text, strict=True)]
        frame[col] = frame[col].astype(object)

    dup = frame.duplicated(KEYS, keep=False)
    if dup.any():
        lines = [int(i) + 2 for i in np.flatnonzero(dup.to_numpy())]
        first = lines[0] - 2
        key = "/".join(str(frame[k].iloc[first]) or "-" for k in KEYS)
        same = [ln for ln in lines if tuple(frame[KEYS].iloc[ln - 2]) == tuple(frame[KEYS].iloc[first])]
        raise error(f"duplicate row {key} on lines {', '.join(map(str, same))}", source=src, field="scenario")
    return frame


def _line(mask: pd.Series) -> int:
    """CSV line (header = 1) of the first True in ``mask``."""
    return int(np.argmax(mask.to_numpy())) + 2
