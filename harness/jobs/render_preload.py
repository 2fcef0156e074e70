"""Imported by the pools' forkserver when the run's only workers are renderers (``run`` without
``--jobs``): the renderer's imports and ``gc.freeze``, without the observers and numba's set-up that
a scenario worker needs (about 2 s of CPU a renderer never uses). It never renders itself.
"""

from __future__ import annotations

from roadtruth.harness.jobs.warm_start import leave_without_teardown, warm_renderer

warm_renderer()
leave_without_teardown()
