"""The heave chain's measurement rows, kept compactly while the run goes on: a 600 s run has
about 54,000 of them, which as objects (perception.pipeline.Measurement) would take 8 MB and
grow with the run. Each is a float64 record (fusion.records; on disk when given a store), its
method, quantity and status as codes into their tables; iterating gives the objects back."""

from __future__ import annotations

from typing import Iterable, Iterator

import numpy as np

from boomtip.fusion.records import BlockStore, Records
from boomtip.perception.pipeline import Measurement

__all__ = ["MeasurementRows"]

# a record: t, value, sigma, time_ms, sigma_systematic, then the codes of method, quantity, status
_FLOATS = ("t_s", "value", "sigma", "time_ms", "sigma_systematic")
_TEXTS = ("method", "quantity", "status")
WIDTH = len(_FLOATS) + len(_TEXTS)


class MeasurementRows:
    """Measurements appended in order; iterated (as often as wanted) in that order."""

    def __init__(self, store: BlockStore | None = None) -> None:
        self._records = Records(WIDTH, store)
        self._texts: dict[str, list[str]] = {k: [] for k in _TEXTS}  # each field's distinct values
        self._codes: dict[str, dict[str, int]] = {k: {} for k in _TEXTS}

    def _code(self, field: str, value: str) -> int:
        codes = self._codes[field]
        if value not in codes:
            codes[value] = len(codes)
            self._texts[field].append(value)
        return codes[value]

    def append(self, m: Measurement) -> None:
        self._records.append([*(getattr(m, k) for k in _FLOATS), *(self._code(k, getattr(m, k)) for k in _TEXTS)])

    def extend(self, rows: Iterable[Measurement]) -> None:
        for m in rows:
            self.append(m)

    def __len__(self) -> int:
        return len(self._records)

    def __iter__(self) -> Iterator[Measurement]:
        methods, quantities, statuses = (self._texts[k] for k in _TEXTS)
        step = 4096
        for a in range(0, len(self._records), step):
            block = self._records.read(a, a + step)
            codes = block[:, len(_FLOATS):].astype(np.int64).tolist()
            for (t, v, s, ms, sys), (m, q, st) in zip(block[:, :len(_FLOATS)].tolist(), codes):
                yield Measurement(t, methods[m], quantities[q], v, s, ms, statuses[st], sys)
