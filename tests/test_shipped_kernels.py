"""The compiled kernels shipped with the package serve a fresh install: the bundle matches the
sources it was built from, a cache seeded from it runs a simulation and observers without compiling
anything, and seeding adds entries to numba's cache without replacing any."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import zipfile
from pathlib import Path

import numba
import pytest
from compile_listener import LISTENER

from roadtruth.harness.files import shipped_kernels as sk
from roadtruth.harness.files.disk_cache import CACHE_ENV

pytestmark = pytest.mark.skipif(
    sk.bundle_path() is None,
    reason=f"no kernel bundle for Python {sys.version_info[0]}.{sys.version_info[1]} on "
           f"{platform.machine()} {sys.platform} with numba {numba.__version__} (kernels compile on first use)")

#: In a fresh interpreter: seed (unless told not to), then simulate a short step steer and run two
#: observers in this process, printing which of roadtruth's functions numba compiled and a digest of
#: the truth and the estimates.
_PROBE = r'''
import json, sys
from roadtruth.harness.files.shipped_kernels import seed_numba_cache
if sys.argv[1] == "seed":
    r = seed_numba_cache()
    assert r.added == int(sys.argv[2]) and r.stale == 0, r
COMPILED_PREFIX = "roadtruth."
''' + LISTENER + r'''
from roadtruth.harness.evaluation import observer_host
from roadtruth.harness.evaluation.estimate import measurement_times, observer_inputs
from roadtruth.observers.registry import observer_class
import roadtruth as rt

sc = rt.load_scenario("step_steer")
'''


def _compiled(tmp_path: Path, mode: str) -> tuple[list[str], str]:
    """(roadtruth functions compiled, digest of the results); "cold" compiles for the host CPU."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / mode / "numba"), CACHE_ENV: str(tmp_path / mode / "cache"),
           "MUJOCO_GL": "egl"}
    env.pop("NUMBA_CPU_NAME", None)
    if mode == "seed":
        env["NUMBA_CPU_NAME"] = "generic"
    with zipfile.ZipFile(sk.bundle_path()) as zf:
        shipped = _entries(zf, [n for n in zf.namelist() if n.endswith(".nbi")])
    out = subprocess.run([sys.executable, "-c", _PROBE + _RUN, mode, str(shipped)], env=env, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    compiled, digest = json.loads(out.stdout.strip().splitlines()[-1])
    return compiled, digest


_RUN = r'''
vehicle = rt.load_vehicle(sc.vehicle)
truth = rt.simulate(sc, seed=0)
meas = rt.emulate(truth.frame, vehicle, rt.load_sensor_config(sc.sensors, sc.sensor_overrides), seed=0)
import hashlib
digest = hashlib.sha256(truth.frame.to_numpy().tobytes())
for o in ("kf_bicycle", "ekf_bicycle"):
    cls = observer_class(o)
    req = observer_host.request_for(cls, vehicle, {}, measurement_times(meas.frame),
                                    observer_inputs(meas.frame, cls.inputs))
    reply = observer_host.run_request(req, in_process=True)
    assert not reply.error, reply.error
    for part in (reply.track.x, reply.track.var):
        if part is not None:
            digest.update(part.tobytes())
print(json.dumps([sorted(set(compiled)), digest.hexdigest()]))
'''


def test_every_entry_of_the_bundle_was_built_from_the_current_sources() -> None:
    """A stale entry is never wrong (numba skips it) but makes the first run compile again: after
    editing a kernel module, ``scripts/ship_kernels.py`` rebuilds the bundle."""
    bundle = sk.bundle_path()
    stale, functions = [], 0
    with zipfile.ZipFile(bundle) as zf:
        for member in (n for n in zf.namelist() if n.endswith(".nbi")):
            functions += 1
            rel = Path(member)
            source = sk.PACKAGE_ROOT / rel.parent / (rel.name.split(".", 1)[0] + ".py")
            version, stamp, overloads = sk.read_index(zf.read(member))
            if version != numba.__version__ or stamp != sk.source_digest(source):
                stale.append(member)
            assert all(f"{rel.parent.as_posix()}/{name}" in zf.namelist() for name in overloads.values())
    assert functions >= 20
    assert stale == [], f"rebuild with scripts/ship_kernels.py: {stale}"


def test_a_seeded_cache_runs_a_simulation_and_observers_without_compiling(tmp_path: Path) -> None:
    """...and the portable code gives the host code's results bit for bit (no fast-math: LLVM may
    not reassociate or fuse floating-point operations on either target)."""
    cold, host_digest = _compiled(tmp_path, "cold")
    assert any("simulate" in k or "tire" in k for k in cold), cold  # the probe does see compilation
    assert any("kalman" in k for k in cold), cold
    assert _compiled(tmp_path, "seed") == ([], host_digest)


def _fake_index(tmp: Path, member: str, zf: zipfile.ZipFile) -> tuple[Path, object]:
    """An index of the same function and source holding one foreign entry, as if compiled here."""
    version, stamp, _ = sk.read_index(zf.read(member))
    folder = tmp / "numba" / Path(member).parent.name
    folder.mkdir(parents=True)
    base = Path(member).name[: -len(".nbi")]
    (folder / f"{base}.1.nbc").write_bytes(b"compiled here")
    (folder / Path(member).name).write_bytes(sk.index_bytes(version, stamp, {("foreign key",): f"{base}.1.nbc"}))
    return folder, base


@pytest.fixture()
def seeding(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The portable target on, an empty roadtruth cache, and numba's cache folder of each module
    under ``tmp_path / "numba"`` (named by the module's folder)."""
    monkeypatch.setenv("NUMBA_CPU_NAME", "generic")
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.delenv(sk.SHIPPED_ENV, raising=False)
    monkeypatch.setattr(sk, "numba_cache_dir", lambda source: tmp_path / "numba" / source.parent.name)
    return tmp_path


def _entries(zf: zipfile.ZipFile, members: list[str]) -> int:
    return sum(len(sk.read_index(zf.read(m))[2]) for m in members)


def test_seeding_adds_entries_beside_existing_ones_and_is_done_once(seeding: Path) -> None:
    tmp_path = seeding
    with zipfile.ZipFile(sk.bundle_path()) as zf:
        indexes = sorted(n for n in zf.namelist() if n.endswith(".nbi"))
        member = indexes[0]
        folder, base = _fake_index(tmp_path, member, zf)
        shipped = sk.read_index(zf.read(member))[2]
    first = sk.seed_numba_cache()
    assert first.stale == 0 and first.present == 0 and first.added >= len(indexes), first
    _, _, merged = sk.read_index((folder / Path(member).name).read_bytes())
    assert merged[("foreign key",)] == f"{base}.1.nbc"
    assert (folder / f"{base}.1.nbc").read_bytes() == b"compiled here"  # never replaced
    assert set(merged) == {("foreign key",), *shipped} and len(set(merged.values())) == len(merged)
    assert sk.seed_numba_cache().reason == "seeded before"
    (folder / Path(member).name).unlink()  # numba's cache cleared by hand: seeded again, the rest kept
    again = sk.seed_numba_cache()
    assert again.added == len(shipped) and again.present == first.added - len(shipped), again


def test_the_portable_target_is_left_to_the_user(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(sk.SHIPPED_ENV, "0")
    monkeypatch.delenv("NUMBA_CPU_NAME", raising=False)
    assert not sk.use_portable_target() and "NUMBA_CPU_NAME" not in os.environ
    assert sk.seed_numba_cache().reason == f"{sk.SHIPPED_ENV} is off"
    monkeypatch.delenv(sk.SHIPPED_ENV)
    monkeypatch.setenv("NUMBA_CPU_NAME", "znver3")
    assert not sk.use_portable_target()
    assert "not 'generic'" in sk.seed_numba_cache().reason
    monkeypatch.delenv("NUMBA_CPU_NAME")
    assert not sk.use_portable_target()  # numba is imported here: too late to choose its target


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="observer hosts are forked on Linux only")
def test_a_kernel_command_compiles_portably_and_still_forks_its_observer_hosts(tmp_path: Path) -> None:
    """The CLI sets numba's target after ``import roadtruth`` recorded the start-up environment; a
    host forked from the command must still count as a fresh interpreter (else every host would be
    started as one: seconds of imports each)."""
    probe = ("import roadtruth\nfrom roadtruth.harness import cli\ncli._load_shipped_kernels()\n"
             "from numba.core import config\nfrom roadtruth.harness.evaluation.host_fork import fork_is_safe\n"
             "print(config.CPU_NAME, fork_is_safe())")
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_NAME", sk.SHIPPED_ENV)}
    env.update({"NUMBA_CACHE_DIR": str(tmp_path / "numba"), CACHE_ENV: str(tmp_path / "cache"), "MUJOCO_GL": "egl"})
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["generic", "True"]


def test_the_workers_server_starts_on_the_portable_target_before_numba_is_imported(tmp_path: Path) -> None:
    """``run``/``check``/``stress`` start their workers' server once the target is set (the server
    inherits it) and before the seeding, whose numba import its preload then overlaps."""
    probe = ("import os, sys\nfrom roadtruth.harness import cli\nseen = []\n"
             "cli._load_shipped_kernels(lambda a: seen.append(('numba' in sys.modules, os.environ.get('NUMBA_CPU_NAME'))), "
             "object())\nprint(seen, 'numba' in sys.modules)")
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_NAME", sk.SHIPPED_ENV)}
    env.update({"NUMBA_CACHE_DIR": str(tmp_path / "numba"), CACHE_ENV: str(tmp_path / "cache")})
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[(False, 'generic')] True"


def test_an_entry_of_an_edited_module_is_skipped_and_the_others_seeded(seeding: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """numba would ignore an entry whose source changed; seeding does not even copy it."""
    real = sk.source_digest
    monkeypatch.setattr(sk, "source_digest", lambda p: b"edited" if p.name == "kalman_loop.py" else real(p))
    with zipfile.ZipFile(sk.bundle_path()) as zf:
        indexes = [n for n in zf.namelist() if n.endswith(".nbi")]
        edited = [n for n in indexes if Path(n).name.startswith("kalman_loop.")]
        n_edited, n_all = _entries(zf, edited), _entries(zf, indexes)
    r = sk.seed_numba_cache()
    assert edited and r.stale == n_edited and r.added == n_all - n_edited, r
    assert not any((seeding / "numba").rglob("kalman_loop.*"))


def test_a_failed_seeding_is_a_reason_not_an_error(seeding: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Seeding relies on numba's cache file format: if a numba release changed it, commands must
    still run (and compile), not stop with a traceback."""

    def changed_format(bundle: Path) -> None:
        raise AttributeError("module 'numba.core.caching' has no attribute 'CompileResultCacheImpl'")

    monkeypatch.setattr(sk, "_seed", changed_format)
    r = sk.seed_numba_cache()
    assert r.added == 0 and r.reason.startswith("not seeded: AttributeError"), r
    assert not (seeding / "cache" / sk.SEED_KIND).exists()  # not recorded: tried again next time
