"""Imported by the worker pools' multiprocessing forkserver before it forks any worker (and nowhere else).

Importing this module warms the importing process (:func:`roadtruth.harness.jobs.warm_start.warm_process`):
every heavy import, every observer, numba's target context, and ``gc.freeze``. The forkserver only
forks; it never renders, so its workers may still make an OpenGL context after the fork.
"""

from __future__ import annotations

from roadtruth.harness.jobs.warm_start import leave_without_teardown, warm_process

warm_process()
leave_without_teardown()
