"""Blocks of float64 rows in an unnamed temporary file (removed when closed or collected): where
a long run keeps its per-frame history instead of in memory. Writes are finished or fail (a short
write would shift every later row); reads are positional (``os.preadv``), so a forked process
reading the same file does not move this one's offset, and a short read fails."""

from __future__ import annotations

import os
import tempfile
import weakref

import numpy as np

__all__ = ["DiskBlocks", "write_all", "read_into"]


def _named(file) -> str:
    """A file's name for a message: an unnamed temporary file's is its descriptor's number."""
    return file.name if isinstance(file.name, str) else f"a temporary file of the run (in {tempfile.gettempdir()})"


def write_all(file, data: bytes) -> None:
    """An unbuffered write may write less than asked (a full disk): finished, or it fails."""
    view = memoryview(data)
    while len(view):
        n = file.write(view)
        if not n:
            raise OSError(f"{_named(file)}: no space left to write")
        view = view[n:]


def read_into(file, out: np.ndarray, offset: int) -> None:
    """Fill `out` from the file at `offset`, or fail: a short read would leave np.empty's garbage."""
    n = os.preadv(file.fileno(), [memoryview(out).cast("B")], offset)
    if n != out.nbytes:
        raise OSError(f"{_named(file)}: read {n} of {out.nbytes} bytes at {offset}")


class DiskBlocks:
    """A fusion.records.BlockStore on disk: blocks of rows of one width, appended, read by row ranges."""

    def __init__(self, prefix: str = "boomtip-records-") -> None:
        # unbuffered: a forked process holding this object has no write of it pending
        self._file = tempfile.TemporaryFile(prefix=prefix, buffering=0)
        self._closer = weakref.finalize(self, self._file.close)  # closed with this store, however it ends
        self._width: int | None = None
        self._n = 0

    def write(self, block: np.ndarray) -> None:
        block = np.ascontiguousarray(block, dtype=float)
        if self._width is None:
            self._width = block.shape[1]
        elif block.shape[1] != self._width:
            raise ValueError(f"rows of {block.shape[1]} values written to a store of rows of {self._width}")
        write_all(self._file, block.tobytes())
        self._n += len(block)

    def __len__(self) -> int:
        return self._n

    def read(self, start: int, stop: int) -> np.ndarray:
        start, stop = max(start, 0), min(stop, self._n)
        out = np.empty((max(stop - start, 0), self._width or 0))
        if out.size:
            read_into(self._file, out, start * out.shape[1] * 8)
        return out

    def close(self) -> None:
        self._closer()
