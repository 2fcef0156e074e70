"""A report section: a template name, a title, an anchor, and the context it fills the template with."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

from roadtruth.harness.report.rundata import RunData


class Section(ABC):
    """One part of the report. Subclasses set ``template``, ``title`` and ``anchor``."""

    template: str
    title: str
    anchor: str

    @abstractmethod
    def context(self, run: RunData, page: Any) -> dict[str, Any]:
        """Values for the template. ``page`` collects page-wide things (figures, observer colours)."""
