"""Reading, mapping, validating and segmenting recorded logs (harness/jobs/replay_log.py, replay_segments.py)."""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.io
import yaml

from roadtruth.harness.errors import InputError, LogError
from roadtruth.harness.jobs.replay_log import (
    G0,
    apply_map,
    identity_map,
    load_column_map,
    read_log,
)
from roadtruth.harness.jobs.replay_segments import RUN, SKIPPED, segment_log, segment_measurements


def steady_turn_log(t: np.ndarray, vx: float | np.ndarray = 20.0) -> pd.DataFrame:
    """A canonical log of a car on a slow steering sine: linear-bicycle steady state at each instant."""
    L, K = 2.4, 0.002  # wheelbase [m], understeer gradient [rad/(m/s^2)]
    vx = np.broadcast_to(np.asarray(vx, float), t.shape).copy()
    delta = 0.03 * np.sin(2 * np.pi * 0.2 * t)
    r = vx * delta / (L + K * vx**2)
    vy = 0.05 * r * 1.07  # small, consistent sideslip
    return pd.DataFrame({"t_s": t, "vx_mps": vx, "vy_mps": vy, "beta_rad": np.arctan2(vy, vx),
                         "delta_rad": delta, "yaw_rate_radps": r, "ax_mps2": np.zeros_like(t),
                         "ay_mps2": vx * r})


def write_map(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data))
    return path


BASE_MAP = {
    "time": {"column": "time"},
    "delta_rad": {"column": "steer", "unit": "deg"},
    "yaw_rate_radps": {"column": "r", "unit": "deg/s"},
    "ay_mps2": {"column": "acc_y", "unit": "g"},
    "vx_mps": {"column": "speed", "unit": "km/h"},
    "beta_rad": {"column": "slip", "unit": "deg"},
    "measured": ["delta_rad", "yaw_rate_radps", "ay_mps2", "vx_mps"],
    "reference": ["beta_rad", "vx_mps"],
}


def vendor_log(t: np.ndarray) -> pd.DataFrame:
    """The steady-turn log at 40 m/s in a logger's own names and units (deg, deg/s, g, km/h)."""
    c = steady_turn_log(t, 40.0)
    return pd.DataFrame({"time": t, "steer": np.degrees(c.delta_rad), "r": np.degrees(c.yaw_rate_radps),
                         "acc_y": c.ay_mps2 / G0, "speed": c.vx_mps * 3.6, "slip": np.degrees(c.beta_rad)})


# ---- the real log ------------------------------------------------------------------------------

def test_revs_log_maps_to_one_regular_segment(revs_log: Path) -> None:
    cmap = load_column_map("revs_250lm")
    frame = apply_map(read_log(revs_log), cmap, str(revs_log))
    assert len(frame) == 55001
    assert frame.t_s.iloc[0] == pytest.approx(149.99) and frame.t_s.iloc[-1] == pytest.approx(699.99)
    # the INS reference obeys the kinematic identity beta = atan(vy / vx)
    np.testing.assert_allclose(frame.beta_rad, np.arctan2(frame.vy_mps, frame.vx_mps), atol=1e-6)
    segs = segment_log(frame, cmap.measured, cmap.rules)
    # the car never drops below 16 m/s and the logger never skips a sample: nothing is skipped
    assert [(s.status, s.n_samples, s.resampled) for s in segs] == [(RUN, 55001, False)]


def test_identity_map_of_a_canonical_log_matches_the_shipped_revs_map(revs_log: Path) -> None:
    raw = read_log(revs_log)
    ident = identity_map(list(raw.columns), str(revs_log))
    assert set(load_column_map("revs_250lm").measured) <= set(ident.measured)
    assert {"beta_rad", "vy_mps", "vx_mps"} <= set(ident.reference)
    assert "yaw_rate_filt_degps" not in ident.channels  # not canonical: ignored, never misread as rad/s


# ---- units and formats ---------------------------------------------------------------------------

