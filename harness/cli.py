"""The ``roadtruth`` command line: parsing only; every command calls one library function.

Exit codes: 0 success, 1 a check failed, 2 bad input (one line on stderr naming the file, field or
value at fault; nothing written), 130 Ctrl-C, 143 SIGTERM (129 SIGHUP); interrupted runs keep nothing
half-written. Heavy packages (mujoco, numba, cvxpy) are imported inside the
command functions so that ``--help`` stays instant.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import NoReturn

from roadtruth.harness import __version__
from roadtruth.harness.errors import CheckFailed, InputError
from roadtruth.harness.jobs.warm_start import one_blas_thread

EXIT_OK, EXIT_CHECK_FAILED, EXIT_BAD_INPUT = 0, 1, 2

# Offscreen rendering must be chosen before anything imports mujoco; with no display, GLFW cannot work.
os.environ.setdefault("MUJOCO_GL", "egl")
# One BLAS thread per process (the run's parallelism is its processes), before anything imports NumPy.
os.environ.update(one_blas_thread())


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage mistake is one line on stderr and exit 2 (like every bad input)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see --help)\n")


def _csv_list(text: str) -> list[str]:
    items = [s.strip() for s in text.split(",") if s.strip()]
    if not items:
        raise argparse.ArgumentTypeError(f"empty list {text!r}")
    return items


def _number(text: str, *, whole: bool, lo: float, hi: float, what: str) -> float:
    try:
        v = int(text) if whole else float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a {'whole number' if whole else 'number'}: {text!r}") from None
    if not (lo <= v <= hi):
        raise argparse.ArgumentTypeError(f"must be {what} (got {text})")
    return v


def _positive_int(text: str) -> int:
    return int(_number(text, whole=True, lo=1, hi=10**6, what=">= 1"))


def _seed(text: str) -> int:
    return int(_number(text, whole=True, lo=0, hi=2**63 - 1, what=">= 0"))


def _rate(text: str) -> float:
    v = _number(text, whole=False, lo=0.0, hi=100000.0, what="in (0, 100000] Hz")
    if v <= 0.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 100000] Hz (got {text})")
    return v


def _timeout(text: str) -> float:
    v = _number(text, whole=False, lo=0.0, hi=1e6, what="in (0, 1000000] s")
    if v <= 0.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 1000000] s (got {text})")
    return v


_OBSERVER_TIMEOUT_HELP = ("wall-time budget of each observer's design and run in seconds; an observer over "
                          "it is reported as 'error: timed out after N s' and the others go on "
                          "(default: max(60, 20 x the simulated duration))")


class _CacheDirAction(argparse.Action):
    """``--cache-dir DIR``: the caches (LMI designs, finished stress cases) for this command.

    Applied as ``$ROADTRUTH_CACHE`` so that worker processes use the same folder.
    """

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: object,
                 option_string: str | None = None) -> None:
        from roadtruth.harness.files.disk_cache import CACHE_ENV

        path = Path(str(values)).expanduser()
        if path.exists() and not path.is_dir():
            parser.error(f"--cache-dir {values} is not a folder")
        os.environ[CACHE_ENV] = str(path.resolve())
        setattr(namespace, self.dest, str(path))


_CACHE_HELP = "cache folder (default: $ROADTRUTH_CACHE, else the user cache folder)"


def _add_format(sp: argparse.ArgumentParser) -> None:
    sp.add_argument("--format", choices=("csv", "parquet"), default="csv", dest="table_format",
                    help="format of the tables written (truth, measurements, estimates, metrics, ...): "
                    "csv (default) or parquet (smaller, faster, exact floats)")


def _add_observer_options(sp: argparse.ArgumentParser) -> None:
    sp.add_argument("--observer-options", metavar="FILE.yaml",
                    help="observer options: a YAML mapping observer -> {option: value}")
    sp.add_argument("-O", dest="observer_option", action="append", metavar="OBSERVER.OPTION=VALUE",
                    help="one observer option, e.g. -O kf_bicycle.meas_std_ay_mps2=1.5 (repeatable; "
                    "overrides --observer-options; see `roadtruth observers --json` for each observer's options)")


def _observer_options(a: argparse.Namespace) -> dict | None:
    from roadtruth.harness.evaluation.observer_options import options_from_cli

    return options_from_cli(a.observer_options, a.observer_option) or None


# ---- commands -----------------------------------------------------------------------------------

def _start_workers_server(needed: bool, *, renders_only: bool = False) -> None:
    """Start the worker pools' forkserver now, so its preload (~1 s) overlaps the seeding of numba's
    cache and the command's own imports; ``run_suite``/``run_stress`` would otherwise start it after them."""
    if needed:
        from roadtruth.harness.jobs.worker_pool import start_forkserver

        start_forkserver(renders_only=renders_only)


