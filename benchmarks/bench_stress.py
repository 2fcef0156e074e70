"""Cost of ``roadtruth stress`` sweeps: wall time and cases per second, in-process, with worker
processes and on a local Dask cluster (the figures of docs/STRESS.md, "Cost").

Run: ``python benchmarks/bench_stress.py [--skip-dask]``. Two sweeps, base seed 0 (timings are
measurements: run on a quiet machine; the first sweep warms the numba and design caches, and every
sweep recomputes its cases instead of reading the stress case cache):

* ``step_steer`` with ``kf_bicycle,lpv_wang``, μ ∈ {1.0, 0.6, 0.3, ice} × 3 seeds = 12 cases, in-process;
* ``sine_with_dwell`` with every registered observer, μ ∈ {1.0, 0.6, 0.3} × faults {none, gnss dropout}
  × 5 seeds = 30 cases: in-process, ``--jobs 2`` and ``--dask local --jobs 2``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")


def timed(label: str, n_cases: int, **kw: object) -> None:
    from harness.stress import run_stress

    with tempfile.TemporaryDirectory(prefix="bench-stress-") as tmp:
        t = time.perf_counter()
        # fresh: recompute every case (the case cache would otherwise serve a repeated sweep)
        run_stress(out=Path(tmp) / "s", progress=False, base_seed=0, fresh=True, **kw)  # type: ignore[arg-type]
        wall = time.perf_counter() - t
    print(f"{label:56s} {n_cases:3d} cases  {wall:6.1f} s  {n_cases / wall:5.1f} cases/s  "
          f"{wall / n_cases:5.2f} s/case")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--skip-dask", action="store_true", help="skip the Dask LocalCluster sweep")
    a = p.parse_args()
    print(f"cores: {os.cpu_count()}, load average before: {os.getloadavg()[0]:.2f}")
    small = {"scenarios": ["step_steer"], "observers": ["kf_bicycle", "lpv_wang"],
             "frictions": ["1.0", "0.6", "0.3", "ice"], "faults": ["none"], "seeds": 3}
    timed("(warm-up) step_steer, 2 observers, in-process", 12, **small)
    timed("step_steer, kf_bicycle + lpv_wang, in-process", 12, **small)
    big = {"scenarios": ["sine_with_dwell"], "observers": None, "frictions": ["1.0", "0.6", "0.3"],
           "faults": ["none", "gnss:dropout=0.2"], "seeds": 5}
    timed("sine_with_dwell, every observer, in-process", 30, **big)
    timed("sine_with_dwell, every observer, --jobs 2", 30, jobs=2, **big)
    if not a.skip_dask:
        timed("sine_with_dwell, every observer, --dask local --jobs 2", 30, jobs=2, dask="local", **big)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
