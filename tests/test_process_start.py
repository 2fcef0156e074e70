"""Process start-up is paid once: workers fork from a warmed forkserver, observer hosts fork from a
warmed caller when that is safe, and a forked host keeps every guarantee of a fresh-interpreter host.

The host checks run in a fresh interpreter (``_script``), so whether forking is safe does not depend on
what other tests of this session did (a session that rendered has a GL context and must not fork).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import worker_tasks

from roadtruth.harness.jobs.worker_pool import WorkerPool

TESTS = Path(__file__).resolve().parent
LINUX = sys.platform.startswith("linux")
pytestmark = [pytest.mark.usefixtures("isolated_design_cache"),
              pytest.mark.skipif(not LINUX, reason="forkserver, fork and /proc are Linux's")]


def _script(body: str, timeout_s: float = 240.0) -> dict:
    """Run ``body`` in a fresh interpreter (tests folder on the path); it prints one JSON line last."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(TESTS), os.environ.get("PYTHONPATH", "")) if p),
           "MUJOCO_GL": "egl"}
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(body)], env=env, capture_output=True, text=True,
                         timeout=timeout_s)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_worker_starts_with_the_imports_numba_and_frozen_objects_of_the_forkserver() -> None:
    # worker_tasks imports nothing heavy: whatever the worker holds before its first task, it forked with
    with WorkerPool(worker_tasks.process_state, 1) as pool:
        state = pool.submit(0).result(timeout=300)
    assert state["modules"] == sorted(["mujoco", "pandas", "roadtruth.observers.registry",
                                       "roadtruth.harness.jobs.pipeline"])
    assert state["numba_registries"] > 0
    assert state["frozen"] > 10_000


def test_renderers_fork_from_a_lighter_preload_and_scenario_workers_still_get_the_full_one() -> None:
    """A run whose only workers render (``run`` without ``--jobs``) starts a forkserver that preloads
    the renderer's imports, not the observers and numba's set-up; a pool of scenario workers later in
    the same process gets the full preload (the server is restarted while no worker lives)."""
    from multiprocessing import forkserver

    from roadtruth.harness.jobs.worker_pool import RENDER_PRELOAD, start_forkserver

    forkserver._forkserver._stop()  # whatever earlier tests of this process started
    start_forkserver(renders_only=True)
    with WorkerPool(worker_tasks.process_state, 1, what="renderer", preload=RENDER_PRELOAD) as pool:
        light = pool.submit(0).result(timeout=300)
    assert "mujoco" in light["modules"] and "roadtruth.observers.registry" not in light["modules"]
    assert light["numba_registries"] == 0 and light["frozen"] > 1_000
    with WorkerPool(worker_tasks.process_state, 1) as pool:
        full = pool.submit(0).result(timeout=300)
    assert "roadtruth.observers.registry" in full["modules"] and full["numba_registries"] > 0


HOST_GUARANTEES = """
    import json, os, sys, threading, time
    import numpy as np
    import pandas as pd
    import plugin_observers
    from roadtruth.harness.evaluation import observer_host
    from roadtruth.harness.evaluation.estimate import run_observers
    from roadtruth.harness.truth.vehicle import load_vehicle
    from roadtruth.observers import registry

    for cls in (*plugin_observers.MISBEHAVING, plugin_observers.ReportsFrozenObjects):
        registry.register(cls)
    n = 400
    t = np.arange(n) * 0.01
    r = 0.03 * np.sin(2 * np.pi * 0.4 * t)
    frame = pd.DataFrame({"t_s": t, "vx_mps": 15.0, "yaw_rate_radps": r, "ay_mps2": 15.0 * r, "imu_valid": 1,
                          "delta_rad": 0.1 * r, "steering_valid": 1})
    sedan = load_vehicle("sedan")
    out = {"safe": observer_host.fork_is_safe()}
    observer_host.prestart()
    host = observer_host._idle[-1]
    host.wait_ready(300)
    out["forked"] = host.forked
    out["parent"] = os.getpid()
    with open(f"/proc/{host.process.pid}/stat", "rb") as f:
        out["host_parent"] = int(f.read().rsplit(b")", 1)[1].split()[1])
    with open(f"/proc/{host.process.pid}/comm") as f:
        out["host_name"] = f.read().strip()
    bad = [c.name for c in plugin_observers.MISBEHAVING if c.name != "plugin_hang"]
    _, hang = run_observers(frame, sedan, ["plugin_hang"], timeout_s=2.0)
    est, runs = run_observers(frame, sedan, [*bad, "plugin_gc_probe", "open_loop_bicycle"])
    out["status"] = {k: v.status for k, v in {**hang, **runs}.items()}
    out["frozen"] = float(est[est.observer == "plugin_gc_probe"]["value"].min())
    # a non-daemon thread, then a GL context: from here on hosts start as fresh interpreters
    stop = threading.Event()
    th = threading.Thread(target=stop.wait)
    th.start()
    out["safe_with_thread"] = observer_host.fork_is_safe()
    stop.set()
    th.join()
    # a changed start-up environment: a fresh interpreter would import something else than this process holds
    os.environ["PYTHONPATH"] = os.environ.get("PYTHONPATH", "") + os.pathsep + "/nonexistent-site"
    out["safe_with_new_pythonpath"] = observer_host.fork_is_safe()
    os.environ["PYTHONPATH"] = os.environ["PYTHONPATH"].rsplit(os.pathsep, 1)[0]
    out["safe_again"] = observer_host.fork_is_safe()
    import mujoco
    model = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size="1"/></worldbody></mujoco>')
    renderer = mujoco.Renderer(model, 32, 32)
    renderer.update_scene(mujoco.MjData(model))
    renderer.render()
    out["safe_after_gl"] = observer_host.fork_is_safe()
    fresh = observer_host.ObserverHost()
    fresh.wait_ready(300)
    out["fresh_forked"] = fresh.forked
    fresh.close()
    print(json.dumps(out))
"""


