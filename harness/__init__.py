"""roadtruth harness: scenario -> truth -> measurements -> estimates -> metrics -> report."""

__version__ = "0.1.0"
