"""Benchmarks of the filters package (paper Table I)."""
