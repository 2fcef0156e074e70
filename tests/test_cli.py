"""The command line: listings, exit codes and one-line errors (the contract's outside promises)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from roadtruth.harness.cli import main


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "roadtruth.harness.cli", *args], capture_output=True, text=True,
                          timeout=300)


def test_help_for_every_command() -> None:
    for cmd in ("run", "simulate", "scenarios", "observers", "vehicles", "report", "compare", "replay", "check",
                "stress"):
        with pytest.raises(SystemExit) as ex:
            main([cmd, "--help"])
        assert ex.value.code == 0


def test_vehicles_json_lists_every_set_with_bicycle_parameters(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["vehicles", "--json"]) == 0
    sets = json.loads(capsys.readouterr().out)
    names = {s["name"] for s in sets}
    assert {"sedan", "wang2014", "yacine2016", "carla_bessafa", "ferrari_250lm"} <= names
    for s in sets:
        for key in ("mass_kg", "yaw_inertia_kgm2", "lf_m", "lr_m"):
            assert s[key] > 0
        assert s["derived"]["cornering_stiffness_f_Npr"] > 0


def test_usage_error_is_one_line_exit_2() -> None:
    res = run_cli("run", "--jobs", "0")
    assert res.returncode == 2
    assert res.stderr.count("\n") == 1 and "--jobs" in res.stderr


def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path: Path) -> None:
    out = tmp_path / "out"
    res = run_cli("simulate", "no_such_scenario", "--out", str(out))
    assert res.returncode == 2, res.stderr
    assert res.stderr.count("\n") == 1 and "no_such_scenario" in res.stderr
    assert "Traceback" not in res.stderr
    assert not out.exists()
    assert [p for p in tmp_path.iterdir()] == []


def test_scenario_listing_gives_the_rows_of_a_full_load(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`roadtruth scenarios` reads only the headers; every row equals what loading the scenario gives,
    computed or remembered."""
    from roadtruth.harness.truth.scenario import available_scenarios, load_scenario
    from roadtruth.harness.truth.scenario_index import scenario_summaries

    monkeypatch.setenv("ROADTRUTH_CACHE", str(tmp_path / "cache"))
    rows = scenario_summaries()
    assert scenario_summaries() == rows  # the second from the cache
    assert [r["name"] for r in rows] == available_scenarios()
    for r in rows:
        s = load_scenario(r["name"])
        assert r == {"name": s.name, "description": s.description, "standard": s.standard, "tags": list(s.tags),
                     "vehicle": s.vehicle, "duration_s": s.duration_s, "initial_speed_mps": s.initial_speed_mps}


HEAVY = ("numba", "mujoco", "cvxpy", "plotly", "dask", "jinja2", "scipy.signal", "scipy.optimize", "scipy.spatial",
         "scipy.interpolate")


def _loaded_after(code: str) -> list[str]:
    probe = (f"import sys, json, contextlib, io\n{code}\n"
             f"print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))")
    res = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_scenarios_command_imports_none_of_the_compiled_or_report_stack(tmp_path: Path) -> None:
    """Listing scenarios never imports numba & co.; a repeat listing does not even parse YAML."""
    code = (f"import os\nos.environ['ROADTRUTH_CACHE'] = {str(tmp_path / 'cache')!r}\n"
            "from roadtruth.harness.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()) as out:\n"
            "    assert main(['scenarios']) == 0\n"
            "assert 'step_steer' in out.getvalue()\n"
            "print(json.dumps({'yaml': 'yaml' in sys.modules}))")
    assert _loaded_after(code) == []
    assert _loaded_after(code) == []
    again = subprocess.run([sys.executable, "-c", "import sys, json, contextlib, io\n" + code],
                           capture_output=True, text=True, timeout=300)
    assert json.loads(again.stdout.strip().splitlines()[-1]) == {"yaml": False}


def test_simulate_path_imports_neither_the_report_builder_nor_scipy_signal() -> None:
    """`roadtruth simulate` of a flat road on Magic Formula tires writes tables and JSON: no page
    builder (jinja2, plotly), none of scipy's signal, optimize (tire-file fits), spatial (projection
    without a path hint) or interpolate (road profiles) subpackages."""
    loaded = _loaded_after("import roadtruth.harness.jobs.pipeline, roadtruth.harness.sensors, roadtruth.harness.truth.simulate, roadtruth.harness.files.table_io")
    assert not {"jinja2", "plotly", "scipy.signal", "scipy.optimize", "scipy.spatial", "scipy.interpolate"} & set(loaded), loaded


