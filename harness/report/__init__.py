"""The HTML report: sections (``sections/*.py``) rendered through Jinja templates (``templates/``).

``build_report(run_dir)`` rebuilds ``run_dir/index.html`` from the saved files alone.

The builder (Jinja, plotly, the sections) is imported on first use of one of its names, not when a
submodule such as ``roadtruth.harness.report.rundata`` is imported: ``roadtruth simulate`` writes run files
through ``rundata`` and never builds a page.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from roadtruth.harness.report.builder import ReportBuilder, build_report, default_sections, render_report

__all__ = ["ReportBuilder", "build_report", "default_sections", "render_report"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from roadtruth.harness.report import builder

        return getattr(builder, name)
    raise AttributeError(f"module 'roadtruth.harness.report' has no attribute {name!r}")
