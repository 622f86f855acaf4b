"""Per-stage wall-clock timing.

Every pipeline stage reports its own time so that APT (average processing time per
measurement cycle, document 000 section 5.1.2) tables come from the pipeline itself,
not from a stopwatch wrapped around it.
"""

from __future__ import annotations

import time
from collections import defaultdict


class StageTimes:
    """Accumulates milliseconds per named stage for one frame (or one run)."""

    def __init__(self) -> None:
        self.ms: dict[str, float] = defaultdict(float)

    def stage(self, name: str) -> "_Stage":
        """`with times.stage("deck.planes"): ...` adds the block's wall time to that stage."""
        return _Stage(self.ms, name)

    def total(self, *names: str) -> float:
        """Sum of the named stages (all stages when no name is given)."""
        keys = names or tuple(self.ms)
        return float(sum(self.ms.get(k, 0.0) for k in keys))

    def merge(self, other: "StageTimes") -> None:
        for k, v in other.ms.items():
            self.ms[k] += v


class _Stage:
    """A plain context manager, not @contextmanager: a generator-based one costs a few
    microseconds per use, which shows in stages that themselves take tens of microseconds."""

    __slots__ = ("ms", "name", "start")

    def __init__(self, ms: dict[str, float], name: str) -> None:
        self.ms, self.name = ms, name

    def __enter__(self) -> None:
        self.start = time.perf_counter()

    def __exit__(self, *exc) -> None:
        self.ms[self.name] += (time.perf_counter() - self.start) * 1e3
