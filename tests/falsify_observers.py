"""A synthetic interval observer with a known breaking point, for the falsification tests.

``mu_promise`` claims the road friction under the front-left wheel lies in [0.6, 2.0] (its promise
assumes μ ≥ 0.6): it outputs the constant interval whatever it measures. Its inclusion therefore
fails exactly when the front-left wheel drives on a μ below ``BREAKING_MU``, and its robustness is
``min μ_fl − 0.6``. Importable by module name, so worker and observer-host processes find it.
"""

from __future__ import annotations

from roadtruth.observers.base import ScalarLoopObserver

BREAKING_MU = 0.6


class MuPromise(ScalarLoopObserver):
    name = "mu_promise"
    citation = "test observer: promises mu >= 0.6"
    inputs = ("yaw_rate_radps",)
    states = ("mu_fl",)
    has_bounds = True

    def _initial_state(self) -> list[float]:
        return [1.0]

    def _advance(self, t_s: float, y: list[float]) -> None:
        pass  # the promise does not depend on what it measures

    def _values(self) -> list[float]:
        return [1.0]

    def _bounds(self) -> tuple[list[float], list[float]]:
        return [BREAKING_MU], [2.0]
