"""What a simulation keeps compactly, so that its memory does not grow with the run's length:
the frame schedule as arrays (`FrameSchedule`), and the truth made a chunk of rows at a time
(on disk: data/stored_truth.py)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Iterator

import numpy as np

__all__ = ["TRUTH_CHUNK", "FrameSchedule"]

TRUTH_CHUNK = 4096  # truth rows made at a time


class FrameSchedule(Sequence):
    """A simulation's frame schedule, (time stamp, sensor, index) in order, as arrays (13 bytes a
    frame): as a list of tuples a 700 s hook run's 14,000 frames would hold 1.7 MB for the whole run."""

    def __init__(self, items: list[tuple[float, str, int]]) -> None:
        self._sensors = sorted({s for _, s, _ in items})
        code = {s: k for k, s in enumerate(self._sensors)}
        self._t = np.array([t for t, _, _ in items], float)
        self._s = np.array([code[s] for _, s, _ in items], np.int8)
        self._i = np.array([i for _, _, i in items], np.int32)

    def __len__(self) -> int:
        return len(self._t)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[j] for j in range(*k.indices(len(self)))]
        return float(self._t[k]), self._sensors[int(self._s[k])], int(self._i[k])

    def __iter__(self) -> Iterator[tuple[float, str, int]]:
        for a in range(0, len(self), TRUTH_CHUNK):  # a chunk at a time as Python values
            b = a + TRUTH_CHUNK
            for t, s, i in zip(self._t[a:b].tolist(), self._s[a:b].tolist(), self._i[a:b].tolist()):
                yield t, self._sensors[s], i
