"""Report sections, one per file; ``harness.report.builder.default_sections`` orders them."""
