"""Cost of replaying the shared Revs Ferrari 250 LM log: wall time, peak memory and bytes written.

Runs ``roadtruth replay <log> --vehicle ferrari_250lm --columns revs_250lm`` as a child process
(a fresh interpreter each time, as a user would), after one warm-up run that fills the numba and
LMI design caches, and prints per output format:

* wall time of the whole command [s] (start of the interpreter to exit),
* peak resident memory [MB]: ``ru_maxrss`` of the child as ``os.wait4`` reports it, i.e. the
  largest single process among the command and the observer host it started (not their sum),
* bytes written to the output folder [MB] and the three largest files.

The machine's 1-minute load average is printed before and after, because the figures are only
comparable between runs in the same conditions.

    .venv/bin/python benchmarks/bench_replay_cost.py [--format csv,parquet] [--repeat 1] [--no-warmup]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REVS_LOG = (Path(__file__).resolve().parents[1].parent / "shared" / "data" / "revs-250lm"
            / "revs_250lm_2014-02-22.csv.gz")


SOURCE = Path(__file__).resolve().parents[1]


def replay_cost(out: Path, fmt: str | None, source: Path = SOURCE,
                observers: str | None = None) -> dict[str, float | list[tuple[str, int]]]:
    """One ``roadtruth replay`` of the Revs log into ``out``: wall [s], peak RSS [MB], bytes [MB].

    ``source``: the roadtruth checkout whose ``harness`` runs (an older revision, for a before/after
    comparison on the same machine); ``observers``: comma-separated names (default: all registered).
    """
    cmd = [sys.executable, "-m", "harness.cli", "replay", str(REVS_LOG), "--vehicle", "ferrari_250lm",
           "--columns", "revs_250lm", "--out", str(out)]
    if fmt is not None:
        cmd += ["--format", fmt]
    if observers:
        cmd += ["--observer", observers]
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=source,
                            env={**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(source)})
    # wait4 gives the child's own resource use, with its waited-for descendants (the observer host)
    # folded into ru_maxrss as a maximum; RUSAGE_CHILDREN of this process would mix all runs.
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"replay failed ({os.waitstatus_to_exitcode(status)}): {err.strip()[-500:]}")
    files = [(str(p.relative_to(out)), p.stat().st_size) for p in out.rglob("*") if p.is_file()]
    files.sort(key=lambda f: -f[1])
    return {"wall_s": wall, "peak_rss_mb": usage.ru_maxrss / 1024.0,
            "written_mb": sum(s for _, s in files) / 1e6, "largest": files[:3],
            "stderr_lines": float(len(err.splitlines()))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--format", default="csv,parquet",
                    help="comma-separated output formats to measure; 'none' = the command without --format")
    ap.add_argument("--repeat", type=int, default=1, help="measured runs per format (the minimum wall is kept)")
    ap.add_argument("--no-warmup", action="store_true", help="skip the warm-up run (cold caches)")
    ap.add_argument("--source", type=Path, default=SOURCE,
                    help="roadtruth checkout to run (default: this one), e.g. an exported older revision")
    ap.add_argument("--observer", help="comma-separated observers (default: every registered one)")
    a = ap.parse_args()
    if not REVS_LOG.is_file():
        raise SystemExit(f"the shared Revs log is not available ({REVS_LOG.name})")
    formats = [None if f == "none" else f for f in a.format.split(",") if f]
    print(f"load average (1 min) before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        if not a.no_warmup:
            replay_cost(Path(tmp) / "warmup", formats[0], a.source, a.observer)
        for fmt in formats:
            best = None
            for k in range(max(1, a.repeat)):
                r = replay_cost(Path(tmp) / f"{fmt}-{k}", fmt, a.source, a.observer)
                best = r if best is None or r["wall_s"] < best["wall_s"] else best
            assert best is not None
            largest = ", ".join(f"{n} {s / 1e6:.1f} MB" for n, s in best["largest"])  # type: ignore[union-attr]
            print(f"format {fmt or '(default)'}: wall {best['wall_s']:.1f} s, peak RSS {best['peak_rss_mb']:.0f} MB, "
                  f"written {best['written_mb']:.1f} MB (largest: {largest}); "
                  f"{best['stderr_lines']:.0f} progress lines on stderr")
    print(f"load average (1 min) after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
