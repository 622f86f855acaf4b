"""`bench startup` times each command in a fresh interpreter and states its ratio and verdict."""

from __future__ import annotations

from boomtip.tools.bench.startup import CEILING_S, STARTUP_COMMANDS, bench_startup


def test_the_figures_are_each_commands_median_and_the_ratio_follows_from_them():
    r = bench_startup(repeats=1)
    assert set(r["commands"]) == set(STARTUP_COMMANDS)
    for c in r["commands"].values():
        assert 0 < c["min_s"] <= c["median_s"] <= c["max_s"]
    assert r["slowest_s"] == max(c["median_s"] for c in r["commands"].values())
    assert r["ratio"] == r["load_all_s"] / r["slowest_s"]
    assert r["within_ceiling"] == (r["slowest_s"] <= CEILING_S)
