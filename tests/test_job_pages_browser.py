"""Open the check, compare and stress pages in Debian's headless Chromium at 1400 px and 400 px wide:
each opens with its verdict, the stress charts are drawn without console errors, and at 400 px the
page body never scrolls sideways (wide tables scroll inside their own box). Screenshots are kept in
test-artifacts/ (check_1400.png, check_400.png, compare_…, stress_…).

Every page is built from synthetic inputs (no simulation) and opened from a file:// URL. Headless
Chromium will not make a window narrower than 500 px, so each page is opened inside an iframe exactly
``width`` CSS px wide (its own viewport: media queries and layout are those of a ``width`` px screen);
the host page reads the frame's measurements, and screenshots are cropped to the frame.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pandas as pd
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_report_browser import ARTIFACTS, CHROMIUM, body_attrs, chromium, console_lines  # noqa: E402

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's /usr/bin/chromium (scripts/test.sh installs it)"),
]

WIDTHS = (1400, 400)
HEIGHT = 1800
TALL = 6000
#: Chromium's smallest headless window width [px].
MIN_WINDOW = 500


def framed(page: Path, width: int, height: int = HEIGHT) -> Path:
    """A host page showing ``page`` in an iframe ``width`` px wide that copies the frame's body data
    attributes (and its scroll width) onto its own body once the frame has settled."""
    host = page.with_name(f"host_{width}_{height}_{page.name}")
    host.write_text(f"""<!doctype html><html><head><meta charset="utf-8"><style>body{{margin:0}}
