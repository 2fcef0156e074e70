"""Cut a recorded log into the segments the observers run on, and put each on a uniform time base.

A row is usable when the speed is known and above ``min_speed_mps`` (the bicycle models divide by vx)
and at least one measured channel has a value. The log is cut

- at every *gap*: a time step longer than ``gap_factor`` × the log's median step;
- wherever usability changes (standstill, speed missing, nothing measured).

Usable stretches shorter than ``min_duration_s`` are skipped as too short. Every skipped stretch and
every gap is reported (start, end, reason); nothing is interpolated across it. Observers are reset at
the start of each segment they run on.

Irregular timestamps. Within a segment whose steps differ from the segment's median step ``h`` by more
than ``regular_tolerance`` (relative), the samples are placed on the uniform grid
``t0 + k h``: each sample goes to the first grid time at or after its own time stamp (like a sensor
sample that *arrives* then), and when several land on one grid time the latest value per channel is
kept (nearest previous sample). A grid time that receives no sample holds NaN (``log_valid = 0``), so
the observers predict through it; no value is invented. A regular segment is passed through unchanged.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

from roadtruth.harness.jobs.replay_column_map import SegmentRules

RUN = "run"
SKIPPED = "skipped"

_OK, _NO_MEASUREMENT, _NO_SPEED, _STANDSTILL = 0, 1, 2, 3


@dataclass(frozen=True)
class Segment:
    """A stretch of the log. Rows ``[i0, i1)`` of the canonical frame (``i0 == i1`` for a gap).

    ``status`` is ``run`` (observers were run on it) or ``skipped``; ``reason`` says why it was skipped;
    ``note`` says how a run segment was prepared (resampling).
    """

    index: int
    t_start_s: float
    t_end_s: float
    i0: int
    i1: int
    status: str
    reason: str = ""
    resampled: bool = False
    note: str = ""

    @property
    def n_samples(self) -> int:
        return self.i1 - self.i0

    @property
    def duration_s(self) -> float:
        return self.t_end_s - self.t_start_s

    def to_dict(self) -> dict[str, object]:
        d = asdict(self)
        d["n_samples"] = self.n_samples
        d["duration_s"] = self.duration_s
        return d


def _row_codes(frame: pd.DataFrame, measured: tuple[str, ...], min_speed_mps: float) -> np.ndarray:
    n = len(frame)
    m = frame[list(measured)].to_numpy(dtype=float)
    codes = np.zeros(n, dtype=np.int8)
    codes[~np.isfinite(m).any(axis=1)] = _NO_MEASUREMENT
    if "vx_mps" in frame.columns:
        vx = frame["vx_mps"].to_numpy(dtype=float)
        with np.errstate(invalid="ignore"):
            codes[(codes == _OK) & (vx < min_speed_mps)] = _STANDSTILL
        codes[(codes == _OK) & ~np.isfinite(vx)] = _NO_SPEED
    return codes


def _reason(code: int, rules: SegmentRules) -> str:
    return {
        _NO_MEASUREMENT: "no measurement (every measured channel NaN)",
        _NO_SPEED: "speed missing (vx_mps NaN)",
        _STANDSTILL: f"standstill or reversing (vx_mps < {rules.min_speed_mps:g} m/s)",
    }[code]


def median_step(t: np.ndarray) -> float:
    """Median time step [s] of a strictly increasing (n,) time vector (NaN when n < 2)."""
    return float(np.median(np.diff(t))) if t.size >= 2 else math.nan


def segment_log(frame: pd.DataFrame, measured: tuple[str, ...], rules: SegmentRules) -> tuple[Segment, ...]:
    """Segments of a canonical log frame (``apply_map`` output), in time order.

    Parameters
    ----------
    frame : DataFrame
        (n, k) with strictly increasing ``t_s`` [s] and the measured channels.
    measured : tuple of str
        Channels fed to the observers.
    rules : SegmentRules

    Returns
    -------
    tuple of Segment
        Covers every row once; gaps appear as zero-row skipped segments between the rows they separate.
    """
    t = frame["t_s"].to_numpy(dtype=float)
    n = t.size
    codes = _row_codes(frame, measured, rules.min_speed_mps)
    h = median_step(t)
    gap_after = np.zeros(n, dtype=bool)  # gap between row i and row i + 1
    if n >= 2:
        gap_after[:-1] = np.diff(t) > rules.gap_factor * h
    # a new stretch starts at row i when the code changes or a gap precedes it
    start = np.zeros(n, dtype=bool)
    start[0] = True
    start[1:] = (codes[1:] != codes[:-1]) | gap_after[:-1]
    starts = np.flatnonzero(start)
    ends = np.append(starts[1:], n)
    segs: list[Segment] = []
    for i0, i1 in zip(starts.tolist(), ends.tolist(), strict=True):
        code = int(codes[i0])
        t0, t1 = float(t[i0]), float(t[i1 - 1])
        if code != _OK:
            segs.append(Segment(len(segs), t0, t1, i0, i1, SKIPPED, _reason(code, rules)))
        elif i1 - i0 < 2 or t1 - t0 < rules.min_duration_s:
            segs.append(Segment(len(segs), t0, t1, i0, i1, SKIPPED,
                                f"too short ({t1 - t0:.3g} s < {rules.min_duration_s:g} s)"))
        else:
            seg_dt = np.diff(t[i0:i1])
            hs = float(np.median(seg_dt))
            irregular = bool(np.max(np.abs(seg_dt / hs - 1.0)) > rules.regular_tolerance)
            note = (f"irregular steps ({seg_dt.min():.4g}…{seg_dt.max():.4g} s): resampled to a uniform "
                    f"{hs:.4g} s grid, nearest previous sample" if irregular else "")
            segs.append(Segment(len(segs), t0, t1, i0, i1, RUN, "", irregular, note))
        if i1 < n and gap_after[i1 - 1]:
            segs.append(Segment(len(segs), t1, float(t[i1]), i1, i1, SKIPPED,
                                f"gap of {t[i1] - t1:.4g} s (> {rules.gap_factor:g} x median step {h:.4g} s)"))
    return tuple(segs)


def segment_measurements(frame: pd.DataFrame, seg: Segment, measured: tuple[str, ...]) -> pd.DataFrame:
    """The observers' measurement frame of one run segment: ``t_s``, measured channels, ``log_valid``.

    A regular segment is the log's own rows. An irregular one is put on a uniform grid (module
    docstring): each sample lands on the first grid time at or after it, the latest value per channel
    wins, empty grid times are NaN with ``log_valid = 0``.

    Returns
    -------
    DataFrame
        (m, 2 + len(measured)); ``t_s`` [s] uniform when ``seg.resampled``.
    """
    part = frame.iloc[seg.i0:seg.i1]
    t = part["t_s"].to_numpy(dtype=float)
    values = part[list(measured)].reset_index(drop=True)
    if not seg.resampled:
        out = pd.concat([pd.DataFrame({"t_s": t}), values], axis=1)
        out["log_valid"] = np.isfinite(values.to_numpy(dtype=float)).any(axis=1).astype(np.int8)
        return out
    h = float(np.median(np.diff(t)))
    # a tiny tolerance keeps a sample exactly on a grid time on that grid time despite rounding
    cell = np.ceil((t - t[0]) / h - 1e-9).astype(np.int64)
    m = int(cell[-1]) + 1
    latest = values.groupby(cell).last()  # last non-NaN value per channel within a cell
    grid = pd.DataFrame({"t_s": t[0] + h * np.arange(m)})
    grid = grid.join(latest.reindex(np.arange(m)).reset_index(drop=True))
    grid["log_valid"] = np.isfinite(grid[list(measured)].to_numpy(dtype=float)).any(axis=1).astype(np.int8)
    return grid


def segments_frame(segs: tuple[Segment, ...]) -> pd.DataFrame:
    """``segments.csv``: one row per segment (run or skipped), in time order."""
    cols = ["segment", "t_start_s", "t_end_s", "duration_s", "n_samples", "status", "reason", "resampled", "note"]
    rows = [{"segment": s.index, "t_start_s": s.t_start_s, "t_end_s": s.t_end_s, "duration_s": s.duration_s,
             "n_samples": s.n_samples, "status": s.status, "reason": s.reason, "resampled": s.resampled,
             "note": s.note} for s in segs]
    return pd.DataFrame(rows, columns=cols)
