"""Safe output folders: checked before any work, written aside, renamed into place when whole.

Every writing command (run, simulate, replay, check, stress, compare) writes through
:func:`atomic_output_dir`, which guarantees:

- ``out`` is replaced only if it is missing, empty, or a folder roadtruth wrote (it holds the
  :data:`MARKER` file listing its entries; folders written before the marker existed are recognised by
  a ``run.json`` with a ``"command"`` key). A folder holding anything else, a file at ``out``, a folder
  holding one of the command's inputs, ``/``, the home folder, the working folder or one of its
  parents is refused with an :class:`OutputPathError` (exit 2) before anything is touched.
- the location is writable (probed, not guessed from permission bits) before any work starts.
- the new folder is built in a hidden sibling ``.NAME.partial-XXXXXXXX`` holding an owner file (pid,
  process start time, host); an interrupted run removes it, and one killed outright leaves it for the
  next run writing into the same parent folder to remove once the owner process is gone.
- concurrent writers into the same ``out`` serialise their final rename on a lock of the parent
  folder, so each either replaces the folder whole or fails with an ``OutputPathError``.
- the folder gets the permissions of any folder the user creates (``0o777`` minus the umask, 0755 with
  the usual umask 022), whichever command wrote it.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import socket
import tempfile
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

from roadtruth.harness.errors import InputError

try:  # POSIX: serialise the final rename; elsewhere the retry-free rename is the best we can do.
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

MARKER = ".roadtruth"
"""File in every finished output folder: the command that wrote it and the entries it wrote (JSON)."""

OWNER = ".roadtruth-owner"
#: The owner file while it is written (renamed to OWNER when whole).
OWNER_WRITING = f"{OWNER}.writing"
"""File in a folder being written: the writing process (pid, start time, host), to tell stale from live."""

LATE_ENTRIES = frozenset({"check.csv", "check.json", "check.html", "index.html"})
"""Entries roadtruth adds to a finished folder (``check`` after its run, ``report`` rebuilding the page)."""

LEGACY_COMPARE = frozenset({"compare.csv", "compare.html"})
"""A ``compare --out`` folder written before the marker existed holds exactly these."""


class OutputPathError(InputError):
    """An output location that roadtruth must not or cannot write (the CLI exits 2, nothing touched)."""


# ---- refusals (no side effects) --------------------------------------------------------------------

def _shown(path: str | Path, *, folder: bool) -> str:
    text = str(path)
    return text if not folder or text.endswith("/") else text + "/"


def _absolute(path: str | Path) -> Path:
    """``path`` made absolute without following symlinks (``..`` is folded textually)."""
    return Path(os.path.abspath(os.path.expanduser(str(path))))


def _protected(p: Path) -> str | None:
    """Why ``p`` (resolved) can never be an output folder, or None."""
    if p == Path(p.anchor):
        return "the root folder"
    with contextlib.suppress(RuntimeError, KeyError):
        if p == Path.home().resolve():
            return "your home folder"
    cwd = Path.cwd().resolve()
    if p == cwd:
        return "the current folder"
    if p in cwd.parents:
        return "a parent of the current folder"
    return None


def _is_roadtruth_temp(name: str) -> bool:
    # Hidden temp files roadtruth itself writes inside a finished folder (index.html, check files).
    return name.startswith(".") and "partial" in name


def foreign_entry(folder: Path) -> str | None:
    """The first entry of an existing folder that roadtruth did not write, or None if it may be replaced.

    A folder may be replaced when it is empty, or holds the :data:`MARKER` and nothing beyond the
    entries it lists (plus :data:`LATE_ENTRIES` and roadtruth's own temp files), or is a folder written
    before the marker existed (a ``run.json`` with a ``"command"`` key, or only ``compare`` files).
    A folder that is gone (renamed away by a concurrent writer) has nothing to protect.
    """
    # A concurrent writer may swap the folder between our listing and our look at its marker (its two
    # renames leave ``folder`` missing for an instant): a verdict counts only when two consecutive
    # looks agree, since what a user put there stays put while a swap does not.
    last: object = object()
    for _ in range(20):
        try:
            found = _foreign_entry(folder)
        except FileNotFoundError:
            # Renamed away while being read: look again at whatever now stands at ``folder``.
            if not folder.exists():
                return None
            continue
        if found is None or found == last:
            return found
        last = found
        time.sleep(0.005)
    return _foreign_entry(folder)


def _foreign_entry(folder: Path) -> str | None:
    names = sorted(os.listdir(folder))
    if not names:
        return None
    marker = folder / MARKER
    if marker.is_file() and not marker.is_symlink():
        try:
            data = json.loads(marker.read_text(encoding="utf-8"))
            listed = set(data["entries"])
        except FileNotFoundError:
            raise
        except (OSError, ValueError, KeyError, TypeError):
            return MARKER
        extra = [n for n in names if n not in listed and n not in (MARKER, OWNER, OWNER_WRITING) and n not in LATE_ENTRIES
                 and not _is_roadtruth_temp(n)]
        return extra[0] if extra else None
    run_json = folder / "run.json"
    if run_json.is_file() and not run_json.is_symlink():
        try:
            data = json.loads(run_json.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise
        except (OSError, ValueError):
            data = None
        if isinstance(data, dict) and isinstance(data.get("command"), str):
            return None
    if set(names) <= LEGACY_COMPARE:
        return None
    return names[0]


def _kind(p: Path) -> str | None:
    """``"dir"``, ``"file"`` (anything else, symlinks included) or None if nothing is there.

    One ``lstat`` per look. A concurrent writer's two renames (:func:`_replace`) leave the path missing
    for an instant, which must not read as "nothing": while the old folder it moved aside is there,
    the look is repeated; once that is gone the swap is over, so one more look tells.
    """
    import stat

    for _ in range(20):
        try:
            mode = os.lstat(p).st_mode
        except NotADirectoryError:
            return None  # below a regular file: nothing can be there (check_writable says why)
        except FileNotFoundError:
            if _swap_in_progress(p):
                time.sleep(0.002)
                continue
            try:
                mode = os.lstat(p).st_mode
            except (FileNotFoundError, NotADirectoryError):
                return None  # a new path: nothing there, and no writer swapping it
        return "dir" if stat.S_ISDIR(mode) else "file"
    return None


def _swap_in_progress(p: Path) -> bool:
    """Whether a writer has moved ``p`` aside (its ``.NAME.old-*`` sibling exists) and not yet finished."""
    try:
        names = os.listdir(p.parent)
    except (FileNotFoundError, NotADirectoryError):
        return False  # a new path below a new folder: no concurrent writer can be swapping it
    prefix = f".{p.name}.old-"
    return any(n.startswith(prefix) for n in names)


def check_writable(path: str | Path, *, what: str, folder: bool = True) -> Path:
    """Check that ``path`` can be created: raise :class:`OutputPathError` if it cannot, touch nothing.

    ``folder`` says whether ``path`` is to be a folder (``--out``) or a file (``--junit``). The nearest
    existing ancestor must be a folder in which a (removed at once) probe folder can be made: this
    catches read-only file systems, ``/proc``, a path below a regular file and missing permissions,
    whatever the permission bits claim (root passes every ``os.access`` check).

    Returns the absolute path.
    """
    p = _absolute(path)
    shown = _shown(path, folder=folder)
    kind = _kind(p)
    if kind is not None:
        if not folder and kind == "dir":
            raise OutputPathError(f"{what} {path} is a folder; give a file path")
        if folder and kind != "dir":
            raise OutputPathError(f"{what} {path} is an existing file; choose a new or empty folder")
    anc = p.parent
    while not anc.exists():
        anc = anc.parent
    if not anc.is_dir():
        raise OutputPathError(f"{what} {shown} is below {anc}, which is a file, not a folder")
    try:
        probe = tempfile.mkdtemp(prefix=".roadtruth-probe-", dir=anc)
        os.rmdir(probe)
    except OSError as exc:
        raise OutputPathError(f"{what} {shown} cannot be written: {anc} is not writable "
                              f"({exc.strerror or type(exc).__name__})") from None
    return p


def check_output_dir(out: str | Path, *, inputs: Iterable[str | Path | None] = (), what: str = "--out") -> Path:
    """Every refusal of an output folder, checked before any work; raises :class:`OutputPathError`.

    Parameters
    ----------
    out : the output folder as the user gave it.
    inputs : the command's input paths (scenario/log/column map/thresholds/baseline/vehicle YAML...);
        items that are None or do not name an existing path (a scenario *name*) are ignored.
    what : how the user named ``out`` (the option), for the message.

    Returns
    -------
    Path
        ``out`` resolved.
    """
    shown = _shown(out, folder=True)
    p = Path(out).resolve()
    why = _protected(p) or _protected(_absolute(out))
    if why:
        raise OutputPathError(f"{what} {shown} is {why}; choose a new folder for the output")
    for inp in inputs:
        if inp is None or str(inp) == "":
            continue
        ip = Path(inp)
        if not (ip.exists() or ip.is_symlink()):
            continue
        for candidate in {ip.resolve(), _absolute(ip)}:
            for folder_ in {p, _absolute(out)}:
                if candidate == folder_ or folder_ in candidate.parents:
                    raise OutputPathError(f"{what} {shown} holds {inp}, an input of this command; "
                                          "choose another folder")
    if _kind(p) == "dir":
        foreign = foreign_entry(p)
        if foreign is not None:
            raise OutputPathError(f"{what} {shown} holds files roadtruth did not write (such as {foreign}); "
                                  "choose an empty or new folder")
    check_writable(out, what=what, folder=True)
    return p


# ---- owner files and stale partial folders ----------------------------------------------------------

def _proc_stat(pid: int) -> tuple[str, str] | None:
    """(state, start time in clock ticks since boot) of a process from /proc, or None where unavailable."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rfind(")") + 2:].split()
    return (fields[0], fields[19]) if len(fields) > 19 else None


