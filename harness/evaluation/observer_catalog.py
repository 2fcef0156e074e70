"""The list of observers for ``roadtruth observers``, remembered between commands.

Listing the observers means importing every observer module (``roadtruth.observers.registry.observer_info``),
and with them numba, cvxpy and the compiled loops: seconds, for a few lines of text. The rows only
change when code changes, so they are kept in the cache folder (``roadtruth.harness.files.disk_cache``, kind
``observer-catalog``) under a key made of everything they are derived from: the roadtruth version,
the Python version, and the path, size and modification time of every ``.py`` file of the
``roadtruth.harness`` and ``roadtruth.observers`` packages. Editing, adding or removing any of them gives a new key.

Not cached: a listing with observer plug-ins (entry points of ``roadtruth.observers``: their code
lives elsewhere and is not in the key) or with observers a script registered in its own process, and
a listing during which a module failed to import (its warning must be shown again next time). A cache that cannot be read or written only costs the import.
"""

from __future__ import annotations

import hashlib
import json
import sys
import warnings
from importlib.util import find_spec
from pathlib import Path
from typing import Any

CACHE_KIND = "observer-catalog"
PACKAGES = ("roadtruth.harness", "roadtruth.observers")


def _package_dir(name: str) -> Path:
    spec = find_spec(name)  # finds the package without importing it
    if spec is None or not spec.submodule_search_locations:
        raise ModuleNotFoundError(name)
    return Path(next(iter(spec.submodule_search_locations)))


def catalog_key() -> str:
    """SHA-256 (hex) of what the observer rows are derived from (module doc)."""
    from roadtruth.harness import __version__
    h = hashlib.sha256(f"{__version__}\n{sys.version}\n".encode())
    for pkg in PACKAGES:
        root = _package_dir(pkg)
        for p in sorted(root.rglob("*.py")):
            st = p.stat()
            h.update(f"{pkg}/{p.relative_to(root).as_posix()}\t{st.st_size}\t{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def _has_plugins() -> bool:
    from importlib.metadata import entry_points

    from roadtruth.observers.registry import ENTRY_POINT_GROUP

    return len(entry_points(group=ENTRY_POINT_GROUP)) > 0


def _only_packaged_observers() -> bool:
    """True if every registered observer comes from the package's own modules (a class a script or
    test registered in this process is not in the key, so a listing holding it is not remembered)."""
    from roadtruth.observers.registry import available_observers, observer_class

    return all(observer_class(n).__module__.startswith("roadtruth.observers.") for n in available_observers())


def observer_rows() -> list[dict[str, Any]]:
    """``roadtruth.observers.registry.observer_info()``, from the cache when the code is unchanged."""
    from roadtruth.harness.files.disk_cache import cache_folder, read_entry, write_entry

    if _has_plugins():
        from roadtruth.observers.registry import observer_info

        return observer_info()
    key, folder = catalog_key(), cache_folder(CACHE_KIND)
    hit = read_entry(folder, key)
    if isinstance(hit, dict) and isinstance(hit.get("rows_json"), str):
        return json.loads(hit["rows_json"])  # the text keeps the rows' key order
    from roadtruth.observers.registry import observer_info

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rows = observer_info()
    for w in caught:  # shown as they would have been, and nothing is remembered
        warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    if not caught and _only_packaged_observers():
        write_entry(folder, key, {"rows_json": json.dumps(rows, default=str)})
    return json.loads(json.dumps(rows, default=str))