def test_quick_exit_runs_atexit_handlers_and_flushes_before_leaving() -> None:
    code = ("import atexit, sys\nfrom roadtruth.harness import cli\n"
            "atexit.register(lambda: sys.stdout.write('handler ran\\n'))\n"
            "sys.stdout.write('x' * 100000)\n"
            "cli._leave(3)\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 3
    assert res.stdout == "x" * 100000 + "handler ran\n"


def test_console_script_keeps_exit_codes_and_whole_output() -> None:
    res = run_cli("scenarios", "--json")
    assert res.returncode == 0, res.stderr
    names = [r["name"] for r in json.loads(res.stdout)]
    assert "step_steer" in names
    bad = run_cli("scenarios", "--no-such-flag")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1



def test_installed_command_works_outside_the_source_folder(tmp_path: Path) -> None:
    """The ``roadtruth`` script as a user runs it: from another folder, where only the installed
    ``roadtruth`` package is importable (no ``harness`` or ``observers`` on the path)."""
    import os
    import shutil

    exe = Path(sys.executable).parent / "roadtruth"
    script = str(exe) if exe.is_file() else shutil.which("roadtruth")
    if script is None:
        pytest.skip("the roadtruth console script is not installed in this environment")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["ROADTRUTH_CACHE"] = str(tmp_path / "cache")
    for _ in range(2):  # computed, then remembered
        for cmd in ("scenarios", "observers", "vehicles"):
            res = subprocess.run([script, cmd, "--json"], capture_output=True, text=True, timeout=300,
                                 cwd=tmp_path, env=env)
            assert res.returncode == 0, res.stderr
            assert len(json.loads(res.stdout)) >= 3

def test_observer_listing_is_remembered_and_then_imports_no_observer(tmp_path: Path) -> None:
    """The second `roadtruth observers` reads the remembered rows: same text, no numba or cvxpy."""
    import os

    env = {**os.environ, "ROADTRUTH_CACHE": str(tmp_path / "cache")}
    probe = ("import sys, json, contextlib, io\nfrom roadtruth.harness.cli import main\n"
             "with contextlib.redirect_stdout(io.StringIO()) as out:\n    assert main(['observers', '--json']) == 0\n"
             f"print(json.dumps({{'out': out.getvalue(), 'heavy': [m for m in {HEAVY!r} if m in sys.modules]}}))")
    runs = []
    for _ in range(2):
        res = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300, env=env)
        assert res.returncode == 0, res.stderr
        runs.append(json.loads(res.stdout.strip().splitlines()[-1]))
    assert "numba" in runs[0]["heavy"]  # the first listing imports the observers ...
    assert runs[1]["heavy"] == []       # ... the second does not
    assert runs[0]["out"] == runs[1]["out"]
    from roadtruth.observers.registry import observer_info

    assert runs[1]["out"] == json.dumps(observer_info(), indent=2, default=str) + "\n"


def test_observer_catalog_key_follows_every_source_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import os

    from roadtruth.harness.evaluation import observer_catalog
    pkgs = {name: tmp_path / name for name in observer_catalog.PACKAGES}
    for d in pkgs.values():
        (d / "sub").mkdir(parents=True)
        (d / "a.py").write_text("x = 1\n")
    monkeypatch.setattr(observer_catalog, "_package_dir", lambda name: pkgs[name])
    k0 = observer_catalog.catalog_key()
    assert observer_catalog.catalog_key() == k0
    (pkgs["roadtruth.observers"] / "sub" / "new.py").write_text("")
    k1 = observer_catalog.catalog_key()
    f = pkgs["roadtruth.harness"] / "a.py"
    st = f.stat()
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    k2 = observer_catalog.catalog_key()
    assert len({k0, k1, k2}) == 3


def test_a_listing_with_an_observer_registered_in_process_is_not_remembered(tmp_path: Path,
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """A class a script registers in its own process is not part of the listing's key: a listing
    holding it must not be served to the next command (which would list an observer it lacks)."""
    from roadtruth.harness.evaluation import observer_catalog
    from roadtruth.observers import registry
    from roadtruth.observers.kalman import KalmanBicycle

    monkeypatch.setenv("ROADTRUTH_CACHE", str(tmp_path / "cache"))

    class ScriptObserver(KalmanBicycle):
        name = "script_kf_listing_probe"

    registry.register(ScriptObserver)
    try:
        rows = observer_catalog.observer_rows()
        assert "script_kf_listing_probe" in [r["name"] for r in rows]
    finally:
        registry.unregister("script_kf_listing_probe")
    from roadtruth.harness.files.disk_cache import cache_folder, read_entry

    folder, key = cache_folder(observer_catalog.CACHE_KIND), observer_catalog.catalog_key()
    assert read_entry(folder, key) is None
    rows = observer_catalog.observer_rows()  # without it: listed afresh, and now remembered
    assert "script_kf_listing_probe" not in [r["name"] for r in rows]
    assert read_entry(folder, key) is not None