def test_unit_conversions_recover_the_si_log(tmp_path: Path) -> None:
    t = np.arange(0.0, 5.0, 0.01)
    src = tmp_path / "vendor.csv"
    vendor_log(t).to_csv(src, index=False)
    cmap = load_column_map(write_map(tmp_path / "map.yaml", BASE_MAP))
    frame = apply_map(read_log(src), cmap, str(src))
    si = steady_turn_log(t, 40.0)
    for name in ("delta_rad", "yaw_rate_radps", "ay_mps2", "vx_mps", "beta_rad"):
        np.testing.assert_allclose(frame[name], si[name], rtol=1e-12, atol=1e-12)


def test_scale_and_offset(tmp_path: Path) -> None:
    t = np.arange(0.0, 2.0, 0.01)
    log = steady_turn_log(t)
    log["hw"] = log.delta_rad * 15.0  # a handwheel angle in rad
    log["t_ms"] = t * 1000.0 + 5.0
    src = tmp_path / "hw.csv"
    log.to_csv(src, index=False)
    cmap = load_column_map(write_map(tmp_path / "m.yaml", {
        "time": {"column": "t_ms", "unit": "ms", "offset": -0.005},
        "delta_rad": {"column": "hw", "scale": 1 / 15.0}, "measured": ["delta_rad"]}))
    frame = apply_map(read_log(src), cmap, str(src))
    np.testing.assert_allclose(frame.t_s, t, atol=1e-12)
    np.testing.assert_allclose(frame.delta_rad, log.delta_rad, atol=1e-15)


def test_gzip_parquet_and_mat_round_trips_equal_the_csv(tmp_path: Path) -> None:
    t = np.arange(0.0, 3.0, 0.02)
    log = steady_turn_log(t)
    log.to_csv(tmp_path / "a.csv", index=False)
    with gzip.open(tmp_path / "a.csv.gz", "wt") as fh:
        log.to_csv(fh, index=False)
    log.to_parquet(tmp_path / "a.parquet")
    # MATLAB: one struct of column vectors, and plain (1, n) row-vector variables
    scipy.io.savemat(tmp_path / "struct.mat", {"run1": {c: log[c].to_numpy()[:, None] for c in log.columns},
                                               "fs_hz": 50.0})
    scipy.io.savemat(tmp_path / "plain.mat", {c: log[c].to_numpy()[None, :] for c in log.columns})
    want = apply_map(read_log(tmp_path / "a.csv"), identity_map(list(log.columns), "a.csv"), "a.csv")
    for name in ("a.csv.gz", "a.parquet", "struct.mat", "plain.mat"):
        raw = read_log(tmp_path / name)
        got = apply_map(raw, identity_map(list(raw.columns), name), name)
        pd.testing.assert_frame_equal(got[want.columns], want, check_exact=False, rtol=1e-14)
    # struct fields are also reachable by their dotted name
    assert "run1.yaw_rate_radps" in read_log(tmp_path / "struct.mat").columns


# ---- bad logs: one LogError each, naming the file and the column ---------------------------------

def test_missing_column_names_the_column_and_the_file(tmp_path: Path) -> None:
    src = tmp_path / "nospeed.csv"
    vendor_log(np.arange(0.0, 2.0, 0.01)).drop(columns="speed").to_csv(src, index=False)
    cmap = load_column_map(write_map(tmp_path / "map.yaml", BASE_MAP))
    with pytest.raises(LogError, match=r"nospeed\.csv: missing required column 'speed' \(mapped to vx_mps"):
        apply_map(read_log(src), cmap, str(src))


@pytest.mark.parametrize(("signal", "hint"), [
    ("yaw_rate_radps", "deg/s instead of rad/s"),
    ("delta_rad", "degrees, or the handwheel angle"),
    ("ay_mps2", "wrong unit"),
    ("vx_mps", "km/h or mph"),
])
def test_wrong_unit_is_caught_by_its_plausibility_range(tmp_path: Path, signal: str, hint: str) -> None:
    src = tmp_path / "vendor.csv"
    vendor_log(np.arange(0.0, 10.0, 0.01)).to_csv(src, index=False)
    bad = dict(BASE_MAP)
    spec = dict(bad[signal])
    spec.pop("unit")  # the vendor unit is read as if it were SI
    if signal == "ay_mps2":
        spec["scale"] = 1000.0 * G0  # a logger in mm/s^2 mistaken for m/s^2
    bad[signal] = spec
    cmap = load_column_map(write_map(tmp_path / "bad.yaml", bad))
    with pytest.raises(LogError, match=rf"vendor\.csv: column '{spec['column']}' as {signal}: .*{hint}"):
        apply_map(read_log(src), cmap, str(src))


