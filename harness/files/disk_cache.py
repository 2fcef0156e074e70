"""Where roadtruth keeps its caches, and content-checked JSON entries in them.

Location: ``$ROADTRUTH_CACHE`` if set (the CLI's ``--cache-dir`` sets it for the whole command,
worker processes included), else the user cache folder of the platform
(``platformdirs.user_cache_dir("roadtruth")``, e.g. ``~/.cache/roadtruth`` on Linux). Nothing is
ever written into the working directory. Each kind of entry has a sub-folder: ``designs`` (LMI
designs, :mod:`roadtruth.observers.lmi`), ``stress-cases`` (finished sweep cases, :mod:`roadtruth.harness.jobs.stress`) and
``design-warmups`` (which parallel runs already had their designs solved, :func:`presolve_designs`).

Entry format: ``<key>.json`` (canonical JSON text) and beside it ``<key>.sha256``, the SHA-256 of
``key + "\\n" + text``. :func:`read_entry` returns an entry only when the digest matches the bytes
on disk, so an edited, truncated or swapped entry reads as absent and the caller recomputes (and
overwrites) it. The digest has no secret: it detects edits and corruption, not a forgery by someone
who recomputes it (who could as well edit the installed code).

Cache failures never break a run: an unwritable folder means no caching, not an error.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

CACHE_ENV = "ROADTRUTH_CACHE"
APP_NAME = "roadtruth"


def cache_root() -> Path:
    """``$ROADTRUTH_CACHE`` if set and not empty, else the platform's user cache folder for roadtruth."""
    env = os.environ.get(CACHE_ENV, "").strip()
    if env:
        return Path(env).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir(APP_NAME, appauthor=False))


def cache_folder(kind: str) -> Path:
    """The folder of one kind of entry (``"designs"``, ``"stress-cases"``) under :func:`cache_root`."""
    return cache_root() / kind


def canonical_json(data: Any) -> str:
    """Deterministic JSON text (sorted keys; floats as Python ``repr``, which round-trips exactly)."""
    return json.dumps(data, sort_keys=True, indent=1, allow_nan=True, default=repr) + "\n"


def entry_digest(key: str, text: str) -> str:
    """SHA-256 (hex) of ``key``, a newline and the entry text: binds the content to its key."""
    return hashlib.sha256(key.encode() + b"\n" + text.encode()).hexdigest()


def _paths(folder: Path, key: str) -> tuple[Path, Path]:
    if not key or any(c not in "0123456789abcdef" for c in key):
        raise ValueError(f"cache keys are lowercase hex digests (got {key!r})")
    return folder / f"{key}.json", folder / f"{key}.sha256"


def read_entry(folder: Path, key: str) -> Any | None:
    """The parsed entry ``key`` of ``folder``, or None if absent, unreadable or not matching its digest."""
    data_path, digest_path = _paths(folder, key)
    try:
        text = data_path.read_bytes().decode("utf-8")
        digest = digest_path.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        return None
    if digest != entry_digest(key, text):
        return None
    try:
        return json.loads(text)
    except ValueError:
        return None


def _write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.chmod(tmp, 0o644)  # mkstemp makes it private; a cache may be shared by the user's tools
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_entry(folder: Path, key: str, data: Any) -> bool:
    """Store ``data`` (JSON-serialisable) as entry ``key``; True when written, False on any OS error.

    Each file is replaced atomically; a reader between the two renames sees a digest that does not
    match and treats the entry as absent, never as valid with the wrong content.
    """
    data_path, digest_path = _paths(folder, key)
    text = canonical_json(data)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        _write_atomic(data_path, text)
        _write_atomic(digest_path, entry_digest(key, text) + "\n")
    except OSError:
        return False
    return True


# ---- filling the design cache before parallel workers start --------------------------------------
#
# Why: worker processes that start on a fresh cache all need the same LMI designs at about the same
# time, and each would solve them (seconds of SDP each), writing the same entries. Solving them once,
# in one worker, before the others take their first task, costs the others nothing: they are still
# importing meanwhile. With a warm cache the warm-up is only the design loads the worker needs anyway.

