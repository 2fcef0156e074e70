"""Observers of this project, registered with roadtruth by the entry points in pyproject.toml."""
