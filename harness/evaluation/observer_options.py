"""Observer options from the command line and the library call, checked before any work.

An observer class declares the options it accepts and their defaults (``default_options``,
``observers/base.py``). Users set them per observer:

* a YAML file (``--observer-options FILE.yaml``), one mapping per observer::

      kf_bicycle:
        meas_std_ay_mps2: 1.5
        process_std_vy_mps2: 0.8
      ekf_bicycle: {mu: 0.9}

* the short form ``-O observer.option=value`` (repeatable; it overrides the file), the value read
  as a YAML 1.2 scalar or flow list (``1e-3`` is a number, ``true`` a boolean, ``[0, 0, 1]`` a list,
  ``null`` none) by :func:`roadtruth.harness.files.strict_yaml.parse_yaml`;
* the Python API: ``observer_options={"kf_bicycle": {"meas_std_ay_mps2": 1.5}}`` of ``run_suite``,
  ``run_check``, ``run_stress`` and ``replay``.

:func:`check_observer_options` validates them against the observers being run: an unknown observer,
an observer that is not being run, an unknown option or a value whose type differs from the
default's raises :class:`ObserverOptionsError` (one line, exit 2). A float option takes any finite
or infinite number (``.inf`` switches a gate off), an integer option an integer, a boolean only
``true``/``false``, a text option text, a list option a list of the same length (numbers where the
default has numbers), an option whose default is ``null`` a number or ``null``. The checked options are
recorded in ``run.json`` (``observer_options``) and are part of a stress case's cache key.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from roadtruth.harness.errors import InputError

ObserverOptions = dict[str, dict[str, Any]]


class ObserverOptionsError(InputError):
    """An observer option (file, ``-O`` or API mapping) names an unknown observer or option, or has a
    value of the wrong type."""


def parse_assignment(text: str) -> tuple[str, str, Any]:
    """``observer.option=value`` → (observer, option, value); the value is a YAML 1.2 scalar or flow list."""
    from roadtruth.harness.files.strict_yaml import parse_yaml

    head, sep, raw = str(text).partition("=")
    obs, dot, opt = head.strip().partition(".")
    if not sep or not dot or not obs or not opt.strip() or not raw.strip():
        raise ObserverOptionsError(f"expected observer.option=value (got {text!r})", field="-O")
    try:
        value = parse_yaml(raw.strip())
    except yaml.YAMLError as e:
        problem = str(getattr(e, "problem", None) or e).splitlines()[0]
        raise ObserverOptionsError(f"value of {head.strip()} is not a YAML value ({problem})", field="-O") from None
    if isinstance(value, Mapping):
        raise ObserverOptionsError(f"value of {head.strip()} must be a number, text, true/false, null or a list "
                                   f"(got a mapping)", field="-O")
    return obs, opt.strip(), value


def parse_assignments(items: Iterable[str]) -> ObserverOptions:
    """Every ``-O observer.option=value`` as ``{observer: {option: value}}`` (a later one wins)."""
    out: ObserverOptions = {}
    for item in items:
        obs, opt, value = parse_assignment(item)
        out.setdefault(obs, {})[opt] = value
    return out


def load_options_file(path: str | Path) -> ObserverOptions:
    """``--observer-options FILE.yaml``: a mapping observer -> {option: value} (strict YAML reading)."""
    from roadtruth.harness.files.strict_yaml import load_mapping

    data = load_mapping(path, error=ObserverOptionsError)
    out: ObserverOptions = {}
    for obs, opts in data.items():
        if opts is None:
            opts = {}
        if not isinstance(opts, Mapping):
            raise ObserverOptionsError(f"must map option names to values (got {type(opts).__name__})",
                                       source=str(path), field=str(obs))
        out[str(obs)] = {str(k): v for k, v in opts.items()}
    return out


def merge_options(*layers: Mapping[str, Mapping[str, Any]] | None) -> ObserverOptions:
    """Later layers override earlier ones option by option (file, then ``-O``)."""
    out: ObserverOptions = {}
    for layer in layers:
        for obs, opts in (layer or {}).items():
            out.setdefault(str(obs), {}).update(dict(opts))
    return out


def options_from_cli(file: str | None, assignments: Sequence[str] | None) -> ObserverOptions:
    """The options of ``--observer-options FILE`` and ``-O`` together (``-O`` wins), not yet checked."""
    return merge_options(load_options_file(file) if file else None, parse_assignments(assignments or ()))


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _checked_value(obs: str, opt: str, default: Any, value: Any) -> Any:
    """``value`` converted to the default's type, or ``ObserverOptionsError``."""
    where = f"{obs}.{opt}"

    def bad(expected: str) -> ObserverOptionsError:
        from roadtruth.harness.files.strict_yaml import short_repr

        return ObserverOptionsError(f"must be {expected} (got {short_repr(value)})", field=where)

    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if isinstance(default, int):
        if not (isinstance(value, int) and not isinstance(value, bool)):
            raise bad("a whole number")
        return value
    if isinstance(default, float) or default is None:
        if default is None and value is None:
            return None
        if not _is_number(value) or math.isnan(value):
            raise bad("a number" + (" or null" if default is None else ""))
        return float(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise bad("text")
        return value
    if isinstance(default, tuple | list):
        if not isinstance(value, list | tuple) or len(value) != len(default):
            raise bad(f"a list of {len(default)} value(s)")
        items = [_checked_value(obs, f"{opt}[{i}]", d, v) for i, (d, v) in enumerate(zip(default, value, strict=True))]
        return tuple(items) if isinstance(default, tuple) else items
    if isinstance(default, Mapping):
        if not isinstance(value, Mapping):
            raise bad("a mapping")
        return dict(value)
    return value  # an option type this check does not know: the observer's own constructor checks it


def check_observer_options(options: Mapping[str, Mapping[str, Any]] | None, observers: Sequence[str],
                           vehicle: Any = None) -> ObserverOptions:
    """Validate ``options`` for a run of ``observers``; returns them with values in the defaults' types.

    Raises :class:`ObserverOptionsError` for an observer that is unknown or not being run, an option
    it does not declare, a value of the wrong type, and (when ``vehicle`` is given) any value the
    observer's own constructor refuses.
    """
    from roadtruth.observers.registry import available_observers, observer_class

    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise ObserverOptionsError(f"must map observer names to options (got {type(options).__name__})",
                                   field="observer_options")
    known = available_observers()
    out: ObserverOptions = {}
    for obs, opts in options.items():
        obs = str(obs)
        if obs not in known:
            raise ObserverOptionsError(f"unknown observer {obs!r} (available: {', '.join(known)})",
                                       field="observer options")
        if obs not in observers:
            raise ObserverOptionsError(f"options given for observer {obs!r}, which is not being run",
                                       field="observer options")
        if not isinstance(opts, Mapping):
            raise ObserverOptionsError(f"must map option names to values (got {type(opts).__name__})", field=obs)
        defaults = observer_class(obs).default_options
        checked: dict[str, Any] = {}
        for opt, value in opts.items():
            if opt not in defaults:
                names = ", ".join(sorted(defaults)) or "none"
                raise ObserverOptionsError(f"unknown option {opt!r} (known: {names})", field=f"observer {obs}")
            checked[str(opt)] = _checked_value(obs, str(opt), defaults[opt], value)
        if checked:
            out[obs] = checked
    if vehicle is not None:
        for obs, opts in out.items():
            try:
                observer_class(obs)(vehicle, **opts)
            except InputError:
                raise
            except (TypeError, ValueError) as e:
                raise ObserverOptionsError(f"refused by the observer: {e}".splitlines()[0], field=obs) from None
    return out


def options_record(options: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """The checked options as ``run.json`` records them (observers and options sorted, lists as lists)."""
    return {obs: {k: list(v) if isinstance(v, tuple) else v for k, v in sorted(opts.items())}
            for obs, opts in sorted(options.items())}
