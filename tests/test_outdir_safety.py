"""Writing commands never destroy what roadtruth did not write, check writability before any work,
leave nothing behind when interrupted, clean up after killed runs, and survive concurrent writers."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from synthetic_run import make_run_folder

from roadtruth.harness.cli import main
from roadtruth.harness.errors import InputError
from roadtruth.harness.files.outdir import (
    MARKER,
    OWNER,
    OWNER_WRITING,
    atomic_output_dir,
    foreign_entry,
    owner_alive,
    remove_stale_partials,
)
from roadtruth.harness.jobs.check import DEFAULT_THRESHOLDS
from roadtruth.harness.truth.scenario import scenarios_dir

pytestmark = pytest.mark.usefixtures("isolated_design_cache")

CHEAP_RUN = ["run", "--scenario", "step_steer", "--observer", "kinematic_vy", "--no-render"]


def cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """``roadtruth ARGS`` in this process: (exit code, stderr)."""
    capsys.readouterr()
    rc = main(args)
    return rc, capsys.readouterr().err


def one_line_error(err: str, *needles: str) -> None:
    assert err.count("\n") == 1 and err.startswith("roadtruth: error: "), err
    assert "Traceback" not in err
    for n in needles:
        assert n in err, (n, err)


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def leftovers(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if ".partial-" in p.name or ".old-" in p.name)


def canonical_log(path: Path) -> Path:
    """A 10 s recorded log in canonical names: linear-bicycle steady state on a slow steering sine."""
    t = np.arange(0.0, 10.0, 0.01)
    vx = np.full_like(t, 20.0)
    delta = 0.03 * np.sin(2 * np.pi * 0.2 * t)
    r = vx * delta / (2.4 + 0.002 * vx**2)
    vy = 0.05 * r
    pd.DataFrame({"t_s": t, "vx_mps": vx, "vy_mps": vy, "beta_rad": np.arctan2(vy, vx), "delta_rad": delta,
                  "yaw_rate_radps": r, "ax_mps2": 0 * t, "ay_mps2": vx * r}).to_csv(path, index=False)
    return path


# ---- 1. --out never deletes what roadtruth did not write ---------------------------------------------

def test_run_refuses_a_folder_holding_a_users_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    thesis = tmp_path / "mythesis"
    thesis.mkdir()
    (thesis / "thesis.tex").write_text("\\chapter{Results}\n")
    before = snapshot(thesis)
    rc, err = cli([*CHEAP_RUN, "--out", f"{thesis}/"], capsys)
    assert rc == 2
    one_line_error(err, "mythesis/", "did not write", "thesis.tex", "choose an empty or new folder")
    assert snapshot(thesis) == before and sorted(os.listdir(thesis)) == ["thesis.tex"]
    assert leftovers(tmp_path) == []


def test_run_refuses_the_working_folder_and_its_parents(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    work = tmp_path / "work"
    work.mkdir()
    shutil.copy(scenarios_dir() / "step_steer.yaml", work / "step_steer.yaml")
    monkeypatch.chdir(work)
    before = snapshot(tmp_path)
    for out, why in ((".", "current folder"), ("..", "parent of the current folder"), ("/", "root folder")):
        rc, err = cli(["run", "--scenario", "step_steer.yaml", "--observer", "kinematic_vy", "--no-render",
                       "--out", out], capsys)
        assert rc == 2, err
        one_line_error(err, why)
    assert snapshot(tmp_path) == before


def test_replay_refuses_the_folder_holding_its_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "data"
    data.mkdir()
    log = canonical_log(data / "drive.csv")
    before = log.read_bytes()
    t0 = time.perf_counter()
    rc, err = cli(["replay", str(log), "--observer", "kinematic_vy", "--out", str(data)], capsys)
    assert rc == 2
    one_line_error(err, "drive.csv", "input")
    assert time.perf_counter() - t0 < 5.0  # refused before the observers ran
    assert log.read_bytes() == before and os.listdir(data) == ["drive.csv"]
    assert leftovers(tmp_path) == []


def test_inputs_below_out_are_refused_for_every_input_kind(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A scenario YAML, a thresholds file and a compared run folder inside --out: refused, untouched."""
    box = tmp_path / "box"
    (box / "deep").mkdir(parents=True)
    scen = shutil.copy(scenarios_dir() / "step_steer.yaml", box / "deep" / "s.yaml")
    rc, err = cli(["simulate", str(scen), "--out", str(box)], capsys)
    assert rc == 2
    one_line_error(err, "s.yaml", "input")
    thresholds = shutil.copy(DEFAULT_THRESHOLDS, box / "deep" / "t.yaml")
    rc, err = cli(["check", "--scenario", "step_steer", "--thresholds", str(thresholds), "--out", str(box)], capsys)
    assert rc == 2
    one_line_error(err, "t.yaml", "input")
    assert sorted(p.name for p in box.rglob("*")) == ["deep", "s.yaml", "t.yaml"]
    a = make_run_folder(tmp_path / "a", scenarios=("s",))
    b = make_run_folder(tmp_path / "b", scenarios=("s",))
    before = snapshot(a)
    rc, err = cli(["compare", str(a), str(b), "--out", str(a)], capsys)
    assert rc == 2
    one_line_error(err, "input")
    assert snapshot(a) == before


