#!/usr/bin/env bash
# Set up a fresh virtual environment from pyproject.toml and run the linter and the test suite.
# Used verbatim by CI (.ci/run). On Debian as root it also installs the system packages the tests
# use for real: Mesa (offscreen MuJoCo rendering) and Chromium (the report is opened in a browser).
# Tests that read the recorded example log (../shared/data beside the repository) skip when it is
# absent; ROADTRUTH_REQUIRE_DATA=1 (set by .ci/run) makes them fail instead.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
  need=""
  command -v chromium >/dev/null || need="$need chromium"
  dpkg -s libosmesa6 >/dev/null 2>&1 || need="$need libosmesa6"
  dpkg -s libegl1 >/dev/null 2>&1 || need="$need libegl1 libgl1-mesa-dri"
  if [ -n "$need" ]; then
    apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $need >/dev/null
  fi
fi
python3 -m venv .venv
.venv/bin/pip install -q --upgrade pip
.venv/bin/pip install -q -e '.[test]'
export MUJOCO_GL="${MUJOCO_GL:-egl}"
.venv/bin/ruff check roadtruth harness observers mjcf tests benchmarks scripts
.venv/bin/python -m pytest -q -n 2 "$@"
