"""Benchmarks a person reads as tables: the paper's experiments, the estimator family, the real recordings."""
