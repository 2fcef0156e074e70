"""The report is rebuilt from a run folder's files alone, has every section, and is written atomically."""

from __future__ import annotations

import json
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from synthetic_run import make_run_folder

from roadtruth.harness.errors import InputError
from roadtruth.harness.report import ReportBuilder, build_report
from roadtruth.harness.report.builder import default_sections
from roadtruth.harness.report.rundata import RunData


class Collect(HTMLParser):
    """Ids, tags with attributes, and script bodies of a page."""

    def __init__(self) -> None:
        super().__init__()
        self.ids: set[str] = set()
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.external: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        self.tags.append((tag, a))
        if a.get("id"):
            self.ids.add(a["id"])
        for key in ("src", "href"):
            v = a.get(key) or ""
            if re.match(r"^(https?:)?//", v):
                self.external.append(v)


@pytest.fixture()
def run_dir(tmp_path: Path) -> Path:
    return make_run_folder(tmp_path / "run")


def parse(path: Path) -> Collect:
    c = Collect()
    c.feed(path.read_text(encoding="utf-8"))
    return c


def test_every_section_is_present_and_self_contained(run_dir: Path):
    page = build_report(run_dir)
    assert page == run_dir / "index.html"
    doc = parse(page)
    for s in default_sections():
        assert s.anchor in doc.ids, s.anchor
    # Offline: nothing is fetched from the network (plotly.js is inlined once).
    assert doc.external == []
    text = page.read_text(encoding="utf-8")
    assert text.count("plotly.js v") == 1
    # One leaderboard per scored state; the failed observer is visible with its status.
    boards = [a for t, a in doc.tags if t == "table" and "leaderboard" in (a.get("class") or "")]
    assert {b["data-state"] for b in boards} == {"beta_rad", "yaw_rate_radps"}
    assert "error: LMI infeasible" in text
    assert "✔ certified" in text
    # Frames are referenced relatively and exist.
    imgs = [a["src"] for t, a in doc.tags if t == "img"]
    assert len(imgs) == 6 and all((run_dir / s).is_file() for s in imgs)
    # Every figure has a JSON spec that parses and names its traces.
    specs = re.findall(r'<script type="application/json" id="(fig-[^"]+)">(.*?)</script>', text, re.S)
    assert len(specs) == 2 * 3  # per scenario: path + beta + yaw rate
    for _, body in specs:
        spec = json.loads(body)
        assert spec["data"] and "layout" in spec
    # Events appear as vertical lines in the time plots.
    beta_spec = json.loads(dict(specs)["fig-step_steer-beta_rad"])
    assert [s["x0"] for s in beta_spec["layout"]["shapes"]] == [1.0, 2.5]


def test_rebuild_uses_saved_files_only_and_reflects_them(run_dir: Path):
    build_report(run_dir)
    m = pd.read_csv(run_dir / "metrics.csv")
    m.loc[m.observer == "ekf", "observer"] = "ekf_renamed"
    m.to_csv(run_dir / "metrics.csv", index=False)
    text = build_report(run_dir).read_text(encoding="utf-8")
    assert "ekf_renamed" in text


def test_rebuild_is_atomic(run_dir: Path, monkeypatch: pytest.MonkeyPatch):
    first = build_report(run_dir).read_text(encoding="utf-8")

    def boom(self: ReportBuilder):
        yield "<!doctype html><html><body>half a page"  # written to the temporary file already
        raise RuntimeError("section failed half-way")

    monkeypatch.setattr(ReportBuilder, "pieces", boom)
    with pytest.raises(RuntimeError):
        build_report(run_dir)
    assert (run_dir / "index.html").read_text(encoding="utf-8") == first
    assert not list(run_dir.glob(".index.html.*"))


def test_no_gl_is_said_and_the_rest_is_complete(run_dir: Path):
    run = json.loads((run_dir / "run.json").read_text())
    run["render"] = {"enabled": False, "reason": "offscreen OpenGL unavailable (MUJOCO_GL=egl): no EGL"}
    for s in run["scenarios"]:
        s["render"] = {"frames": [], "video": None, "reason": "offscreen OpenGL unavailable"}
    (run_dir / "run.json").write_text(json.dumps(run))
    text = build_report(run_dir).read_text(encoding="utf-8")
    assert "Frames and videos were not rendered: offscreen OpenGL unavailable (MUJOCO_GL=egl): no EGL" in text
    assert "<img" not in text
    doc = parse(run_dir / "index.html")
    assert {"leaderboard", "scenarios", "provenance"} <= doc.ids


