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



def source_tree(root: Path) -> tuple[dict[str, str], Path]:
    """The environment variables and working folder that make ``python -m roadtruth...`` run the
    code of the source tree ``root`` (e.g. an older checkout, for a before/after) instead of the
    installed one.

    The installed package is an editable install of this checkout, and its import hook maps
    ``roadtruth.harness`` to this checkout's ``harness/`` whatever the working folder: running from
    ``root`` would time this checkout's code under the old tree's name. So the ``roadtruth``
    namespace of ``root`` (its ``roadtruth/``, ``harness/``, ``observers/`` and ``mjcf/``) is linked
    into a private folder, which the commands run from and which is put first on ``PYTHONPATH`` for
    every process of a run (forkserver, workers, renderers); checked before use. For this checkout
    itself: no variables, and ``root``.
    """
    import hashlib
    import subprocess

    root = Path(root).resolve()
    if root == Path(__file__).resolve().parents[1]:
        return {}, root
    tree = Path(tempfile.gettempdir()) / f"roadtruth-bench-tree-{hashlib.sha256(str(root).encode()).hexdigest()[:12]}"
    package = tree / "roadtruth"
    package.mkdir(parents=True, exist_ok=True)
    links = {package / p.name: p for p in (root / "roadtruth").iterdir() if p.name != "__pycache__"}
    links.update({package / sub: root / sub for sub in ("harness", "observers", "mjcf")})
    for link, target in links.items():
        if not link.is_symlink():
            link.symlink_to(target)
    env = {"PYTHONPATH": os.pathsep.join([str(tree), *filter(None, [os.environ.get("PYTHONPATH")])])}
    probe = subprocess.run([sys.executable, "-c", "import roadtruth.harness as h, roadtruth.observers as o; "
                            "print(h.__file__); print(o.__file__)"], env={**os.environ, **env}, cwd=tree,
                           capture_output=True, text=True, check=True).stdout.split()
    if any(not Path(f).resolve().is_relative_to(root) for f in probe):
        raise SystemExit(f"--root {root}: its code is not what would run (imported from {probe})")
    return env, tree


def phases_of(folder: Path, wall_s: float) -> dict[str, float]:
    """The phases of the run or sweep written to ``folder`` (its ``timings.json``: ``phases_s``),
    with ``imports and exit``: the command's ``wall_s`` outside them. Empty for code that does not
    write phases (an older tree)."""
    import json

    timings = json.loads((Path(folder) / "timings.json").read_text(encoding="utf-8"))
    phases = {k: float(v) for k, v in (timings.get("phases_s") or {}).items()}
    if phases:
        phases["imports and exit"] = wall_s - float(timings["wall_s"])
    return phases


def busy_cpu_seconds() -> float:
    """CPU seconds the machine has been busy since boot, on every core together (user, nice, system,
    irq and softirq time of ``/proc/stat``); NaN where there is no ``/proc/stat``.

    The difference over a command is the CPU every process of it used (the command, its workers'
    server, workers and observer hosts, which a parent's ``getrusage`` misses when they are not its
    own waited-for children), plus whatever else ran meanwhile: read it on an otherwise idle machine.
    """
    try:
        with open("/proc/stat", encoding="ascii") as f:
            fields = f.readline().split()
    except OSError:
        return float("nan")
    user, nice, system, _idle, _iowait, irq, softirq = (int(v) for v in fields[1:8])
    return (user + nice + system + irq + softirq) / os.sysconf("SC_CLK_TCK")
