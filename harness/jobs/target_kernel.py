"""The one tiny kernel a process calls to have numba set up its target context ahead of real work
(:func:`roadtruth.harness.jobs.warm_start.set_up_numba`).

Kept in a module of its own that does not change: the shipped kernel bundle holds its compiled
entry, keyed to this file's contents, so editing the code around it would make every fresh install
compile it again until the bundle is rebuilt.
"""

from __future__ import annotations

from numba import njit


@njit(cache=True)
def one_more(x: float) -> float:
    return x + 1.0
