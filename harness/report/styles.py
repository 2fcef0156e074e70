"""One line style per observer, the same on every page (run, check, compare, stress, replay).

A style is a colour × dash pair. Registered observers take the slots of their position in the
sorted registry list, so ``ekf_bicycle`` looks the same in every report made by this install, and
the first 12 observers differ in colour alone (solid lines). Names the registry does not know (a
plug-in that is not installed, a renamed observer in an old run folder) take a slot after the
registered ones chosen by a stable hash of the name (CRC-32, not Python's salted ``hash``);
``observer_styles`` resolves collisions among them deterministically.

Usage from any page: ``from roadtruth.harness.report.figures import observer_style``;
``observer_style("ekf_bicycle").plotly_line(width=1.4)``.
"""

from __future__ import annotations

import sys
import zlib
from collections.abc import Iterable
from dataclasses import dataclass
from functools import cache

#: Colour-blind-safe Okabe-Ito first, then Tableau; no two alike, none close to the black truth line.
PALETTE: tuple[str, ...] = (
    "#0072B2", "#E69F00", "#009E73", "#CC79A7", "#D55E00", "#56B4E9", "#8c564b", "#7f7f7f",
    "#bcbd22", "#17becf", "#9467bd", "#882255",
)
#: Plotly dash names and the SVG stroke-dasharray that draws the same pattern in a table swatch.
DASHES: tuple[tuple[str, str], ...] = (("solid", ""), ("dash", "6,3"), ("dot", "1.5,2.5"), ("dashdot", "6,2,1.5,2"),
                                       ("longdash", "10,3"), ("longdashdot", "10,2,1.5,2"))
N_STYLES = len(PALETTE) * len(DASHES)
TRUTH_COLOUR = "#111111"


@dataclass(frozen=True)
class LineStyle:
    colour: str
    dash: str
    dasharray: str

    def plotly_line(self, width: float = 1.4) -> dict[str, object]:
        return {"color": self.colour, "dash": self.dash, "width": width}


def _slot_style(slot: int) -> LineStyle:
    colour = PALETTE[slot % len(PALETTE)]
    dash, dasharray = DASHES[(slot // len(PALETTE)) % len(DASHES)]
    return LineStyle(colour, dash, dasharray)


@cache
def registry_names() -> tuple[str, ...]:
    """Sorted names of every registered observer (empty if the registry cannot be loaded).

    From the registry when this process has imported it (``run``, ``replay``), else from the
    remembered observer listing (``roadtruth.harness.evaluation.observer_catalog``): the same names,
    without importing every observer for a ``roadtruth report`` (about 1.5 s).
    """
    try:
        registry = sys.modules.get("roadtruth.observers.registry")
        if registry is None or not registry.loaded():
            from roadtruth.harness.evaluation.observer_catalog import observer_rows

            return tuple(str(r["name"]) for r in observer_rows())
        from roadtruth.observers.registry import available_observers

        return tuple(available_observers())
    except Exception:  # noqa: BLE001 - a broken plug-in must not stop a report from being drawn
        return ()


def _hash_slot(name: str, n_registered: int) -> int:
    free = max(N_STYLES - n_registered, 1)
    return n_registered + zlib.crc32(name.encode("utf-8")) % free


def observer_style(name: str) -> LineStyle:
    """The style of one observer: its registry slot, or a stable hashed slot for unknown names."""
    names = registry_names()
    if name in names:
        return _slot_style(names.index(name))
    return _slot_style(_hash_slot(name, len(names)))


def observer_styles(names: Iterable[str]) -> dict[str, LineStyle]:
    """Styles of several observers, all distinct while there are fewer than ``N_STYLES``: registered
    ones as ``observer_style``; unknown ones from their hashed slot, moved on to the next free slot
    (in sorted name order) when two collide."""
    registered = registry_names()
    names = list(dict.fromkeys(names))
    taken = {registered.index(n) for n in names if n in registered}
    out = {n: _slot_style(registered.index(n)) for n in names if n in registered}
    for n in sorted(n for n in names if n not in registered):
        slot = _hash_slot(n, len(registered))
        for _ in range(N_STYLES):
            if slot % N_STYLES not in taken:
                break
            slot += 1
        taken.add(slot % N_STYLES)
        out[n] = _slot_style(slot % N_STYLES)
    return {n: out[n] for n in names}


def swatch_svg(style: LineStyle) -> str:
    """A small inline SVG line sample (colour and dash) for tables and legends in HTML."""
    dash = f' stroke-dasharray="{style.dasharray}"' if style.dasharray else ""
    return (f'<svg class="swatch" width="24" height="10" viewBox="0 0 24 10" aria-hidden="true">'
            f'<line x1="1" y1="5" x2="23" y2="5" stroke="{style.colour}" stroke-width="2.5"{dash}/></svg>')