def test_time_going_backwards_names_the_row(tmp_path: Path) -> None:
    log = steady_turn_log(np.arange(0.0, 2.0, 0.01))
    log.loc[100, "t_s"] = 0.5
    src = tmp_path / "back.csv"
    log.to_csv(src, index=False)
    raw = read_log(src)
    with pytest.raises(LogError, match=r"back\.csv: time column 't_s' goes backwards at row 101 \(t=0.99 then 0.5\)"):
        apply_map(raw, identity_map(list(raw.columns), str(src)), str(src))


@pytest.mark.parametrize("content", [b"", b"t_s,vx_mps,delta_rad\n"])
def test_empty_file(tmp_path: Path, content: bytes) -> None:
    src = tmp_path / "empty.csv"
    src.write_bytes(content)
    with pytest.raises(LogError, match=r"empty\.csv: empty file"):
        read_log(src)


@pytest.mark.parametrize(("name", "content", "message"), [
    ("log.parquet", b"this is not parquet at all" * 10, r"log\.parquet: unreadable as parquet"),
    ("log.mat", b"MATLAB garbage" * 20, r"log\.mat: unreadable MATLAB file"),
    ("log.csv.gz", b"\x1f\x8b\x08 truncated gzip", r"log\.csv\.gz: unreadable as csv"),
    ("log.xlsx", b"PK\x03\x04", r"log\.xlsx: unreadable format '\.xlsx'"),
])
def test_unreadable_file(tmp_path: Path, name: str, content: bytes, message: str) -> None:
    src = tmp_path / name
    src.write_bytes(content)
    with pytest.raises(LogError, match=message):
        read_log(src)


def test_non_numeric_column_names_the_row(tmp_path: Path) -> None:
    log = steady_turn_log(np.arange(0.0, 1.0, 0.01)).astype(object)
    log.loc[7, "yaw_rate_radps"] = "n/a?"
    src = tmp_path / "text.csv"
    log.to_csv(src, index=False)
    raw = read_log(src)
    with pytest.raises(LogError, match=r"column 'yaw_rate_radps' \(yaw_rate_radps\) is not numeric \(row 8"):
        apply_map(raw, identity_map(list(raw.columns), str(src)), str(src))


@pytest.mark.parametrize(("change", "message"), [
    ({"yaw_rate_deg": {"column": "r"}}, r"bad\.yaml: yaw_rate_deg: unknown map key"),
    ({"delta_rad": {"column": "steer", "units": "deg"}}, r"bad\.yaml: delta_rad\.units: unknown field"),
    ({"vx_mps": {"column": "speed", "unit": "deg"}}, r"vx_mps\.unit: 'deg' converts to rad, but vx_mps is in m/s"),
    ({"reference": ["beta_rad", "vy_mps"]}, r"reference: 'vy_mps' is listed but has no mapping"),
    ({"measured": ["beta_rad"]}, r"measured: 'beta_rad' is not a measurement column"),
])
def test_bad_column_map(tmp_path: Path, change: dict, message: str) -> None:
    with pytest.raises(LogError, match=message):
        load_column_map(write_map(tmp_path / "bad.yaml", {**BASE_MAP, **change}))


def test_log_error_is_an_input_error_and_one_line() -> None:
    with pytest.raises(InputError) as err:
        load_column_map("no_such_map")
    assert "\n" not in str(err.value) and "revs_250lm" in str(err.value)


def test_canonical_log_without_time_needs_a_map(tmp_path: Path) -> None:
    with pytest.raises(LogError, match=r"x\.csv: no 't_s' column"):
        identity_map(["time", "vx_mps"], str(tmp_path / "x.csv"))


# ---- segmentation ----------------------------------------------------------------------------------