@dataclass(frozen=True)
class DesignWarmup:
    """The designs a set of parallel tasks will need (picklable: sent to a worker).

    ``scenarios``: ``(scenario, vehicle override or None, friction override or None)`` per task,
    resolved to vehicles in the worker; ``observers``: observer names; ``options``: observer ->
    {option: value}, as the tasks pass them (options change a design, hence its key).
    """

    scenarios: tuple[tuple[str, str | None, str | None], ...]
    observers: tuple[str, ...]
    options: tuple[tuple[str, tuple[tuple[str, Any], ...]], ...] = ()
    timeout_s: float = 600.0  # budget of each observer's design [s], as in a task

    @classmethod
    def of(cls, scenarios: Iterable[tuple[str, str | None, str | None]], observers: Iterable[str],
           options: Mapping[str, Mapping[str, Any]] | None = None, timeout_s: float | None = None) -> DesignWarmup:
        opts = tuple(sorted((o, tuple(sorted(dict(v).items()))) for o, v in (options or {}).items() if v))
        return cls(tuple(dict.fromkeys(scenarios)), tuple(dict.fromkeys(observers)), opts,
                   600.0 if timeout_s is None else float(timeout_s))


def solve_designs(warmup: DesignWarmup) -> int:
    """Worker side: design every observer of ``warmup`` for every distinct vehicle; returns how many
    (vehicle, observer) designs were requested.

    Each observer is designed and run on a two-sample input in this process's observer host
    (:func:`roadtruth.harness.evaluation.observer_host.run_isolated`), so a design that crashes or hangs is contained and
    timed out exactly as in a task; the host keeps the designs in memory for this worker's tasks,
    and the design cache on disk serves every other worker. Whatever fails here is ignored: the
    tasks meet the same failure and report it.
    """
    import numpy as np

    from roadtruth.harness.evaluation.observer_host import run_isolated
    from roadtruth.harness.jobs.pipeline import prepare_scenario
    from roadtruth.observers.registry import observer_class

    options = {o: dict(v) for o, v in warmup.options}
    vehicles: dict[str, Any] = {}
    for name, vehicle, friction in warmup.scenarios:
        try:
            v = prepare_scenario(name, vehicle, friction).vehicle_params()
        except Exception:  # noqa: BLE001 - a scenario that fails to load fails in its task
            continue
        vehicles.setdefault(repr(v), v)  # the full parameters: a design depends on all of them
    t = np.array([0.0, 0.001])
    n = 0
    for v in vehicles.values():
        for o in warmup.observers:
            try:
                cls = observer_class(o)
            except Exception:  # noqa: BLE001
                continue
            run_isolated(cls, v, options.get(o, {}), t, np.zeros((2, len(cls.inputs))), warmup.timeout_s)
            n += 1
    return n


#: Sub-folder of warm-up records: "these designs were put in this cache by this code".
WARMUP_KIND = "design-warmups"


def warmup_key(warmup: DesignWarmup) -> str:
    """Hash of the warm-up and of every file of the installed roadtruth packages (scenarios, vehicles,
    observer code: anything a design depends on), and of whether shipped designs are read."""
    from roadtruth.harness.jobs.stress_cache import code_fingerprint

    text = canonical_json({"warmup": repr(warmup), "code": code_fingerprint(),
                           "shipped": os.environ.get("ROADTRUTH_SHIPPED_DESIGNS", "")})
    return hashlib.sha256(text.encode()).hexdigest()


def presolve_designs(submit: Callable[[Callable[[Any], Any], Any], Any], warmup: DesignWarmup) -> None:
    """Run :func:`solve_designs` through ``submit(fn, arg) -> future`` (``WorkerPool.submit_call``,
    ``distributed.Client.submit``) and wait for it; a failure (even a crashed worker) is ignored.

    The warm-up holds every worker back until one worker's observer host has started, so it runs
    only when this cache has not been warmed for the same warm-up by the same code (a record in
    ``design-warmups``). A record outlives a design deleted by hand, or a vehicle file outside the
    package edited since: then workers may solve a design twice, as without the warm-up; results
    never depend on it (designs are keyed by their content).
    """
    if not warmup.observers or not warmup.scenarios:
        return
    key = warmup_key(warmup)
    if read_entry(cache_folder(WARMUP_KIND), key) is not None:
        return
    try:
        n = submit(solve_designs, warmup).result()
    except Exception:  # noqa: BLE001 - the tasks design for themselves then, as without the warm-up
        return
    write_entry(cache_folder(WARMUP_KIND), key, {"designs": n})


__all__ = ["APP_NAME", "CACHE_ENV", "DesignWarmup", "cache_folder", "cache_root", "canonical_json", "entry_digest",
           "presolve_designs", "read_entry", "solve_designs", "write_entry"]