def test_user_strings_are_escaped(run_dir: Path):
    run = json.loads((run_dir / "run.json").read_text())
    run["scenarios"][0]["description"] = "<script>alert(1)</script>"
    (run_dir / "run.json").write_text(json.dumps(run))
    text = build_report(run_dir).read_text(encoding="utf-8")
    assert "<script>alert(1)</script>" not in text
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in text


def test_not_a_run_folder_is_an_input_error(tmp_path: Path):
    with pytest.raises(InputError, match="does not exist"):
        build_report(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="metrics.csv"):
        build_report(tmp_path / "empty")


def test_run_data_orders_states_canonically(run_dir: Path):
    run = RunData.load(run_dir)
    assert run.states == ["beta_rad", "yaw_rate_radps"]
    assert run.scenario_names == ["step_steer", "ice_patch"]


# ---- honest verdicts: skipped is not failed, ranks, axes, styles, decimation ------------------------

def _cards(text: str) -> dict[str, str]:
    return dict(re.findall(r'data-(failed|not-applicable)="(\d+)"', text))


def test_skips_are_not_failures_and_not_rejections(tmp_path: Path):
    from report_folders import RADAR, skips_only_run_folder

    text = build_report(skips_only_run_folder(tmp_path / "run")).read_text(encoding="utf-8")
    # 2 scenarios x (lpv_interval, ekf) ok, the radar observer skipped in both.
    assert _cards(text) == {"failed": "0", "not-applicable": "2"}
    assert "0 failed" in text and "not ok" not in text
    assert "n/a — needs radar" in text
    # Skipped everywhere: its design was never evaluated here; that is not a rejection.
    doc = parse(tmp_path / "run" / "index.html")
    row = text[text.index(f"{RADAR}</th>"):]
    row = row[:row.index("</tr>")]
    assert "rejected" not in row and "not designed here" in row
    assert not any(t == "td" and "failed" in (a.get("class") or "").split() for t, a in doc.tags)


def test_a_failed_run_is_counted_and_shown_as_failed(run_dir: Path):
    text = build_report(run_dir).read_text(encoding="utf-8")
    assert _cards(text)["failed"] == "2"  # ts_uio on both scenarios: error: LMI infeasible
    assert '<td class="cell failed" data-status="failed" title="error: LMI infeasible">✘ error</td>' in text


def test_ranks_ties_share_the_best_rank_and_empty_cells_get_none():
    from roadtruth.harness.report.ranking import leaders, rank_state

    rows = [("s1", "a", "ok", 1.0), ("s1", "b", "ok", 1.0), ("s1", "c", "ok", 2.0), ("s1", "d", "skipped: missing range_m", None),
            ("s2", "a", "ok", 3.0), ("s2", "b", "diverged", 0.1), ("s2", "c", "ok", 1.0), ("s2", "d", "ok", None),
            ("s3", "d", "ok", 5.0)]
    m = pd.DataFrame(rows, columns=["scenario", "observer", "status", "rmse"]).assign(state="beta_rad")
    # Row order (and names' alphabetical order) must not matter; rows as dicts rank as the frame.
    for frame in (m, m.iloc[::-1], m.to_dict("records"), m.iloc[::-1].to_dict("records")):
        r = rank_state(frame, "beta_rad", "rmse", "low", ["s1", "s2", "s3"])
        assert r["a"].ranks == {"s1": 1, "s2": 2} and r["b"].ranks == {"s1": 1}
        assert r["c"].ranks == {"s1": 3, "s2": 1} and r["d"].ranks == {"s3": 1}
        assert (r["a"].mean, r["a"].n_ranked, r["a"].n_scenarios) == (1.5, 2, 3)
        assert r["c"].mean == 2.0 and r["a"].coverage_text == "1.5 over 2 of 3 scenarios"
        # The best is chosen among those ranked in the most scenarios: a (1.5) beats b (1.0 over 1).
        assert [x.observer for x in leaders(r)] == ["a"]
    # Values equal to the 3 digits shown are ties; "high" is better for coverage.
    m2 = pd.DataFrame([("s1", "x", "ok", 0.9001), ("s1", "y", "ok", 0.9004), ("s1", "z", "ok", 0.5)],
                      columns=["scenario", "observer", "status", "coverage"]).assign(state="beta_rad")
    r2 = rank_state(m2, "beta_rad", "coverage", "high", ["s1"])
    assert {k: v.ranks["s1"] for k, v in r2.items()} == {"x": 1, "y": 1, "z": 3}
    nobody = rank_state(m2, "beta_rad", "rmse", "low", ["s1"])
    assert all(v.mean is None and v.n_ranked == 0 for v in nobody.values())


