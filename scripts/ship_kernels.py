"""Write the compiled-kernel bundle shipped with the package (``harness/compiled/``).

    python scripts/ship_kernels.py [--replay "LOG [replay options]"] [--check]

In fresh processes with an empty numba cache and numba's portable target (``NUMBA_CPU_NAME=generic``),
runs every shipped scenario with every observer (``roadtruth run``, no rendering) and, with
``--replay``, ``roadtruth replay`` of a recorded log (e.g. ``--replay "../shared/data/revs-250lm/
revs_250lm_2014-02-22.csv.gz --vehicle ferrari_250lm --columns revs_250lm"``); then packs the cache entries numba wrote for roadtruth's own modules
(``harness/``, ``observers/``) into ``harness/compiled/kernels-<numba>-<python>-<machine>.zip``
(members: the package-relative folder of the module, then numba's file name; stored in sorted
order with fixed dates, so the same entries give the same archive). Only the entries those
commands *load* are kept (a kernel called only from other kernels is compiled into them; its own
entry serves only a recompilation): the same commands are run again on a copy of the cache with
numba's cache log on. Last, the commands run as on a fresh install (empty caches, the new bundle)
and the script exits 1 if numba compiled anything. The previous bundle for this
interpreter and machine is replaced; the folder holds nothing else.

``--check`` writes nothing: exit 1, naming them, when an entry of the bundle was built from a
source file that has changed since (or for another numba). numba would skip such an entry and
compile the function at first use, so after editing a kernel module run this script again.
Bundles are loaded by :mod:`roadtruth.harness.files.shipped_kernels`.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Folders of the package whose modules hold kernels.
KERNEL_TREES = ("harness", "observers")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--replay", help="also replay a recorded log: its path and replay options, one string")
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 if an entry is stale")
    a = p.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    if a.check:
        return check()
    return build(a.replay)


def check() -> int:
    import numba

    from roadtruth.harness.files.shipped_kernels import PACKAGE_ROOT, bundle_path, read_index, source_digest

    bundle = bundle_path()
    if bundle is None:
        print(f"no bundle for this interpreter, machine and numba {numba.__version__}")
        return 1
    stale = []
    with zipfile.ZipFile(bundle) as zf:
        indexes = [n for n in zf.namelist() if n.endswith(".nbi")]
        for member in indexes:
            rel = Path(member)
            source = PACKAGE_ROOT / rel.parent / (rel.name.split(".", 1)[0] + ".py")
            version, stamp, _ = read_index(zf.read(member))
            if version != numba.__version__ or not source.is_file() or stamp != source_digest(source):
                stale.append(member)
    for m in stale:
        print(f"stale: {m}")
    print(f"{bundle.name}: {len(indexes)} functions, {len(stale)} stale")
    return 1 if stale else 0


def build(replay: str | None) -> int:
    import shutil

    from roadtruth.harness.files.shipped_kernels import BUNDLE_DIR, SHIPPED_ENV, bundle_name

    scratch = Path(tempfile.mkdtemp(prefix="roadtruth-kernels-"))
    base = {**os.environ, "NUMBA_CPU_NAME": "generic", SHIPPED_ENV: "0", "MUJOCO_GL": "egl"}
    print("pass 1: compile", flush=True)
    if not _commands(replay, scratch / "run1", {**base, "NUMBA_CACHE_DIR": str(scratch / "numba"),
                                                "ROADTRUTH_CACHE": str(scratch / "cache1")}):
        return 1
    # A kernel called only from other kernels is compiled into them: its own entry is never loaded
    # by a command, only when a caller is compiled again. The bundle keeps what the same commands
    # load from a warm cache (numba's cache log, NUMBA_DEBUG_CACHE).
    print("pass 2: what a warm cache serves", flush=True)
    shutil.copytree(scratch / "numba", scratch / "numba2")
    log = _commands(replay, scratch / "run2", {**base, "NUMBA_CACHE_DIR": str(scratch / "numba2"),
                                              "ROADTRUTH_CACHE": str(scratch / "cache2"), "NUMBA_DEBUG_CACHE": "1"})
    if not log:
        return 1
    loaded = set(re.findall(r"\[cache\] data loaded from '([^']+)'", log))
    members = _members(scratch / "numba", {Path(p).name for p in loaded})
    import numba

    BUNDLE_DIR.mkdir(exist_ok=True)
    out = BUNDLE_DIR / bundle_name(numba.__version__)
    tmp = out.with_suffix(".tmp")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
        for name in sorted(members):
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, members[name])
    os.replace(tmp, out)
    n = sum(1 for m in members if m.endswith(".nbi"))
    size = sum(len(v) for v in members.values())
    print(f"{out.relative_to(ROOT)}: {n} functions, {len(members) - n} compiled signatures, "
          f"{size / 1e6:.1f} MB of cache files, {out.stat().st_size / 1e6:.1f} MB packed", flush=True)
    print("pass 3: a fresh install's commands with the bundle compile nothing", flush=True)
    env3 = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_NAME", SHIPPED_ENV)}
    log = _commands(replay, scratch / "run3", {**env3, "MUJOCO_GL": "egl", "NUMBA_DEBUG_CACHE": "1",
                                              "NUMBA_CACHE_DIR": str(scratch / "numba3"),
                                              "ROADTRUTH_CACHE": str(scratch / "cache3")})
    compiled = sorted(set(re.findall(r"\[cache\] data saved to '([^']+)'", log or "")))
    for path in compiled:
        print(f"compiled despite the bundle: {Path(path).name}")
    return 0 if log and not compiled else 1


def _commands(replay: str | None, out: Path, env: dict[str, str]) -> str | None:
    """Run every shipped scenario with every observer (no rendering) and, if given, the replay;
    their stdout (numba's cache log, when asked for), or None if one failed."""
    import shlex

    cli = [sys.executable, "-m", "roadtruth.harness.cli"]
    scenarios = json.loads(subprocess.run([*cli, "scenarios", "--json"], env=env, check=True,
                                          capture_output=True, text=True).stdout)
    runs = [[*cli, "run", "--scenario", ",".join(s["name"] for s in scenarios), "--no-render", "--out", str(out / "run")]]
    if replay:
        log, *options = shlex.split(replay)
        runs.append([*cli, "replay", str(Path(log).resolve()), *options, "--out", str(out / "replay")])
    log = []
    out.mkdir(parents=True)
    for cmd in runs:
        t = time.perf_counter()
        done = subprocess.run(cmd, env=env, cwd=out, capture_output=True, text=True)
        print(f"  {' '.join(cmd[3:5])}: exit {done.returncode}, {time.perf_counter() - t:.1f} s", flush=True)
        if done.returncode not in (0, 1):
            print(done.stderr[-2000:], file=sys.stderr)
            return None
        log.append(done.stdout)
    return "".join(log)


def _members(cache: Path, loaded: set[str]) -> dict[str, bytes]:
    """The bundle's files: each loaded data file, and its index listing only the loaded entries."""
    from numba.core.caching import _CacheLocator

    from roadtruth.harness.files.shipped_kernels import PACKAGE_ROOT, index_bytes, read_index

    # numba names each module folder's cache by a hash of its absolute path: map those back.
    folders = {}
    for tree in KERNEL_TREES:
        for d in [PACKAGE_ROOT / tree, *sorted((PACKAGE_ROOT / tree).rglob("*/"))]:
            if d.is_dir() and "__pycache__" not in d.parts:
                folders[_CacheLocator.get_suitable_cache_subpath(str(d / "x.py"))] = d.relative_to(PACKAGE_ROOT)
    members: dict[str, bytes] = {}
    for sub in sorted(cache.iterdir()):
        rel = folders.get(sub.name)
        if rel is None:
            continue
        for index in sorted(sub.glob("*.nbi")):
            version, stamp, overloads = read_index(index.read_bytes())
            kept = {key: name for key, name in overloads.items() if name in loaded}
            if kept:
                members[(rel / index.name).as_posix()] = index_bytes(version, stamp, kept)
                for name in kept.values():
                    members[(rel / name).as_posix()] = (sub / name).read_bytes()
    return members


if __name__ == "__main__":
    raise SystemExit(main())
