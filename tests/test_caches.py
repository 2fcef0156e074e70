"""The LMI design cache cannot lie and does not litter: an edited entry is ignored and recomputed,
the cache lives in the user cache folder (or ``$ROADTRUTH_CACHE`` / ``--cache-dir``), never in the
working directory."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from roadtruth.harness.files.disk_cache import CACHE_ENV, read_entry, write_entry
from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers import lmi
from roadtruth.observers.lmi import DesignStatus
from roadtruth.observers.registry import create

#: An "as printed" variant whose certification fails (the printed gain is not Metzler): a cheap design
#: that is REJECTED, the case where a lying cache would do harm.
REJECTED = "interval_wang_printed"


@pytest.fixture
def cache_root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    root = tmp_path / "cache"
    monkeypatch.setenv(CACHE_ENV, str(root))
    monkeypatch.setenv(lmi.SHIPPED_DESIGNS_ENV, "0")
    lmi.clear_memory_cache()
    yield root
    lmi.clear_memory_cache()


def _entry(root: Path) -> Path:
    files = list((root / "designs").glob("*.json"))
    assert len(files) == 1, files
    return files[0]


def _tamper(path: Path, **design_fields: object) -> None:
    data = json.loads(path.read_text())
    data["design"].update(design_fields)
    path.write_text(json.dumps(data, sort_keys=True, indent=1))


@pytest.mark.parametrize("forged", [
    {"certified": True},                                                 # the flag alone
    {"certified": True, "status": "certified", "reason": "all checks passed at every vertex and grid point"},
])
def test_a_tampered_rejected_design_is_not_certified_and_is_recomputed(cache_root: Path, forged: dict) -> None:
    v = load_vehicle("sedan")
    first = create(REJECTED, v).design()
    assert first.status is DesignStatus.REJECTED and not first.certified and not first.from_cache
    path = _entry(cache_root)
    _tamper(path, **forged)
    lmi.clear_memory_cache()
    again = create(REJECTED, v).design()
    assert again.status is DesignStatus.REJECTED and again.certified is False
    assert not again.from_cache  # the edited entry was ignored: the design was solved and checked again
    stored = json.loads(path.read_text())["design"]
    assert stored["certified"] is False and stored["status"] == "rejected"  # and the entry rewritten
    lmi.clear_memory_cache()
    third = create(REJECTED, v).design()
    assert third.from_cache and third == again  # the rewritten entry is valid again


def test_an_untouched_entry_is_used_and_a_swapped_digest_is_not(cache_root: Path) -> None:
    v = load_vehicle("sedan")
    certified = create("lpv_wang_printed", v).design()
    lmi.clear_memory_cache()
    assert create("lpv_wang_printed", v).design().from_cache
    # a valid entry and digest of another design copied under this key is refused too
    rejected = create(REJECTED, v).design()
    folder = cache_root / "designs"
    for suffix in (".json", ".sha256"):
        (folder / f"{certified.key}{suffix}").write_bytes((folder / f"{rejected.key}{suffix}").read_bytes())
    lmi.clear_memory_cache()
    again = create("lpv_wang_printed", v).design()
    assert not again.from_cache and again.certified and again.key == certified.key


def test_entry_round_trip_and_truncation(tmp_path: Path) -> None:
    assert write_entry(tmp_path, "abc123", {"x": [1.5, float("nan")], "y": "z"})
    got = read_entry(tmp_path, "abc123")
    assert got["y"] == "z" and got["x"][0] == 1.5 and got["x"][1] != got["x"][1]
    p = tmp_path / "abc123.json"
    p.write_bytes(p.read_bytes()[:-3])
    assert read_entry(tmp_path, "abc123") is None
    assert read_entry(tmp_path, "0000") is None  # absent
    assert not list(tmp_path.glob("*.tmp")) and not list(tmp_path.glob(".*"))  # no temp files left


def test_no_cache_in_the_working_directory_and_the_user_cache_is_used(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    work, user_cache = tmp_path / "work", tmp_path / "xdg"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.delenv(CACHE_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(user_cache))  # where platformdirs puts user caches on Linux
    monkeypatch.setenv(lmi.SHIPPED_DESIGNS_ENV, "0")  # a design solved here, not read from the package
    lmi.clear_memory_cache()
    try:
        design = create(REJECTED, load_vehicle("sedan")).design()
    finally:
        lmi.clear_memory_cache()
    assert list(work.iterdir()) == []  # nothing (no .roadtruth-cache) in the working directory
    assert (user_cache / "roadtruth" / "designs" / f"{design.key}.json").is_file()
    assert (user_cache / "roadtruth" / "designs" / f"{design.key}.sha256").is_file()


def test_roadtruth_cache_environment_variable_is_respected(cache_root: Path) -> None:
    design = create(REJECTED, load_vehicle("sedan")).design()
    assert lmi.design_cache_dir() == cache_root / "designs"
    assert (cache_root / "designs" / f"{design.key}.json").is_file()


def test_cache_dir_option_sets_the_cache_for_the_command(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from roadtruth.harness.cli import build_parser

    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "elsewhere"))  # restored after the test
    build_parser().parse_args(["stress", "--cache-dir", str(tmp_path / "mine"), "--seeds", "1"])
    assert lmi.design_cache_dir() == (tmp_path / "mine").resolve() / "designs"
    build_parser().parse_args(["--cache-dir", str(tmp_path / "global"), "observers"])
    assert lmi.design_cache_dir() == (tmp_path / "global").resolve() / "designs"
    (tmp_path / "afile").write_text("x")
    with pytest.raises(SystemExit) as info:
        build_parser().parse_args(["run", "--cache-dir", str(tmp_path / "afile")])
    assert info.value.code == 2


def test_shipped_designs_are_read_after_the_user_cache_and_checked_like_it(
        cache_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A design shipped with the package is used on a fresh install (empty user cache), only when its
    digest matches, and not at all with ROADTRUTH_SHIPPED_DESIGNS=0."""
    v = load_vehicle("sedan")
    solved = create(REJECTED, v).design()
    shipped = tmp_path / "shipped"
    shipped.mkdir()
    for f in (cache_root / "designs").iterdir():  # what scripts/ship_designs.py copies
        (shipped / f.name).write_bytes(f.read_bytes())
    for f in (cache_root / "designs").iterdir():
        f.unlink()
    monkeypatch.setattr(lmi, "SHIPPED_DESIGNS_DIR", shipped)
    monkeypatch.setenv(lmi.SHIPPED_DESIGNS_ENV, "1")
    lmi.clear_memory_cache()
    hit = create(REJECTED, v).design()
    assert hit.from_cache and hit == solved and not hit.certified
    # an edited shipped entry is ignored (solved again), exactly like an edited user-cache entry
    _tamper(next(shipped.glob("*.json")), certified=True)
    for f in (cache_root / "designs").glob("*"):
        f.unlink()
    lmi.clear_memory_cache()
    again = create(REJECTED, v).design()
    assert not again.from_cache and again.certified is False
    # and switched off, a valid shipped entry is not read at all
    for f in (cache_root / "designs").iterdir():
        (shipped / f.name).write_bytes(f.read_bytes())
        f.unlink()
    assert lmi.load_design(hit.key) is not None
    monkeypatch.setenv(lmi.SHIPPED_DESIGNS_ENV, "0")
    assert lmi.load_design(hit.key) is None


