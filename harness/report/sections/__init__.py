"""Report sections, one per file; ``roadtruth.harness.report.builder.default_sections`` orders them."""
