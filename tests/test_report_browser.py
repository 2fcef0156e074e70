"""Open a real run's index.html in Debian's headless Chromium: the leaderboard is there, the frames are
rendered, plots are drawn, and the console stays clean. A screenshot is kept in test-artifacts/.

Everything stays on this machine: the page is opened from a file:// URL with networking features off.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

CHROMIUM = Path("/usr/bin/chromium")
ARTIFACTS = Path(__file__).resolve().parents[1] / "test-artifacts"

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's /usr/bin/chromium (scripts/test.sh installs it)"),
]


def chromium(page: Path, profile: Path, *extra: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    args = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0", "--hide-scrollbars",
            "--virtual-time-budget=15000", *extra, page.resolve().as_uri()]
    return subprocess.run(args, capture_output=True, text=True, timeout=timeout, check=False)


def console_lines(stderr: str) -> list[str]:
    """Console messages and uncaught errors the page produced (chromium logs them as CONSOLE lines)."""
    return [ln for ln in stderr.splitlines() if ":CONSOLE" in ln or "Uncaught" in ln]


def body_attrs(dom: str) -> dict[str, str]:
    m = re.search(r"<body([^>]*)>", dom)
    assert m, "no <body> in the dumped DOM"
    return dict(re.findall(r'data-([a-z-]+)="([^"]*)"', m.group(1)))


def test_console_check_catches_a_broken_page(tmp_path: Path):
    # The detector itself must be able to fail: a page with an uncaught error is caught.
    page = tmp_path / "broken.html"
    page.write_text("<html><body><script>notDefinedAnywhere();</script></body></html>")
    res = chromium(page, tmp_path / "profile", "--dump-dom")
    assert any("Uncaught ReferenceError" in ln for ln in console_lines(res.stderr))


@pytest.fixture(scope="module")
def real_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from roadtruth.harness.jobs.pipeline import run_suite
    from roadtruth.observers.registry import available_observers

    # two sideslip observers that run on the scenario's sensors, so the β leaderboard has cells
    names = [n for n in ("kf_bicycle", "open_loop_bicycle") if n in available_observers()]
    out = tmp_path_factory.mktemp("browser") / "run"
    return run_suite(scenarios=["step_steer"], observers=names, seed=3, out=out, render=True, progress=False)


def test_report_opens_with_leaderboard_images_and_no_console_errors(real_run: Path, tmp_path: Path):
    page = real_run / "index.html"
    # Figures are drawn when they scroll into view (an IntersectionObserver callback, which runs after
    # a rendered frame). Once in a full parallel test run headless Chromium dumped the DOM before its
    # first frame ("plots-drawn": "0", everything else in place), so a dump without a drawn plot
    # is taken once more; a page that cannot draw fails both.
    for attempt in (1, 2):
        res = chromium(page, tmp_path / f"profile{attempt}", "--dump-dom", "--window-size=1400,3000")
        assert res.returncode == 0, res.stderr[-2000:]
        if int(body_attrs(res.stdout).get("plots-drawn", "0")) >= 1:
            break
    dom = res.stdout
    assert console_lines(res.stderr) == []
    attrs = body_attrs(dom)
    assert attrs.get("js-errors") == "0", attrs.get("js-error-text")
    # The leaderboard was built and coloured by the page's script.
    assert re.search(r'<table class="leaderboard"[^>]*data-state="beta_rad"', dom)
    assert re.search(r'<td class="cell ok"[^>]*style="background: rgb\(', dom)
    assert re.search(r'<td class="rank"[^>]*>\d', dom)
    # Every <img> (rendered MuJoCo frames) decoded; at least the key frames are there.
    n_img = len(re.findall(r"<img ", dom))
    render = (real_run / "run.json").read_text()
    if '"enabled": true' in render:
        assert n_img >= 3
        assert attrs.get("images-ok") == str(n_img) and attrs.get("images-broken") == "0"
    # plotly drew the figures in view (SVG roots exist).
    assert int(attrs.get("plots-drawn", "0")) >= 1
    assert "main-svg" in dom


def test_screenshot_is_kept_as_an_artifact(real_run: Path, tmp_path: Path):
    ARTIFACTS.mkdir(exist_ok=True)
    shot = tmp_path / "report.png"
    res = chromium(real_run / "index.html", tmp_path / "profile", f"--screenshot={shot}", "--window-size=1400,2600")
    assert res.returncode == 0 and shot.is_file(), res.stderr[-2000:]
    import cv2

    img = cv2.imread(str(shot))
    assert img is not None and img.shape[:2] == (2600, 1400)
    # Not a blank page: the header bar is dark and the page has many distinct colours.
    assert img[10, 10].mean() < 80
    assert len({tuple(p) for p in img[::25, ::25].reshape(-1, 3)}) > 50
    shutil.copy(shot, ARTIFACTS / "report.png")


def _frame_page(tmp_path: Path, page: Path, width: int, height: int) -> Path:
    """A page holding ``page`` in an iframe exactly ``width`` px wide. Headless Chromium will not
    make its window narrower than 500 px, so a 400 px screen is emulated by the iframe's viewport
    (media queries and plotly's responsive sizing see 400 px). The outer page records the inner
    document's scroll width once it has loaded."""
    wrapper = tmp_path / f"frame{width}.html"
    wrapper.write_text(
        "<!doctype html><html><body style='margin:0'>"
        f"<iframe id='f' src='{page.resolve().as_uri()}' style='border:0;width:{width}px;height:{height}px;display:block'></iframe>"
        "<script>document.getElementById('f').addEventListener('load', function () {"
        " var d = this.contentDocument.documentElement;"
        " setTimeout(function () { document.body.dataset.innerScrollWidth = String(d.scrollWidth); }, 3000); });"
        "</script></body></html>")
    return wrapper


@pytest.fixture(scope="module")
def skips_only_report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from report_folders import skips_only_run_folder

    from roadtruth.harness.report import build_report

    return build_report(skips_only_run_folder(tmp_path_factory.mktemp("skips") / "run"))


def test_summary_counts_zero_failures_when_the_only_non_ok_runs_are_skips(skips_only_report: Path, tmp_path: Path):
    res = chromium(skips_only_report, tmp_path / "profile", "--dump-dom", "--window-size=1400,2000")
    assert res.returncode == 0, res.stderr[-2000:]
    dom = res.stdout
    assert console_lines(res.stderr) == []
    card = re.search(r'<div class="card (\w+)" id="failed-card"><div class="big" data-failed="(\d+)">([^<]*)</div>', dom)
    assert card and card.groups() == ("good", "0", "0 failed"), card and card.groups()
    assert 'data-not-applicable="2">2 n/a' in dom
    # The skipped radar runs are grey dots in the observers table; nothing is drawn as failed.
    assert '<span class="dot na" title="step_steer: skipped: missing range_m"></span>' in dom
    assert '<td class="cell failed"' not in dom and 'class="dot fail" title=' not in dom
    assert "✘ rejected" not in dom and "not designed here (never ran)" in dom


def test_screenshots_at_1400_and_400_px_and_no_overflow_at_400(skips_only_report: Path, real_run: Path, tmp_path: Path):
    import cv2

    ARTIFACTS.mkdir(exist_ok=True)
    page = real_run / "index.html"
    wide = tmp_path / "wide.png"
    res = chromium(page, tmp_path / "p1", f"--screenshot={wide}", "--window-size=1400,2600")
    assert res.returncode == 0 and wide.is_file(), res.stderr[-2000:]
    img = cv2.imread(str(wide))
    assert img.shape[:2] == (2600, 1400)
    shutil.copy(wide, ARTIFACTS / "report-1400.png")
    # 400 px: the page fits (wide tables scroll inside their own box), and a screenshot is kept.
    wrapper = _frame_page(tmp_path, page, 400, 2600)
    res = chromium(wrapper, tmp_path / "p2", "--dump-dom", "--window-size=600,2600", "--allow-file-access-from-files")
    attrs = body_attrs(res.stdout)
    assert "inner-scroll-width" in attrs, res.stderr[-2000:]
    assert int(attrs["inner-scroll-width"]) <= 400
    narrow = tmp_path / "narrow.png"
    res = chromium(wrapper, tmp_path / "p3", f"--screenshot={narrow}", "--window-size=600,2600",
                   "--allow-file-access-from-files")
    assert res.returncode == 0 and narrow.is_file(), res.stderr[-2000:]
    img = cv2.imread(str(narrow))[:, :400]
    assert img[10, 10].mean() < 80  # the header bar is drawn inside the 400 px frame
    cv2.imwrite(str(ARTIFACTS / "report-400.png"), img)
