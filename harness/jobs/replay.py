"""``roadtruth replay``: run the observers on a recorded log and score them against its reference channels.

The log takes the place of simulated truth; everything downstream is the simulated suite's:
``roadtruth.harness.evaluation.estimate.run_observers`` runs the observers, ``roadtruth.harness.evaluation.scoring.score`` computes the same
metrics, ``roadtruth.harness.report.build_report`` writes the same report (without rendered frames).

Steps: read the log and map it to canonical signals (``harness/jobs/replay_log.py``), cut it into
segments (``harness/jobs/replay_segments.py``: gaps, standstill, missing speed, irregular timestamps),
run every observer on every usable segment from a fresh reset, score on the reference channels of
those segments only, and report the skipped ones.

Folder written (``out``), like a one-scenario ``run`` whose scenario is the log's name::

    metrics.csv  run.json  index.html
    <log>/truth.csv         the log's reference channels on the log's own time base (+ segment)
    <log>/measurements.csv  what the observers were fed, per run segment (+ segment, log_valid)
    <log>/estimates.csv     wide: t_s, segment, <observer>.<state> (+ _lo, _hi, _var), one row per step
    <log>/segments.csv      every segment, run or skipped, with the reason
    (``.parquet`` instead of ``.csv`` for every table with ``table_format="parquet"``)
    <log>/events.json       skipped segments as report events
    <log>/scenario.json     what the report shows about the log

Scoring across segments. ``score`` holds estimates zero-order onto the truth times. Run segments are
therefore scored on one *stitched* time axis on which the skipped spans are cut out (each segment is
shifted to start two median steps after the previous one ends), so no estimate is ever held across a
skipped span and every metric pools the scored samples of all run segments exactly. ``conv_time_s`` is
measured from the start of the first run segment on that axis. Files keep the log's own times.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.errors import LogError
from roadtruth.harness.evaluation.observer_options import check_observer_options, options_record
from roadtruth.harness.files.outdir import atomic_output_dir, check_output_dir
from roadtruth.harness.files.table_io import TableWriter, WideEstimates, check_format, write_table
from roadtruth.harness.jobs.replay_checks import CheckResult, check_consistency
from roadtruth.harness.jobs.replay_log import (
    ColumnMap,
    apply_map,
    identity_map,
    load_column_map,
    read_log,
    resolve_vehicle,
)
from roadtruth.harness.jobs.replay_segments import (
    RUN,
    Segment,
    segment_log,
    segment_measurements,
    segments_frame,
)
from roadtruth.harness.progress import Progress as ProgressBar
from roadtruth.harness.report.rundata import git_revision, versions, write_json
from roadtruth.harness.truth.vehicle import VehicleParams, load_vehicle

Progress = Callable[[str], None]

#: The stages of a replay, in order, as ``replay(on_stage=...)`` announces them (benchmarks measure
#: wall time and memory per stage with it).
STAGES: tuple[str, ...] = ("prepare", "observers", "write", "score", "report")


def default_jobs() -> int:
    """Observer host processes run at once by default: 2 when the machine has 2 cores or more.

    Each host holds numpy, numba, cvxpy and every observer (about 300 MB), so the default does not
    grow with the core count; ``jobs`` asks for more.
    """
    return 2 if (os.cpu_count() or 1) >= 2 else 1


def check_jobs(jobs: int | None) -> int:
    """``jobs`` (None: :func:`default_jobs`) if it is an integer >= 1, else ``InputError`` on ``--jobs``."""
    from roadtruth.harness.errors import InputError

    if jobs is None:
        return default_jobs()
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise InputError(f"must be a whole number >= 1 (got {jobs!r})", field="--jobs")
    return jobs


@dataclass(frozen=True)
class ReplayLog:
    """A log made ready for the observers.

    ``frame`` is the canonical frame on the log's own time base (n rows); ``segments`` covers it;
    ``measurements`` holds one observer input frame per run segment (keyed by segment index).
    """

    path: Path
    name: str
    column_map: ColumnMap
    frame: pd.DataFrame
    segments: tuple[Segment, ...]
    measurements: dict[int, pd.DataFrame]
    time_origin_s: float = 0.0  # the log clock at t_s = 0 (0: files keep the log's own times)
    checks: tuple[CheckResult, ...] = ()  # sign/unit consistency (harness/jobs/replay_checks.py)
    notes: tuple[str, ...] = ()  # what was derived or only warned about, one line each

    @property
    def run_segments(self) -> tuple[Segment, ...]:
        return tuple(s for s in self.segments if s.status == RUN)


def log_name(path: Path) -> str:
    """Scenario name of a log: its file name without the format suffixes (``a.csv.gz`` → ``a``)."""
    name = path.name
    for suffix in (".gz", ".csv", ".tsv", ".txt", ".parquet", ".pq", ".mat", ".mf4", ".mdf", ".mcap"):
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
    return name or path.stem


def prepare_log(log: Path, columns: str | Path | ColumnMap | None = None, *, vehicle: VehicleParams | None = None,
                rate_hz: float | None = None) -> ReplayLog:
    """Read, map, check and segment a log (no observers run). Raises ``LogError`` on a bad log.

    ``vehicle`` supplies the parameters derived channels name (``steering_ratio`` …) and the wheel
    radius of the speed check; ``rate_hz`` is the sample rate of a log without a time column.
    A failed sign/unit check raises unless the map says ``checks: warn`` (then it is a note) or ``off``.
    """
    log = Path(log)
    cmap = load_column_map(columns) if isinstance(columns, str | Path) else columns
    if cmap is not None and rate_hz is not None:
        cmap = cmap.with_rate(rate_hz)
    raw = read_log(log, cmap.log_columns() if cmap is not None else None)
    if cmap is None:
        cmap = identity_map(list(raw.columns), str(log), rate_hz=rate_hz)
    frame = apply_map(raw, cmap, str(log), vehicle)
    notes = [f"{k}: {c.note}" for k, c in cmap.channels.items() if c.note]
    if vehicle is not None and vehicle.derived_note:
        notes.append(vehicle.derived_note)
    checks = tuple(check_consistency(frame, vehicle.wheel_radius_m if vehicle is not None else None)
                   ) if cmap.checks != "off" else ()
    failed = [c for c in checks if c.status == "fail"]
    if failed and cmap.checks == "error":
        raise LogError("; ".join(c.evidence for c in failed) + " (or 'checks: warn' in the column map to go on)",
                       source=str(log))
    notes += [f"check {c.check}: {c.evidence}" for c in checks if c.status in ("fail", "warn")]
    segs = segment_log(frame, cmap.measured, cmap.rules)
    runs = [s for s in segs if s.status == RUN]
    if not runs:
        why = "; ".join(sorted({s.reason.split(" (")[0] for s in segs}))
        raise LogError(f"no segment the observers can run on (every stretch skipped: {why})", source=str(log))
    meas = {s.index: segment_measurements(frame, s, cmap.measured) for s in runs}
    return ReplayLog(path=log, name=log_name(log), column_map=cmap, frame=frame, segments=segs,
                     measurements=meas, time_origin_s=float(frame.attrs.get("time_origin_s", 0.0)),
                     checks=checks, notes=tuple(notes))


def stitched_offsets(rl: ReplayLog) -> dict[int, float]:
    """Time shift [s] per run segment that cuts the skipped spans out of the scoring axis (module doc)."""
    h = float(np.median(np.diff(rl.frame["t_s"].to_numpy()))) if len(rl.frame) > 1 else 1.0
    offsets: dict[int, float] = {}
    end = -math.inf
    for s in rl.run_segments:
        m = rl.measurements[s.index]
        t0 = s.t_start_s
        start = t0 if not offsets else end + 2.0 * h
        offsets[s.index] = start - t0
        end = max(float(m["t_s"].iloc[-1]), s.t_end_s) + offsets[s.index]
    return offsets


def _rank(status: str) -> int:
    """Which status of one observer over several segments is reported: failure > ok > skipped."""
    return 0 if status.startswith("skipped") else 1 if status.startswith("ok") else 2


def merge_runs(per_segment: list[tuple[int, dict[str, Any]]]) -> dict[str, Any]:
    """One ``ObserverRun`` per observer over all run segments.

    The first failure (``diverged``, ``error: …``) wins (naming its segment when there are several);
    otherwise ``ok`` if the observer ran on any segment (``skipped`` on another only when a channel is
    empty there); the cost per step is averaged over the steps it ran; the step counts add up.
    """
    merged: dict[str, Any] = {}
    for seg_index, runs in per_segment:
        for name, r in runs.items():
            if _rank(str(r.status)) == 2 and len(per_segment) > 1:
                r = replace(r, status=f"{r.status} (segment {seg_index})")
            old = merged.get(name)
            if old is None:
                merged[name] = r
                continue
            n_old, n_new = old.n_steps or 0, r.n_steps or 0
            cost = old.us_per_step if n_new == 0 else r.us_per_step if n_old == 0 else (
                (old.us_per_step * n_old + r.us_per_step * n_new) / (n_old + n_new))
            best = r if _rank(str(r.status)) > _rank(str(old.status)) else old
            merged[name] = replace(best, us_per_step=cost, n_steps=n_old + n_new)
    return merged


def _run_dict(run: Any) -> dict[str, Any]:
    out = {k: getattr(run, k, None) for k in ("status", "us_per_step", "certified", "design_reason",
                                              "design_status", "n_steps", "detail")}
    if isinstance(out["us_per_step"], float) and not math.isfinite(out["us_per_step"]):
        out["us_per_step"] = None
    return out


def _observer_table(names: list[str]) -> list[dict[str, Any]]:
    from roadtruth.observers.registry import observer_info

    info = {i["name"]: i for i in observer_info()}
    return [{k: v for k, v in info.get(n, {"name": n}).items() if k in ("name", "citation", "states", "inputs")}
            for n in names]


def _description(rl: ReplayLog) -> str:
    runs = rl.run_segments
    skipped = [s for s in rl.segments if s.status != RUN]
    text = (f"Replay of the recorded log {rl.path.name} (column map {rl.column_map.name}): "
            f"{len(runs)} segment(s) run, {sum(s.duration_s for s in runs):.1f} s scored")
    if skipped:
        parts = [f"{s.t_start_s:.2f}–{s.t_end_s:.2f} s {s.reason}" for s in skipped[:20]]
        more = f"; … {len(skipped) - 20} more in segments.csv" if len(skipped) > 20 else ""
        text += f"; {len(skipped)} skipped: " + "; ".join(parts) + more
    else:
        text += "; nothing skipped"
    resampled = [s for s in runs if s.resampled]
    if resampled:
        text += f"; {len(resampled)} segment(s) resampled onto a uniform grid (nearest previous sample)"
    return text + "."


def replay(
    log: Path,
    *,
    vehicle: str | Path | None = None,
    columns: str | Path | None = None,
    observers: list[str] | None = None,
    out: Path = Path("reports/replay"),
    progress: Progress | None = None,
    observer_timeout_s: float | None = None,
    rate_hz: float | None = None,
    observer_options: dict[str, dict[str, Any]] | None = None,
    table_format: str = "csv",
    jobs: int | None = None,
    on_stage: Callable[[str], None] | None = None,
) -> Path:
    """Run observers on a recorded log and score them against its reference channels.

    Parameters
    ----------
    log : Path
        CSV, gzip CSV, Parquet or MATLAB .mat log.
    vehicle : str or Path, optional
        Vehicle set name (``harness/vehicles``) or YAML path (a full or a replay vehicle,
        docs/VEHICLES.md); the observers' model parameters. Required unless the column map names one
        (``vehicle:``); when both are given this one is used.
    columns : str or Path, optional
        Column map: a shipped name (``"revs_250lm"``) or a YAML path. None: the log's columns must
        already be canonical names (identity map).
    observers : list of str, optional
        Observer names (default: every registered observer; those needing signals the log lacks
        are reported as skipped).
    out : Path
        Output folder, replaced atomically when complete.
    progress : callable, optional
        Called with one line per step. Without it, a bar on a terminal and one line per segment and
        observer on stderr otherwise (``roadtruth.harness.progress.Progress``).
    observer_timeout_s : float, optional
        Wall-time budget of each observer per segment [s] (default: max(60 s, 20 × the segment's duration)).
    rate_hz : float, optional
        Sample rate [Hz] of a log without a time column (``t = k / rate_hz``).
    observer_options : mapping, optional
        Observer -> {option: value} (``roadtruth.harness.evaluation.observer_options``), checked before the log is read and
        recorded in run.json.
    table_format : str
        ``"csv"`` (default) or ``"parquet"`` for every table written (``roadtruth.harness.files.table_io``).
    jobs : int, optional
        Observers run at the same time, each in its own host process (default :func:`default_jobs`).
        The files are the same for any value: each observer's run does not depend on the others.
    on_stage : callable, optional
        Called with the name of each stage of :data:`STAGES` as it starts (for benchmarks).

    Returns
    -------
    Path
        ``out`` (resolved).
    """
    from roadtruth.harness.evaluation.estimate import run_observer_tracks
    from roadtruth.harness.evaluation.scoring import score
    from roadtruth.harness.report import build_report
    from roadtruth.observers.registry import available_observers, observer_class

    say = progress or (lambda _msg: None)
    stage = on_stage or (lambda _name: None)
    t_wall = time.perf_counter()
    check_output_dir(out, inputs=[log, columns, vehicle])  # before any work: refusals and writability
    cmap = load_column_map(columns) if columns is not None else None
    veh: VehicleParams = load_vehicle(resolve_vehicle(vehicle, cmap), replay=True)
    check_format(table_format)
    n_jobs = check_jobs(jobs)
    if n_jobs > 1:
        from roadtruth.harness.evaluation import observer_host
        # Their imports overlap this process's own (the observers) and reading the log.
        observer_host.prestart(min(n_jobs, len(set(observers)) if observers else n_jobs))
    names = list(dict.fromkeys(observers)) if observers else available_observers()
    for name in names:
        observer_class(name)  # an unknown observer is refused before the log is read
    observer_options = check_observer_options(observer_options, names, veh)
    stage("prepare")
    rl = prepare_log(Path(log), cmap, vehicle=veh, rate_hz=rate_hz)
    for note in rl.notes:  # derived channels and fields, warnings of the consistency checks
        print(f"roadtruth replay: note: {note}", file=sys.stderr)
    say(f"{rl.name}: {len(rl.frame)} rows, {len(rl.run_segments)} run segment(s), "
        f"{len(rl.segments) - len(rl.run_segments)} skipped")

    # Estimates are kept as float arrays per <observer>.<state> and segment (WideEstimates), not as
    # a long frame with copies per segment: that is what made a long log's replay peak near 2 GB.
    stage("observers")
    wide = WideEstimates()
    per_segment: list[tuple[int, dict[str, Any]]] = []
    offsets = stitched_offsets(rl)
    bar = ProgressBar(len(rl.run_segments) * len(names), None, desc="roadtruth replay") if progress is None else None

    def run_one(m: pd.DataFrame, name: str) -> tuple[dict[str, Any], dict[str, Any], float]:
        t_obs = time.perf_counter()
        opts = {name: observer_options[name]} if name in observer_options else None
        tracks, runs = run_observer_tracks(m, veh, [name], timeout_s=observer_timeout_s, options=opts)
        return tracks, runs, time.perf_counter() - t_obs

    # Each observer runs in a host process of its own thread's (harness/evaluation/observer_host.py): n_jobs of
    # them at once. Results are taken in submission order, so files and progress lines do not
    # depend on which observer finishes first.
    pool = ThreadPoolExecutor(max_workers=n_jobs, thread_name_prefix="replay-observer")
    try:
        tasks: list[tuple[Segment, list[tuple[str, Future[Any]]]]] = []
        for s in rl.run_segments:
            m = rl.measurements[s.index]
            tasks.append((s, [(name, pool.submit(run_one, m, name)) for name in names]))
        for s, futures in tasks:
            m = rl.measurements[s.index]
            say(f"segment {s.index}: {s.t_start_s:.2f}–{s.t_end_s:.2f} s, {len(m)} steps")
            seg_runs: dict[str, Any] = {}
            wide.add_times(s.index, m["t_s"].to_numpy(float))
            while futures:
                name, fut = futures.pop(0)  # the future holds the track: let both go once stored
                tracks, runs, seconds = fut.result()
                del fut
                for track in tracks.values():
                    wide.add_track(s.index, track)
                del tracks
                seg_runs.update(runs)
                if bar is not None:
                    bar.item(f"segment {s.index} ({s.t_start_s:.0f}–{s.t_end_s:.0f} s): {name}: "
                             f"{runs[name].status}, {seconds:.1f} s")
            per_segment.append((s.index, seg_runs))
    except BaseException:
        # Ctrl-C (or a failure here): start no further observer; the ones running end within
        # their time budget, and their hosts with this process.
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    else:
        pool.shutdown(wait=True)
    finally:
        if bar is not None:
            bar.close()
    runs_all = merge_runs(per_segment)

    ref = list(rl.column_map.reference)
    seg_of_row = np.full(len(rl.frame), -1, dtype=np.int64)
    for s in rl.segments:
        seg_of_row[s.i0:s.i1] = s.index if s.status == RUN else -1
    truth = rl.frame[["t_s", *ref]].copy()
    truth["segment"] = seg_of_row
    scoring_parts = []
    for s in rl.run_segments:
        part = truth.iloc[s.i0:s.i1].copy()
        part["t_s"] = part["t_s"] + offsets[s.index]
        scoring_parts.append(part)
    scoring_truth = pd.concat(scoring_parts, ignore_index=True)

    out = Path(out)
    with atomic_output_dir(out, command="replay", inputs=[log, columns, vehicle]) as tmp:
        stage("write")
        sub = tmp / rl.name
        sub.mkdir()
        write_table(truth, sub, "truth", table_format)
        with TableWriter(sub, "measurements", table_format) as meas_file:  # segment by segment, no concat copy
            for s in rl.run_segments:
                meas_file.write(rl.measurements[s.index].assign(segment=s.index))
        wide.write(sub, "estimates", table_format)  # wide: one row per time step, from the arrays
        stage("score")
        # Scored one observer at a time (score() treats observers independently: the same rows as
        # one call); its arrays are written already and freed once it is scored.
        scored = []
        for name, run in runs_all.items():
            track = wide.track(name, offsets)
            scored.append(score(scoring_truth, {name: track} if track is not None else {}, scenario=rl.name,
                                runs={name: run}, mass_kg=veh.mass_kg))
            del track
            wide.drop(name)
        metrics = pd.concat(scored, ignore_index=True) if scored else score(
            scoring_truth, {}, scenario=rl.name, runs={}, mass_kg=veh.mass_kg)
        write_table(segments_frame(rl.segments), sub, "segments", table_format)
        events = [{"t_s": s.t_start_s, "label": f"skipped: {s.reason.split(' (')[0]}"}
                  for s in rl.segments if s.status != RUN]
        write_json(events, sub / "events.json")
        description = _description(rl)
        info = {"name": rl.name, "kind": "replay", "description": description, "vehicle": veh.name,
                "duration_s": float(rl.frame["t_s"].iloc[-1] - rl.frame["t_s"].iloc[0]), "tags": ["replay"]}
        write_json(info, sub / "scenario.json")
        write_table(metrics, tmp, "metrics", table_format)
        run_json = {
            "command": "replay",
            "log": str(Path(log).resolve()),
            "time_origin_s": rl.time_origin_s,
            "input_checks": [c.to_dict() for c in rl.checks],
            "notes": list(rl.notes),
            "column_map": rl.column_map.to_dict(),
            "table_format": table_format,
            "observer_options": options_record(observer_options),
            "vehicle": veh.name,
            "vehicle_path": veh.path,
            "observers": _observer_table(list(runs_all)),
            "observer_runs": {rl.name: {k: _run_dict(v) for k, v in runs_all.items()}},
            "scenarios": [{"name": rl.name, "kind": "replay", "status": "ok", "description": description,
                           "vehicle": veh.name, "tags": ["replay"], "duration_s": info["duration_s"],
                           "rows": len(rl.frame), "render": {"reason": "recorded log: no rendered frames"},
                           "segments": [s.to_dict() for s in rl.segments]}],
            "skipped_segments": [{"t_start_s": s.t_start_s, "t_end_s": s.t_end_s, "reason": s.reason}
                                 for s in rl.segments if s.status != RUN],
            "scoring": "run segments on a stitched time axis (skipped spans cut out); files keep log times",
            "versions": versions(),
            "git_revision": git_revision(),
            "wall_s": round(time.perf_counter() - t_wall, 3),
        }
        write_json(run_json, tmp / "run.json")
        stage("report")
        build_report(tmp)
    say(f"report: {out.resolve() / 'index.html'}")
    return out.resolve()
