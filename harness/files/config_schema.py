"""JSON Schemas of roadtruth's YAML formats, generated from the parsers themselves.

There is one definition per format: the parse function that reads it. Each field a parser reads goes
through ``roadtruth.harness.files.strict_yaml.Fields`` (``number(lo, hi)``, ``string(choices)``, ``boolean``,
``sub``, ``items``, ``done``); :func:`roadtruth.harness.files.strict_yaml.trace_fields` records those reads while the
parser runs over the shipped files of the format, and this module turns the record into a JSON
Schema (draft 2020-12). A field added to a parser, a new range or a new choice is in the schema as
soon as a shipped file exercises it; the schema and the parser cannot drift apart.

What the record cannot know stays open rather than wrong: a mapping whose discriminating choice
(``type: …``) has values that no shipped file uses accepts any further key (the parser still checks
them), and a field that the parser reads without a type (``raw``) accepts any value. Cross-field rules
(``name`` equals the file name, strictly increasing points) are the parser's alone.

Two formats are not read through ``Fields``: replay vehicles (``roadtruth.harness.truth.vehicle_replay``'s field
tables) and observer options (each registered observer's ``default_options``); their schemas are
built from those tables.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable
from importlib.resources import files
from pathlib import Path
from typing import Any

from roadtruth.harness.errors import InputError
from roadtruth.harness.files.outdir import OutputPathError, check_writable, write_atomic
from roadtruth.harness.files.strict_yaml import FieldRead, trace_fields

#: ``$schema`` of every generated schema.
DIALECT = "https://json-schema.org/draft/2020-12/schema"
#: Prefix of the ``$id`` of every generated schema (also how ``--out`` recognises a file it wrote).
ID_PREFIX = "https://roadtruth.dev/schema/"


class SchemaFormatError(InputError):
    """An unknown format name given to ``roadtruth schema``."""


def _harness_dir(*parts: str) -> Path:
    return Path(str(files("roadtruth.harness"))).joinpath(*parts)


def _scenario_files() -> list[Path]:
    return sorted(_harness_dir("scenarios").glob("*.yaml"))


def _vehicle_files() -> list[Path]:
    shipped = sorted(_harness_dir("vehicles").glob("*.yaml"))
    examples = Path(__file__).resolve().parents[2] / "examples" / "vehicles"
    return shipped + (sorted(examples.glob("*.yaml")) if examples.is_dir() else [])


def _read_scenario(p: Path) -> None:
    from roadtruth.harness.truth.scenario import load_scenario

    load_scenario(p)


def _read_vehicle(p: Path) -> None:
    from roadtruth.harness.truth.vehicle import load_vehicle

    load_vehicle(p)


def _read_sensors(p: Path) -> None:
    from roadtruth.harness.sensors.config import load_sensor_config

    load_sensor_config(p)


def _read_column_map(p: Path) -> None:
    from roadtruth.harness.jobs.replay_column_map import load_column_map

    load_column_map(p)


def _read_thresholds(p: Path) -> None:
    from roadtruth.harness.jobs.check_rules import load_thresholds

    load_thresholds(p)


def _read_faults(p: Path) -> None:
    from roadtruth.harness.sensors.faults import parse_faults

    parse_faults(str(p))


def _read_space(p: Path) -> None:
    from roadtruth.harness.jobs.falsify_space import load_space

    load_space(p)


#: Traced formats: (title, files that exercise the parser, parse one file, every mapping is closed).
#: ``closed`` is True for the vehicle format, whose parser collects unknown keys itself.
_TRACED: dict[str, tuple[str, Callable[[], list[Path]], Callable[[Path], None], bool]] = {
    "scenario": ("roadtruth scenario", _scenario_files, _read_scenario, False),
    "vehicle": ("roadtruth vehicle parameter set", lambda: [p for p in _vehicle_files() if not _is_replay(p)],
                _read_vehicle, True),
    "sensors": ("roadtruth sensor suite preset", lambda: sorted(_harness_dir("sensors", "presets").glob("*.yaml")),
                _read_sensors, False),
    "faults": ("roadtruth sensor faults file", lambda: [_harness_dir("schema_examples", "faults.yaml")],
               _read_faults, False),
    "column_map": ("roadtruth replay column map", lambda: sorted(_harness_dir("replay_maps").glob("*.yaml")),
                   _read_column_map, False),
    "thresholds": ("roadtruth check thresholds", lambda: sorted(_harness_dir("thresholds").glob("*.yaml")),
                   _read_thresholds, False),
    "falsify_space": ("roadtruth falsify search space",
                      lambda: [_harness_dir("schema_examples", "falsify_space.yaml")], _read_space, False),
}

#: Every format of ``roadtruth schema``.
FORMATS: tuple[str, ...] = ("scenario", "vehicle", "replay_vehicle", "sensors", "faults", "column_map",
                            "thresholds", "falsify_space", "observer_options")


def _is_replay(p: Path) -> bool:
    from roadtruth.harness.files.strict_yaml import load_mapping

    return load_mapping(p).get("kind") == "replay"


def shipped_files(fmt: str) -> list[Path]:
    """The files of format ``fmt`` that roadtruth ships (each must validate against its schema)."""
    if fmt == "replay_vehicle":
        return [p for p in _vehicle_files() if _is_replay(p)]
    if fmt == "observer_options":
        return []
    return _TRACED[fmt][1]()


# ---- from the record of field reads to a schema -------------------------------------------------

def _parts(path: str) -> tuple[str, ...]:
    parts: list[str] = []
    for piece in path.split(".") if path else []:
        name, _, rest = piece.partition("[]")
        if name:
            parts.append(name)
        parts.extend(["[]"] * (piece.count("[]")))
        del rest
    return tuple(parts)


class _Node:
    """One mapping (or list) position of a format, with the reads made there."""

    def __init__(self) -> None:
        self.children: dict[str, _Node] = {}
        self.reads: dict[str, list[FieldRead]] = {}
        self.mapping = False
        self.closed = False
        self.owners: set[int] = set()  # the Fields objects opened here (each reading of this mapping)

    def at(self, parts: Iterable[str]) -> _Node:
        node = self
        for p in parts:
            node = node.children.setdefault(p, _Node())
        return node


def _tree(reads: list[FieldRead]) -> _Node:
    root = _Node()
    for r in reads:
        node = root.at(_parts(r.path))
        if r.kind == "mapping":
            node.mapping = True
            node.owners.add(r.owner)
        elif r.kind == "closed":
            node.closed = True
        else:
            node.reads.setdefault(r.key, []).append(r)
    return root


def _scalar(reads: list[FieldRead]) -> dict[str, Any] | None:
    """Schema of one key's value from its typed reads (None if only untyped reads)."""
    kinds = {r.kind for r in reads} - {"any", "has"}
    if not kinds:
        return None
    variants: list[dict[str, Any]] = []
    if "number" in kinds:
        nums = [r for r in reads if r.kind == "number"]
        integer = all(r.integer for r in nums)
        lo = min(r.lo for r in nums)
        hi = max(r.hi for r in nums)
        s: dict[str, Any] = {"type": "integer" if integer else "number"}
        if math.isfinite(lo):
            open_lo = all(r.lo_open for r in nums if r.lo == lo)
            s["exclusiveMinimum" if open_lo else "minimum"] = lo
        if math.isfinite(hi):
            s["maximum"] = hi
        variants.append(s)
    if "string" in kinds:
        strs = [r for r in reads if r.kind == "string"]
        s = {"type": "string"}
        if all(r.choices is not None for r in strs):
            s["enum"] = sorted({c for r in strs for c in r.choices or ()})
        variants.append(s)
    if "boolean" in kinds:
        variants.append({"type": "boolean"})
    if "items" in kinds:
        variants.append({"type": "array"})
    if any(r.nullable for r in reads if r.kind not in ("any", "has")):
        variants.append({"type": "null"})
    return variants[0] if len(variants) == 1 else {"anyOf": variants}


