"""Compiled kernels shipped with the package: a fresh install's first run loads them instead of
compiling ~190 numba functions (about 90 s of CPU on a 2-core VM).

numba caches each compiled function in an index file (``<module>.<function>-<line>.pyXY.nbi``)
and one data file per signature (``….N.nbc``); an entry is used only when the index carries the
numba version of the loading process and the SHA-256 of the function's source file, and its key
names the signature, the bytecode and the CPU target. The bundle
(``harness/compiled/kernels-<numba>-<python>-<machine>.zip``, written by
``scripts/ship_kernels.py``) holds such files compiled for numba's portable target
(``NUMBA_CPU_NAME=generic``: baseline x86-64 instructions, no AVX), so they are valid on any
x86-64 CPU.

:func:`use_portable_target` makes a roadtruth command compile for that same target (set before
numba is imported; every process of the command inherits it), and :func:`seed_numba_cache`
copies the bundle's entries into the folder numba itself would cache each function in (it asks
numba's own cache locators: ``NUMBA_CACHE_DIR``, the package's ``__pycache__`` or the user cache).
Seeding adds entries and never removes or replaces one: an index already holding the same key is
left as it is, and the others gain the shipped entry under the next free data-file number. An
entry whose source changed since the bundle was built, or built for another numba or Python, is
skipped and numba compiles that function as it would without a bundle (slow, never wrong).

``ROADTRUTH_SHIPPED_KERNELS=0`` turns both off: kernels are then compiled for the host CPU on
first use. The portable code runs most kernels at the host code's speed (the simulation loop
alike); a few vectorisable ones run up to 1.6x slower per step, a few milliseconds of a default run
(``benchmarks/bench_kernel_target.py``; the README's measured figures).
"""

from __future__ import annotations

import hashlib
import io
import os
import pickle
import platform
import sys
import types
import zipfile
from dataclasses import dataclass
from pathlib import Path

from roadtruth.harness.files.disk_cache import cache_folder, read_entry, write_entry

#: ``0`` (or ``off``/``no``/``false``) turns the shipped kernels and the portable target off.
SHIPPED_ENV = "ROADTRUTH_SHIPPED_KERNELS"
#: numba's variable naming the CPU that code is generated for.
CPU_ENV = "NUMBA_CPU_NAME"
PORTABLE_CPU = "generic"
#: Where the bundles are (package data).
BUNDLE_DIR = Path(__file__).resolve().parents[1] / "compiled"
#: The package's root folder: bundle members are paths relative to it.
PACKAGE_ROOT = Path(__file__).resolve().parents[2]
#: Cache kind (:func:`~roadtruth.harness.files.disk_cache.cache_folder`) recording finished seedings.
SEED_KIND = "kernel-seeds"


def shipped_kernels_enabled() -> bool:
    return os.environ.get(SHIPPED_ENV, "1").strip().lower() not in {"0", "off", "no", "false"}


def bundle_name(numba_version: str) -> str:
    """The bundle file name for this interpreter and machine, e.g. ``kernels-numba0.68.1-py311-x86_64.zip``."""
    tag = f"py{sys.version_info[0]}{sys.version_info[1]}{getattr(sys, 'abiflags', '')}"
    return f"kernels-numba{numba_version}-{tag}-{platform.machine().lower()}.zip"


def _pinned_numba_version() -> str | None:
    """numba's version from its installed metadata (no import of numba: 0.15 s)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("numba")
    except PackageNotFoundError:
        return None


def bundle_path() -> Path | None:
    """The bundle that fits this interpreter, machine and installed numba, or None."""
    v = _pinned_numba_version()
    if v is None or not sys.platform.startswith("linux"):
        return None
    p = BUNDLE_DIR / bundle_name(v)
    return p if p.is_file() else None


def use_portable_target() -> bool:
    """Make numba generate the shipped kernels' portable code in this process and its children.

    Only when a bundle fits, ``NUMBA_CPU_NAME`` is not set by the user and numba is not imported yet
    (its configuration is read on import). Returns whether the portable target is in effect.
    """
    if not shipped_kernels_enabled() or bundle_path() is None:
        return False
    if CPU_ENV in os.environ:
        return os.environ[CPU_ENV].strip().lower() == PORTABLE_CPU
    if "numba" in sys.modules:
        return False
    os.environ[CPU_ENV] = PORTABLE_CPU
    # Nothing imported so far read it (numba is not imported): the start-up environment this
    # process's imports were made under includes it, so a host forked from here still stands in
    # for a fresh interpreter (``host_fork.fork_is_safe`` compares the two).
    import roadtruth

    roadtruth.ENVIRON_AT_IMPORT[CPU_ENV] = PORTABLE_CPU
    return True


def kernel_target() -> str:
    """The CPU numba generates code for in this process: ``generic`` (portable), another name set
    by the user, or ``host``. Per-step times (``us_per_step``) are times of that code."""
    if "numba" in sys.modules:
        from numba.core import config

        return config.CPU_NAME or "host"
    return os.environ.get(CPU_ENV, "").strip() or "host"


@dataclass(frozen=True)
class SeedResult:
    """What :func:`seed_numba_cache` did: entries added, already present, skipped as stale."""

    added: int = 0
    present: int = 0
    stale: int = 0
    reason: str = ""


def source_digest(path: Path) -> bytes:
    """numba's source stamp of a module: the SHA-256 of the file's bytes."""
    return hashlib.sha256(path.read_bytes()).digest()


def read_index(data: bytes) -> tuple[str, object, dict]:
    """(numba version, source stamp, {key: data-file name}) of an index file's bytes."""
    f = io.BytesIO(data)
    version = pickle.load(f)
    stamp, overloads = pickle.loads(f.read())
    return version, stamp, overloads