iframe{{border:0;width:{width}px;height:{height}px;display:block}}</style></head><body>
<iframe id="f" src="{page.name}"></iframe><script>
var f = document.getElementById("f");
f.addEventListener("load", function () {{
  setTimeout(function () {{
    var d = f.contentDocument, b = d.body;
    Object.keys(b.dataset).forEach(function (k) {{ document.body.dataset[k] = b.dataset[k]; }});
    document.body.dataset.frameScrollWidth = String(d.documentElement.scrollWidth);
    document.body.dataset.frameViewWidth = String(f.contentWindow.innerWidth);
    document.body.dataset.frameMain = d.querySelector("main").innerHTML.trim().slice(0, 200);
  }}, 4000);
}});
</script></body></html>""")
    return host


def _check_page(root: Path) -> Path:
    from roadtruth.harness.jobs.check import CheckResult, evaluate
    from roadtruth.harness.jobs.check_rules import DEFAULT_THRESHOLDS, Rule
    from roadtruth.harness.report.check_page import check_page

    rows = []
    for sc in ("step_steer", "brake_in_turn", "split_mu_braking"):
        for obs in ("ekf_bicycle", "lpv_wang", "interval_wang_printed", "radar_high_gain"):
            status = "skipped: missing range_m" if obs == "radar_high_gain" else "ok"
            rmse = math.nan if obs == "radar_high_gain" else 0.002 * (1 + len(obs) % 3)
            rows.append({"scenario": sc, "observer": obs, "state": "beta_rad", "rmse": rmse, "status": status})
    m = pd.DataFrame(rows)
    m.loc[(m.scenario == "split_mu_braking") & (m.observer == "lpv_wang"), ["status", "rmse"]] = ["diverged", math.nan]
    rules = [Rule(metric="status", equals="ok", where="rules[0]"),
             Rule(metric="rmse", state=("beta_rad",), max=0.005, where="rules[1]"),
             Rule(metric="rmse", observer=("ekf_bicycle",), state=("beta_rad",), max=0.003, where="rules[2]")]
    result = CheckResult.from_outcomes(evaluate(m, rules), root)
    root.mkdir(parents=True, exist_ok=True)
    path = root / "check.html"
    path.write_text(check_page(result, thresholds=DEFAULT_THRESHOLDS, baseline=None, run_report=None))
    return path


def _compare_page(root: Path) -> Path:
    from synthetic_run import make_run_folder

    from roadtruth.harness.jobs.compare import compare

    a = make_run_folder(root / "a", scenarios=("step_steer", "ice_patch", "lane_change_with_a_long_name"))
    b = make_run_folder(root / "b", scenarios=("step_steer", "lane_change_with_a_long_name", "double_lane_change"))
    m = pd.read_csv(b / "metrics.csv")
    m.loc[m.observer == "ekf", "rmse"] *= 2.5
    m.loc[(m.observer == "lpv_interval") & (m.state == "beta_rad"), "rmse"] *= 0.4
    m.to_csv(b / "metrics.csv", index=False)
    run = json.loads((b / "run.json").read_text())
    run["vehicle"], run["versions"]["mujoco"] = "suv_long_wheelbase", "3.2.7"
    (b / "run.json").write_text(json.dumps(run))
    compare(a, b, root / "cmp")
    return root / "cmp" / "compare.html"


def _stress_page(root: Path) -> Path:
    from stress_synthetic import RUN, stress_rows

    from roadtruth.harness.report.stress_report import summarize, write_index

    root.mkdir(parents=True, exist_ok=True)
    return write_index(root, summarize(stress_rows()), RUN)


BUILDERS = {"check": _check_page, "compare": _compare_page, "stress": _stress_page}


@pytest.fixture(scope="module")
def pages(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("job_pages")
    return {name: build(root / name) for name, build in BUILDERS.items()}


@pytest.mark.parametrize("name", list(BUILDERS))
@pytest.mark.parametrize("width", WIDTHS)
def test_page_renders_without_errors_or_sideways_scroll(pages: dict[str, Path], name: str, width: int,
                                                        tmp_path: Path) -> None:
    # A frame (and window) tall enough to hold the whole page: the charts, drawn when they come into
    # view, are all drawn, so the width is measured with them.
    host = framed(pages[name], width, height=TALL)
    res = chromium(host, tmp_path / "profile", "--allow-file-access-from-files", "--dump-dom",
                   f"--window-size={max(width, MIN_WINDOW)},{TALL}")
    assert res.returncode == 0, res.stderr[-2000:]
    assert console_lines(res.stderr) == []
    attrs = body_attrs(res.stdout)
    assert attrs.get("js-errors") == "0", attrs
    assert int(attrs["frame-view-width"]) == width
    # The page itself never scrolls sideways; wide tables scroll inside their .table-wrap box.
    assert int(attrs["frame-scroll-width"]) <= width, f"{name} at {width} px is {attrs['frame-scroll-width']} px wide"
    # The verdict comes first on every page.
    assert attrs["frame-main"].startswith("&lt;div class=&quot;verdict "), attrs["frame-main"]
    if name == "stress":
        assert int(attrs.get("plots-drawn", "0")) >= 2


@pytest.mark.parametrize("name", list(BUILDERS))
@pytest.mark.parametrize("width", WIDTHS)
def test_screenshot_is_kept(pages: dict[str, Path], name: str, width: int, tmp_path: Path) -> None:
    import cv2

    ARTIFACTS.mkdir(exist_ok=True)
    shot = tmp_path / f"{name}_{width}.png"
    host = framed(pages[name], width)
    res = chromium(host, tmp_path / "profile", "--allow-file-access-from-files", f"--screenshot={shot}",
                   f"--window-size={max(width, MIN_WINDOW)},{HEIGHT}")
    assert res.returncode == 0 and shot.is_file(), res.stderr[-2000:]
    img = cv2.imread(str(shot))
    assert img is not None and img.shape[0] == HEIGHT and img.shape[1] >= width
    img = img[:, :width]  # the frame
    assert img[10, 10].mean() < 80  # the dark header bar of the run report's look
    assert len({tuple(p) for p in img[::20, ::20].reshape(-1, 3)}) > 20  # not a blank page
    cv2.imwrite(str(ARTIFACTS / f"{name}_{width}.png"), img)
