"""Benchmarks (run as modules, e.g. `python -m bench.train_step`); not part of the test suite."""
