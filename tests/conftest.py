"""Shared fixtures. Offscreen rendering must be selected before mujoco is imported."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
