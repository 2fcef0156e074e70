"""Strict YAML reading: bounded input, unknown keys rejected, types and ranges checked, errors name file and field.

Every data file of roadtruth (vehicles, scenarios, sensor presets, faults, friction maps, column
maps, thresholds) is read through ``load_mapping`` and checked with ``Fields``; a bad value raises
the given ``InputError`` subclass with a one-line message ``<file>: <field>: <reason> (got <value>)``.

``load_mapping`` is the only YAML reader of the package. It bounds what a file can cost before
anything is built from it: at most ``MAX_YAML_BYTES`` of text, ``MAX_YAML_DEPTH`` levels of nesting
and ``MAX_YAML_NODES`` values after expanding aliases (a 600-byte "billion laughs" file of nested
``*alias`` references would otherwise stand for 10^9 strings). Mapping keys must be strings and
may not repeat. Scalars are resolved by the YAML 1.2 core schema, not PyYAML's YAML 1.1 one:
``1e-3`` and ``9.82e2`` are numbers (1.1 reads ``1e-3`` as a string), only ``true``/``false`` are
booleans (not ``yes``/``on``), ``0123`` is decimal, and ``1:20`` or ``2024-05-02`` stay strings.
"""

from __future__ import annotations

import itertools
import math
import re
import reprlib
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from roadtruth.harness.errors import InputError

#: Largest data file read [bytes]; roadtruth's own files are a few kB.
MAX_YAML_BYTES = 1_000_000
#: Deepest nesting of mappings and lists (a scenario needs about 6 levels).
MAX_YAML_DEPTH = 64
#: Most values (scalars, lists, mappings) a file may stand for once every alias is expanded.
MAX_YAML_NODES = 100_000

_short_repr = reprlib.Repr()
_short_repr.maxstring = 60
_short_repr.maxother = 60
_short_repr.maxlist = _short_repr.maxtuple = _short_repr.maxdict = _short_repr.maxset = 6
_short_repr.maxlevel = 3


def short_repr(value: Any) -> str:
    """``repr`` cut to about 80 characters, so that an error message stays one readable line."""
    return _short_repr.repr(value)


class _Refused(yaml.YAMLError):
    """A limit or rule of ``load_mapping`` broken; carries the position like PyYAML's own errors."""

    def __init__(self, problem: str, mark: Any) -> None:
        super().__init__(problem)
        self.problem = problem
        self.problem_mark = mark


class _BoundedRules(yaml.composer.Composer, yaml.constructor.SafeConstructor, yaml.resolver.Resolver):
    """What this module adds to PyYAML's safe loading: the YAML 1.2 core schema, a depth bound and
    string-only, unique keys. Composition and construction are Python; the events come from a
    parser mixed in after it (libyaml's when PyYAML was built with it, else PyYAML's own)."""

    # A fresh resolver table (not SafeLoader's YAML 1.1 one), filled below.
    yaml_implicit_resolvers: dict[str | None, list[tuple[str, re.Pattern[str]]]] = {}

    def _init_rules(self) -> None:
        yaml.composer.Composer.__init__(self)
        yaml.constructor.SafeConstructor.__init__(self)
        yaml.resolver.Resolver.__init__(self)
        self._depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        # The composer recurses once per level: bound it here, long before Python's recursion limit.
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise _Refused(f"nested deeper than {MAX_YAML_DEPTH} levels", self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node: Any, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, yaml.MappingNode):
            self.flatten_mapping(node)  # resolve `<<: *anchor` merges first, as SafeLoader does
        seen: set[str] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if not isinstance(key, str):
                raise _Refused(f"mapping key {short_repr(key)} is not a string (quote it: "
                               f"\"{key_node.value if isinstance(key_node.value, str) else key}\")",
                               key_node.start_mark)
            if key in seen:
                raise _Refused(f"duplicate key {key!r}", key_node.start_mark)
            seen.add(key)
        return yaml.constructor.BaseConstructor.construct_mapping(self, node, deep=deep)

    def construct_yaml_int(self, node: Any) -> int:  # type: ignore[override]
        text = self.construct_scalar(node)
        sign = -1 if text.startswith("-") else 1
        digits = text.lstrip("+-")
        if digits.startswith("0o"):
            return sign * int(digits[2:], 8)
        if digits.startswith("0x"):
            return sign * int(digits[2:], 16)
        return sign * int(digits, 10)  # YAML 1.2: a leading 0 is not octal


