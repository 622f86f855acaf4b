"""Frozen earlier implementations of stages, kept only as the benchmarks' baselines; no run uses them."""
