"""Per-stage wall-clock timing.

Every pipeline stage reports its own time so that APT (average processing time per
measurement cycle, document 000 section 5.1.2) tables come from the pipeline itself,
not from a stopwatch wrapped around it.
"""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager
from typing import Iterator


class StageTimes:
    """Accumulates milliseconds per named stage for one frame (or one run)."""

    def __init__(self) -> None:
        self.ms: dict[str, float] = defaultdict(float)

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.ms[name] += (time.perf_counter() - start) * 1e3

    def total(self, *names: str) -> float:
        """Sum of the named stages (all stages when no name is given)."""
        keys = names or tuple(self.ms)
        return float(sum(self.ms.get(k, 0.0) for k in keys))

    def merge(self, other: "StageTimes") -> None:
        for k, v in other.ms.items():
            self.ms[k] += v