class _BoundedLoader(yaml.reader.Reader, yaml.scanner.Scanner, yaml.parser.Parser, _BoundedRules):
    """The rules over PyYAML's pure-Python reader, scanner and parser."""

    def __init__(self, stream: str) -> None:
        yaml.reader.Reader.__init__(self, stream)
        yaml.scanner.Scanner.__init__(self)
        yaml.parser.Parser.__init__(self)
        self._init_rules()


try:
    from yaml._yaml import CParser as _CParser
except ImportError:  # PyYAML built without libyaml: the pure-Python parser alone
    _FastBoundedLoader: type[_BoundedRules] = _BoundedLoader
else:
    class _FastBoundedLoader(_BoundedRules, _CParser):  # type: ignore[no-redef, misc]
        """The rules over libyaml's scanner and parser (C; about five times faster than PyYAML's
        Python one, which is most of a file's cost). The Python composer comes first in the MRO, so
        the depth bound applies to every node (libyaml's C composer is never used)."""

        def __init__(self, stream: str) -> None:
            _CParser.__init__(self, stream)
            self._init_rules()


# YAML 1.2 core schema (https://yaml.org/spec/1.2.2/#1032-tag-resolution), plus `<<` merge keys.
_BoundedRules.add_implicit_resolver(
    "tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"), list("tTfF"))
_BoundedRules.add_implicit_resolver(
    "tag:yaml.org,2002:int", re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$"), list("-+0123456789"))
_BoundedRules.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
               r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"),
    list("-+0123456789."))
_BoundedRules.add_implicit_resolver(
    "tag:yaml.org,2002:null", re.compile(r"^(?:~|null|Null|NULL|)$"), ["~", "n", "N", ""])
_BoundedRules.add_implicit_resolver("tag:yaml.org,2002:merge", re.compile(r"^(?:<<)$"), ["<"])
_BoundedRules.add_constructor("tag:yaml.org,2002:int", _BoundedRules.construct_yaml_int)


def _expanded_size(root: yaml.Node) -> int:
    """Number of values ``root`` stands for with every alias expanded (stops above the bound).

    Aliases make the node graph a DAG (or, for ``&a [*a]``, a cycle): sizes are memoised per node,
    so the count costs one visit per distinct node however large the expansion.
    """
    sizes: dict[int, int] = {}
    active: set[int] = set()

    def size(node: yaml.Node) -> int:
        key = id(node)
        if key in sizes:
            return sizes[key]
        if key in active:
            raise _Refused("an alias refers to the collection that contains it (infinite expansion)",
                           node.start_mark)
        active.add(key)
        total = 1
        if isinstance(node, yaml.SequenceNode):
            total += sum(size(child) for child in node.value)
        elif isinstance(node, yaml.MappingNode):
            total += sum(size(k) + size(v) for k, v in node.value)
        active.discard(key)
        if total > MAX_YAML_NODES:
            raise _Refused(f"expands to more than {MAX_YAML_NODES:,} values (aliases repeated too often)",
                           node.start_mark)
        sizes[key] = total
        return total

    return size(root)