def index_bytes(version: str, stamp: object, overloads: dict) -> bytes:
    """An index file's bytes, as numba writes them (its version, then the stamp and the entries)."""
    from numba.core.serialize import dumps

    return pickle.dumps(version, protocol=-1) + dumps((stamp, overloads))


def numba_cache_dir(py_file: Path) -> Path | None:
    """The folder numba caches the functions of ``py_file`` in, chosen by numba's own locators."""
    from numba.core.caching import CompileResultCacheImpl

    def probe() -> None:  # pragma: no cover - never called: only its code's file name is read
        return None

    func = types.FunctionType(probe.__code__.replace(co_filename=str(py_file)), {})
    try:
        return Path(CompileResultCacheImpl(func).locator.get_cache_path())
    except (RuntimeError, OSError):
        return None


def _seed_key(bundle: Path) -> str:
    import numba.core.config as numba_config

    h = hashlib.sha256()
    for part in (bundle.name, str(bundle.stat().st_size), str(PACKAGE_ROOT), numba_config.CACHE_DIR or "",
                 os.environ.get("NUMBA_CACHE_LOCATOR_CLASSES", ""), sys.executable):
        h.update(part.encode() + b"\0")
    h.update(hashlib.sha256(bundle.read_bytes()).digest())
    return h.hexdigest()


def _already_seeded(key: str) -> bool:
    entry = read_entry(cache_folder(SEED_KIND), key)
    return bool(entry) and all(Path(p).is_file() for p in entry.get("indexes", []))


def seed_numba_cache() -> SeedResult:
    """Add the bundle's entries to numba's cache (see the module docstring); cheap once done.

    A seeding that finished is recorded (cache kind ``kernel-seeds``, keyed by the bundle's bytes,
    the package location and numba's cache setting) and not repeated while every index it wrote is
    still there. Never raises: a cache that cannot be written means compiling, not an error.
    """
    if not shipped_kernels_enabled():
        return SeedResult(reason=f"{SHIPPED_ENV} is off")
    bundle = bundle_path()
    if bundle is None:
        return SeedResult(reason="no bundle for this interpreter, machine and numba")
    if os.environ.get(CPU_ENV, "").strip().lower() != PORTABLE_CPU:
        return SeedResult(reason=f"{CPU_ENV} is not {PORTABLE_CPU!r}: kernels are compiled for this CPU")
    try:
        key = _seed_key(bundle)
        if _already_seeded(key):
            return SeedResult(reason="seeded before")
        result, indexes = _seed(bundle)
        if result.stale == 0 or result.added or result.present:
            write_entry(cache_folder(SEED_KIND), key, {"indexes": sorted(indexes)})
        return result
    except Exception as exc:  # noqa: BLE001 - a cache that cannot be seeded means compiling, never a failed command
        return SeedResult(reason=f"not seeded: {type(exc).__name__}: {exc}")


def _seed(bundle: Path) -> tuple[SeedResult, list[str]]:
    import numba

    added = present = stale = 0
    indexes: list[str] = []
    digests: dict[Path, bytes | None] = {}
    with zipfile.ZipFile(bundle) as zf:
        names = zf.namelist()
        for member in sorted(n for n in names if n.endswith(".nbi")):
            rel = Path(member)
            source = PACKAGE_ROOT / rel.parent / (rel.name.split(".", 1)[0] + ".py")
            if source not in digests:
                digests[source] = source_digest(source) if source.is_file() else None
            version, stamp, shipped = read_index(zf.read(member))
            if version != numba.__version__ or stamp != digests[source]:
                stale += len(shipped)
                continue
            target = numba_cache_dir(source)
            if target is None:
                stale += len(shipped)
                continue
            target.mkdir(parents=True, exist_ok=True)
            index_path = target / rel.name
            overloads = _fresh_overloads(index_path, version, stamp)
            taken = set(overloads.values())
            changed = False
            for entry_key, data_name in sorted(shipped.items(), key=lambda kv: kv[1]):
                if entry_key in overloads:
                    present += 1
                    continue
                name = _free_name(rel.name[: -len(".nbi")], taken)
                _write_atomic(target / name, zf.read(str(rel.parent / data_name)))
                overloads[entry_key] = name
                taken.add(name)
                added += 1
                changed = True
            if changed:
                _write_atomic(index_path, index_bytes(version, stamp, overloads))
            indexes.append(str(index_path))
    return SeedResult(added=added, present=present, stale=stale), indexes


def _fresh_overloads(index_path: Path, version: str, stamp: object) -> dict:
    """The entries of an existing index that numba would use (same version and source), else {}."""
    try:
        have_version, have_stamp, overloads = read_index(index_path.read_bytes())
    except (OSError, pickle.UnpicklingError, EOFError, ValueError):
        return {}
    return dict(overloads) if (have_version, have_stamp) == (version, stamp) else {}


def _free_name(base: str, taken: set[str]) -> str:
    n = 1
    while f"{base}.{n}.nbc" in taken:
        n += 1
    return f"{base}.{n}.nbc"


def _write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(f"{path.name}.tmp.{os.getpid()}")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
