"""Benchmarks: each measures boomtip against a baseline in the same run and reports the ratio."""
