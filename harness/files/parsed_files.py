"""Files parsed once per process and read again only when they change.

A stress sweep or a suite loads the same vehicle set and sensor preset for every case; parsing the
YAML each time was a sixth of a short case. :class:`ParsedFiles` keeps what a parser made of a file
under ``(resolved path, modification time, size)``, so an edited file gives a new key and is read again.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any


class ParsedFiles:
    """What ``parse()`` made of each file, keyed by its path, modification time and size.

    At most ``limit`` entries (all are dropped when full: the working set is a handful of files).
    """

    def __init__(self, limit: int = 64) -> None:
        self._limit = limit
        self._hits: dict[tuple[str, int, int], Any] = {}

    def get(self, path: Path, parse: Callable[[], Any]) -> Any:
        """``parse()``'s result for ``path``, from memory while the file is unchanged; a path that
        cannot be stat'ed is parsed every time (the parser says what is wrong with it)."""
        try:
            st = path.stat()
        except OSError:
            return parse()
        key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
        if key not in self._hits:
            value = parse()
            if len(self._hits) >= self._limit:
                self._hits.clear()
            self._hits[key] = value
        return self._hits[key]