def parse_yaml(text: str, *, pure_python: bool = False) -> Any:
    """Parse YAML text with the bounds and schema of this module (raises ``yaml.YAMLError``).

    libyaml scans and parses when PyYAML has it; ``pure_python`` forces PyYAML's own parser
    (the two give the same values; tests compare them).
    """
    loader = (_BoundedLoader if pure_python else _FastBoundedLoader)(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _expanded_size(node)
        return loader.construct_document(node)
    except yaml.MarkedYAMLError as exc:
        # libyaml's scanner looks ahead through flow collections and stops at its own depth limit
        # (1000 levels) before the composer reaches this module's: the same refusal, in our words.
        if "maximum nesting depth" in str(exc.problem):
            raise _Refused(f"nested deeper than {MAX_YAML_DEPTH} levels", exc.problem_mark) from None
        raise
    finally:
        loader.dispose()


def load_mapping(path: str | Path, error: type[InputError] = InputError) -> dict[str, Any]:
    """Read a YAML file whose top level must be a mapping (bounded as the module doc says)."""
    p = Path(path)
    if not p.is_file():
        raise error("file not found", source=str(p))
    try:
        with p.open("rb") as fh:
            raw = fh.read(MAX_YAML_BYTES + 1)
    except OSError as exc:
        raise error(f"unreadable ({exc.strerror or type(exc).__name__})", source=str(p)) from None
    if len(raw) > MAX_YAML_BYTES:
        raise error(f"larger than {MAX_YAML_BYTES:,} bytes: not a roadtruth data file", source=str(p))
    try:
        data = parse_yaml(raw.decode("utf-8"))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "?"
        problem = str(getattr(exc, "problem", None) or exc).splitlines()[0]
        what = where if isinstance(exc, _Refused) else f"malformed YAML at {where}"
        raise error(f"{what}: {problem}", source=str(p)) from None
    except UnicodeDecodeError:
        raise error("not a UTF-8 text file", source=str(p)) from None
    if not isinstance(data, dict):
        raise error(f"top level must be a mapping, got {type(data).__name__}", source=str(p))
    return data


@dataclass(frozen=True)
class FieldRead:
    """One field a parser asked ``Fields`` for: what it accepts (the source of the JSON Schemas).

    ``kind`` is ``mapping`` (a ``Fields`` opened at ``path``; ``key`` empty), ``closed`` (its
    ``done()``: no other keys), ``any``, ``has``, ``number``, ``string``, ``boolean``, ``items``.
    ``path`` is the prefix with list indices written ``[]`` (``road.segments[].arc``).
    """

    source: str
    path: str
    key: str
    kind: str
    required: bool = False
    nullable: bool = False
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    integer: bool = False
    choices: tuple[str, ...] | None = None
    value: Any = None
    owner: int = 0  # number of the Fields object: tells one reading of a mapping from another


@dataclass
class FieldTrace:
    """Every :class:`FieldRead` made while :func:`trace_fields` is active."""

    reads: list[FieldRead] = field(default_factory=list)


_trace: ContextVar[FieldTrace | None] = ContextVar("roadtruth_field_trace", default=None)
_OWNER_IDS = itertools.count(1)  # one number per Fields object read while tracing (ids are reused)
_INDEX = re.compile(r"\[[^\]]*\]")


@contextmanager
def trace_fields() -> Iterator[FieldTrace]:
    """Record what every ``Fields`` is asked while the block runs (``roadtruth.harness.files.config_schema`` builds
    the published JSON Schemas from it, so that the schema is what the parser reads)."""
    trace = FieldTrace()
    token = _trace.set(trace)
    try:
        yield trace
    finally:
        _trace.reset(token)


def tracing() -> bool:
    """True inside :func:`trace_fields`: a parser must then read its file again rather than hand out
    what it remembered (the trace is made of the ``Fields`` calls of the reading)."""
    return _trace.get() is not None


class Fields:
    """Checked access to one mapping of a data file.

    >>> f = Fields({"mass_kg": 1500}, source="sedan.yaml", error=InputError)
    >>> f.number("mass_kg", lo=1.0, hi=1e5)
    1500.0
    >>> f.done()   # raises on keys nobody asked for
    """

    def __init__(self, data: Mapping[str, Any], *, source: str, error: type[InputError] = InputError,
                 prefix: str = "") -> None:
        if not isinstance(data, Mapping):
            raise error(f"must be a mapping, got {type(data).__name__}", source=source, field=prefix or None)
        for key in data:
            if not isinstance(key, str):  # a mapping built in code, not read by load_mapping
                raise error(f"mapping key {short_repr(key)} is not a string", source=source,
                            field=prefix or None)
        self.data = dict(data)
        self.source = source
        self.error = error
        self.prefix = prefix
        self._seen: set[str] = set()
        self._owner = next(_OWNER_IDS) if _trace.get() is not None else 0
        self._note("", "mapping")

    def _note(self, key: str, kind: str, default: Any = ..., **spec: Any) -> None:
        trace = _trace.get()
        if trace is not None:
            trace.reads.append(FieldRead(self.source, _INDEX.sub("[]", self.prefix), key, kind,
                                         required=default is ..., nullable=default is None, owner=self._owner,
                                         **spec))

    def _name(self, key: str) -> str:
        return f"{self.prefix}.{key}" if self.prefix else key

    def fail(self, key: str, reason: str) -> InputError:
        return self.error(reason, source=self.source, field=self._name(key))

    def has(self, key: str) -> bool:
        self._note(key, "has", None)
        return key in self.data

    def raw(self, key: str, default: Any = ...) -> Any:
        self._note(key, "any", default)
        self._seen.add(key)
        if key not in self.data:
            if default is ...:
                raise self.fail(key, "required field is missing")
            return default
        return self.data[key]

    def number(self, key: str, default: Any = ..., *, lo: float = -math.inf, hi: float = math.inf,
               lo_open: bool = False, integer: bool = False) -> float:
        self._note(key, "number", default, lo=lo, hi=hi, lo_open=lo_open, integer=integer)
        v = self.raw(key, default)
        if v is None and default is None:
            return None  # type: ignore[return-value]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.fail(key, f"must be a number (got {short_repr(v)})")
        v = float(v)
        if not math.isfinite(v):
            raise self.fail(key, f"must be finite (got {short_repr(v)})")
        if integer and v != int(v):
            raise self.fail(key, f"must be a whole number (got {short_repr(v)})")
        if v < lo or (lo_open and v <= lo) or v > hi:
            lo_s = f"> {lo:g}" if lo_open else f">= {lo:g}"
            raise self.fail(key, f"must be {lo_s} and <= {hi:g} (got {v:g})")
        return int(v) if integer else v

    def string(self, key: str, default: Any = ..., *, choices: tuple[str, ...] | None = None) -> str:
        self._note(key, "string", default, choices=tuple(choices) if choices is not None else None,
                   value=self.data.get(key))
        v = self.raw(key, default)
        if v is None and default is None:
            return None  # type: ignore[return-value]
        if not isinstance(v, str):
            raise self.fail(key, f"must be a string (got {short_repr(v)})")
        if choices is not None and v not in choices:
            raise self.fail(key, f"must be one of {', '.join(choices)} (got {short_repr(v)})")
        return v

    def boolean(self, key: str, default: Any = ...) -> bool:
        self._note(key, "boolean", default)
        v = self.raw(key, default)
        if not isinstance(v, bool):
            raise self.fail(key, f"must be true or false (got {short_repr(v)})")
        return v

    def sub(self, key: str, default: Any = ...) -> Fields:
        v = self.raw(key, default)
        return Fields(v if v is not None else {}, source=self.source, error=self.error, prefix=self._name(key))

    def items(self, key: str, default: Any = ...) -> list[Any]:
        self._note(key, "items", default)
        v = self.raw(key, default)
        if not isinstance(v, list):
            raise self.fail(key, f"must be a list (got {short_repr(v)})")
        return v

    def done(self) -> None:
        self._note("", "closed")
        extra = sorted(set(self.data) - self._seen)
        if extra:
            raise self.error(f"unknown field (known: {', '.join(sorted(self._seen))})", source=self.source,
                             field=self._name(extra[0]))