def _run_server(a: argparse.Namespace) -> None:
    _start_workers_server(a.jobs > 1 or not a.no_render, renders_only=a.jobs <= 1)


def _check_server(a: argparse.Namespace) -> None:
    _start_workers_server(a.jobs > 1)


def _stress_server(a: argparse.Namespace) -> None:
    if a.dask == "local":
        from roadtruth.harness.jobs.dask_setup import start_local_cluster_server

        start_local_cluster_server()
    _start_workers_server(a.jobs > 1 and not a.dask)


def _cmd_run(a: argparse.Namespace) -> int:
    from roadtruth.harness.jobs.pipeline import run_suite

    out = run_suite(scenarios=a.scenario, suite_name=a.suite, observers=a.observer, seed=a.seed,
                    jobs=a.jobs, out=Path(a.out), vehicle=a.vehicle, friction=a.friction,
                    sensors=a.sensors, faults=a.faults, log_rate_hz=a.log_rate, render=not a.no_render,
                    progress=None, observer_timeout_s=a.observer_timeout,
                    observer_options=_observer_options(a), table_format=a.table_format)
    print(f"report: {out / 'index.html'}")
    return EXIT_OK


def _cmd_simulate(a: argparse.Namespace) -> int:
    from roadtruth.harness.jobs.pipeline import simulate_to_dir

    out = simulate_to_dir(a.scenario, Path(a.out or f"reports/simulate-{Path(a.scenario).stem}"), vehicle=a.vehicle,
                          friction=a.friction, seed=a.seed, log_rate_hz=a.log_rate, sensors=a.sensors,
                          faults=a.faults, table_format=a.table_format)
    print(f"wrote {out}")
    return EXIT_OK


def _cmd_scenarios(a: argparse.Namespace) -> int:
    # The headers only: a full load builds roads and imports the compiled (numba) code.
    from roadtruth.harness.truth.scenario_index import scenario_summaries

    rows = scenario_summaries()
    if a.json:
        print(json.dumps(rows, indent=2))
        return EXIT_OK
    width = max(len(r["name"]) for r in rows)
    for r in rows:
        tags = ",".join(r.get("tags", []))
        print(f"{r['name']:<{width}}  {r.get('description', '')}  [{tags}]")
    return EXIT_OK


def _cmd_observers(a: argparse.Namespace) -> int:
    # Remembered between commands while the code is unchanged: listing imports every observer module.
    from roadtruth.harness.evaluation.observer_catalog import observer_rows

    rows = observer_rows()
    if a.json:
        print(json.dumps(rows, indent=2, default=str))
        return EXIT_OK
    width = max(len(r["name"]) for r in rows)
    for r in rows:
        states = ",".join(r.get("states", []))
        print(f"{r['name']:<{width}}  states: {states}  ({r.get('citation', '')})")
    return EXIT_OK


def _cmd_vehicles(a: argparse.Namespace) -> int:
    from roadtruth.harness.truth.vehicle import available_vehicles, load_vehicle

    sets = [load_vehicle(n) for n in available_vehicles()]
    if a.json:
        print(json.dumps([v.to_dict() for v in sets], indent=2))
        return EXIT_OK
    print(f"{'name':<15} {'mass kg':>8} {'Iz kg m2':>9} {'lf m':>6} {'lr m':>6} {'Cf kN/rad':>10} "
          f"{'Cr kN/rad':>10} {'K mrad/(m/s2)':>14}  drive")
    for v in sets:
        print(f"{v.name:<15} {v.mass_kg:>8.0f} {v.yaw_inertia_kgm2:>9.0f} {v.lf_m:>6.3f} {v.lr_m:>6.3f} "
              f"{v.cornering_stiffness_f_Npr / 1e3:>10.1f} {v.cornering_stiffness_r_Npr / 1e3:>10.1f} "
              f"{v.understeer_gradient_radpmps2 * 1e3:>14.2f}  {v.drivetrain.layout}")
    return EXIT_OK


def _cmd_report(a: argparse.Namespace) -> int:
    from roadtruth.harness.report import build_report

    path = build_report(Path(a.dir))
    print(f"report: {path}")
    return EXIT_OK


def _cmd_compare(a: argparse.Namespace) -> int:
    from roadtruth.harness.jobs.compare import compare

    result = compare(Path(a.dir_a), Path(a.dir_b), Path(a.out) if a.out else None)
    print(result.terminal())
    if a.out:
        print(f"full table: {Path(a.out) / 'compare.csv'}; page: {Path(a.out) / 'compare.html'}")
    return EXIT_OK


def _cmd_check(a: argparse.Namespace) -> int:
    from roadtruth.harness.jobs.check import run_check

    result = run_check(thresholds=Path(a.thresholds) if a.thresholds else None,
                       baseline=Path(a.baseline) if a.baseline else None,
                       junit=Path(a.junit) if a.junit else None, suite_name=a.suite, scenarios=a.scenario,
                       observers=a.observer, seed=a.seed, jobs=a.jobs, out=Path(a.out),
                       observer_timeout_s=a.observer_timeout, observer_options=_observer_options(a),
                       table_format=a.table_format)
    print(result.summary())
    if not result.passed:
        raise CheckFailed(f"{result.n_failed} of {result.n_checks} checks failed (see {result.out})")
    return EXIT_OK


def _cmd_stress(a: argparse.Namespace) -> int:
    from roadtruth.harness.jobs.stress import parse_fault_specs, parse_friction_list, run_stress

    out = run_stress(scenarios=a.scenario, suite_name=a.suite, observers=a.observer,
                     frictions=parse_friction_list(a.friction) if a.friction else None,
                     faults=parse_fault_specs(a.faults) if a.faults else None,
                     seeds=a.seeds, base_seed=a.seed, jobs=a.jobs, dask=a.dask, out=Path(a.out), progress=None,
                     fresh=a.fresh, observer_timeout_s=a.observer_timeout,
                     observer_options=_observer_options(a), table_format=a.table_format)
    print(f"report: {out / 'index.html'}")
    return EXIT_OK


def _cmd_falsify(a: argparse.Namespace) -> int:
    from roadtruth.harness.jobs.falsify import run_falsify

    out = run_falsify(observer=a.observer, prop=a.property, scenario=a.scenario, space=a.space, budget=a.budget,
                      jobs=a.jobs, dask=a.dask, seed=a.seed, out=Path(a.out), progress=None,
                      observer_timeout_s=a.observer_timeout)
    print(f"report: {out / 'index.html'}")
    return EXIT_OK


def _cmd_replay(a: argparse.Namespace) -> int:
    from roadtruth.harness.jobs.replay import replay

    out = replay(Path(a.log), vehicle=a.vehicle, columns=a.columns, observers=a.observer, out=Path(a.out),
                 observer_timeout_s=a.observer_timeout, rate_hz=a.rate_hz,
                 observer_options=_observer_options(a), table_format=a.table_format, jobs=a.jobs)
    print(f"report: {out / 'index.html'}")
    return EXIT_OK


def _cmd_init(a: argparse.Namespace) -> int:
    from roadtruth.harness.jobs.scaffold import init_project

    written = init_project(a.dir)
    print(f"wrote a starter project with {len(written)} files to {a.dir}; next: pip install -e {a.dir}, then "
          f"roadtruth check as its README says")
    return EXIT_OK


def _cmd_mjcf(a: argparse.Namespace) -> int:
    from roadtruth.harness.truth.mjcf_export import write_model

    write_model(a.vehicle, a.scenario, Path(a.out))
    print(f"wrote the MuJoCo model of {a.vehicle}{' on ' + a.scenario if a.scenario else ''} to {a.out} "
          "(open it with: python -m mujoco.viewer --mjcf " + str(a.out) + ")")
    return EXIT_OK


