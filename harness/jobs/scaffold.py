"""``roadtruth init DIR``: a starter project for a user's own observer.

The project is a plug-in package: ``src/<package>/complementary_vy.py`` (a real observer, see its
docstring), a ``pyproject.toml`` that registers it in the entry-point group ``roadtruth.observers``,
a ``thresholds.yaml`` it passes, the CI workflow files of ``harness/ci_templates`` and a README. The
files come from ``harness/scaffold_template``; ``$package`` and ``$distribution`` are filled in from
the folder name.

It never replaces a user's file: ``DIR`` must be new or an empty folder (one error line and exit 2
otherwise), and the files are written to a hidden partial folder beside it that is renamed into place
only when complete, so an interrupted ``init`` leaves no half-written project.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from importlib.resources import files
from pathlib import Path
from string import Template

from roadtruth.harness.files.outdir import OutputPathError, check_writable

#: Template file -> path in the new project; ``{package}`` is the import package name.
PROJECT_FILES: dict[str, str] = {
    "scaffold_template/pyproject.toml": "pyproject.toml",
    "scaffold_template/README.md": "README.md",
    "scaffold_template/thresholds.yaml": "thresholds.yaml",
    "scaffold_template/package_init.py": "src/{package}/__init__.py",
    "scaffold_template/observer.py": "src/{package}/complementary_vy.py",
    "ci_templates/github-actions.yml": ".github/workflows/roadtruth.yml",
    "ci_templates/gitlab-ci.yml": ".gitlab-ci.yml",
}
#: Templates whose ``$package``/``$distribution`` placeholders are filled in (the others are copied).
_FILLED = {"scaffold_template/pyproject.toml", "scaffold_template/README.md"}


def project_names(folder: str | Path) -> tuple[str, str]:
    """(distribution name, import package name) for a project in ``folder``.

    ``my-car obs`` -> (``my-car-obs``, ``my_car_obs``); a name that does not start with a letter gets
    the prefix ``observers_`` so that the package is importable.
    """
    stem = Path(folder).resolve().name.lower()
    words = [w for w in re.split(r"[^a-z0-9]+", stem) if w]
    if not words:
        words = ["my", "observers"]
    if not words[0][0].isalpha():
        words.insert(0, "observers")
    return "-".join(words), "_".join(words)


def _template_text(name: str) -> str:
    return (files("roadtruth.harness") / name).read_text(encoding="utf-8")


def render_project(folder: str | Path) -> dict[str, str]:
    """Relative path -> text of every file of the starter project for ``folder`` (nothing written)."""
    distribution, package = project_names(folder)
    out: dict[str, str] = {}
    for template, target in PROJECT_FILES.items():
        text = _template_text(template)
        if template in _FILLED:
            text = Template(text).substitute(distribution=distribution, package=package)
        out[target.format(package=package)] = text
    return out


def _refuse_existing(folder: Path, shown: str) -> None:
    if folder.is_symlink() or (folder.exists() and not folder.is_dir()):
        raise OutputPathError(f"init: {shown} exists and is not a folder; give a new or empty folder")
    if folder.is_dir():
        try:
            entries = next(os.scandir(folder), None)
        except OSError as exc:
            raise OutputPathError(f"init: {shown} cannot be read ({exc.strerror or type(exc).__name__})") from None
        if entries is not None:
            raise OutputPathError(f"init: {shown} is not empty; roadtruth init writes only into a new or "
                                  "empty folder (it never replaces files)")


def init_project(folder: str | Path) -> list[Path]:
    """Write the starter project into ``folder`` (new or empty) and return the files written.

    Raises :class:`roadtruth.harness.files.outdir.OutputPathError` (exit 2) before writing anything if ``folder`` is
    a file, a non-empty folder or not writable.
    """
    shown = str(folder)
    target = Path(folder).absolute()
    _refuse_existing(target, shown)
    check_writable(target, what="init:", folder=True)
    texts = render_project(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = Path(tempfile.mkdtemp(prefix=f".{target.name}.roadtruth-init-", dir=target.parent))
    try:
        for rel, text in texts.items():
            p = partial / rel
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_text(text, encoding="utf-8")
        partial.chmod(0o777 & ~_umask())
        # The empty folder (if any) is replaced by the complete one; rmdir fails if a file appeared.
        if target.is_dir():
            try:
                target.rmdir()
            except OSError:
                raise OutputPathError(f"init: {shown} is not empty; roadtruth init writes only into a new "
                                      "or empty folder (it never replaces files)") from None
        try:
            partial.rename(target)
        except OSError:
            raise OutputPathError(f"init: {shown} appeared while writing; nothing was replaced") from None
    finally:
        if partial.exists():
            shutil.rmtree(partial, ignore_errors=True)
    return [target / rel for rel in texts]


def _umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask
