"""Files parsed once per process and read again only when they change.

A stress sweep or a suite loads the same scenario, vehicle set and sensor preset for every case;
parsing the YAML each time was a sixth of a short case. :class:`ParsedFiles` keeps what a parser
made of a file under ``(resolved path, modification time, size)`` (plus a ``variant`` for whatever
else the parse depends on), so an edited file gives a new key and is read again.

A file's modification time has the resolution of the kernel's clock tick (a few milliseconds), so
two writes of the same size within one tick leave the same key. An entry stored while its file was
that young ("racily clean", as git calls it) also keeps the digest of the file's bytes, and every
hit compares them until the file has aged past :data:`RACY_WINDOW_NS`.

What is handed out is shared by every caller: parsers whose results callers might change must
return frozen objects, or the caller copies (``roadtruth.harness.sensors.config`` deep-copies its
mappings; ``roadtruth.harness.truth.scenario`` hands out a scenario with its own overrides dict).
"""

from __future__ import annotations

import hashlib
import sys
import time
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

#: A file modified less than this before it was parsed is checked by content on every hit [ns]
#: (mtime ticks are 1-10 ms on Linux; network file systems can lag by about a second).
RACY_WINDOW_NS = 2_000_000_000


def _digest(path: Path) -> bytes | None:
    """BLAKE2b of the file's bytes, or None when it cannot be read (the parser will say why)."""
    try:
        return hashlib.blake2b(path.read_bytes(), digest_size=16).digest()
    except OSError:
        return None


def _tracing() -> bool:
    """``strict_yaml.tracing()``, without importing it (and YAML) here: ``roadtruth scenarios`` uses
    this cache and reads no YAML; with the module not imported, no trace can be running."""
    module = sys.modules.get("roadtruth.harness.files.strict_yaml")
    return module is not None and module.tracing()


class ParsedFiles:
    """What ``parse()`` made of each file, keyed by its path, modification time, size and a variant.

    At most ``limit`` entries (all are dropped when full: the working set is a handful of files).
    """

    def __init__(self, limit: int = 64) -> None:
        self._limit = limit
        # key -> (value, digest of the bytes while the file is racily young, else None)
        self._hits: dict[tuple[Any, ...], tuple[Any, bytes | None]] = {}

    def get(self, path: Path, parse: Callable[[], Any], variant: Hashable = None) -> Any:
        """``parse()``'s result for ``path``, from memory while the file is unchanged; a path that
        cannot be stat'ed is parsed every time (the parser says what is wrong with it).

        ``variant`` names anything besides the file's bytes that the result depends on (for
        a scenario: how its path was spelled and the working folder its relative paths are
        resolved in); results for different variants are kept apart. While a JSON Schema is traced
        from the parsers' field reads (``strict_yaml.tracing``), every call parses.
        """
        if _tracing():  # the published schemas are traced from a reading: read, do not remember
            return parse()
        try:
            st = path.stat()
        except OSError:
            return parse()
        key = (str(path.resolve()), st.st_mtime_ns, st.st_size, variant)
        young = time.time_ns() - st.st_mtime_ns < RACY_WINDOW_NS
        hit = self._hits.get(key)
        if hit is not None:
            value, digest = hit
            if digest is None:
                return value
            now_digest = _digest(path)
            if now_digest == digest:
                if not young:  # aged past the window: the stat key alone is trustworthy from now on
                    self._hits[key] = (value, None)
                return value
        digest = _digest(path) if young else None  # read before parsing: a later write shows as a change
        value = parse()
        if len(self._hits) >= self._limit:
            self._hits.clear()
        self._hits[key] = (value, digest)
        return value

    def clear(self) -> None:
        """Forget every entry (tests; a long-lived process that wants to re-read everything)."""
        self._hits.clear()
