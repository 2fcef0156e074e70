"""The HTML report: sections (``sections/*.py``) rendered through Jinja templates (``templates/``).

``build_report(run_dir)`` rebuilds ``run_dir/index.html`` from the saved files alone.
"""

from harness.report.builder import ReportBuilder, build_report, default_sections, render_report

__all__ = ["ReportBuilder", "build_report", "default_sections", "render_report"]
