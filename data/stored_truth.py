"""Tables kept on disk so that a long run's memory does not grow with its length: tracks in
unnamed temporary files read back by rows (`TrackFiles`), and a truth table on them
(`StoredTruth`): a simulation's as it makes it, a recording's truth.csv as it is read."""

from __future__ import annotations

import tempfile
import weakref
from collections.abc import Mapping
from typing import IO, Iterator

import numpy as np

from boomtip.data.frames import HOOK_TRUTH_COLUMNS, Truth
from boomtip.data.io.blocks import read_into, write_all

__all__ = ["TrackFiles", "StoredTruth"]


def _close_all(files: dict) -> None:
    for fh in files.values():
        fh.close()


class TrackFiles:
    """Arrays of a common length, each in an unnamed temporary file (removed when closed or
    collected), appended a chunk of rows at a time and read back by rows. Unbuffered writes and
    positional reads (data.io.blocks): a forked process reading the same files neither moves this
    one's offsets nor writes again what this one had pending."""

    def __init__(self) -> None:
        self._files: dict[str, IO[bytes]] = {}
        self._row_shape: dict[str, tuple[int, ...]] = {}
        self._rows: dict[str, int] = {}
        weakref.finalize(self, _close_all, self._files)  # the files closed with the tracks, however they end

    def append(self, name: str, rows: np.ndarray) -> None:
        rows = np.ascontiguousarray(rows, dtype=float)
        if name not in self._files:
            # unbuffered: nothing pending that a forked process's copy could write again
            self._files[name] = tempfile.TemporaryFile(prefix="boomtip-track-", buffering=0)
            self._row_shape[name], self._rows[name] = rows.shape[1:], 0
        write_all(self._files[name], rows.tobytes())
        self._rows[name] += len(rows)

    def replace(self, name: str, rows: np.ndarray) -> None:
        """The track's rows, instead of what it held (a new file; the old one is closed)."""
        if name in self._files:
            self._files.pop(name).close()
        self.append(name, rows)

    def read(self, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Rows start..stop-1 of a track."""
        fh, shape = self._files[name], self._row_shape[name]
        stop = self._rows[name] if stop is None else min(stop, self._rows[name])
        out = np.empty((max(stop - start, 0), *shape))
        if out.size:
            row_bytes = out.itemsize * int(np.prod(shape, dtype=int))
            read_into(fh, out, start * row_bytes)
        return out

    def interp(self, name: str, t: np.ndarray, t_grid: np.ndarray, **kw) -> np.ndarray:
        """``np.interp`` of the track (per column) at t over the grid t_grid, reading only the rows
        that bracket t: each value depends on its two neighbours alone, so the same numbers."""
        t = np.asarray(t, dtype=float)
        if t.size and np.all(np.isfinite(t)):
            i0 = max(int(np.searchsorted(t_grid, t.min(), "right")) - 1, 0)
            i1 = min(int(np.searchsorted(t_grid, t.max(), "left")) + 1, len(t_grid))
        else:
            i0, i1 = 0, len(t_grid)
        v, tg = self.read(name, i0, i1), t_grid[i0:i1]
        if v.ndim == 1:
            return np.interp(t, tg, v, **kw)
        return np.stack([np.interp(t, tg, v[:, k], **kw) for k in range(v.shape[1])], axis=-1)


class _TruthColumns(Mapping):
    """The truth table's columns, each read from its file when asked for."""

    def __init__(self, t: np.ndarray, files: TrackFiles, names: tuple[str, ...]) -> None:
        self._t, self._files, self._names = t, files, names

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "t":
            return self._t
        if name not in self._names:
            raise KeyError(name)
        return self._files.read(name)

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)


class StoredTruth(Truth):
    """A truth table with its columns on disk (`TrackFiles`), a simulation's or a recording's:
    ``at`` reads only the rows about the asked times, ``columns`` reads a whole column when indexed."""

    def __init__(self, t: np.ndarray, files: TrackFiles, names: tuple[str, ...] = HOOK_TRUTH_COLUMNS) -> None:  # noqa: D107 (no dataclass fields of its own)
        self._t, self._files, self._names = t, files, names

    @property
    def columns(self) -> Mapping:
        return _TruthColumns(self._t, self._files, self._names)

    def at(self, name: str, t_s: np.ndarray) -> np.ndarray:
        if name == "t":
            return super().at(name, t_s)
        return self._files.interp(name, t_s, self._t, left=np.nan, right=np.nan)

    @classmethod
    def of_columns(cls, columns: Mapping[str, np.ndarray], names: tuple[str, ...]) -> "StoredTruth":
        """A truth table read whole (a recording's truth.csv), its columns but the time put on disk."""
        files = TrackFiles()
        for name in names:
            if name != "t":
                files.append(name, np.asarray(columns[name], dtype=float))
        return cls(np.array(columns["t"], dtype=float), files, tuple(names))  # a copy: a view would keep the whole table
