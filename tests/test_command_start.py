"""What a command pays before its work starts: no garbage collection over its imports (they are frozen
once made), and numba's BLAS without the rest of ``scipy.linalg``.

Each check runs in a fresh interpreter: what a test session imported earlier would hide both.
"""

from __future__ import annotations

import gc
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from roadtruth.harness.jobs.warm_start import collection_paused, one_blas_thread


def _fresh(code: str) -> dict:
    res = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_simulate_starts_without_collecting_and_freezes_what_its_start_up_made(tmp_path: Path) -> None:
    out = tmp_path / "sim"
    seen = _fresh(f"""
        import gc, json, sys
        from roadtruth.harness import cli
        collections = []
        gc.callbacks.append(lambda phase, info: phase == "stop" and collections.append(info["generation"]))
        from roadtruth.harness.jobs import warm_start
        pause, paused_at = warm_start.collection_paused, []
        def recorded_pause(**kw):
            paused_at.append(len(collections))
            return pause(**kw)
        warm_start.collection_paused = recorded_pause
        work = cli._cmd_simulate
        def observed(args):
            at_start = {{"collections": collections[paused_at[0]:], "enabled": gc.isenabled(),
                        "frozen": gc.get_freeze_count(), "numba": "numba" in sys.modules}}
            code = work(args)
            print(json.dumps({{**at_start, "scipy_linalg": "scipy.linalg" in sys.modules,
                              "blas": "scipy.linalg.cython_blas" in sys.modules,
                              "numba_set_up": "numba.np.arraymath" in sys.modules}}), flush=True)
            return code
        cli._cmd_simulate = observed
        sys.argv = ["roadtruth", "simulate", "step_steer", "--out", {str(out)!r}]
        cli.console_main()
    """)
    # Start-up (shipped kernels, imports of pandas, numba, MuJoCo and the pipeline) ran with no
    # collection; what it made is frozen and collection is back on for the command's own garbage.
    assert seen["collections"] == []
    assert seen["enabled"] is True
    assert seen["numba"] is True
    assert seen["frozen"] > 100_000
    # numba set itself up with BLAS from SciPy's extension modules, not the whole scipy.linalg.
    assert seen["numba_set_up"] and seen["blas"]
    assert seen["scipy_linalg"] is False
    assert (out / "truth.csv").stat().st_size > 0


def test_numba_linear_algebra_works_on_blas_loaded_alone_and_scipy_linalg_still_imports() -> None:
    seen = _fresh("""
        import json, sys
        from roadtruth.harness.jobs.warm_start import load_numba_blas
        load_numba_blas()
        import numpy as np
        from numba import njit

        @njit
        def solve_and_dot(a, b):
            return np.linalg.solve(a, b), np.dot(a, b), np.linalg.eigvalsh(a)

        a = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]]); b = np.array([1.0, -2.0, 0.5])
        x, d, w = solve_and_dot(a, b)
        alone = "scipy.linalg" not in sys.modules
        import scipy.linalg
        ok = (np.allclose(x, np.linalg.solve(a, b), rtol=1e-14, atol=0) and np.allclose(d, a @ b, rtol=1e-15, atol=0)
              and np.allclose(w, np.linalg.eigvalsh(a), rtol=1e-13, atol=0)
              and np.allclose(scipy.linalg.solve(a, b), x, rtol=1e-14, atol=0))
        print(json.dumps({"alone": alone, "ok": bool(ok),
                          "same_module": sys.modules["scipy.linalg.cython_blas"].__name__ == "scipy.linalg.cython_blas"}))
    """)
    assert seen == {"alone": True, "ok": True, "same_module": True}


def test_collection_pause_gives_back_the_state_it_found() -> None:
    assert gc.isenabled()
    with collection_paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    gc.disable()
    try:
        with collection_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()  # a caller that had collection off keeps it off
    finally:
        gc.enable()


def test_a_workers_server_leaves_without_the_teardown_and_its_children_keep_theirs() -> None:
    code = textwrap.dedent("""
        import os, sys
        from roadtruth.harness.jobs.warm_start import leave_without_teardown

        class Noted:
            def __del__(self):
                sys.stdout.write(f"torn down in {'child' if os.getpid() != parent else 'parent'}\\n")
                sys.stdout.flush()

        parent = os.getpid()
        kept = Noted()  # freed only by the interpreter's teardown
        leave_without_teardown()
        child = os.fork()
        if child == 0:
            sys.exit(0)  # a child that exits normally keeps its teardown
        os.waitpid(child, 0)
        sys.stdout.write("unflushed line of the parent")  # flushed by the quick exit
        sys.exit(0)
    """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout == "torn down in child\nunflushed line of the parent"



BLAS_IN_WORKERS = """
    import json, os, sys
    sys.path.insert(0, {tests!r})
    for name in ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS"):
        os.environ.pop(name, None)
    os.environ.update({user!r})
    import worker_tasks
    from roadtruth.harness.jobs.worker_pool import WorkerPool
    with WorkerPool(worker_tasks.blas_environment, 1) as pool:
        seen = pool.submit(0).result(timeout=300)
    seen["caller"] = os.environ.get("OPENBLAS_NUM_THREADS")
    print(json.dumps(seen))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the forkserver and /proc are Linux's")
def test_workers_load_blas_with_one_thread_and_the_caller_and_a_user_s_choice_are_left_alone() -> None:
    tests = str(Path(__file__).resolve().parent)
    seen = _fresh(BLAS_IN_WORKERS.format(tests=tests, user={}))
    # The server loaded OpenBLAS under it, its workers inherit it; the caller's environment is untouched.
    assert (seen["server"], seen["worker"], seen["caller"]) == ("1", "1", None)
    chosen = _fresh(BLAS_IN_WORKERS.format(tests=tests, user={"OMP_NUM_THREADS": "2"}))
    assert (chosen["server"], chosen["worker"], chosen["caller"]) == (None, None, None)
    assert one_blas_thread({"OPENBLAS_NUM_THREADS": "4"}) == {"OPENBLAS_NUM_THREADS": "4"}
    assert one_blas_thread({"OPENBLAS_NUM_THREADS": " ", "X": "y"}) == {"OPENBLAS_NUM_THREADS": "1", "X": "y"}


def test_a_command_s_own_process_loads_blas_with_one_thread() -> None:
    seen = _fresh("""
        import json, os
        for name in ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS"):
            os.environ.pop(name, None)
        from roadtruth.harness import cli
        import numpy
        print(json.dumps({"value": os.environ.get("OPENBLAS_NUM_THREADS")}))
    """)
    assert seen["value"] == "1"
