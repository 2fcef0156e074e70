"""Observer registry: ``@register`` on a class, lookup by name, plugins via entry points.

Built-ins register themselves when their module is imported; every module of the ``observers``
package (except the framework modules) is imported on first use, so a new built-in is one file.
Third-party packages declare a class (or a module that registers its classes) in the entry-point
group ``roadtruth.observers``::

    [project.entry-points."roadtruth.observers"]
    my_observer = "my_package.my_module:MyObserver"

A plugin that fails to load only warns; the others still load.
"""

from __future__ import annotations

import importlib
import pkgutil
import warnings
from importlib.metadata import entry_points
from typing import TYPE_CHECKING, Any

from roadtruth.harness.errors import InputError, RoadtruthError
from roadtruth.harness.signals import ESTIMABLE

if TYPE_CHECKING:
    from roadtruth.harness.truth.vehicle import VehicleParams
    from roadtruth.observers.base import Observer

ENTRY_POINT_GROUP = "roadtruth.observers"
_FRAMEWORK_MODULES = frozenset({"base", "registry", "lmi"})

_REGISTRY: dict[str, type[Observer]] = {}
_loaded = False


class ObserverRegistryError(RoadtruthError, ValueError):
    """An observer class is malformed or its name is already taken."""


def register(cls: type[Observer]) -> type[Observer]:
    """Class decorator: add an observer class under ``cls.name``. A duplicate name raises."""
    name = getattr(cls, "name", "")
    if not isinstance(name, str) or not name.isidentifier():
        raise ObserverRegistryError(f"observer class {cls.__qualname__} needs a name that is an identifier")
    for attr in ("inputs", "states"):
        if not isinstance(getattr(cls, attr, None), tuple) or not getattr(cls, attr):
            raise ObserverRegistryError(f"observer {name!r}: {attr} must be a non-empty tuple")
    bad = [s for s in cls.states if s not in ESTIMABLE]
    if bad:
        raise ObserverRegistryError(f"observer {name!r}: state {bad[0]!r} is not a canonical estimable signal")
    if not all(isinstance(s, str) and s for s in cls.inputs):
        raise ObserverRegistryError(f"observer {name!r}: inputs must be column names")
    old = _REGISTRY.get(name)
    if old is not None and old is not cls and (old.__module__, old.__qualname__) != (cls.__module__, cls.__qualname__):
        raise ObserverRegistryError(f"observer name {name!r} is already registered by "
                                    f"{old.__module__}.{old.__qualname__}")
    _REGISTRY[name] = cls
    return cls


def unregister(name: str) -> None:
    """Remove an observer (for tests and plugin development)."""
    _REGISTRY.pop(name, None)


def _load_all() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    import roadtruth.observers as observers

    for info in pkgutil.iter_modules(observers.__path__):
        if info.name in _FRAMEWORK_MODULES or info.name.startswith("_"):
            continue
        try:
            importlib.import_module(f"roadtruth.observers.{info.name}")
        except Exception as exc:  # noqa: BLE001 - one broken module must not hide the others
            warnings.warn(f"observer module roadtruth.observers.{info.name} failed to import: {exc}", stacklevel=2)
    load_plugins()


def load_plugins() -> list[str]:
    """Load the entry-point group ``roadtruth.observers``; return the names of loaded entry points."""
    from roadtruth.observers.base import Observer

    loaded = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            obj = ep.load()
            if isinstance(obj, type) and issubclass(obj, Observer) and _REGISTRY.get(obj.name) is not obj:
                register(obj)
            loaded.append(ep.name)
        except Exception as exc:  # noqa: BLE001 - a broken plugin only warns
            warnings.warn(f"observer plugin {ep.name!r} ({ep.value}) failed to load: {exc}", stacklevel=2)
    return loaded


def loaded() -> bool:
    """True once this process has imported every observer module (``available_observers`` and the
    like do it on first use)."""
    return _loaded


def available_observers() -> list[str]:
    """Sorted names of every registered observer."""
    _load_all()
    return sorted(_REGISTRY)


def observer_class(name: str) -> type[Observer]:
    """The class registered as ``name``; an unknown name raises ``InputError``."""
    _load_all()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise InputError(f"unknown observer {name!r} (available: {', '.join(sorted(_REGISTRY))})",
                         field="observer") from None


def create(name: str, vehicle: VehicleParams, **options: Any) -> Observer:
    """Instantiate observer ``name`` for ``vehicle``; unknown options raise ``InputError``."""
    return observer_class(name)(vehicle, **options)


def observer_info() -> list[dict[str, Any]]:
    """One mapping per observer (for ``roadtruth observers --json``)."""
    _load_all()
    out = []
    for name in sorted(_REGISTRY):
        cls = _REGISTRY[name]
        doc = (cls.__doc__ or "").strip().splitlines()
        out.append({
            "name": name,
            "description": doc[0] if doc else "",
            "citation": cls.citation,
            "inputs": list(cls.inputs),
            "states": list(cls.states),
            "bounds": bool(cls.has_bounds),
            "covariance": bool(cls.has_covariance),
            "variant": cls.variant,
            "options": {k: list(v) if isinstance(v, tuple) else
                        (v if isinstance(v, (int, float, str, bool, type(None))) else repr(v))
                        for k, v in cls.default_options.items()},
            "module": cls.__module__,
        })
    return out
