"""The interpreter settings a benchmark measures under: those of a user's installed package.

pip writes bytecode (``.pyc``) for an installed package and Python writes it for a source checkout on
first import, so a user's commands load compiled modules. ``PYTHONDONTWRITEBYTECODE=1`` (set in some
CI and container images) makes every process compile every module of the package from source again:
0.2-0.5 s per process here, paid by the main process, each observer host, worker and renderer. A
benchmark that starts under it re-runs itself once with that variable removed and the bytecode kept
in a private folder (``PYTHONPYCACHEPREFIX``; the source tree gets no ``__pycache__``), and says so.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

#: Bytecode of benchmark runs (kept between runs, like an installed package's).
PYCACHE = Path(tempfile.gettempdir()) / "roadtruth-bench-pycache"
_MARK = "ROADTRUTH_BENCH_BYTECODE"


def with_bytecode() -> None:
    """Re-run this process with bytecode on, if ``PYTHONDONTWRITEBYTECODE`` is set (module doc)."""
    if not os.environ.get("PYTHONDONTWRITEBYTECODE") or os.environ.get(_MARK):
        return
    env = {**os.environ, "PYTHONPYCACHEPREFIX": str(PYCACHE), _MARK: "1"}
    env.pop("PYTHONDONTWRITEBYTECODE")
    print(f"PYTHONDONTWRITEBYTECODE is set: measuring with bytecode in {PYCACHE}, as an installed package runs",
          file=sys.stderr, flush=True)
    os.execve(sys.executable, [sys.executable, *sys.orig_argv[1:]], env)