def _unexercised_choice(node: _Node) -> bool:
    """A discriminating string field here has a choice no shipped file uses (its branch is unseen)."""
    for reads in node.reads.values():
        for r in reads:
            if r.kind == "string" and r.choices and r.key in ("type", "kind", "fault", "model"):
                seen = {x.value for x in reads if x.kind == "string"}
                if set(r.choices) - seen:
                    return True
    return False


def _node_schema(node: _Node, closed_always: bool) -> dict[str, Any]:
    if "[]" in node.children and not node.mapping:
        return {"type": "array", "items": _node_schema(node.children["[]"], closed_always)}
    if not node.mapping and not node.children and not node.reads:
        return {}
    props: dict[str, Any] = {}
    required: list[str] = []
    for key in sorted(set(node.reads) | set(node.children)):
        reads = node.reads.get(key, [])
        child = node.children.get(key)
        if child is not None:
            sub = _node_schema(child, closed_always)
            typed = _scalar(reads)
            if typed is not None and typed.get("type") == "array" and "[]" in child.children:
                sub = {"type": "array", "items": _node_schema(child.children["[]"], closed_always)}
            elif any(r.nullable for r in reads):
                sub = {"anyOf": [sub, {"type": "null"}]}
        else:
            sub = _scalar(reads) or {}
        props[key] = sub
        # Required only if every reading of this mapping asked for it, each time without a default.
        # (A key the parser first tests with ``has`` is read only when present: optional.)
        typed = [r for r in reads if r.kind != "has"]
        conditional = any(r.kind == "has" for r in reads)
        if (node.owners and typed and not conditional and all(r.required for r in typed)
                and {r.owner for r in typed} >= node.owners):
            required.append(key)
    s: dict[str, Any] = {"type": "object", "properties": props}
    if required:
        s["required"] = required
    if (node.closed or closed_always) and not _unexercised_choice(node):
        s["additionalProperties"] = False
    return s


