"""Benchmarks (run as modules, e.g. `python -m bench.released_comparison`); not part of the test suite."""