def test_a_forked_host_keeps_every_guarantee_and_hosts_fork_only_when_safe() -> None:
    got = _script(HOST_GUARANTEES)
    assert got["safe"] and got["forked"]
    assert got["host_parent"] == got["parent"]  # the caller's child: it dies with the caller
    assert got["host_name"] == "roadtruth-host"
    assert got["status"] == {
        "plugin_input_error": "error: InputError: plugin: plug-in refused its input at run time",
        "plugin_design_error": "error: RuntimeError: design exploded",
        "plugin_sys_exit": "error: SystemExit: 3",
        "plugin_segfault": "error: observer process crashed (signal 11)",
        "plugin_hang": "error: timed out after 2 s",
        "plugin_gc_probe": "diverged",  # ran: its "yaw rate" is the frozen-object count
        "open_loop_bicycle": "ok",
    }
    assert got["frozen"] > 10_000  # the forked host froze what it inherited out of garbage collection
    assert not got["safe_with_thread"]
    assert not got["safe_with_new_pythonpath"] and got["safe_again"]
    assert not got["safe_after_gl"] and not got["fresh_forked"]


def test_a_pythonpath_changed_before_the_host_module_is_imported_still_forbids_forking() -> None:
    """What a process's imports were made under is read when roadtruth is first imported: a caller
    (a notebook, a test) that changes ``PYTHONPATH`` afterwards, but before the first observer host,
    gets a fresh-interpreter host that sees the new path, not a forked one that holds the old imports."""
    got = _script("""
        import json, os
        import roadtruth
        os.environ["PYTHONPATH"] = os.environ.get("PYTHONPATH", "") + os.pathsep + "/nonexistent-site"
        from roadtruth.harness.evaluation.host_fork import fork_is_safe
        changed = fork_is_safe()
        os.environ["PYTHONPATH"] = os.environ["PYTHONPATH"].rsplit(os.pathsep, 1)[0]
        print(json.dumps({"changed": changed, "restored": fork_is_safe()}))
    """)
    assert got == {"changed": False, "restored": True}


def test_dask_local_workers_fork_from_the_preloaded_server_under_dask_s_hash_seed_and_fork_their_host() -> None:
    """``stress --dask local``: each worker of the LocalCluster forks from this process's preloaded
    server, started under the ``PYTHONHASHSEED`` Dask gives its workers (so a worker hashes strings as
    a fresh Dask worker would), and has one idle observer host forked at start-up, when it was still
    single-threaded; a sweep's tasks then run on it instead of fresh-interpreter hosts."""
    pytest.importorskip("distributed")
    got = _script("""
        import json, os, sys
        if __name__ == "__main__":
            from distributed import Client
            from roadtruth.harness.jobs.dask_setup import local_cluster, worker_hash_seed

            def probe():
                from roadtruth.harness.evaluation import observer_host
                return {"hosts": [[h.forked, h.alive()] for h in observer_host._idle],
                        "hash": hash("roadtruth"), "seed": os.environ.get("PYTHONHASHSEED"),
                        "preloaded": "roadtruth.observers.registry" in sys.modules}

            cluster = local_cluster(2)
            client = Client(cluster)
            try:
                workers = list(client.run(probe).values())
            finally:
                client.close()
                cluster.close()
            print(json.dumps({"workers": workers, "seed": worker_hash_seed()}))
    """)
    fresh = subprocess.run([sys.executable, "-c", "print(hash('roadtruth'))"], capture_output=True, text=True,
                           env={**os.environ, "PYTHONHASHSEED": got["seed"]}, check=True)
    assert len(got["workers"]) == 2
    for w in got["workers"]:
        assert w["hosts"] == [[True, True]]
        assert w["preloaded"] and w["seed"] == got["seed"]
        assert w["hash"] == int(fresh.stdout)


def test_a_command_started_without_mujoco_gl_still_forks_its_hosts() -> None:
    """roadtruth chooses offscreen GL (``MUJOCO_GL=egl``) itself when the caller did not; it does so
    when it is first imported, so a command's later modules leave the start-up environment as it was
    and its observer hosts still fork."""
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    body = ("import json, os\nimport roadtruth.harness.cli\nimport roadtruth.harness.jobs.pipeline\n"
            "from roadtruth.harness.evaluation.host_fork import fork_is_safe\n"
            "print(json.dumps({'gl': os.environ.get('MUJOCO_GL'), 'safe': fork_is_safe()}))")
    out = subprocess.run([sys.executable, "-c", body], env=env, capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr[-3000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == {"gl": "egl", "safe": True}