def _traced_schema(fmt: str) -> dict[str, Any]:
    title, paths, read, closed_always = _TRACED[fmt]
    reads: list[FieldRead] = []
    for p in paths():
        with trace_fields() as trace:
            read(p)
        reads.extend(r for r in trace.reads if r.source == str(p))
    tree = _tree(reads)
    _add_fault_item_keys(tree, top_level=fmt == "faults")
    return {**_node_schema(tree, closed_always), "title": title}


def _add_fault_item_keys(node: _Node, *, top_level: bool) -> None:
    """Fault items: ``parse_fault_list`` takes ``sensor``, ``fault`` and ``channel`` off the mapping
    before its parameters go through ``Fields``; they are added here from the parser's own tables."""
    from roadtruth.harness.sensors.catalog import SENSORS
    from roadtruth.harness.sensors.faults import FAULT_KINDS

    for key, child in node.children.items():
        item = child.children.get("[]")
        if key == "faults" and item is not None:
            for o in item.owners or {0}:
                item.reads.setdefault("fault", []).append(
                    FieldRead("", "", "fault", "string", required=True, choices=tuple(FAULT_KINDS), owner=o))
                item.reads.setdefault("channel", []).append(FieldRead("", "", "channel", "string", owner=o))
                if top_level:
                    item.reads.setdefault("sensor", []).append(
                        FieldRead("", "", "sensor", "string", required=True, choices=tuple(SENSORS), owner=o))
        _add_fault_item_keys(child, top_level=top_level)


def _replay_vehicle_schema() -> dict[str, Any]:
    from roadtruth.harness.truth.vehicle_replay import REPLAY_OPTIONAL, REPLAY_REQUIRED, TIRE_SHAPE

    positive = {"type": "number", "exclusiveMinimum": 0}
    props: dict[str, Any] = {k: dict(positive) for k in REPLAY_REQUIRED + REPLAY_OPTIONAL}
    props["name"] = {"type": "string", "minLength": 1}
    props["kind"] = {"const": "replay"}
    props["description"] = props["source"] = {"type": "string"}
    props["tire_shape"] = {"type": "object", "additionalProperties": False,
                           "properties": {k: {"type": "number"} for k in TIRE_SHAPE if k in ("Cy", "Ey")}}
    return {"title": "roadtruth replay vehicle", "type": "object", "properties": props,
            "required": ["kind", *REPLAY_REQUIRED], "additionalProperties": False}


def _observer_options_schema() -> dict[str, Any]:
    from roadtruth.observers.registry import available_observers, observer_class

    def value_schema(default: Any) -> dict[str, Any]:
        if isinstance(default, bool):
            return {"type": "boolean"}
        if isinstance(default, int | float):
            return {"type": "number"}
        if isinstance(default, str):
            return {"type": "string"}
        if isinstance(default, list | tuple):
            return {"type": "array"}
        return {}

    props = {}
    for name in available_observers():
        opts = dict(getattr(observer_class(name), "default_options", {}) or {})
        props[name] = {"type": ["object", "null"], "additionalProperties": False,
                       "properties": {k: value_schema(v) for k, v in sorted(opts.items())}}
    return {"title": "roadtruth observer options (observer -> {option: value})", "type": "object",
            "properties": props, "additionalProperties": False}


def schema(fmt: str) -> dict[str, Any]:
    """The JSON Schema (a dict) of format ``fmt`` (one of :data:`FORMATS`)."""
    if fmt not in FORMATS:
        raise SchemaFormatError(f"unknown format {fmt!r} (known: {', '.join(FORMATS)})", field="FORMAT")
    if fmt == "replay_vehicle":
        body = _replay_vehicle_schema()
    elif fmt == "observer_options":
        body = _observer_options_schema()
    else:
        body = _traced_schema(fmt)
    return {"$schema": DIALECT, "$id": f"{ID_PREFIX}{fmt}.json", **body}


def schema_text(fmt: str) -> str:
    """The schema as indented JSON text with a final newline (same input, same bytes)."""
    return json.dumps(schema(fmt), indent=2, sort_keys=True) + "\n"


def write_schema(fmt: str, out: Path) -> None:
    """Write the schema to ``out``: a new file, or one this command wrote before (never another file)."""
    check_writable(out, what="--out", folder=False)
    if out.exists():
        try:
            previous = json.loads(out.read_text(encoding="utf-8"))
            ours = isinstance(previous, dict) and str(previous.get("$id", "")).startswith(ID_PREFIX)
        except (OSError, UnicodeDecodeError, ValueError):
            ours = False
        if not ours:
            raise OutputPathError(f"--out {out} exists and is not a schema roadtruth wrote; choose a new file")
    write_atomic(out, schema_text(fmt))