def test_irregular_timestamps_and_a_gap_give_two_resampled_segments() -> None:
    rng = np.random.default_rng(7)
    h = 0.01
    t1 = np.cumsum(rng.uniform(0.6 * h, 1.4 * h, 500))  # jittered 100 Hz, 5 s
    t2 = t1[-1] + 2.0 + np.cumsum(rng.uniform(0.6 * h, 1.4 * h, 400))  # 2 s without samples
    log = steady_turn_log(np.concatenate([t1, t2]))
    cmap = identity_map(list(log.columns), "irregular.csv")
    frame = apply_map(log, cmap, "irregular.csv")
    segs = segment_log(frame, cmap.measured, cmap.rules)
    assert [s.status for s in segs] == [RUN, SKIPPED, RUN]
    assert segs[1].reason.startswith("gap of 2.0") and segs[1].n_samples == 0
    assert segs[1].t_start_s == t1[-1] and segs[1].t_end_s == t2[0]
    for seg, t in ((segs[0], t1), (segs[2], t2)):
        assert seg.resampled
        m = segment_measurements(frame, seg, cmap.measured)
        steps = np.diff(m.t_s.to_numpy())
        np.testing.assert_allclose(steps, steps[0], rtol=1e-9)  # uniform grid
        assert m.t_s.iloc[0] == t[0] and m.t_s.iloc[-1] >= t[-1] and m.t_s.iloc[-1] - t[-1] < steps[0]
        # no invented values: every grid value is the latest log sample at or before that grid time
        valid = m[m.log_valid == 1]
        j = np.searchsorted(t, valid.t_s.to_numpy() + 1e-9, side="right") - 1
        np.testing.assert_array_equal(valid.yaw_rate_radps.to_numpy(),
                                      frame.yaw_rate_radps.to_numpy()[seg.i0 + j])
        empty = m[m.log_valid == 0]
        assert len(empty) > 0 and empty[list(cmap.measured)].isna().all().all()


def test_standstill_nan_and_short_stretches_are_skipped_and_reported() -> None:
    t = np.arange(0.0, 30.0, 0.01)
    vx = np.where((t >= 10.0) & (t < 15.0), 0.5, 20.0)  # stopped between 10 and 15 s
    log = steady_turn_log(t, vx)
    cols = ["delta_rad", "yaw_rate_radps", "ax_mps2", "ay_mps2"]
    log.loc[(t >= 20.0) & (t < 21.0), cols + ["vx_mps"]] = np.nan  # logger dropped everything for 1 s
    log.loc[(t >= 21.0) & (t < 21.5), "vx_mps"] = np.nan  # then the speed alone for 0.5 s
    log.loc[(t >= 25.0) & (t < 25.3), "yaw_rate_radps"] = np.nan  # one channel missing: fed as NaN
    cmap = identity_map(list(log.columns), "stops.csv")
    frame = apply_map(log, cmap, "stops.csv")
    segs = segment_log(frame, cmap.measured, cmap.rules)
    got = [(s.status, round(s.t_start_s, 2), s.reason.split(" (")[0]) for s in segs]
    assert got == [
        (RUN, 0.0, ""),
        (SKIPPED, 10.0, "standstill or reversing"),
        (RUN, 15.0, ""),
        (SKIPPED, 20.0, "no measurement"),
        (SKIPPED, 21.0, "speed missing"),
        (RUN, 21.5, ""),
    ]
    assert sum(s.n_samples for s in segs) == len(t)  # every row accounted for once
    m = segment_measurements(frame, segs[-1], cmap.measured)
    assert m.yaw_rate_radps.isna().sum() == 30 and (m.log_valid == 1).all() and not segs[-1].resampled
    assert math.isclose(segs[-1].t_end_s, t[-1])


def test_short_stretch_between_stops_is_skipped() -> None:
    t = np.arange(0.0, 12.0, 0.01)
    vx = np.where((t >= 5.0) & (t < 5.5), 10.0, 1.0)
    vx[t >= 8.0] = 10.0
    log = steady_turn_log(t, vx)
    cmap = identity_map(list(log.columns), "short.csv")
    segs = segment_log(apply_map(log, cmap, "short.csv"), cmap.measured, cmap.rules)
    assert [s.status for s in segs] == [SKIPPED, SKIPPED, SKIPPED, RUN]
    assert segs[1].reason.startswith("too short (0.49 s < 1 s)")
