"""What a report figure draws: the per-pixel-column envelope of a long trace (every peak, dip and
step kept), a short trace exactly, numbers on a grid finer than the axis shows, and compact arrays
that the page's JavaScript and the Python twin expand to the same numbers."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from synthetic_run import make_run_folder

from roadtruth.harness.report import build_report
from roadtruth.harness.report.figures import state_figure
from roadtruth.harness.report.plot_data import (
    PIXEL_COLUMNS,
    ArrayPool,
    compact_values,
    envelope_indices,
    expand_array,
    expand_figure,
    read_varint_text,
    varint_text,
)
from roadtruth.harness.report.rundata import ObserverSeries, RunData

REPORT_JS = Path(__file__).resolve().parents[1] / "harness" / "report" / "assets" / "report.js"


def _bins(x: np.ndarray, columns: int) -> np.ndarray:
    """Pixel column of each sample: equal-width bins from the first to the last x (written out
    independently of the code under test)."""
    return np.minimum(np.floor((x - x[0]) / (x[-1] - x[0]) * columns), columns - 1).astype(int)


def test_the_min_and_max_of_every_pixel_column_survive_with_their_spikes():
    rng = np.random.default_rng(7)
    n, columns = 200_000, PIXEL_COLUMNS
    x = np.arange(n) * 0.001
    y = np.cumsum(rng.standard_normal(n)) * 0.01 + 0.05 * rng.standard_normal(n)
    # One-sample spikes, at most one a column (a lesser spike beside a greater one of the same sign
    # lies inside the column's drawn extent and need not be kept).
    cols = rng.choice(columns, 60, replace=False)
    spikes = ((cols + 0.2 + 0.6 * rng.random(cols.size)) * n / columns).astype(int)
    y[spikes] += rng.choice([-1.0, 1.0], spikes.size) * (20 + rng.random(spikes.size))  # one-sample spikes
    idx = envelope_indices(x, y, columns)
    assert idx.size <= 4 * columns and np.all(np.diff(idx) > 0)
    assert set(spikes.tolist()) <= set(idx.tolist())
    b = _bins(x, columns)
    kept = pd.Series(y[idx]).groupby(b[idx])
    full = pd.Series(y).groupby(b)
    assert (kept.max() == full.max()).all() and (kept.min() == full.min()).all()
    # ... and the first and last sample of every column, so the lines between columns are the same.
    firsts = np.flatnonzero(np.r_[True, b[1:] != b[:-1]])
    assert set(firsts.tolist()) <= set(idx.tolist()) and set((np.r_[firsts[1:], n] - 1).tolist()) <= set(idx.tolist())
    every_nth = np.arange(0, n, n // (4 * columns))  # what plain thinning to the same count loses
    assert not set(spikes.tolist()) <= set(every_nth.tolist())


def test_a_step_edge_survives_to_the_sample():
    n, columns = 50_000, 100
    x = np.arange(n) * 0.01
    for k in (12_345, 30_001):
        y = np.where(np.arange(n) >= k, 3.0, -1.0)
        idx = envelope_indices(x, y, columns)
        assert idx.size <= 4 * columns
        assert k in idx  # the first sample at the new level, at its own time
        before = idx[idx < k].max()
        assert y[before] == -1.0 and _bins(x, columns)[before] == _bins(x, columns)[k]  # edge within one column


def test_a_short_trace_is_drawn_exactly_and_gaps_stay_gaps():
    x = np.arange(4 * PIXEL_COLUMNS) * 0.01
    y = np.sin(x)
    assert np.array_equal(envelope_indices(x, y), np.arange(x.size))
    y_gap = np.r_[np.linspace(0, 1, 30_000), np.full(100, np.nan), np.linspace(1, 0, 30_000)]
    idx = envelope_indices(np.arange(y_gap.size, dtype=float), y_gap, 200)
    assert 30_000 in idx  # the first missing sample breaks the drawn line


def test_compact_arrays_round_trip_on_their_grid():
    rng = np.random.default_rng(1)
    d = np.r_[0, 1, -1, 15, -15, 16, -16, 2**50, -(2**50), rng.integers(-10**12, 10**12, 500)]
    assert np.array_equal(read_varint_text(varint_text(d)), d)
    assert len(varint_text(np.array([3, -15, 15, 0]))) == 4  # small steps: one character each
    v = np.r_[rng.standard_normal(300) * 7.0, np.nan, np.nan, np.inf, 2.5]
    a = compact_values(v, -4)
    back = expand_array(json.loads(json.dumps(a)))
    assert back[300:303] == [None, None, None] and a["nan"] == [[300, 3]]
    got = np.array([b for b in back if b is not None])
    want = np.r_[v[:300], 2.5]
    assert np.max(np.abs(got - want)) <= 0.5e-4 + 1e-12
    # Time samples taken from a uniform grid are written as index steps on it: exact.
    t = np.round(np.arange(0, 50, 0.01), 10)
    pool = ArrayPool()
    assert pool.times(t) == {"x0": 0.0, "dx": 0.01}
    sel = np.array([0, 5, 6, 4000, 4999])
    ref = pool.times(t, sel)
    assert pool.times(t, sel) == ref and len(pool.arrays) == 1  # written once, shared
    assert expand_array(ref["x"], pool.arrays) == pytest.approx(t[sel].tolist(), abs=1e-12)


def _series(t: np.ndarray, v: np.ndarray, name: str = "obs") -> ObserverSeries:
    return ObserverSeries(name, t, v, np.full(t.size, np.nan), np.full(t.size, np.nan))


def test_a_figure_draws_every_sample_of_a_short_run_and_the_error_as_estimate_minus_truth():
    t = np.round(np.arange(0.0, 8.0, 0.01), 10)
    beta = 0.05 * np.sin(t)
    truth = pd.DataFrame({"t_s": t, "beta_rad": beta})
    # An estimate across the ±180° seam of the truth's angle: its error is small, not ±360°.
    est = beta + 0.002 * np.cos(7 * t)
    est[100] = beta[100] + 2 * np.pi - 0.01
    spec = state_figure("beta_rad", truth, [_series(t, est)], {}, [])
    text = json.dumps(spec)
    assert len(text) < 12 * t.size  # all 800 samples of two lines, a few bytes each
    fig = expand_figure(json.loads(text))
    tr = {d["name"]: d for d in fig["data"]}
    deg = 180 / np.pi
    assert np.allclose(tr["truth"]["x"], t, atol=1e-12) and np.allclose(tr["obs"]["x"], t, atol=1e-12)
    assert np.max(np.abs(np.array(tr["truth"]["y"]) - beta * deg)) < 1e-3
    assert np.max(np.abs(np.array(tr["obs"]["y"]) - est * deg)) < 1e-3
    err = (est - beta) * deg
    err[100] = -0.01 * deg
    assert np.max(np.abs(np.array(tr["obs error"]["y"]) - err)) < 2e-3
    assert isinstance(spec["data"][-1]["y"], dict) and "minus" in spec["data"][-1]["y"]


def test_the_unscored_end_is_shaded_and_a_centred_band_is_written_once():
    t = np.round(np.arange(0.0, 6.0, 0.01), 10)
    beta = 0.05 * np.sin(t)
    est = beta + 0.003
    sigma = 0.01 + 0.02 * np.exp(-t)
    series = ObserverSeries("kf", t, est, est - 2 * sigma, est + 2 * sigma)
    spec = state_figure("beta_rad", pd.DataFrame({"t_s": t, "beta_rad": beta}), [series], {},
                        [{"t_s": 4.0, "label": "spun out"}], 4.0, "spun out")
    rect = [s for s in spec["layout"]["shapes"] if s["type"] == "rect"]
    assert len(rect) == 1 and rect[0]["x0"] == 4.0 and rect[0]["x1"] == pytest.approx(5.99)
    fig = expand_figure(json.loads(json.dumps(spec)))
    assert "not scored (spun out)" in [a["text"] for a in fig["layout"]["annotations"]]
    tr = {d["name"]: d for d in fig["data"]}
    deg = 180 / np.pi
    assert np.max(np.abs(np.array(tr["kf lower bound"]["y"]) - (est - 2 * sigma) * deg)) < 2e-3
    assert np.max(np.abs(np.array(tr["kf bounds"]["y"]) - (est + 2 * sigma) * deg)) < 2e-3
    assert tr["kf bounds"]["fill"] == "tonexty" and list(tr)[1:3] == ["kf lower bound", "kf bounds"]
    assert spec["data"][1]["y"] == {"around": [3, 0], "side": -1}  # value - half width, half width once


def test_a_long_run_keeps_its_spikes_in_the_estimate_and_in_the_error():
    rng = np.random.default_rng(5)
    n = 100_000
    t = np.round(np.arange(n) * 0.01, 10)
    beta = 0.05 * np.sin(0.01 * t)
    truth = pd.DataFrame({"t_s": t, "beta_rad": beta})
    est = beta + 0.001 * rng.standard_normal(n)
    est[54_321] += 0.3  # a one-sample glitch of the estimate
    spec = state_figure("beta_rad", truth, [_series(t, est)], {}, [])
    fig = expand_figure(json.loads(json.dumps(spec)))
    tr = {d["name"]: d for d in fig["data"]}
    assert all(len(tr[k]["y"]) <= 4 * PIXEL_COLUMNS + 2 for k in ("truth", "obs", "obs error"))
    deg = 180 / np.pi
    k = int(np.argmax(tr["obs"]["y"]))
    assert tr["obs"]["x"][k] == pytest.approx(t[54_321], abs=1e-9)
    assert tr["obs"]["y"][k] == pytest.approx(est[54_321] * deg, abs=1e-3)
    j = int(np.argmax(tr["obs error"]["y"]))
    assert tr["obs error"]["x"][j] == pytest.approx(t[54_321], abs=1e-9)
    assert tr["obs error"]["y"][j] == pytest.approx((est - beta)[54_321] * deg, abs=1e-3)
    assert len(json.dumps(spec)) < 60_000  # a 1000 s run is no bigger than a figure can show


def test_the_page_of_a_run_has_one_figure_per_scored_state_and_path_and_each_expands(tmp_path: Path):
    run_dir = make_run_folder(tmp_path / "run")
    run = RunData.load(run_dir)
    m = run.metrics
    ok = m[m["status"].astype(str).str.startswith("ok") & m["rmse"].notna()]
    want = sum(1 + ok[ok["scenario"] == s]["state"].nunique() for s in run.scenario_names)
    text = build_report(run_dir).read_text(encoding="utf-8")
    specs = re.findall(r'<script type="application/json" id="(fig-[^"]+)">(.*?)</script>', text, re.S)
    assert len(specs) == want == 6
    for fid, body in specs:
        fig = expand_figure(json.loads(body))
        for tr in fig["data"]:
            if tr.get("mode", "lines") == "lines":
                assert len(tr["x"]) == len(tr["y"]) > 1, (fid, tr.get("name"))
    assert "The metrics are not read from the plots: they are computed during the run from every simulation step" in text


@pytest.mark.skipif(shutil.which("node") is None, reason="needs node to run the page's decoder")
def test_the_pages_decoder_and_the_python_twin_agree(tmp_path: Path):
    js = REPORT_JS.read_text(encoding="utf-8")
    decoder = js[js.index("  var VARINT"):js.index("  function drawPlot(")]
    t = np.round(np.arange(0.0, 3.0, 0.01), 10)
    beta = 0.4 * np.sin(2 * t)
    est = beta + 0.01 * np.cos(9 * t)
    est[50:60] = np.nan
    est[200] = beta[200] - 2 * np.pi + 0.02  # wraps
    lo, hi = est - 0.02, est + 0.02
    short = ObserverSeries("sparse", t[::7], est[::7], lo[::7], hi[::7])  # off the truth's grid: explicit error
    spec = state_figure("beta_rad", pd.DataFrame({"t_s": t, "beta_rad": beta}),
                        [ObserverSeries("obs", t, est, lo, hi), short], {},
                        [{"t_s": 1.0, "label": "steer"}, {"t_s": 2.0, "label": "spun out"}], 2.5, "spun out")
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    (tmp_path / "run.js").write_text(decoder + "\nvar fs = require('fs');\n"
                                     "var spec = expandFigure(JSON.parse(fs.readFileSync(process.argv[2], 'utf8')));\n"
                                     "process.stdout.write(JSON.stringify(spec.data.map(function (t) {"
                                     " return {x: t.x, y: t.y, x0: t.x0, dx: t.dx}; })"
                                     ".concat([spec.layout.annotations])));\n")
    out = subprocess.run(["node", str(tmp_path / "run.js"), str(tmp_path / "spec.json")],
                         capture_output=True, text=True, check=True, timeout=60)
    js_data = json.loads(out.stdout)
    js_notes = js_data.pop()
    py = expand_figure(spec)
    py_data = py["data"]
    assert js_notes == py["layout"]["annotations"]
    assert [a["text"] for a in js_notes] == ["<b>1</b>", "<b>2</b>", "not scored (spun out)"]
    assert js_notes[0]["bgcolor"] == "rgba(255,255,255,0.85)" and js_notes[2]["borderwidth"] == 0
    assert len(js_data) == len(py_data) >= 6
    for a, b in zip(js_data, py_data, strict=True):
        ya = np.array([np.nan if v is None else v for v in a["y"]], float)
        yb = np.array([np.nan if v is None else v for v in b["y"]], float)
        assert np.array_equal(np.isnan(ya), np.isnan(yb)) and np.allclose(ya, yb, atol=1e-9, equal_nan=True)
        xa = a["x"] if a.get("x") is not None else (a["x0"] + a["dx"] * np.arange(ya.size)).tolist()
        assert np.allclose(xa, b["x"], atol=1e-9)


def _union_envelope(x: np.ndarray, y: np.ndarray, columns: int) -> np.ndarray:
    """The envelope's definition written out with set unions (as the figures' first version did):
    in each pixel column of the finite samples, the first, last and first lowest and highest one,
    plus the first sample of every run of missing ones; every finite sample when they are few."""
    finite = np.isfinite(x) & np.isfinite(y)
    gaps = np.flatnonzero(~finite & np.r_[True, finite[:-1]])
    fi = np.flatnonzero(finite)
    if y.size <= 4 * columns:
        return np.arange(y.size)
    if fi.size <= 4 * columns:
        return np.union1d(fi, gaps)
    cols = _bins(x[fi], columns)
    keep = []
    for c in np.unique(cols):
        members = fi[cols == c]
        v = y[members]
        keep += [members[0], members[-1], members[np.argmin(v)], members[np.argmax(v)]]
    return np.union1d(np.asarray(keep), gaps)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_envelope_is_the_union_of_each_columns_first_last_min_max_and_the_gaps(seed: int):
    """The kept samples are exactly the envelope's definition: sorted, unique, with missing runs
    (NaN, ±inf), repeated minima and flat stretches, on long and on short traces."""
    rng = np.random.default_rng(seed)
    columns = 50
    for n in (150, 199, 200, 201, 5_000):
        x = np.cumsum(rng.uniform(0.001, 0.02, n))
        y = np.round(rng.standard_normal(n), 1)  # rounded: many equal minima and maxima in a column
        y[rng.integers(0, n, n // 20)] = np.nan
        y[rng.integers(0, n, 3)] = np.inf
        y[n // 3: n // 3 + n // 10] = np.nan  # a long gap
        y[-n // 8:] = 0.25  # a flat end
        idx = envelope_indices(x, y, columns)
        assert idx.dtype == np.int64 and np.all(np.diff(idx) > 0)
        np.testing.assert_array_equal(idx, _union_envelope(x, y, columns))


def test_a_long_logs_figure_needs_little_more_memory_than_its_series():
    """A figure of 15 observers' β with bounds over 550 s at 100 Hz (19 MB of series) works in at
    most 2.5 times that memory: the value grid is found array by array, not from one array of every
    value and bound (3.8 times before), so the report of a long log does not set a command's peak."""
    import tracemalloc

    rng = np.random.default_rng(3)
    n = 55_000
    t = np.arange(n) * 0.01
    beta = 0.05 * np.sin(0.3 * t)
    truth = pd.DataFrame({"t_s": t, "beta_rad": beta})
    series = []
    for i in range(15):
        v = beta + 0.002 * rng.standard_normal(n)
        series.append(ObserverSeries(f"o{i}", t, v, v - 0.01 - 0.001 * rng.random(n), v + 0.01 + 0.001 * rng.random(n)))
    data = sum(a.nbytes for s in series for a in (s.value, s.lo, s.hi))
    tracemalloc.start()
    try:
        spec = state_figure("beta_rad", truth, series, {}, [])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len([d for d in spec["data"] if d["name"].endswith(" error")]) == 15
    assert peak < 2.5 * data, f"peak {peak / 2**20:.1f} MB for {data / 2**20:.1f} MB of series"
