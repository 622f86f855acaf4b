"""A boomtip recording's frame files (OUT/lidar/*.pcd, OUT/radar/*.pcd, named by their time in
ns) in time order, as arrays."""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

__all__ = ["FRAME_SENSORS", "FrameFiles"]

FRAME_SENSORS = ("lidar", "radar")  # their folders; in this order where two frames share a time


class FrameFiles:
    """A recording's frame files in time order, as arrays (a Path per frame would be 400 bytes
    each, 7 MB for a 600 s recording's 18,000 frames): (time in ns, sensor, path) when iterated."""

    def __init__(self, root: Path, t_ns: np.ndarray, sensor_codes: np.ndarray, names: list[str]) -> None:
        # the names as UTF-8 bytes: their order is the names' own (code points)
        names_b = np.array([n.encode() for n in names], dtype=np.bytes_) if names else np.zeros(0, dtype="S1")
        order = np.lexsort((names_b, sensor_codes, t_ns))  # by time, then sensor, then name
        self.root, self._t_ns, self._sensor, self._names = root, t_ns[order], sensor_codes[order], names_b[order]

    def __len__(self) -> int:
        return len(self._t_ns)

    def __iter__(self) -> Iterator[tuple[int, str, Path]]:
        for t_ns, code, name in zip(self._t_ns.tolist(), self._sensor.tolist(), self._names.tolist()):
            sensor = FRAME_SENSORS[code]
            yield t_ns, sensor, self.root / sensor / name.decode()
