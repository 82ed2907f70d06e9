"""Benchmarks (not shipped): alignment against registration baselines."""
