"""A fresh virtual environment with roadtruth "installed", shared by the scaffold and CI-template tests.

Nothing is downloaded: the new environment sees this checkout's environment (``sys.prefix`` of the
test run) through a ``.pth`` file, so ``pip install roadtruth`` finds it already satisfied, and gets
the ``roadtruth`` launcher pip writes for the console script. Packages installed into it (the user's
plug-in project) go into its own site-packages. The environment is built once per test session.
"""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

#: pip may not reach a package index in the tests: everything needed is already installed.
OFFLINE_PIP = {"PIP_NO_INDEX": "1", "PIP_NO_BUILD_ISOLATION": "0", "PIP_DISABLE_PIP_VERSION_CHECK": "1"}


def _new_venv(root: Path) -> Path:
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(root)], check=True, capture_output=True)
    py = root / "bin" / "python"
    purelib = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             check=True, capture_output=True, text=True).stdout.strip()
    base = sysconfig.get_paths()["purelib"]
    # addsitedir (not a plain path line) so that the base's own .pth files (editable installs) apply.
    Path(purelib, "_roadtruth_base.pth").write_text(f"import site; site.addsitedir({base!r})\n")
    launcher = root / "bin" / "roadtruth"
    launcher.write_text(f"#!{py}\nimport sys\nfrom roadtruth.harness.cli import main\nsys.exit(main())\n")
    launcher.chmod(0o755)
    return root


def fresh_venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The session's fresh virtual environment (created on first use)."""
    root = tmp_path_factory.getbasetemp() / "fresh-venv"
    done = root / ".ready"
    if not done.exists():
        _new_venv(root)
        done.write_text("ok\n")
    return root


def venv_env(venv: Path, extra: dict[str, str] | None = None) -> dict[str, str]:
    """Environment of a shell in ``venv`` (its bin first on PATH, pip offline, no outer PYTHONPATH)."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env.update(OFFLINE_PIP)
    env["VIRTUAL_ENV"] = str(venv)
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env.setdefault("MUJOCO_GL", "egl")
    env.update(extra or {})
    return env


def run_shell(command: str, cwd: Path, env: dict[str, str], timeout_s: float = 600.0) -> subprocess.CompletedProcess:
    """Run one workflow ``run:``/``script:`` entry with bash -e, as the CI runners do."""
    return subprocess.run(["bash", "-e", "-c", command], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout_s)