def _cmd_schema(a: argparse.Namespace) -> int:
    from roadtruth.harness.files.config_schema import schema_text, write_schema

    if a.out:
        write_schema(a.format, Path(a.out))
        print(f"wrote the JSON Schema of the {a.format} format to {a.out}")
    else:
        sys.stdout.write(schema_text(a.format))
    return EXIT_OK


# ---- parser ---------------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="roadtruth", description="Validate vehicle state observers against MuJoCo ground truth "
                "and recorded logs.")
    p.add_argument("--version", action="version", version=f"roadtruth {__version__}")
    p.add_argument("--cache-dir", action=_CacheDirAction, help=_CACHE_HELP)
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    def common_sim(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--vehicle", help="vehicle set name or YAML path (default: the scenario's)")
        sp.add_argument("--friction", help="override road friction: a number (uniform mu), a surface "
                        "(dry, wet, snow, ice) or a friction YAML")
        sp.add_argument("--seed", type=_seed, help="seed for everything random (default: the scenario's)")
        sp.add_argument("--sensors", help="sensor preset (ideal, automotive, consumer) or YAML")
        sp.add_argument("--faults", help="sensor faults, e.g. 'gnss:dropout=0.2' (see docs/SENSORS.md)")

    r = sub.add_parser("run", help="the main job: simulate, sense, estimate, score, report")
    r.add_argument("--suite", default="default", help="scenario suite (tag): default, ci, stress")
    r.add_argument("--scenario", type=_csv_list, help="comma-separated scenarios (overrides --suite)")
    r.add_argument("--observer", type=_csv_list, help="comma-separated observers (default: all)")
    r.add_argument("--jobs", type=_positive_int, default=1, help="parallel processes")
    r.add_argument("--out", default="reports/latest", help="output folder (default reports/latest)")
    r.add_argument("--log-rate", type=_rate, default=100.0, help="truth.csv rate in Hz (default 100)")
    r.add_argument("--no-render", action="store_true", help="skip MuJoCo frames and videos")
    common_sim(r)
    r.add_argument("--cache-dir", action=_CacheDirAction, help=_CACHE_HELP)
    r.add_argument("--observer-timeout", type=_timeout, metavar="SECONDS", help=_OBSERVER_TIMEOUT_HELP)
    _add_observer_options(r)
    _add_format(r)
    r.set_defaults(func=_cmd_run, start_server=_run_server)

    s = sub.add_parser("simulate", help="ground truth and measurements only")
    s.add_argument("scenario", help="scenario name or YAML path")
    s.add_argument("--out", help="output folder (default reports/simulate-SCENARIO)")
    s.add_argument("--log-rate", type=_rate, default=1000.0, help="truth.csv rate in Hz (default 1000)")
    common_sim(s)
    _add_format(s)
    s.set_defaults(func=_cmd_simulate)

    for name, func, what in (("scenarios", _cmd_scenarios, "list scenarios"),
                             ("observers", _cmd_observers, "list observers"),
                             ("vehicles", _cmd_vehicles, "list vehicle parameter sets")):
        sp = sub.add_parser(name, help=what)
        sp.add_argument("--json", action="store_true", help="machine-readable output")
        sp.set_defaults(func=func)

    rp = sub.add_parser("report", help="rebuild DIR/index.html from saved results")
    rp.add_argument("dir")
    rp.set_defaults(func=_cmd_report)

    c = sub.add_parser("compare", help="per-observer metric deltas between two runs")
    c.add_argument("dir_a")
    c.add_argument("dir_b")
    c.add_argument("--out", help="write compare.csv and compare.html here")
    c.set_defaults(func=_cmd_compare)

    ck = sub.add_parser("check", help="the CI gate: run a suite, exit 1 on a threshold or regression breach")
    ck.add_argument("--thresholds", help="thresholds YAML (default: the shipped harness/thresholds/ci.yaml)")
    ck.add_argument("--baseline", help="a previous metrics.csv: fail on regressions against it")
    ck.add_argument("--junit", help="write a JUnit XML report here")
    ck.add_argument("--suite", default="ci", help="scenario suite (default ci)")
    ck.add_argument("--scenario", type=_csv_list, help="comma-separated scenarios (overrides --suite)")
    ck.add_argument("--observer", type=_csv_list, help="comma-separated observers (default: all)")
    ck.add_argument("--seed", type=_seed, help="seed for everything random")
    ck.add_argument("--jobs", type=_positive_int, default=1, help="parallel processes")
    ck.add_argument("--out", default="reports/check", help="run folder (default reports/check)")
    ck.add_argument("--cache-dir", action=_CacheDirAction, help=_CACHE_HELP)
    ck.add_argument("--observer-timeout", type=_timeout, metavar="SECONDS", help=_OBSERVER_TIMEOUT_HELP)
    _add_observer_options(ck)
    _add_format(ck)
    ck.set_defaults(func=_cmd_check, start_server=_check_server)

    st = sub.add_parser("stress", help="robustness sweeps: friction x faults x Monte Carlo seeds")
    st.add_argument("--suite", default="stress", help="scenario suite (default stress)")
    st.add_argument("--scenario", type=_csv_list, help="comma-separated scenarios (overrides --suite)")
    st.add_argument("--observer", type=_csv_list, help="comma-separated observers (default: all)")
    st.add_argument("--friction", help="comma-separated: numbers, surfaces, friction YAMLs, or 'scenario'")
    st.add_argument("--faults", help="';'-separated --faults specs, 'none' allowed")
    st.add_argument("--seeds", type=_positive_int, default=1, help="Monte Carlo seeds per case")
    st.add_argument("--seed", type=_seed, help="base seed the Monte Carlo seeds derive from (default 0)")
    st.add_argument("--jobs", type=_positive_int, default=1, help="parallel processes (or Dask workers)")
    st.add_argument("--dask", help="Dask scheduler address, or 'local' for a LocalCluster on 127.0.0.1")
    st.add_argument("--out", default="reports/stress", help="output folder (default reports/stress)")
    st.add_argument("--fresh", action="store_true",
                    help="recompute every case instead of loading the ones an earlier sweep finished")
    st.add_argument("--cache-dir", action=_CacheDirAction, help=_CACHE_HELP)
    st.add_argument("--observer-timeout", type=_timeout, metavar="SECONDS", help=_OBSERVER_TIMEOUT_HELP)
    _add_observer_options(st)
    _add_format(st)
    st.set_defaults(func=_cmd_stress, start_server=_stress_server)

    fz = sub.add_parser("falsify", help="search roads, manoeuvres, faults and vehicles for the case that "
                        "breaks an observer's promise")
    fz.add_argument("--observer", required=True, help="the observer to falsify")
    fz.add_argument("--property", required=True, help="coverage[:STATE], nees[:STATE], METRIC:STATE<=X "
                    "(rmse, max_abs, p95_abs, mae, bias) or check:RULES.yaml")
    fz.add_argument("--scenario", help="base scenario: a shipped name or a YAML path (default step_steer)")
    fz.add_argument("--space", help="search space YAML (default: a μ patch, speed, steering, vehicle)")
    fz.add_argument("--budget", type=_positive_int, default=40, help="candidates evaluated in all (default 40)")
    fz.add_argument("--seed", type=_seed, default=0, help="seed of the sampler (default 0)")
    fz.add_argument("--jobs", type=_positive_int, default=1, help="parallel processes (or Dask workers)")
    fz.add_argument("--dask", help="Dask scheduler address, or 'local' for a LocalCluster on 127.0.0.1")
    fz.add_argument("--out", default="reports/falsify", help="output folder (default reports/falsify)")
    fz.add_argument("--cache-dir", action=_CacheDirAction, help=_CACHE_HELP)
    fz.add_argument("--observer-timeout", type=_timeout, metavar="SECONDS", help=_OBSERVER_TIMEOUT_HELP)
    fz.set_defaults(func=_cmd_falsify)

    rl = sub.add_parser("replay", help="run observers on a recorded log and score them")
    rl.add_argument("log", help="CSV, CSV.gz, Parquet, .mat, MDF4 (.mf4) or ROS 2 MCAP (.mcap or bag folder) log")
    rl.add_argument("--vehicle", help="vehicle set name or YAML path (a full or a replay vehicle); required "
                    "unless the column map has a 'vehicle:' key")
    rl.add_argument("--columns", help="column map YAML (log names/units -> canonical signals)")
    rl.add_argument("--rate-hz", type=float, metavar="HZ",
                    help="sample rate of a log without a time column (t = row / HZ)")
    rl.add_argument("--observer", type=_csv_list, help="comma-separated observers (default: all)")
    rl.add_argument("--out", default="reports/replay", help="output folder (default reports/replay)")
    rl.add_argument("--cache-dir", action=_CacheDirAction, help=_CACHE_HELP)
    rl.add_argument("--observer-timeout", type=_timeout, metavar="SECONDS", help=_OBSERVER_TIMEOUT_HELP)
    rl.add_argument("--jobs", type=_positive_int, default=None,
                    help="observers run at once, one process each (default: 2 on a machine with 2 cores or more)")
    _add_observer_options(rl)
    _add_format(rl)
    rl.set_defaults(func=_cmd_replay)

    it = sub.add_parser("init", help="write a starter project for your own observer (plug-in package, "
                        "thresholds, CI workflows) into a new or empty folder")
    it.add_argument("dir")
    it.set_defaults(func=_cmd_init)

    sc = sub.add_parser("schema", help="print or write the JSON Schema of a configuration format "
                        "(for editor completion and validation)")
    sc.add_argument("format", choices=_SCHEMA_FORMATS, metavar="FORMAT", help=", ".join(_SCHEMA_FORMATS))
    sc.add_argument("--out", help="write the schema to this file instead of printing it")
    sc.set_defaults(func=_cmd_schema)

    mj = sub.add_parser("mjcf", help="write the MuJoCo model of a vehicle (and a scenario's road) for MuJoCo's "
                        "own viewer")
    mj.add_argument("vehicle", help="vehicle set name or YAML path")
    mj.add_argument("--scenario", help="scenario name or YAML path: adds its road, markings, friction patches, "
                    "lead car and a 'start' keyframe at its initial pose and speed")
    mj.add_argument("--out", required=True, help="the .xml file to write (a new file, or one this command wrote)")
    mj.set_defaults(func=_cmd_mjcf)
    return p


#: Formats of `roadtruth schema` (kept here, not imported, so that building the parser stays cheap;
#: tests/test_config_schema.py checks it equals roadtruth.harness.files.config_schema.FORMATS).
_SCHEMA_FORMATS = ("scenario", "vehicle", "replay_vehicle", "sensors", "faults", "column_map", "thresholds",
                   "falsify_space", "observer_options")


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP arrived: unwound exactly like Ctrl-C (temp folders removed), exit 128 + signal."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def _termination_as_interrupt() -> Iterator[None]:
    """While the command runs, SIGTERM/SIGHUP raise :class:`Terminated` in this (the main) process.

    Forked worker processes inherit the handler; in them it restores the default action and re-sends
    the signal, so a worker still dies of it as before. A second signal during the clean-up is ignored
    so that the clean-up itself is not cut short (SIGKILL still ends everything).
    """
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be installed from the main thread (e.g. main() called in a thread)
        return
    owner = os.getpid()
    raised = False

    def handler(signum: int, _frame: object) -> None:
        nonlocal raised
        if os.getpid() != owner:
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        if not raised:
            raised = True
            raise Terminated(signum)

    previous = {s: signal.signal(s, handler) for s in _TERMINATING}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


_TERMINATING = tuple(s for s in (getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None)) if s)


def main(argv: Sequence[str] | None = None, *, own_process: bool = False) -> int:
    """Run one command; the exit code. ``own_process``: this process exists for the command alone
    (the console script), so what its start-up made may be frozen out of garbage collection's reach."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command in KERNEL_COMMANDS:
            _start_kernel_command(args, freeze=own_process)
        with _termination_as_interrupt():
            return int(args.func(args))
    except InputError as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"roadtruth: error: {msg}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except CheckFailed as exc:
        print(f"roadtruth: check failed: {exc}", file=sys.stderr)
        return EXIT_CHECK_FAILED
    except Terminated as exc:
        print(f"roadtruth: stopped by {exc} (nothing half-written was kept)", file=sys.stderr)
        return 128 + exc.signum
    except KeyboardInterrupt:
        print("roadtruth: interrupted (nothing half-written was kept)", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # Output piped into `head` and closed early: not an error of ours.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK


#: Commands that run compiled kernels (simulation, observers): they load the shipped ones. Each
#: maps to the module that holds its work, imported while garbage collection waits.
KERNEL_COMMANDS: dict[str, str] = {
    "run": "roadtruth.harness.jobs.pipeline",
    "simulate": "roadtruth.harness.jobs.pipeline",
    "check": "roadtruth.harness.jobs.check",
    "stress": "roadtruth.harness.jobs.stress",
    "falsify": "roadtruth.harness.jobs.falsify",
    "replay": "roadtruth.harness.jobs.replay",
}


def _start_kernel_command(args: argparse.Namespace, *, freeze: bool) -> None:
    """Load the shipped kernels and import the command's module with garbage collection paused, then
    (``freeze``) move what that made out of the collector's reach.

    Importing pandas, numba, MuJoCo and the harness makes some 150 000 tracked objects that live as
    long as the process. Collected as they are made, they cost three full collections walking them
    (0.15-0.25 s of a 1.4 s ``roadtruth simulate``); frozen (``gc.freeze``) once they are made, no
    collection walks them again, and the command's own garbage is still collected as usual. Only a
    process that exists for the command freezes: in a caller's process (a test calling :func:`main`)
    freezing would keep whatever garbage it had pending for good.
    """
    from roadtruth.harness.jobs.warm_start import collection_paused, load_numba_blas

    with collection_paused(freeze=freeze):
        _load_shipped_kernels(getattr(args, "start_server", None), args)  # the workers' server first
        load_numba_blas()  # before any kernel runs (numba's first dispatch imports its BLAS)
        importlib.import_module(KERNEL_COMMANDS[args.command])


def _load_shipped_kernels(start_server: Callable[[argparse.Namespace], None] | None = None,
                          args: argparse.Namespace | None = None) -> None:
    """Compile for the portable target of the kernels shipped with the package and add them to
    numba's cache before numba is first used (:mod:`roadtruth.harness.files.shipped_kernels`), so a
    fresh install's first command loads them instead of compiling them.

    ``start_server(args)``: starts the command's worker server once the target is set (the server
    inherits it) and before the seeding, which its preload then overlaps. Its workers take tasks
    only after this returns, so they find every shipped kernel seeded; the preload itself calls one
    tiny kernel, which it compiles if it gets there first (a fraction of a second, never wrong).
    """
    from roadtruth.harness.files.shipped_kernels import seed_numba_cache, use_portable_target

    portable = use_portable_target()
    if start_server is not None and args is not None:
        start_server(args)
    if portable:
        seed_numba_cache()


def _leave(code: int) -> NoReturn:
    """End the process with ``code`` once everything is written, skipping the interpreter's teardown.

    Tearing down a process that loaded numba, llvmlite, mujoco and pandas costs about half a second
    of freeing modules one by one, after the last file is already written. What the teardown does
    that anyone could observe is done here first, in the same order as a normal exit: the ``atexit``
    handlers (idle observer hosts told to exit, multiprocessing's children joined, temporary folders
    removed), then stdout and stderr flushed. Only when another non-daemon thread is still running
    (a normal exit would wait for it) is the ordinary exit taken instead.
    """
    if any(t.is_alive() and not t.daemon for t in threading.enumerate() if t is not threading.main_thread()):
        sys.exit(code)
    import atexit

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (BrokenPipeError, ValueError):  # a reader that left early, or a closed stream
            pass
    os._exit(code)


def console_main() -> NoReturn:
    """The ``roadtruth`` console script: :func:`main`, then a quick exit (:func:`_leave`)."""
    _leave(main(own_process=True))


if __name__ == "__main__":
    console_main()
