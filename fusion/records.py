"""A filter's per-frame history as fixed-width float64 rows, held a block at a time: the full
blocks go to a store, in memory by default (`MemoryBlocks`) or wherever the caller keeps them
(a file: the chains keep a long run's history on disk, so that a run's memory does not grow with
its length). The last row stays in memory and may still be amended."""

from __future__ import annotations

from typing import Protocol

import numpy as np

__all__ = ["BlockStore", "MemoryBlocks", "Records", "RECORDS_BLOCK"]

RECORDS_BLOCK = 1024  # rows held in memory before they go to the store


class BlockStore(Protocol):
    """Where full blocks of rows go: appended in order, read back by row ranges. `write` is
    given the caller's buffer, which is reused: a store keeps a copy (or the bytes)."""

    def write(self, block: np.ndarray) -> None: ...

    def read(self, start: int, stop: int) -> np.ndarray: ...


class MemoryBlocks:
    """The blocks kept in memory, as written."""

    def __init__(self) -> None:
        self._blocks: list[np.ndarray] = []
        self._starts: list[int] = []
        self._n = 0

    def write(self, block: np.ndarray) -> None:
        self._blocks.append(np.array(block, dtype=float))
        self._starts.append(self._n)
        self._n += len(block)

    def read(self, start: int, stop: int) -> np.ndarray:
        parts = [b[max(start - s, 0):max(stop - s, 0)] for s, b in zip(self._starts, self._blocks)
                 if s < stop and s + len(b) > start]
        return np.concatenate(parts) if parts else np.zeros((0, self._blocks[0].shape[1] if self._blocks else 0))


class Records:
    """Rows of `width` float64 numbers appended one at a time."""

    def __init__(self, width: int, store: BlockStore | None = None, block_rows: int = RECORDS_BLOCK) -> None:
        self.width = width
        self.store: BlockStore = store if store is not None else MemoryBlocks()
        self._buf = np.empty((block_rows, width))
        self._n_buf = self._n_stored = 0

    def append(self, row: np.ndarray) -> None:
        if self._n_buf == len(self._buf):  # only now: the last row stays amendable
            self.store.write(self._buf)
            self._n_stored += self._n_buf
            self._n_buf = 0
        self._buf[self._n_buf] = row
        self._n_buf += 1

    def __len__(self) -> int:
        return self._n_stored + self._n_buf

    @property
    def last(self) -> np.ndarray:
        """The last row, a view: what is written to it is recorded."""
        if not len(self):
            raise IndexError("no row recorded yet")
        return self._buf[self._n_buf - 1]

    def read(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Rows start..stop-1 (a copy)."""
        n = len(self)
        stop = n if stop is None else min(stop, n)
        start = min(max(start, 0), stop)
        parts = []
        if start < self._n_stored:
            parts.append(self.store.read(start, min(stop, self._n_stored)))
        if stop > self._n_stored:
            parts.append(self._buf[max(start - self._n_stored, 0):stop - self._n_stored].copy())
        return np.concatenate(parts) if parts else np.zeros((0, self.width))

    def column(self, cols: int | slice) -> np.ndarray:
        """Columns `cols` of every row, read a block at a time."""
        step = len(self._buf)
        parts = [self.read(a, a + step)[:, cols] for a in range(0, len(self), step)]
        return np.concatenate(parts) if parts else self._buf[:0, cols].copy()