def _owner_record() -> dict[str, object]:
    stat = _proc_stat(os.getpid())
    return {"pid": os.getpid(), "start": stat[1] if stat else None, "host": socket.gethostname()}


def owner_alive(record: dict[str, object]) -> bool:
    """Whether the process that wrote an owner ``record`` may still be running (True when unsure)."""
    if record.get("host") != socket.gethostname():
        return True  # a process on another machine sharing this folder: cannot tell, keep its folder
    pid = record.get("pid")
    if not isinstance(pid, int) or pid <= 0:
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, belongs to another user
    stat = _proc_stat(pid)
    if stat is None:
        return True
    state, start = stat
    if state in ("Z", "X"):
        return False  # killed, not yet reaped
    return record.get("start") is None or str(record.get("start")) == start  # else: pid reused


def remove_stale_partials(parent: Path) -> list[Path]:
    """Remove the partial folders in ``parent`` whose owner process is gone; returns those removed.

    Only folders named ``.NAME.partial-*`` or ``.NAME.old-*`` that hold an :data:`OWNER` file are
    considered: a folder roadtruth cannot attribute to a dead process of its own is never touched.
    """
    removed: list[Path] = []
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return removed
    for e in entries:
        if not e.name.startswith(".") or not (".partial-" in e.name or ".old-" in e.name):
            continue
        if not e.is_dir(follow_symlinks=False):
            continue
        try:
            record = json.loads((Path(e.path) / OWNER).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(record, dict) and not owner_alive(record):
            shutil.rmtree(e.path, ignore_errors=True)
            removed.append(Path(e.path))
    return removed


def _write_owner(folder: Path) -> None:
    # Written whole, then renamed into place: a process killed mid-write must not leave an empty
    # owner file, which would make its folder unattributable (never cleaned up) instead of stale.
    tmp = folder / OWNER_WRITING
    tmp.write_text(json.dumps(_owner_record()) + "\n", encoding="utf-8")
    os.replace(tmp, folder / OWNER)


def _new_partial(parent: Path, name: str) -> Path:
    while True:
        tmp = parent / f".{name}.partial-{secrets.token_hex(4)}"
        try:
            os.mkdir(tmp, 0o777)  # minus the umask, like any folder the user makes
        except FileExistsError:
            continue
        _write_owner(tmp)
        return tmp


def _make_parents(folder: Path) -> list[Path]:
    """``mkdir -p folder``; returns the folders it created, deepest last."""
    missing = []
    p = folder
    while not p.exists():
        missing.append(p)
        p = p.parent
    created = []
    for m in reversed(missing):
        try:
            os.mkdir(m, 0o777)
            created.append(m)
        except FileExistsError:
            pass
        except OSError as exc:
            _remove_empty(created)
            raise OutputPathError(f"cannot create {m}: {exc.strerror or type(exc).__name__}") from None
    return created


def _remove_empty(created: list[Path]) -> None:
    for m in reversed(created):
        with contextlib.suppress(OSError):
            os.rmdir(m)  # only if still empty: another writer may have started using it


@contextlib.contextmanager
def _folder_lock(folder: Path) -> Iterator[None]:
    """An exclusive lock on ``folder`` itself (flock on its descriptor: no lock file left behind)."""
    if fcntl is None:  # pragma: no cover
        yield
        return
    fd = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def write_marker(folder: Path, command: str, extra: Iterable[str] = ()) -> None:
    """Write (or extend) ``folder``'s :data:`MARKER`: the command and the top-level entries it wrote."""
    entries = set(extra)
    marker = folder / MARKER
    with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
        entries |= set(json.loads(marker.read_text(encoding="utf-8"))["entries"])
    entries |= {n for n in os.listdir(folder) if n not in (MARKER, OWNER, OWNER_WRITING) and not _is_roadtruth_temp(n)}
    marker.write_text(json.dumps({"command": command, "entries": sorted(entries)}, indent=1) + "\n",
                      encoding="utf-8")


def claim(folder: Path, names: Iterable[str]) -> None:
    """Record top-level ``names`` that roadtruth added to a finished output ``folder`` (e.g. a JUnit file)."""
    marker = folder / MARKER
    try:
        command = json.loads(marker.read_text(encoding="utf-8"))["command"]
    except (OSError, ValueError, KeyError, TypeError):
        return
    write_marker(folder, str(command), names)


def _replace(tmp: Path, target: Path, shown: str, what: str) -> None:
    """Rename ``tmp`` to ``target`` under the parent's lock, moving a replaceable old folder aside first."""
    old: Path | None = None
    try:
        with _folder_lock(target.parent):
            if target.exists() or target.is_symlink():
                # Checked again under the lock: a concurrent writer or the user may have written here.
                if target.is_symlink() or not target.is_dir():
                    raise OutputPathError(f"{what} {shown.rstrip('/')} is an existing file; choose a new or empty "
                                          "folder")
                foreign = foreign_entry(target)
                if foreign is not None:
                    raise OutputPathError(f"{what} {shown} holds files roadtruth did not write (such as "
                                          f"{foreign}); choose an empty or new folder")
                old = target.parent / f".{target.name}.old-{secrets.token_hex(4)}"
                _write_owner(target)  # if we die between the two renames, the next run removes it
                os.replace(target, old)
                try:
                    os.replace(tmp, target)
                except BaseException:
                    os.replace(old, target)
                    (target / OWNER).unlink(missing_ok=True)
                    old = None
                    raise
            else:
                os.replace(tmp, target)
            (target / OWNER).unlink(missing_ok=True)
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def atomic_output_dir(out: str | Path, *, command: str = "roadtruth", inputs: Iterable[str | Path | None] = (),
                      what: str = "--out") -> Iterator[Path]:
    """Yield a temporary folder next to ``out``; on success replace ``out`` with it, else delete it.

    Parameters
    ----------
    out : the output folder.
    command : the command writing it (recorded in the folder's :data:`MARKER`).
    inputs : the command's input paths; ``out`` may not hold any of them (see :func:`check_output_dir`).
    what : how the user named ``out``, for messages.

    Raises
    ------
    OutputPathError
        Before anything is created, when ``out`` may not or cannot be written; or at the end if,
        meanwhile, something roadtruth did not write appeared at ``out`` (the new folder is discarded).

    >>> with atomic_output_dir("reports/latest", command="run") as tmp:
    ...     (tmp / "metrics.csv").write_text("...")
    """
    shown = _shown(out, folder=True)
    target = check_output_dir(out, inputs=inputs, what=what)
    created = _make_parents(target.parent)
    try:
        remove_stale_partials(target.parent)
        tmp = _new_partial(target.parent, target.name)
    except OSError as exc:
        _remove_empty(created)
        raise OutputPathError(f"{what} {shown} cannot be written: {exc.strerror or type(exc).__name__}") from None
    except BaseException:
        _remove_empty(created)
        raise
    try:
        yield tmp
        write_marker(tmp, command)
        _replace(tmp, target, shown, what)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        _remove_empty(created)
        raise


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary sibling file renamed into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.partial-", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
