"""Strict YAML reading: unknown keys rejected, types and ranges checked, errors name file and field.

Every data file of roadtruth (vehicles, scenarios, sensor presets, column maps) is read through
``load_mapping`` and checked with ``Fields``; a bad value raises the given ``InputError`` subclass
with a one-line message ``<file>: <field>: <reason> (got <value>)``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from harness.errors import InputError


def load_mapping(path: str | Path, error: type[InputError] = InputError) -> dict[str, Any]:
    """Read a YAML file whose top level must be a mapping."""
    p = Path(path)
    if not p.is_file():
        raise error("file not found", source=str(p))
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "?"
        raise error(f"malformed YAML at {where}: {getattr(exc, 'problem', exc)}", source=str(p)) from None
    except UnicodeDecodeError:
        raise error("not a UTF-8 text file", source=str(p)) from None
    if not isinstance(data, dict):
        raise error(f"top level must be a mapping, got {type(data).__name__}", source=str(p))
    return data


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
        self.data = dict(data)
        self.source = source
        self.error = error
        self.prefix = prefix
        self._seen: set[str] = set()

    def _name(self, key: str) -> str:
        return f"{self.prefix}.{key}" if self.prefix else key

    def fail(self, key: str, reason: str) -> InputError:
        return self.error(reason, source=self.source, field=self._name(key))

    def has(self, key: str) -> bool:
        return key in self.data

    def raw(self, key: str, default: Any = ...) -> Any:
        self._seen.add(key)
        if key not in self.data:
            if default is ...:
                raise self.fail(key, "required field is missing")
            return default
        return self.data[key]

    def number(self, key: str, default: Any = ..., *, lo: float = -math.inf, hi: float = math.inf,
               lo_open: bool = False, integer: bool = False) -> float:
        v = self.raw(key, default)
        if v is None and default is None:
            return None  # type: ignore[return-value]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.fail(key, f"must be a number (got {v!r})")
        v = float(v)
        if not math.isfinite(v):
            raise self.fail(key, f"must be finite (got {v!r})")
        if integer and v != int(v):
            raise self.fail(key, f"must be a whole number (got {v!r})")
        if v < lo or (lo_open and v <= lo) or v > hi:
            lo_s = f"> {lo:g}" if lo_open else f">= {lo:g}"
            raise self.fail(key, f"must be {lo_s} and <= {hi:g} (got {v:g})")
        return int(v) if integer else v

    def string(self, key: str, default: Any = ..., *, choices: tuple[str, ...] | None = None) -> str:
        v = self.raw(key, default)
        if v is None and default is None:
            return None  # type: ignore[return-value]
        if not isinstance(v, str):
            raise self.fail(key, f"must be a string (got {v!r})")
        if choices is not None and v not in choices:
            raise self.fail(key, f"must be one of {', '.join(choices)} (got {v!r})")
        return v

    def boolean(self, key: str, default: Any = ...) -> bool:
        v = self.raw(key, default)
        if not isinstance(v, bool):
            raise self.fail(key, f"must be true or false (got {v!r})")
        return v

    def sub(self, key: str, default: Any = ...) -> Fields:
        v = self.raw(key, default)
        return Fields(v if v is not None else {}, source=self.source, error=self.error, prefix=self._name(key))

    def items(self, key: str, default: Any = ...) -> list[Any]:
        v = self.raw(key, default)
        if not isinstance(v, list):
            raise self.fail(key, f"must be a list (got {v!r})")
        return v

    def done(self) -> None:
        extra = sorted(set(self.data) - self._seen)
        if extra:
            raise self.error(f"unknown field (known: {', '.join(sorted(self._seen))})", source=self.source,
                             field=self._name(extra[0]))