def test_summary_card_and_leaderboard_show_the_same_rank(run_dir: Path):
    text = build_report(run_dir).read_text(encoding="utf-8")
    card = re.search(r"sideslip β</div>\s*<div>.*?<b>(\w+)</b>.*?mean rank ([\d.]+) over (\d+) of (\d+)", text, re.S)
    assert card, "no sideslip card"
    board = text[text.index('data-state="beta_rad"'):]
    row = re.search(r"<tr data-mean-ranks='([^']+)'>\s*<th class=\"obs\">.*?" + card.group(1) + "</th>", board, re.S)
    ranks = json.loads(row.group(1).replace("&#34;", '"'))["rmse"]
    assert f"{ranks['mean']:.1f}" == card.group(2) and (ranks["n"], ranks["of"]) == (int(card.group(3)), int(card.group(4)))


def test_beta_axis_stays_near_the_truth_when_an_interval_observer_starts_wide(tmp_path: Path):
    from report_folders import wide_start_run_folder

    text = build_report(wide_start_run_folder(tmp_path / "run")).read_text(encoding="utf-8")
    from roadtruth.harness.report.plot_data import expand_figure

    spec = json.loads(re.search(r'id="fig-step_steer-beta_rad">(.*?)</script>', text, re.S).group(1))
    spec = expand_figure(spec)  # the numbers plotly draws
    truth = next(t for t in spec["data"] if t["name"] == "truth")
    t_lo, t_hi = min(truth["y"]), max(truth["y"])
    lo, hi = spec["layout"]["yaxis"]["range"]
    assert lo <= t_lo and hi >= t_hi
    assert hi - lo <= 4.5 * (t_hi - t_lo)  # the ±100° start-up bounds do not set the axis
    est = next(t for t in spec["data"] if t["name"] == "lpv_interval")
    assert max(est["y"]) > 50  # ... although they are drawn, and
    buttons = spec["layout"]["updatemenus"][0]["buttons"]
    assert buttons[1]["args"][0] == {"yaxis.autorange": True, "yaxis2.autorange": True}  # "show all" shows them
    assert spec["meta"]["clipped"] is True


def test_every_observer_has_its_own_style_the_same_on_every_page():
    from roadtruth.harness.report.figures import observer_style, observer_styles
    from roadtruth.harness.report.styles import registry_names

    names = [*registry_names(), "plugin_obs", "my_kf", "team_ukf", "a", "b", "c"]
    assert len(names) >= 20
    styles = observer_styles(names)
    pairs = [(s.colour.lower(), s.dash) for s in styles.values()]
    assert len(set(pairs)) == len(pairs)
    # Same style whatever else is on the page, and the same as the single-name function.
    few = observer_styles(list(reversed(names[:5])))
    for n in names[:5]:
        assert few[n] == styles[n] == observer_style(n)
    assert observer_style("ekf_bicycle") != observer_style("open_loop_bicycle")


def test_each_state_is_ranked_once_per_metric_per_page(run_dir: Path, monkeypatch: pytest.MonkeyPatch):
    """The summary's cards and the leaderboard rank the same rows: one ranking per (state, metric)
    for a whole page, not one per section (the page used to rank every state twice)."""
    import roadtruth.harness.report.sections.leaderboard as leaderboard

    calls: list[tuple[str, str]] = []
    real = leaderboard.rank_state

    def counting(rows, state, column, *args, **kwargs):
        calls.append((state, column))
        return real(rows, state, column, *args, **kwargs)

    monkeypatch.setattr(leaderboard, "rank_state", counting)
    run = RunData.load(run_dir)
    ReportBuilder(run).build()
    assert calls, "nothing was ranked"
    assert len(calls) == len(set(calls)) == len(run.scored_states) * len(leaderboard.SWITCHABLE)