def test_an_existing_file_at_out_is_refused_and_not_hidden(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "results"
    target.write_text("my numbers\n")
    rc, err = cli(["simulate", "step_steer", "--out", str(target)], capsys)
    assert rc == 2
    one_line_error(err, "existing file")
    assert target.read_text() == "my numbers\n"
    assert sorted(os.listdir(tmp_path)) == ["results"]  # no hidden .results.old-PID copy


def test_a_previous_roadtruth_folder_is_replaced(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sim"
    assert cli(["simulate", "step_steer", "--out", str(out)], capsys)[0] == 0
    marker = json.loads((out / MARKER).read_text())
    assert marker["command"] == "simulate" and "truth.csv" in marker["entries"]
    (out / "truth.csv").write_text("stale\n")
    assert cli(["simulate", "step_steer", "--out", str(out), "--seed", "5"], capsys)[0] == 0
    assert (out / "truth.csv").read_text() != "stale\n"
    assert json.loads((out / "run.json").read_text())["seed"] == 5
    assert leftovers(tmp_path) == [] and OWNER not in os.listdir(out)

    # A file the user added to a roadtruth folder is theirs: the folder is no longer replaced.
    (out / "notes.md").write_text("compare with run 3\n")
    rc, err = cli(["simulate", "step_steer", "--out", str(out)], capsys)
    assert rc == 2
    one_line_error(err, "notes.md", "did not write")
    assert (out / "notes.md").exists() and json.loads((out / "run.json").read_text())["seed"] == 5


def test_folders_written_before_the_marker_existed_are_still_replaceable(tmp_path: Path) -> None:
    legacy = tmp_path / "legacy"
    legacy.mkdir()
    (legacy / "run.json").write_text(json.dumps({"command": "run"}))
    (legacy / "metrics.csv").write_text("x\n")
    with atomic_output_dir(legacy, command="run") as tmp:
        (tmp / "metrics.csv").write_text("new\n")
    assert (legacy / "metrics.csv").read_text() == "new\n" and not (legacy / "run.json").exists()
    fake = tmp_path / "fake"
    fake.mkdir()
    (fake / "run.json").write_text("[1, 2]")  # a JSON file of the user's, not a roadtruth run.json
    with pytest.raises(InputError, match="did not write"), atomic_output_dir(fake) as tmp:
        (tmp / "x").write_text("")
    assert os.listdir(fake) == ["run.json"] and leftovers(tmp_path) == []


def test_every_command_gets_the_same_folder_permissions(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    umask = os.umask(0o022)
    try:
        assert cli(["simulate", "step_steer", "--out", str(tmp_path / "sim")], capsys)[0] == 0
        a = make_run_folder(tmp_path / "a", scenarios=("s",))
        b = make_run_folder(tmp_path / "b", scenarios=("s",))
        assert cli(["compare", str(a), str(b), "--out", str(tmp_path / "cmp")], capsys)[0] == 0
        with atomic_output_dir(tmp_path / "lib", command="replay") as tmp:  # replay's folder was 0700
            (tmp / "metrics.csv").write_text("")
    finally:
        os.umask(umask)
    modes = {n: (tmp_path / n).stat().st_mode & 0o777 for n in ("sim", "cmp", "lib")}
    assert modes == {"sim": 0o755, "cmp": 0o755, "lib": 0o755}


# ---- writability before any work ---------------------------------------------------------------------

@pytest.mark.parametrize("where", ["/", "/proc/roadtruth-out", "below-a-file"])
def test_unwritable_out_is_refused_before_work_and_leaves_nothing(where: str, tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "plain.txt").write_text("x")
    out = str(tmp_path / "plain.txt" / "sub" / "out") if where == "below-a-file" else where
    root_before = sorted(os.listdir("/"))
    t0 = time.perf_counter()
    rc, err = cli(["simulate", "step_steer", "--out", out], capsys)
    assert rc == 2
    one_line_error(err, "--out")
    assert time.perf_counter() - t0 < 5.0
    assert sorted(os.listdir("/")) == root_before
    assert sorted(os.listdir(tmp_path)) == ["plain.txt"] and (tmp_path / "plain.txt").read_text() == "x"


@pytest.mark.parametrize("junit", ["below-a-file", "a-folder"])
def test_check_junit_unwritable_exits_2_before_running_anything(junit: str, tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "plain.txt").write_text("x")
    (tmp_path / "reports").mkdir()
    path = tmp_path / "plain.txt" / "junit.xml" if junit == "below-a-file" else tmp_path / "reports"
    t0 = time.perf_counter()
    rc, err = cli(["check", "--scenario", "step_steer", "--observer", "kinematic_vy", "--junit", str(path),
                   "--out", str(tmp_path / "check")], capsys)
    assert time.perf_counter() - t0 < 5.0  # nothing was simulated
    assert rc == 2
    one_line_error(err, "--junit")
    assert sorted(os.listdir(tmp_path)) == ["plain.txt", "reports"] and os.listdir(tmp_path / "reports") == []


# ---- interrupted and killed runs ---------------------------------------------------------------------

def _spawn(args: list[str], cwd: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    return subprocess.Popen([sys.executable, "-m", "roadtruth.harness.cli", *args], cwd=cwd, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _wait_for_partial(parent: Path, proc: subprocess.Popen[str], timeout_s: float = 120.0) -> Path:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        found = [p for p in parent.iterdir() if ".partial-" in p.name]
        if found:
            t_owner = time.monotonic() + 1.0  # the owner file follows the folder at once
            while not (found[0] / OWNER).exists() and time.monotonic() < t_owner:
                time.sleep(0.01)
            return found[0]
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.01)
    raise AssertionError("no partial folder appeared")


def test_sigterm_stops_a_run_like_ctrl_c(tmp_path: Path) -> None:
    proc = _spawn([*CHEAP_RUN, "--out", "run"], tmp_path)
    _wait_for_partial(tmp_path, proc)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert "Traceback" not in err and "nothing half-written" in err
    assert os.listdir(tmp_path) == []


def test_a_killed_run_leaves_a_partial_that_the_next_run_removes(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    proc = _spawn(["simulate", "step_steer", "--out", "a"], tmp_path)
    partial = _wait_for_partial(tmp_path, proc)
    proc.kill()
    proc.communicate(timeout=60)
    assert partial.exists() and not (tmp_path / "a").exists()  # kill -9: nothing could clean up
    assert cli(["simulate", "step_steer", "--out", str(tmp_path / "b")], capsys)[0] == 0
    assert sorted(os.listdir(tmp_path)) == ["b"]


def test_only_partials_of_dead_processes_are_removed(tmp_path: Path) -> None:
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    done = subprocess.Popen([sys.executable, "-c", "pass"])
    done.wait()
    try:
        def partial(name: str, record: dict[str, object] | None) -> Path:
            p = tmp_path / f".{name}.partial-0000"
            p.mkdir()
            (p / "truth.csv").write_text("...")
            if record is not None:
                (p / OWNER).write_text(json.dumps(record))
            return p

        host = os.uname().nodename
        stat = Path(f"/proc/{sleeper.pid}/stat").read_text()
        start = stat[stat.rfind(")") + 2:].split()[19]
        live = partial("live", {"pid": sleeper.pid, "start": start, "host": host})
        dead = partial("dead", {"pid": done.pid, "start": None, "host": host})
        reused = partial("reused", {"pid": sleeper.pid, "start": str(int(start) - 1), "host": host})
        other_host = partial("remote", {"pid": done.pid, "start": None, "host": host + "-elsewhere"})
        unknown = partial("unknown", None)  # not attributable to a roadtruth process: never touched
        assert owner_alive({"pid": os.getpid(), "start": start, "host": host}) is False  # same pid, other start
        removed = remove_stale_partials(tmp_path)
        assert sorted(removed) == sorted([dead, reused])
        assert live.exists() and other_host.exists() and unknown.exists()
        assert not dead.exists() and not reused.exists()
    finally:
        sleeper.kill()
        sleeper.wait()


# ---- concurrency -------------------------------------------------------------------------------------

def test_four_writers_finishing_at_the_same_instant(tmp_path: Path) -> None:
    out = tmp_path / "shared-out"
    errors: list[BaseException] = []
    rounds, writers = 30, 4
    barrier = threading.Barrier(writers)

    def writer(k: int) -> None:
        for i in range(rounds):
            try:
                with atomic_output_dir(out, command="run") as tmp:
                    (tmp / "metrics.csv").write_text(f"{k} {i}\n")
                    (tmp / "run.json").write_text(json.dumps({"command": "run", "writer": k, "round": i}))
                    barrier.wait(timeout=30)  # all four reach the rename together
            except InputError as exc:  # a clean refusal would be acceptable; anything else is not
                errors.append(exc)
                barrier.abort()
                return
            except BaseException as exc:  # noqa: BLE001 - recorded and asserted below
                errors.append(exc)
                barrier.abort()
                return

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(writers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not [e for e in errors if not isinstance(e, InputError)], errors[:3]
    assert len(errors) == 0, f"{len(errors)} of {rounds * writers} writes refused"
    assert sorted(os.listdir(tmp_path)) == ["shared-out"]
    # Whoever won the last round, the folder is one writer's whole output, never a mix.
    k, i = map(int, (out / "metrics.csv").read_text().split())
    assert json.loads((out / "run.json").read_text()) == {"command": "run", "writer": k, "round": i}
    assert i == rounds - 1


def test_the_owner_file_appears_whole_and_its_half_written_form_is_roadtruths(tmp_path: Path) -> None:
    """The owner record is written beside and renamed into place: a command killed mid-write leaves
    no empty owner file (which would make its folder unattributable, never cleaned up), and the
    half-written file it may leave in a finished run folder does not make that folder foreign."""
    with atomic_output_dir(tmp_path / "run", command="run", inputs=[]) as tmp:
        record = json.loads((tmp / OWNER).read_text(encoding="utf-8"))
        assert record["pid"] == os.getpid() and not (tmp / OWNER_WRITING).exists()
        (tmp / "metrics.csv").write_text("x\n")
    done = tmp_path / "run"
    (done / OWNER_WRITING).write_text('{"pid": ')  # killed while replacing this folder
    assert foreign_entry(done) is None
    (done / "mine.txt").write_text("a user's file")
    assert foreign_entry(done) == "mine.txt"


def test_a_folder_swapped_by_another_writer_is_seen_and_a_new_path_is_not_waited_for(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """While a writer's two renames leave ``out`` missing (its old folder moved aside), a look at
    ``out`` waits for the swap to finish and sees a folder; a path nobody is writing is new at once."""
    from roadtruth.harness.files import outdir

    new = tmp_path / "new-out"

    def no_sleep(_: float) -> None:
        raise AssertionError("waited on a path nobody is writing")

    monkeypatch.setattr(outdir.time, "sleep", no_sleep)
    assert outdir._kind(new) is None
    monkeypatch.undo()

    out = tmp_path / "out"
    aside = tmp_path / ".out.old-0123abcd"
    aside.mkdir()  # the first rename is done, the second not yet

    def finish_swap() -> None:
        time.sleep(0.01)
        out.mkdir()
        shutil.rmtree(aside)

    t = threading.Thread(target=finish_swap)
    t.start()
    try:
        assert outdir._kind(out) == "dir"
    finally:
        t.join()
