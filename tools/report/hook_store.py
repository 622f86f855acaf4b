"""A hook estimator's recorded samples kept on disk while the run goes on, so that a run's memory
does not grow with its length: a 700 s run records 140,000 samples per estimator (200 Hz), four
estimators, which in memory would take several hundred MB. The KPIs, the estimates CSV and the report
read them back a chunk at a time.

Each sample is one float64 record: t, the hook's world position and velocity (from the states),
its position and velocity relative to the tip and that position's covariance (world axes).
"""

from __future__ import annotations

import hashlib
import tempfile
import weakref
from pathlib import Path
from typing import IO, Iterator

import numpy as np

from boomtip.fusion.hook_run import HookRunChunk
from boomtip.tools.report.hook_eval import world_hook_from_states

__all__ = ["COV_P", "EstimateStore", "StoredSamples", "P", "V", "P_REL", "V_REL"]

# record layout: column slices
T, P, V, P_REL, V_REL, COV_P = slice(0, 1), slice(1, 4), slice(4, 7), slice(7, 10), slice(10, 13), slice(13, 22)
RECORD = 22
READ_CHUNK = 8192  # samples read back at a time


class StoredSamples:
    """One chunk of samples read back: views into one (M, 22) float64 block."""

    def __init__(self, block: np.ndarray) -> None:
        self.block = block
        self.t = block[:, 0]
        self.p_hook = block[:, P]
        self.v_hook = block[:, V]
        self.p_rel = block[:, P_REL]
        self.v_rel = block[:, V_REL]
        self.cov_p = block[:, COV_P].reshape(-1, 3, 3)


class EstimateStore:
    """The sink of one estimator's run (fusion.hook_run.run_hook_filter's ``sink``): appends each
    chunk to an unnamed temporary file (removed when closed or collected) and keeps a SHA-1 of the
    states, so two runs can be told equal without keeping either."""

    def __init__(self, params) -> None:
        self.params = params
        self._file: IO[bytes] = tempfile.TemporaryFile(prefix="boomtip-hook-")
        weakref.finalize(self, self._file.close)  # closed with the store, however it ends
        self._sha1 = hashlib.sha1()
        self._sha1_hex: str | None = None  # the digest of a run filled by another process
        self.n = 0
        self.t_first = self.t_last = float("nan")

    def __call__(self, chunk: HookRunChunk) -> None:
        _, _, p, v = world_hook_from_states(self.params, chunk.x)
        block = np.empty((len(chunk.t), RECORD))
        block[:, 0] = chunk.t
        block[:, P], block[:, V], block[:, P_REL], block[:, V_REL] = p, v, chunk.p_rel, chunk.v_rel
        block[:, COV_P] = chunk.cov_p.reshape(-1, 9)
        self._file.write(block.tobytes())
        self._sha1.update(np.ascontiguousarray(chunk.x).tobytes())
        if self.n == 0:
            self.t_first = float(chunk.t[0])
        self.t_last = float(chunk.t[-1])
        self.n += len(chunk.t)

    @property
    def states_sha1(self) -> str:
        return self._sha1_hex or self._sha1.hexdigest()

    def state(self) -> tuple[int, float, float, str]:
        """What another process needs to read this store (its file is shared through a fork):
        flushes the samples to the file first."""
        self._file.flush()
        return self.n, self.t_first, self.t_last, self.states_sha1

    def adopt(self, state: tuple[int, float, float, str]) -> None:
        """Take the samples another process wrote to this store's file (``state()`` there)."""
        self.n, self.t_first, self.t_last, self._sha1_hex = state

    def chunks(self, size: int | None = None) -> Iterator[StoredSamples]:
        """The samples in order, ``size`` (default READ_CHUNK) at a time."""
        size = size or READ_CHUNK
        self._file.flush()
        self._file.seek(0)
        for a in range(0, self.n, size):
            m = min(size, self.n - a)
            buf = np.empty((m, RECORD))
            self._file.readinto(memoryview(buf).cast("B"))
            yield StoredSamples(buf)

    def columns(self, cols: slice, every: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """(t, the record's columns ``cols``, e.g. ``P``) of every ``every``-th sample."""
        t, v = [np.zeros(0)], [np.zeros((0, len(range(RECORD)[cols])))]
        for a, c in zip(range(0, self.n, READ_CHUNK), self.chunks(READ_CHUNK)):
            sel = slice((-a) % every, None, every)  # the samples a + i with (a + i) % every == 0
            # copies: a view would keep its whole chunk (READ_CHUNK records) alive until the end,
            # a 700 s run's every chunk (25 MB) for a plot of 5,000 points
            t.append(c.t[sel].copy())
            v.append(c.block[sel, cols].copy())
        return np.concatenate(t), np.concatenate(v)

    def close(self) -> None:
        self._file.close()
