"""The design warm-up does the first run's one-time work ahead, and only that work: it compiles the
kernels a real run then calls (not neighbours of them), it is recorded once per code and cache, and
the observer hosts it keeps busy are counted, so no extra host is started beside them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import plugin_observers
import pytest
from compile_listener import LISTENER

from roadtruth.harness.evaluation import observer_host
from roadtruth.harness.files.disk_cache import CACHE_ENV
from roadtruth.harness.jobs.design_warmup import WARMUP_KIND, BackgroundWarmup, DesignWarmup, warmup_needed
from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers import registry

TESTS = Path(__file__).resolve().parent

#: In a fresh interpreter with an empty numba cache: optionally warm up, then run the observers
#: in this process on a two-second frame made as a task makes its inputs, and print which of
#: roadtruth's observer kernels numba compiled (a kernel loaded from the disk cache is not compiled).
_PROBE = r'''
import json, sys
import numpy as np, pandas as pd
from roadtruth.harness.evaluation import observer_host
from roadtruth.harness.evaluation.estimate import measurement_times, observer_inputs
from roadtruth.harness.jobs.design_warmup import DesignWarmup, solve_designs
from roadtruth.harness.jobs.pipeline import prepare_scenario
from roadtruth.observers.registry import observer_class

observers = sys.argv[2].split(",")
vehicle = prepare_scenario("step_steer", None, None).vehicle_params()
if sys.argv[1] == "warm":
    solve_designs(DesignWarmup.of([("step_steer", None, None)], observers), hosts=2)
    observer_host.shutdown()
COMPILED_PREFIX = "roadtruth.observers"
'''
_PROBE += LISTENER + r'''
t = np.arange(200) * 0.01
frame = pd.DataFrame({"t_s": t, "vx_mps": 20.0, "yaw_rate_radps": 0.1 * np.sin(t), "ay_mps2": 2.0 * np.sin(t),
                      "delta_rad": 0.01 * np.sin(t), "imu_valid": 1.0, "steering_valid": 1.0})
for o in observers:
    cls = observer_class(o)
    req = observer_host.request_for(cls, vehicle, {}, measurement_times(frame), observer_inputs(frame, cls.inputs))
    reply = observer_host.run_request(req, in_process=True)
    assert not reply.error, reply.error
print(json.dumps(sorted(set(compiled))))
'''


def _compiled_kernels(tmp_path: Path, mode: str, observers: list[str]) -> list[str]:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / mode / "numba"), CACHE_ENV: str(tmp_path / mode / "cache"),
           "MUJOCO_GL": "egl"}
    out = subprocess.run([sys.executable, "-c", _PROBE, mode, ",".join(observers)], env=env, check=True,
                         capture_output=True, text=True, timeout=600)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_after_the_warm_up_a_real_run_compiles_no_observer_kernel(tmp_path: Path) -> None:
    """The warm-up's two-sample inputs are made as a task's are (a frame's read-only time column,
    its input columns as one array): numba compiles one specialisation per memory layout and
    writeable flag, so inputs made otherwise would compile kernels the real run never calls and
    leave it to compile its own."""
    observers = ["kf_bicycle", "ekf_bicycle"]
    cold = _compiled_kernels(tmp_path, "cold", observers)
    assert any("kalman" in k for k in cold) and len(cold) >= 2, cold  # the probe does see compilation
    assert _compiled_kernels(tmp_path, "warm", observers) == []


@pytest.fixture()
def hang():
    registry.register(plugin_observers.Hangs)
    registry.register(plugin_observers.Segfaults)
    yield
    registry.unregister(plugin_observers.Hangs.name)
    registry.unregister(plugin_observers.Segfaults.name)


def _hosts() -> tuple[int, int]:
    """(busy, idle and alive) observer hosts of this process."""
    with observer_host._lock:
        return observer_host._busy, sum(1 for h in observer_host._idle if h.alive())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="observer hosts are processes on Linux")
def test_a_host_running_a_request_counts_as_started_and_a_failed_one_is_forgotten(hang) -> None:
    from roadtruth.observers.registry import observer_class

    observer_host.shutdown()
    v = load_vehicle("sedan")
    t, Y = np.array([0.0, 0.01]), np.zeros((2, 1))
    observer_host.prestart(1)
    assert _hosts() == (0, 1)
    th = threading.Thread(target=observer_host.run_isolated, args=(observer_class("plugin_hang"), v, {}, t, Y, 3.0))
    th.start()
    deadline = time.monotonic() + 10.0
    while _hosts()[0] != 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert _hosts() == (1, 0)
    observer_host.prestart(1)  # the busy host is this process's one host: none is added beside it
    assert _hosts() == (1, 0)
    th.join()
    assert _hosts() == (0, 0)  # timed out: killed, and no longer counted
    reply = observer_host.run_isolated(observer_class("plugin_segfault"), v, {}, t, Y, 30.0)
    assert reply.error == "observer process crashed (signal 11)"
    assert _hosts() == (0, 0)
    good = observer_host.run_isolated(observer_class("open_loop_bicycle"), v, {}, t, np.zeros((2, 2)), 30.0)
    assert not good.error and _hosts() == (0, 1)
    observer_host.shutdown()


def test_a_warm_up_is_recorded_once_and_a_warm_cache_starts_none(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    w = DesignWarmup.of([("step_steer", None, None)], ["kf_bicycle", "open_loop_bicycle"])
    assert warmup_needed(w) is not None
    bg = BackgroundWarmup.start(w, hosts=2)
    assert bg is not None
    bg.wait()
    bg.wait()
    assert len(list((tmp_path / "cache" / WARMUP_KIND).glob("*.json"))) == 1
    assert warmup_needed(w) is None and BackgroundWarmup.start(w) is None
    # another set of observers, or another numba cache, is another warm-up
    assert warmup_needed(DesignWarmup.of([("step_steer", None, None)], ["kf_bicycle"])) is not None
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    assert warmup_needed(w) is not None
    assert warmup_needed(DesignWarmup.of([], ["kf_bicycle"])) is None  # nothing to warm
    observer_host.shutdown()
