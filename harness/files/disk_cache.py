"""Where roadtruth keeps its caches, and content-checked JSON entries in them.

Location: ``$ROADTRUTH_CACHE`` if set (the CLI's ``--cache-dir`` sets it for the whole command,
worker processes included), else the user cache folder of the platform
(``platformdirs.user_cache_dir("roadtruth")``, e.g. ``~/.cache/roadtruth`` on Linux). Nothing is
ever written into the working directory. Each kind of entry has a sub-folder: ``designs`` (LMI
designs, :mod:`roadtruth.observers.lmi`), ``stress-cases`` (finished sweep cases, :mod:`roadtruth.harness.jobs.stress`) and
``design-warmups`` (which runs already had their designs solved and kernels compiled,
:mod:`roadtruth.harness.jobs.design_warmup`).

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


__all__ = ["APP_NAME", "CACHE_ENV", "cache_folder", "cache_root", "canonical_json", "entry_digest", "read_entry",
           "write_entry"]
