"""roadtruth: validate vehicle state observers against a multibody MuJoCo car, emulated sensors and real logs.

The names a notebook needs (docs/PYTHON.md)::

    import roadtruth as rt
    sc = rt.load_scenario("step_steer")
    vehicle = rt.load_vehicle(sc.vehicle)
    truth = rt.simulate(sc, seed=0)                    # truth.frame: the truth signals (ISO 8855)
    meas = rt.emulate(truth.frame, vehicle, rt.load_sensor_config(sc.sensors, sc.sensor_overrides), seed=0)
    estimates, runs = rt.run_observers(meas.frame, vehicle, ["kf_bicycle"])

Jobs (what the commands do): :func:`run_suite` (``roadtruth run``), :func:`run_check`,
:func:`run_stress`, :func:`replay`, :func:`compare`, :func:`run_falsify`. Observers:
:class:`Observer`, :func:`register`, :func:`create`, :func:`available_observers`. Scoring:
:func:`score`. Names are imported on first use, so ``import roadtruth`` is cheap.
"""

from __future__ import annotations

import importlib
import os
from typing import Any

__version__ = "0.1.0"

# Offscreen rendering (no display: GLFW cannot work); the GL back-end is chosen when mujoco is first
# imported. Set here, before anything else of roadtruth runs, so that every process of a run (fresh
# or forked) starts under the same value; the modules that import mujoco repeat it for themselves.
os.environ.setdefault("MUJOCO_GL", "egl")

#: The environment when roadtruth was first imported, before a caller (a notebook, a test) could
#: change it: what this process's imports were made under. A child forked later holds those imports,
#: so it may stand in for a fresh interpreter only while the start-up variables are still these
#: (``roadtruth.harness.evaluation.host_fork.fork_is_safe``).
ENVIRON_AT_IMPORT: dict[str, str] = dict(os.environ)

#: public name -> (module, attribute)
_PUBLIC: dict[str, tuple[str, str]] = {
    # scenario and vehicle files
    "load_scenario": ("roadtruth.harness.truth.scenario", "load_scenario"),
    "available_scenarios": ("roadtruth.harness.truth.scenario", "available_scenarios"),
    "Scenario": ("roadtruth.harness.truth.scenario", "Scenario"),
    "load_vehicle": ("roadtruth.harness.truth.vehicle", "load_vehicle"),
    "available_vehicles": ("roadtruth.harness.truth.vehicle", "available_vehicles"),
    "VehicleParams": ("roadtruth.harness.truth.vehicle", "VehicleParams"),
    # truth, sensors, observers, scores
    "simulate": ("roadtruth.harness.truth.simulate", "simulate"),
    "load_sensor_config": ("roadtruth.harness.sensors", "load_sensor_config"),
    "emulate": ("roadtruth.harness.sensors.suite", "emulate"),
    "run_observers": ("roadtruth.harness.evaluation.estimate", "run_observers"),
    "score": ("roadtruth.harness.evaluation.scoring", "score"),
    "Observer": ("roadtruth.observers.base", "Observer"),
    "ScalarLoopObserver": ("roadtruth.observers.base", "ScalarLoopObserver"),
    "StepOutput": ("roadtruth.observers.base", "StepOutput"),
    "register": ("roadtruth.observers.registry", "register"),
    "create": ("roadtruth.observers.registry", "create"),
    "available_observers": ("roadtruth.observers.registry", "available_observers"),
    # jobs
    "run_suite": ("roadtruth.harness.jobs.pipeline", "run_suite"),
    "run_check": ("roadtruth.harness.jobs.check", "run_check"),
    "run_stress": ("roadtruth.harness.jobs.stress", "run_stress"),
    "replay": ("roadtruth.harness.jobs.replay", "replay"),
    "compare": ("roadtruth.harness.jobs.compare", "compare"),
    "run_falsify": ("roadtruth.harness.jobs.falsify", "run_falsify"),
    "RoadtruthError": ("roadtruth.harness.errors", "RoadtruthError"),
    "InputError": ("roadtruth.harness.errors", "InputError"),
}

__all__ = sorted([*_PUBLIC, "__version__"])


def __getattr__(name: str) -> Any:
    try:
        module, attr = _PUBLIC[name]
    except KeyError:
        raise AttributeError(f"module 'roadtruth' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
