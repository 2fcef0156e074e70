"""Shared fixtures. Offscreen rendering must be selected before mujoco is imported."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")


from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

#: Set to 1 (CI does) to make tests that need the recorded example log fail instead of skip.
REQUIRE_DATA_ENV = "ROADTRUTH_REQUIRE_DATA"
#: The recorded example log (Revs Program, Stanford: Ferrari 250 LM, 2014-02-22), kept beside the
#: repository in ``../shared/data`` rather than in it.
REVS_LOG = (Path(__file__).resolve().parents[1].parent / "shared" / "data" / "revs-250lm"
            / "revs_250lm_2014-02-22.csv.gz")


@pytest.fixture(scope="session", autouse=True)
def _session_cache(tmp_path_factory: pytest.TempPathFactory):
    """Every test session gets its own cache folder: tests neither read entries a previous session or
    the user left in the user cache folder nor write there."""
    mp = pytest.MonkeyPatch()
    mp.setenv("ROADTRUTH_CACHE", str(tmp_path_factory.mktemp("cache")))
    yield
    mp.undo()


@pytest.fixture(scope="module")
def isolated_design_cache(tmp_path_factory: pytest.TempPathFactory):
    """A fresh LMI design cache per test module, so tests never read designs another module left
    (nor the designs shipped with the package: these tests exercise the design code itself)."""
    mp = pytest.MonkeyPatch()
    mp.setenv("ROADTRUTH_CACHE", str(tmp_path_factory.mktemp("designs")))
    mp.setenv("ROADTRUTH_SHIPPED_DESIGNS", "0")
    yield
    mp.undo()


@pytest.fixture(scope="session")
def revs_log() -> Path:
    """The recorded Revs log; skips (or fails with ``ROADTRUTH_REQUIRE_DATA=1``) when it is absent."""
    return require_data(REVS_LOG, "recorded example log")


def require_data(path: Path, what: str) -> Path:
    """``path`` if it exists; otherwise skip the calling test with a reason naming the missing file,
    or fail it when ``$ROADTRUTH_REQUIRE_DATA`` is 1 (CI: the data must be there)."""
    if path.is_file():
        return path
    msg = f"{what} not found: {path} (it sits beside the repository, in ../shared/data)"
    if os.environ.get(REQUIRE_DATA_ENV, "").strip() == "1":
        pytest.fail(f"{msg}; {REQUIRE_DATA_ENV}=1 requires it", pytrace=False)
    pytest.skip(msg)
