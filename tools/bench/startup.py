"""`boomtip bench startup`: how long the command line takes to answer before any work, measured
as a user meets it (a fresh interpreter per call), beside the cost of loading every chain (what
a command that processes pays on top, and what every command paid when it loaded up front)."""

from __future__ import annotations

import statistics
import subprocess
import sys
import time

__all__ = ["bench_startup", "STARTUP_COMMANDS", "CEILING_S"]

STARTUP_COMMANDS = {"help": ["--help"], "scenarios": ["scenarios"]}
CEILING_S = 0.3  # what a user feels as "at once"
# the baseline: the interpreter loading the command line with every chain's modules
LOAD_ALL = ("import boomtip.tools.cli.commands, boomtip.tools.config.scenario, boomtip.tools.chains.runner, "
            "boomtip.data.sim.sources, boomtip.data.io.loaders")


def _wall_s(argv: list[str], repeats: int) -> list[float]:
    """Wall times of `argv` run afresh `repeats` times (output discarded; a failure raises)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        times.append(time.perf_counter() - t0)
    return times


def bench_startup(repeats: int = 7) -> dict:
    """Median wall time of each start-up command and of loading every chain, each run `repeats`
    times in a fresh interpreter; ratio = loading everything / the slower start-up command."""
    cli = [sys.executable, "-c", "from boomtip.tools.cli import main; main()"]
    out: dict = {"repeats": repeats, "ceiling_s": CEILING_S, "commands": {}}
    for name, args in STARTUP_COMMANDS.items():
        times = _wall_s(cli + args, repeats)
        out["commands"][name] = {"median_s": statistics.median(times), "min_s": min(times), "max_s": max(times)}
    load_all = _wall_s([sys.executable, "-c", LOAD_ALL], repeats)
    out["load_all_s"] = statistics.median(load_all)
    out["interpreter_s"] = statistics.median(_wall_s([sys.executable, "-c", "pass"], repeats))
    slowest = max(c["median_s"] for c in out["commands"].values())
    out["slowest_s"] = slowest
    out["within_ceiling"] = slowest <= CEILING_S
    out["ratio"] = out["load_all_s"] / slowest
    return out
