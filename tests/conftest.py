"""Shared fixtures. Offscreen rendering must be selected before mujoco is imported."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")


import pytest  # noqa: E402


@pytest.fixture(scope="module")
def isolated_design_cache(tmp_path_factory: pytest.TempPathFactory):
    """A fresh LMI design cache per test module, so tests never read designs another run left."""
    mp = pytest.MonkeyPatch()
    mp.setenv("ROADTRUTH_CACHE", str(tmp_path_factory.mktemp("designs")))
    yield
    mp.undo()