def _wide_run(tmp_path: Path, fmt: str) -> Path:
    """The synthetic run with wide estimates in ``fmt`` and 20 more observers' columns of states no
    figure draws (as in a long log's replay, where they are most of the table), one observer silent
    on a stretch and one that gives no β at all."""
    from roadtruth.harness.files.table_io import estimates_wide, write_table

    run = make_run_folder(tmp_path / fmt)
    for name in ("step_steer", "ice_patch"):
        folder = run / name
        wide = estimates_wide(pd.read_csv(folder / "estimates.csv"))
        (folder / "estimates.csv").unlink()
        n = len(wide)
        gap = slice(n // 3, n // 2)
        for c in ("ekf.beta_rad", "ekf.beta_rad_var"):
            wide.loc[wide.index[gap], c] = np.nan  # ekf did not run on a stretch: no rows there
        wide["quiet.beta_rad"] = np.nan
        for k in range(20):
            wide[f"extra{k}.fy_f_N"] = np.linspace(0.0, 1000.0 + k, n)
            wide[f"extra{k}.fy_f_N_var"] = 4.0
        write_table(wide, folder, "estimates", fmt)
    return run


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_figures_read_one_state_of_a_wide_table_and_draw_what_the_long_frame_draws(
        tmp_path: Path, fmt: str, monkeypatch: pytest.MonkeyPatch):
    """A long log's wide estimates table (every observer's every state) is never read whole: each
    figure reads ``t_s`` and its own state's columns only, and draws exactly what the long frame of
    the whole table draws (gaps and an observer without the state included)."""
    import roadtruth.harness.report.rundata as rundata
    from roadtruth.harness.files.table_io import estimates_long, read_table, table_path
    from roadtruth.harness.report.figures import observer_styles, state_figure

    run_dir = _wide_run(tmp_path, fmt)
    monkeypatch.setattr(rundata, "WHOLE_TABLE_BYTES", 0)  # as a long log's table: one state at a time
    reads: list[list[str] | None] = []
    real = rundata.read_table

    def recording(path, columns=None, **options):
        if Path(path).stem == "estimates" and not options:
            reads.append(None if columns is None else list(columns))
        return real(path, **options) if columns is None else real(path, columns=columns, **options)

    monkeypatch.setattr(rundata, "read_table", recording)
    if hasattr(rundata, "read_numeric_columns"):
        real_numeric = rundata.read_numeric_columns

        def recording_numeric(path, columns):
            reads.append(list(columns))
            return real_numeric(path, columns)

        monkeypatch.setattr(rundata, "read_numeric_columns", recording_numeric)
    run = RunData.load(run_dir)
    assert "fig-step_steer-beta_rad" in ReportBuilder(run).build()
    beta = ["t_s", "lpv_interval.beta_rad", "lpv_interval.beta_rad_lo", "lpv_interval.beta_rad_hi",
            "ekf.beta_rad", "ekf.beta_rad_var", "quiet.beta_rad"]
    yaw = ["t_s", "lpv_interval.yaw_rate_radps", "lpv_interval.yaw_rate_radps_lo",
           "lpv_interval.yaw_rate_radps_hi"]
    assert reads and None not in reads, "a figure read the whole estimates table"
    assert sorted(map(sorted, reads)) == sorted([sorted(beta), sorted(yaw)] * 2)  # per scenario

    styles = observer_styles(run.observer_names)
    for name in run.scenario_names:
        files = run.scenario(name)
        whole = estimates_long(read_table(table_path(files.folder, "estimates")))
        for state in ("beta_rad", "yaw_rate_radps"):
            series = files.series_of(state)
            assert [s.observer for s in series] == (["lpv_interval", "ekf"] if state == "beta_rad" else ["lpv_interval"])
            assert state_figure(state, files.truth, series, styles, files.events) == \
                state_figure(state, files.truth, whole, styles, files.events)
        ekf = files.series_of("beta_rad")[1]
        n = len(files.truth)
        assert ekf.t_s.size == n - (n // 2 - n // 3) and np.isnan(ekf.lo).all()


def test_the_tables_of_a_page_do_not_filter_the_metrics_frame_per_row(run_dir: Path, monkeypatch: pytest.MonkeyPatch):
    """The summary, leaderboard, observers and scenario headers read the metrics rows once (as
    ``RunData.records``): filtering the pandas frame per state, observer and cell cost seconds on
    the default suite. Counted: boolean-mask selections of the metrics frame during a page build."""
    run = RunData.load(run_dir)
    metrics_id = id(run.metrics)
    selections = []
    real = pd.DataFrame.__getitem__

    def counting(self, key):
        if id(self) == metrics_id and isinstance(key, pd.Series) and key.dtype == bool:
            selections.append(key.sum())
        return real(self, key)

    monkeypatch.setattr(pd.DataFrame, "__getitem__", counting)
    text = ReportBuilder(run).build()
    assert "fig-step_steer-beta_rad" in text
    assert selections == [], f"{len(selections)} filters of the metrics frame"


@pytest.mark.parametrize("at_once", [False, True])
@pytest.mark.parametrize("kind", ["float", "int", "text", "missing"])
def test_parquet_state_columns_are_read_as_the_whole_table_reads_them(tmp_path: Path, kind: str, at_once: bool):
    """A Parquet estimates table's columns come back (one at a time) as float arrays equal to the
    whole table's columns, in the order asked; a text column gives None (the caller then names
    it), a column the file lacks is a ValueError (the report's "unreadable Parquet")."""
    import pyarrow.parquet as pq

    from roadtruth.harness.report.rundata import read_numeric_columns

    n = 1000
    rng = np.random.default_rng(1)
    frame = pd.DataFrame({"t_s": np.arange(n) * 0.01, "segment": np.repeat([0, 1], n // 2),
                          "a.beta_rad": rng.standard_normal(n), "a.beta_rad_var": rng.random(n)})
    frame.loc[100:200, "a.beta_rad"] = np.nan
    frame.loc[5, "a.beta_rad_var"] = np.inf
    if kind == "text":
        frame["a.beta_rad_var"] = frame["a.beta_rad_var"].map(str)
    path = tmp_path / "estimates.parquet"
    frame.to_parquet(path)
    asked = {"float": ["a.beta_rad_var", "t_s", "a.beta_rad"], "int": ["t_s", "segment"],
             "text": ["t_s", "a.beta_rad_var"], "missing": ["t_s", "b.beta_rad"]}[kind]
    if kind == "missing":
        with pytest.raises(ValueError, match="b.beta_rad"):
            read_numeric_columns(path, asked, at_once=at_once)
        return
    got = read_numeric_columns(path, asked, at_once=at_once)
    if kind == "text":
        assert got is None
        return
    whole = pq.read_table(path).to_pandas()
    assert list(got) == asked
    for c in asked:
        assert got[c].dtype == np.float64
        np.testing.assert_array_equal(got[c], whole[c].to_numpy(float))


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_a_small_wide_table_is_read_once_per_scenario_and_draws_the_same_page(
        tmp_path: Path, fmt: str, monkeypatch: pytest.MonkeyPatch):
    """A default-suite sized estimates table (CSV or Parquet) is read once for all of a scenario's
    figures (Parquet column by column cost ~1 ms a column, thousands of them on a page), and the
    page is the same, byte for byte, as when each figure reads its own state's columns."""
    import roadtruth.harness.report.rundata as rundata

    run_dir = _wide_run(tmp_path, fmt)
    reads: list[str] = []
    real_table, real_numeric = rundata.read_table, rundata.read_numeric_columns

    def recording_table(path, columns=None, **options):
        if Path(path).stem == "estimates" and not options:
            reads.append(Path(path).parent.name)
        return real_table(path, columns=columns, **options)

    def recording_numeric(path, columns, **options):
        reads.append(Path(path).parent.name)
        return real_numeric(path, columns, **options)

    monkeypatch.setattr(rundata, "read_table", recording_table)
    monkeypatch.setattr(rundata, "read_numeric_columns", recording_numeric)
    whole = ReportBuilder(RunData.load(run_dir)).build()
    assert sorted(reads) == ["ice_patch", "step_steer"]
    monkeypatch.setattr(rundata, "WHOLE_TABLE_BYTES", 0)
    assert ReportBuilder(RunData.load(run_dir)).build() == whole


def test_rebuilding_a_report_does_not_import_the_observers_and_styles_them_as_run_does(run_dir: Path):
    """``roadtruth report`` takes the observers' names (their line styles) from the remembered
    listing, not by importing every observer module with numba and cvxpy; the styles are those of
    the registry, which ``run`` and ``replay`` have loaded. Each step runs in a fresh interpreter:
    this test process may hold observers other tests registered."""
    import subprocess
    import sys

    def fresh(code: str) -> list[str]:
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              check=True).stdout.split()

    # The listing is remembered, as after any earlier `roadtruth observers`, `run` or report.
    fresh("from roadtruth.harness.evaluation.observer_catalog import observer_rows; observer_rows()")
    out = fresh(
        "import sys\n"
        "from pathlib import Path\n"
        "from roadtruth.harness.report import build_report\n"
        "from roadtruth.harness.report.styles import registry_names\n"
        f"build_report(Path({str(run_dir)!r}))\n"
        "reg = sys.modules.get('roadtruth.observers.registry')\n"
        "print(bool(reg and reg.loaded()), 'numba' in sys.modules, ','.join(registry_names()))\n"
    )
    registered = fresh("from roadtruth.observers.registry import available_observers as a; print(','.join(a()))")
    assert out[0] == "False" and out[1] == "False"
    assert out[2].split(",") == registered[0].split(",") and len(registered[0].split(",")) >= 50
