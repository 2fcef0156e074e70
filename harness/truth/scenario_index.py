"""The shipped scenario library as a listing (``roadtruth scenarios``), read without building anything.

A listing needs each file's header (name, description, standard, tags, vehicle, duration, initial
speed), not its road, friction map or driver: those are built by ``roadtruth.harness.truth.scenario.load_scenario``,
which imports the compiled (numba) road, friction and tire code and costs about a second before the
first line could be printed. Here only the YAML is read, and the header fields are checked exactly as
``roadtruth.harness.truth.scenario.parse_scenario`` checks them (the same ``Fields`` calls), so the rows are the ones
a full load gives (tests/test_cli.py compares them for every shipped scenario). The rows are
remembered between commands while the files and the code are unchanged (:func:`listing_key`).
"""

from __future__ import annotations

import hashlib
import json
from importlib.resources import files
from pathlib import Path
from typing import Any

from roadtruth.harness.errors import ScenarioError
from roadtruth.harness.files.parsed_files import ParsedFiles

#: Parsed scenario files: a suite reads every header to pick its scenarios by tag, then loads the
#: chosen ones; a sweep loads the same file for every case. Entries are shared: read, never change them.
_MAPPINGS = ParsedFiles()


def scenario_files() -> list[Path]:
    """The shipped scenario files (``harness/scenarios/*.yaml``), sorted by name."""
    folder = Path(str(files("roadtruth.harness") / "scenarios"))
    return sorted(folder.glob("*.yaml"), key=lambda p: p.stem)


def _vehicle(value: str, source: str, base: Path) -> str:
    """The scenario's vehicle reference as ``parse_scenario`` stores it: a set name, or a YAML path
    resolved against the scenario's folder."""
    from roadtruth.harness.truth.vehicle import available_vehicles

    p = Path(value)
    if p.suffix.lower() in (".yaml", ".yml"):
        if not p.is_absolute() and not p.exists():
            p = base / p
        if not p.is_file():
            raise ScenarioError(f"vehicle file not found (got {value!r})", source=source, field="vehicle")
        return str(p)
    if value not in available_vehicles():
        raise ScenarioError(f"unknown vehicle {value!r} (available: {', '.join(available_vehicles())})",
                            source=source, field="vehicle")
    return value


def scenario_mapping(path: Path) -> dict[str, Any]:
    """The top-level YAML mapping of a scenario file, parsed once while the file is unchanged
    (``roadtruth.harness.files.strict_yaml.load_mapping``; raises ``ScenarioError``).

    The same dict is handed to every caller: parsers only read it (``Fields`` copies what it
    checks), and ``load_scenario`` gives each caller its own copy of anything a scenario keeps from it.
    """
    from roadtruth.harness.files.strict_yaml import load_mapping  # YAML only when not remembered

    return _MAPPINGS.get(path, lambda: load_mapping(path, ScenarioError))


def scenario_header(path: Path) -> dict[str, Any]:
    """One listing row of a scenario file: name, description, standard, tags, vehicle,
    duration_s [s], initial_speed_mps [m/s]. Raises ``ScenarioError`` for a bad header field."""
    from roadtruth.harness.files.strict_yaml import Fields, short_repr

    source = str(path)
    f = Fields(scenario_mapping(path), source=source, error=ScenarioError)
    name = f.string("name")
    if name != path.stem:
        raise f.fail("name", f"must equal the file name {path.stem!r} (got {short_repr(name)})")
    description = f.string("description", "")
    standard = f.string("standard", "")
    tags = f.items("tags", [])
    for t in tags:
        if not isinstance(t, str) or not t.strip():
            raise f.fail("tags", f"each tag must be a non-empty string (got {short_repr(t)})")
    vehicle = _vehicle(f.string("vehicle"), source, path.parent)
    duration = f.number("duration_s", lo=0.0, hi=3600.0, lo_open=True)
    v0 = f.number("initial_speed_mps", hi=100.0)
    return {"name": name, "description": description, "standard": standard, "tags": list(tags),
            "vehicle": vehicle, "duration_s": duration, "initial_speed_mps": v0}


CACHE_KIND = "scenario-listing"


def listing_key() -> str:
    """SHA-256 (hex) of what the rows are derived from: the package sources (as for the observer
    listing, ``roadtruth.harness.evaluation.observer_catalog.catalog_key``) and the path, size and modification time of
    every shipped scenario and vehicle file."""
    from roadtruth.harness.evaluation.observer_catalog import catalog_key

    h = hashlib.sha256(catalog_key().encode() + b"\n")
    root = Path(str(files("roadtruth.harness")))
    for folder in ("scenarios", "vehicles"):
        for p in sorted((root / folder).glob("*.y*ml")):
            st = p.stat()
            h.update(f"{folder}/{p.name}\t{st.st_size}\t{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def scenario_summaries() -> list[dict[str, Any]]:
    """One row per shipped scenario for ``roadtruth scenarios [--json]``, in name order.

    Remembered in the cache folder (kind ``scenario-listing``) under :func:`listing_key`: parsing
    the YAML of every file costs a few tenths of a second, and the rows change only with the files.
    """
    from roadtruth.harness.files.disk_cache import cache_folder, read_entry, write_entry

    key, folder = listing_key(), cache_folder(CACHE_KIND)
    hit = read_entry(folder, key)
    if isinstance(hit, dict) and isinstance(hit.get("rows_json"), str):
        return json.loads(hit["rows_json"])  # the text keeps the rows' key order
    rows = [scenario_header(p) for p in scenario_files()]
    write_entry(folder, key, {"rows_json": json.dumps(rows)})
    return rows
