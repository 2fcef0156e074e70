"""Cost of replaying the shared Revs Ferrari 250 LM log: wall time, memory and bytes written, per stage.

Runs ``roadtruth replay <log> --vehicle ferrari_250lm --columns revs_250lm`` as a child process
(a fresh interpreter each time, as a user would), after one warm-up run that fills the numba and
LMI design caches, and prints per output format:

* wall time of the whole command [s] (start of the interpreter to exit),
* peak resident memory [MB]: ``ru_maxrss`` of the child as ``os.wait4`` reports it, i.e. the
  largest single process among the command and the observer hosts it started (not their sum), and
  the peak of the sum of all of them (sampled every 50 ms from ``/proc``),
* CPU time of the command and its hosts [s] (user + system; comparable between runs on a busy
  machine, where wall time is not),
* bytes written to the output folder [MB] and the three largest files,
* each figure's ratio to the target of a Revs replay: < 10 s wall (warm) and < 500 MB peak RSS of
  any one process (main or observer host).

Then, in one more child interpreter, the CPU time of each observer's ``run()`` over the log's run
segments [s] (``time.process_time``; design and compiled-code loading excluded; best of ``--repeat``),
sorted, with its share: CPU time, unlike wall time, is comparable on a loaded machine.

``--stages`` adds one more run that calls ``roadtruth.harness.jobs.replay.replay`` in a child interpreter with
``on_stage`` and prints, per stage of ``roadtruth.harness.jobs.replay.STAGES`` (plus the interpreter's imports):
wall time, CPU time of the main process and of the observer hosts, and the peak RSS of each; then
each observer's share of the hosts' time (its ``run()`` time from ``run.json``).

The machine's 1-minute load average is printed before and after, because the figures are only
comparable between runs in the same conditions.

    .venv/bin/python benchmarks/bench_replay_cost.py [--format csv,parquet] [--repeat 1] [--no-warmup]
        [--stages] [--no-observer-cpu] [--jobs N] [--observer O,...] [--source CHECKOUT]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import bench_env

REVS_LOG = (Path(__file__).resolve().parents[1].parent / "shared" / "data" / "revs-250lm"
            / "revs_250lm_2014-02-22.csv.gz")


SOURCE = Path(__file__).resolve().parents[1]
SAMPLE_S = 0.05  # memory sampling period [s]
TARGET_WALL_S = 10.0    # target: a warm Revs replay in under 10 s ...
TARGET_PEAK_MB = 500.0  # ... and under 500 MB peak RSS
CLK_TCK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


# ---- /proc readings (Linux) ------------------------------------------------------------------------

def rss_mb(pid: int) -> float:
    """Resident memory of ``pid`` [MB] (0 when it is gone)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def cpu_s(pid: int) -> float:
    """User + system CPU time of ``pid`` so far [s] (0 when it is gone)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / CLK_TCK
    except (OSError, IndexError, ValueError):
        return 0.0


def children(pid: int) -> list[int]:
    """Direct children of ``pid`` (every thread's ``children`` list)."""
    out: list[int] = []
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{tid}/children") as fh:
                out += [int(c) for c in fh.read().split()]
    except OSError:
        pass
    return out


class TreeSampler:
    """Samples the RSS of a process and its children every ``SAMPLE_S`` in a thread: the peak of the
    main process, of the largest child and of their sum [MB], and the last CPU time seen per child."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.main_peak = self.child_peak = self.sum_peak = 0.0
        self.child_cpu: dict[int, float] = {}
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.sample()
            self._stop.wait(SAMPLE_S)

    def sample(self) -> None:
        main = rss_mb(self.pid)
        kids = children(self.pid)
        sizes = [rss_mb(k) for k in kids]
        with self._lock:
            self.main_peak = max(self.main_peak, main)
            self.child_peak = max([self.child_peak, *sizes])
            self.sum_peak = max(self.sum_peak, main + sum(sizes))
            for k in kids:
                self.child_cpu[k] = max(self.child_cpu.get(k, 0.0), cpu_s(k))

    def reset_peaks(self) -> dict[str, float]:
        """The peaks since the last reset (and start again from the current sizes)."""
        self.sample()
        with self._lock:
            peaks = {"main_mb": self.main_peak, "hosts_mb": self.child_peak, "sum_mb": self.sum_peak}
            self.main_peak = self.child_peak = self.sum_peak = 0.0
        return peaks

    def hosts_cpu(self) -> float:
        self.sample()
        with self._lock:
            return sum(self.child_cpu.values())

    def __enter__(self) -> TreeSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


# ---- the whole command -------------------------------------------------------------------------------

def replay_cost(out: Path, fmt: str | None, source: Path = SOURCE, observers: str | None = None,
                jobs: int | None = None) -> dict[str, Any]:
    """One ``roadtruth replay`` of the Revs log into ``out``: wall [s], peak RSS [MB], CPU [s], bytes [MB].

    ``source``: the roadtruth checkout whose ``harness`` runs (an older revision, for a before/after
    comparison on the same machine); ``observers``: comma-separated names (default: all registered);
    ``jobs``: ``--jobs`` (None: the command's default; an older checkout may not have the option).
    """
    cmd = [sys.executable, "-m", "roadtruth.harness.cli", "replay", str(REVS_LOG), "--vehicle", "ferrari_250lm",
           "--columns", "revs_250lm", "--out", str(out)]
    if fmt is not None:
        cmd += ["--format", fmt]
    if observers:
        cmd += ["--observer", observers]
    if jobs is not None:
        cmd += ["--jobs", str(jobs)]
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=source,
                            env={**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(source)})
    err_chunks: list[bytes] = []
    reader = threading.Thread(target=lambda: err_chunks.append(proc.stderr.read() if proc.stderr else b""),
                              daemon=True)
    reader.start()
    with TreeSampler(proc.pid) as sampler:
        # wait4 gives the child's own resource use, with its waited-for descendants (the observer
        # hosts) folded into ru_maxrss as a maximum and into ru_utime/ru_stime as a sum.
        _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t
    reader.join()
    err = b"".join(err_chunks).decode(errors="replace")
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"replay failed ({os.waitstatus_to_exitcode(status)}): {err.strip()[-500:]}")
    files = [(str(p.relative_to(out)), p.stat().st_size) for p in out.rglob("*") if p.is_file()]
    files.sort(key=lambda f: -f[1])
    return {"wall_s": wall, "peak_rss_mb": usage.ru_maxrss / 1024.0, "sum_rss_mb": sampler.sum_peak,
            "main_rss_mb": sampler.main_peak, "host_rss_mb": sampler.child_peak,
            "cpu_s": usage.ru_utime + usage.ru_stime,
            "written_mb": sum(s for _, s in files) / 1e6, "largest": files[:3],
            "stderr_lines": float(len(err.splitlines()))}


# ---- per stage (in a child interpreter) -----------------------------------------------------------

def stage_child(out: Path, fmt: str, observers: str | None, jobs: int | None, t_start: float) -> None:
    """Run the replay with ``on_stage`` and print the per-stage figures as one JSON line."""
    sampler = TreeSampler(os.getpid())
    rows: list[dict[str, Any]] = []
    current = {"name": "imports", "wall": t_start, "cpu": 0.0, "hosts": 0.0}

    def mark(name: str) -> None:
        now, cpu, hosts = time.time(), time.process_time(), sampler.hosts_cpu()
        rows.append({"stage": current["name"], "wall_s": now - current["wall"], "main_cpu_s": cpu - current["cpu"],
                     "hosts_cpu_s": hosts - current["hosts"], **sampler.reset_peaks()})
        current.update(name=name, wall=now, cpu=cpu, hosts=hosts)

    with sampler:
        from roadtruth.harness.jobs.replay import replay

        mark("setup")  # vehicle, column map, observer registry, host start
        replay(REVS_LOG, vehicle="ferrari_250lm", columns="revs_250lm", out=out, table_format=fmt,
               observers=observers.split(",") if observers else None, jobs=jobs, progress=lambda _m: None,
               on_stage=mark)
        mark("end")
    run = json.loads((out / "run.json").read_text())
    runs = next(iter(run["observer_runs"].values()))
    obs = {k: (v.get("us_per_step") or 0.0) * (v.get("n_steps") or 0) / 1e6 for k, v in runs.items()}
    print(json.dumps({"stages": rows, "observer_run_s": obs}))


# ---- CPU per observer (in a child interpreter) -----------------------------------------------------

def observer_cpu_child(observers: str | None, repeat: int) -> None:
    """Print ``{observer: best CPU seconds of run() over the run segments}`` as one JSON line."""
    from roadtruth.harness.jobs.replay import prepare_log
    from roadtruth.harness.jobs.replay_log import load_column_map
    from roadtruth.harness.truth.vehicle import load_vehicle
    from roadtruth.observers.registry import available_observers, create, observer_class

    veh = load_vehicle("ferrari_250lm", replay=True)
    rl = prepare_log(REVS_LOG, load_column_map("revs_250lm"), vehicle=veh)
    names = observers.split(",") if observers else available_observers()
    out: dict[str, float | None] = {}
    for name in names:
        cls = observer_class(name)
        best = None
        if not all(c in rl.measurements[s.index].columns for c in cls.inputs for s in rl.run_segments):
            out[name] = None    # the replay skips it too: the log lacks a signal it needs
            continue
        segs = [(m["t_s"].to_numpy(float), m[list(cls.inputs)].to_numpy(float))
                for m in (rl.measurements[s.index] for s in rl.run_segments)]
        try:
            for _ in range(max(1, repeat)):
                total = 0.0
                for t, Y in segs:
                    obs = create(name, veh)
                    obs.run(t[:5], Y[:5])   # the design and the compiled code's loading, not timed
                    c = time.process_time()
                    obs.run(t, Y)
                    total += time.process_time() - c
                best = total if best is None else min(best, total)
        except Exception:  # noqa: BLE001 - an observer that cannot run on the log is listed as such
            best = None
        out[name] = best
    print(json.dumps(out))


def print_observer_cpu(observers: str | None, repeat: int, source: Path) -> None:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--_cpu-child", "--repeat", str(repeat)]
    cmd += ["--observer", observers] if observers else []
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=source,
                         env={**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(source)})
    if res.returncode != 0:
        raise SystemExit(f"observer CPU run failed: {res.stderr.strip()[-800:]}")
    data = json.loads(res.stdout.strip().splitlines()[-1])
    ran = sorted(((k, v) for k, v in data.items() if v is not None), key=lambda kv: -kv[1])
    total = sum(v for _, v in ran)
    print(f"\nobservers' run() CPU on the log's run segments (best of {max(1, repeat)}), {total:.2f} s in all:")
    for k, v in ran:
        print(f"  {k:<36} {v:7.3f} s  {v / total if total else 0.0:5.1%}")
    failed = [k for k, v in data.items() if v is None]
    if failed:
        print(f"  not run (inputs missing from the log, or failed): {', '.join(failed)}")


def print_stages(fmt: str, observers: str | None, jobs: int | None, source: Path) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--_stage-child", str(Path(tmp) / "out"),
               "--format", fmt, "--_t0", repr(time.time())]
        cmd += ["--observer", observers] if observers else []
        cmd += ["--jobs", str(jobs)] if jobs is not None else []
        res = subprocess.run(cmd, capture_output=True, text=True, cwd=source,
                             env={**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(source)})
    if res.returncode != 0:
        raise SystemExit(f"stage run failed: {res.stderr.strip()[-800:]}")
    data = json.loads(res.stdout.strip().splitlines()[-1])
    print(f"\nper stage, format {fmt} (wall; CPU of the main process and of the observer hosts; peak RSS):")
    print(f"{'stage':<10} {'wall s':>7} {'main CPU s':>10} {'hosts CPU s':>11} {'main MB':>8} {'host MB':>8} "
          f"{'sum MB':>7}")
    for r in data["stages"]:
        print(f"{r['stage']:<10} {r['wall_s']:7.2f} {r['main_cpu_s']:10.2f} {r['hosts_cpu_s']:11.2f} "
              f"{r['main_mb']:8.0f} {r['hosts_mb']:8.0f} {r['sum_mb']:7.0f}")
    total = sum(data["observer_run_s"].values())
    top = sorted(data["observer_run_s"].items(), key=lambda kv: -kv[1])[:8]
    print(f"observers' run() time, {total:.1f} s in all: "
          + ", ".join(f"{k} {v:.1f} s ({v / total:.0%})" for k, v in top if total > 0))


def main() -> None:
    bench_env.with_bytecode()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--format", default="csv,parquet",
                    help="comma-separated output formats to measure; 'none' = the command without --format")
    ap.add_argument("--repeat", type=int, default=1, help="measured runs per format (the minimum wall is kept)")
    ap.add_argument("--no-warmup", action="store_true", help="skip the warm-up run (cold caches)")
    ap.add_argument("--source", type=Path, default=SOURCE,
                    help="roadtruth checkout to run (default: this one), e.g. an exported older revision")
    ap.add_argument("--observer", help="comma-separated observers (default: every registered one)")
    ap.add_argument("--jobs", type=int, help="--jobs of the replay (default: the command's default)")
    ap.add_argument("--stages", action="store_true", help="also print wall, CPU and memory per stage")
    ap.add_argument("--no-observer-cpu", action="store_true", help="skip the CPU time per observer")
    ap.add_argument("--_stage-child", dest="stage_child", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--_cpu-child", dest="cpu_child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--_t0", dest="t0", type=float, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if not REVS_LOG.is_file():
        raise SystemExit(f"the shared Revs log is not available ({REVS_LOG.name})")
    if a.cpu_child:
        observer_cpu_child(a.observer, a.repeat)
        return
    if a.stage_child is not None:
        stage_child(a.stage_child, a.format, a.observer, a.jobs, a.t0 or time.time())
        return
    formats = [None if f == "none" else f for f in a.format.split(",") if f]
    print(f"load average (1 min) before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        if not a.no_warmup:
            replay_cost(Path(tmp) / "warmup", formats[0], a.source, a.observer, a.jobs)
        for fmt in formats:
            best = None
            for k in range(max(1, a.repeat)):
                r = replay_cost(Path(tmp) / f"{fmt}-{k}", fmt, a.source, a.observer, a.jobs)
                best = r if best is None or r["wall_s"] < best["wall_s"] else best
            assert best is not None
            largest = ", ".join(f"{n} {s / 1e6:.1f} MB" for n, s in best["largest"])
            print(f"format {fmt or '(default)'}: wall {best['wall_s']:.1f} s, CPU {best['cpu_s']:.1f} s, "
                  f"peak RSS {best['peak_rss_mb']:.0f} MB (largest process; all processes together "
                  f"{best['sum_rss_mb']:.0f} MB), written {best['written_mb']:.1f} MB (largest: {largest}); "
                  f"{best['stderr_lines']:.0f} progress lines on stderr")
            print(f"  vs the targets: wall {best['wall_s'] / TARGET_WALL_S:.2f}x of {TARGET_WALL_S:.0f} s; peak RSS "
                  f"{best['peak_rss_mb'] / TARGET_PEAK_MB:.2f}x of {TARGET_PEAK_MB:.0f} MB (main process "
                  f"{best['main_rss_mb']:.0f} MB, largest observer host {best['host_rss_mb']:.0f} MB)")
    if not a.no_observer_cpu:
        print_observer_cpu(a.observer, a.repeat, a.source)
    if a.stages:
        for fmt in formats:
            print_stages(fmt or "csv", a.observer, a.jobs, a.source)
    print(f"load average (1 min) after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