# ---- designs are solved once, not once per worker ------------------------------------------------

#: Put on PYTHONPATH of the observer hosts: logs every design that is solved (a cache miss) with
#: the process that solved it, however the run spreads its work.
_SOLVE_LOGGER = '''
import os
if os.environ.get("ROADTRUTH_TEST_SOLVE_LOG"):
    import roadtruth.observers.lmi as _lmi
    _cached_design = _lmi.cached_design

    def _counted(payload, compute, **kw):
        def solve():
            log = os.environ.get("ROADTRUTH_TEST_SOLVE_LOG")  # a host may outlive the test's environment
            if log:
                with open(log, "a") as f:
                    f.write(f"{os.getpid()} {_lmi.design_key(payload)}\\n")
            return compute()
        return _cached_design(payload, solve, **kw)

    _lmi.cached_design = _counted
'''


def _solves(log: Path) -> list[tuple[str, str]]:
    return [tuple(line.split()) for line in log.read_text().splitlines()] if log.exists() else []  # type: ignore[misc]


@pytest.mark.parametrize("dask", [None, "local"])
def test_parallel_workers_on_a_fresh_cache_solve_each_design_once(cache_root: Path, tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch, dask: str | None) -> None:
    """Two workers start on an empty design cache at the same moment; without solving the designs
    before they start, each would solve the same LMI design. Results equal the serial sweep's."""
    import os

    import pandas as pd

    from roadtruth.harness.jobs.stress import run_stress

    if dask:
        pytest.importorskip("distributed")
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(_SOLVE_LOGGER)
    log = tmp_path / "solves.log"
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(site), *filter(None, [os.environ.get("PYTHONPATH")])]))
    monkeypatch.setenv("ROADTRUTH_TEST_SOLVE_LOG", str(log))
    kw = {"scenarios": ["step_steer"], "observers": ["kf_bicycle", "lpv_wang"], "frictions": ["1.0", "0.3"],
          "faults": None, "seeds": 2, "base_seed": 3, "progress": False, "fresh": True}
    par = run_stress(out=tmp_path / "par", jobs=2, dask=dask, **kw)  # type: ignore[arg-type]
    solves = _solves(log)
    assert len(solves) == 1, solves  # lpv_wang's one design (kf_bicycle has none), by one process
    # the warm-up is recorded, so a later parallel run on this cache does not hold its workers back
    assert len(list((cache_root / "design-warmups").glob("*.json"))) == 1
    # A second, serial sweep on another empty cache solves it again (the logger does count) and
    # gives the same rows: a design read back from the cache is the design that was solved.
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache2"))
    from roadtruth.harness.evaluation import observer_host
    observer_host.shutdown()  # a host this process started earlier would lack the logger
    try:
        ser = run_stress(out=tmp_path / "ser", jobs=1, **kw)  # type: ignore[arg-type]
    finally:
        observer_host.shutdown()  # ... and the host started here, with the logger, must not serve later tests
    assert len(_solves(log)) == 2 and _solves(log)[1][1] == solves[0][1]
    a, b = (pd.read_csv(f / "stress.csv").drop(columns=["us_per_step"]) for f in (par, ser))
    pd.testing.assert_frame_equal(a, b, check_exact=True)
