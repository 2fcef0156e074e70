"""Cost of the report stage: ``build_report(folder)`` on existing run folders, time and memory.

For each run folder given, in child interpreters (so the parent's imports and caches do not count):

* **cold** [s]: the first ``build_report`` in a fresh interpreter that has imported the report
  builder and loaded the observer registry, as ``run`` and ``replay`` have when they build the page
  (``--bare``: not loaded, as a lone rebuild), best and median of ``--repeat`` fresh processes;
* **warm** [s]: the best and median of ``--repeat`` more calls in one process after the first
  (Jinja templates, plotly.js and numba-free code paths already loaded);
* **CPU time** [s] of the same builds (``time.process_time``, every thread of the process): less
  disturbed than wall time by other processes on a busy machine;
* **peak RSS growth** [MB]: the process's peak resident memory during its first ``build_report``
  above its resident memory just before (``/proc/self/clear_refs`` resets the peak, then
  ``VmHWM`` is read after), i.e. what the report stage adds to a command's peak;
* **Python allocations peak** [MB] (``--tracemalloc``): ``tracemalloc``'s peak during one build (in a
  separate child: tracing slows Python down several-fold, so it is never timed).

Each time is printed with its ratio to a fresh ``python -c "import numpy"`` measured in the same run
(best of ``--repeat``), since absolute figures on a shared machine mean little; the 1-minute load
average is printed before and after. The folder's ``index.html`` is rewritten by every build (same
bytes each time).

    .venv/bin/python benchmarks/bench_report.py FOLDER [FOLDER ...] [--repeat 3] [--tracemalloc] [--bare]
        [--source OLD/harness/report]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import bench_env

#: The child's program: imports, then one or more builds, printing one JSON line of figures.
_CHILD = r"""
import json, os, sys, time
from pathlib import Path

def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024.0  # kB -> MB
    return float("nan")

folder, warm, trace = Path(sys.argv[1]), int(sys.argv[2]), sys.argv[3] == "1"
if sys.argv[5]:  # another revision's report package: its modules are loaded from there
    import roadtruth.harness.report as package
    package.__path__[:] = [sys.argv[5]]
from roadtruth.harness.report.builder import build_report  # noqa: E402
import jinja2, orjson, pandas, pyarrow.parquet  # noqa: E401,E402,F401 - imports are not the report's cost
if sys.argv[4] == "1":  # a command that builds a report has loaded every observer already (line styles need the registry)
    from roadtruth.harness.report.styles import registry_names
    registry_names()
out = {}
if trace:
    import tracemalloc
    tracemalloc.start()
    build_report(folder)
    out["traced_peak_mb"] = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
else:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")  # reset VmHWM to the current RSS
        out["hwm_reset"] = True
    except OSError:
        out["hwm_reset"] = False
    rss0 = status("VmRSS")
    hwm0 = status("VmHWM")
    t0, c0 = time.perf_counter(), time.process_time()
    build_report(folder)
    out["first_s"], out["first_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
    out["rss_before_mb"] = rss0
    out["peak_growth_mb"] = status("VmHWM") - (rss0 if out["hwm_reset"] else hwm0)
    out["rss_after_mb"] = status("VmRSS")
    times, cpu = [], []
    for _ in range(warm):
        t0, c0 = time.perf_counter(), time.process_time()
        build_report(folder)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    out["warm_s"], out["warm_cpu_s"] = times, cpu
print(json.dumps(out))
"""


def load() -> float:
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def child(folder: Path, warm: int, trace: bool = False, registry: bool = True, source: str = "") -> dict:
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    r = subprocess.run([sys.executable, "-c", _CHILD, str(folder), str(warm), "1" if trace else "0",
                        "1" if registry else "0", source],
                       capture_output=True, text=True, env=env, check=False)
    if r.returncode != 0:
        sys.exit(f"build_report({folder}) failed:\n{r.stderr.strip()}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def numpy_baseline(repeat: int) -> list[float]:
    """Wall time of fresh ``python -c "import numpy"`` processes [s]."""
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import numpy"], check=True)
        out.append(time.perf_counter() - t0)
    return out


def main() -> None:
    bench_env.with_bytecode()  # children inherit it: measured as an installed package runs
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", type=Path, help="run folders (each holds run.json and metrics)")
    ap.add_argument("--repeat", type=int, default=3, help="fresh processes, and warm calls in one (default 3)")
    ap.add_argument("--bare", action="store_true",
                    help="do not load the observer registry before the first build (as `roadtruth report` on its "
                         "own; by default it is loaded first, as in `run` and `replay`, which have it loaded)")
    ap.add_argument("--tracemalloc", action="store_true", help="also print tracemalloc's peak of one build")
    ap.add_argument("--source", type=Path, help="a report package folder to build with instead of the installed "
                    "one, e.g. an older revision's: git archive REV harness/report | tar -x -C /tmp/old, then "
                    "--source /tmp/old/harness/report")
    args = ap.parse_args()
    source = str(args.source.resolve()) if args.source else ""
    if source:
        print(f"report package: {source}")
    repeat = max(1, args.repeat)
    print(f"load average (1 min) before: {load():.2f}")
    base = numpy_baseline(repeat)
    b = min(base)
    print(f"baseline python -c 'import numpy': best {b:.3f} s, median {statistics.median(base):.3f} s")
    for folder in args.folders:
        runs = [child(folder, warm=repeat if i == 0 else 0, registry=not args.bare, source=source) for i in range(repeat)]
        cold = [r["first_s"] for r in runs]
        warm = runs[0]["warm_s"]
        growth = [r["peak_growth_mb"] for r in runs]
        print(f"\n{folder}")
        print(f"  cold build_report: best {min(cold):.3f} s ({min(cold) / b:.2f}x numpy import), "
              f"median {statistics.median(cold):.3f} s")
        print(f"  warm build_report: best {min(warm):.3f} s ({min(warm) / b:.2f}x numpy import), "
              f"median {statistics.median(warm):.3f} s")
        cpu_cold, cpu_warm = [r["first_cpu_s"] for r in runs], runs[0]["warm_cpu_s"]
        print(f"  CPU time (all threads; steadier than wall time on a busy machine): cold best {min(cpu_cold):.3f} s, "
              f"warm best {min(cpu_warm):.3f} s, median {statistics.median(cpu_warm):.3f} s")
        note = "" if runs[0]["hwm_reset"] else " (VmHWM could not be reset: growth over the import peak)"
        print(f"  peak RSS growth during the first build: min {min(growth):.1f} MB, "
              f"median {statistics.median(growth):.1f} MB over RSS {runs[0]['rss_before_mb']:.1f} MB "
              f"after imports{note}")
        page = folder / "index.html"
        if page.is_file():
            print(f"  page: {page.stat().st_size / 1e6:.2f} MB")
        if args.tracemalloc:
            print(f"  tracemalloc peak of one build: {child(folder, 0, trace=True, registry=not args.bare, source=source)['traced_peak_mb']:.1f} MB")
    print(f"\nload average (1 min) after: {load():.2f}")


if __name__ == "__main__":
    main()
