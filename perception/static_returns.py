"""Returns that are static in the sensor frame: the own vessel, the boom, the rope, the hook
and its load. They move with the sensor, not with the feeder, so a registration to the
feeder's model must not see them: 2k of them in a 20k-point frame raised kiss-icp's error
from 1.3 to 8 cm.

A sensor-frame voxel that has held a return in nearly every frame of the recent window is
static; the feeder's deck, moved by the waves relative to the boom tip, crosses a voxel
and leaves it. Each frame's occupancy is dilated by one voxel before it is counted, so a
static surface whose noise straddles a voxel face still counts as held.

The counts live in a fixed hash table (not a dict keyed by voxel): counting a frame is one
`np.unique` and one fancy-indexed add, whatever the number of voxels. A collision can only
make a voxel look more static than it is; at 2^22 slots and ~1e5 voxels in a window, rare.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

_TABLE_BITS = 22
_OFF = 1 << 20  # voxel coordinates are packed 21 bits an axis: +-2^20 voxels of 0.3 m is 300 km
# the packed offsets of a voxel and its six face neighbours
_NEIGHBOURS = np.array([0, 1, -1, 1 << 21, -(1 << 21), 1 << 42, -(1 << 42)], dtype=np.int64)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


class StaticReturnsConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    voxel_m: float = Field(0.5, gt=0, description="sensor-frame voxel edge (dilated by one: a heaving deck still leaves it)")
    window_s: float = Field(12.0, gt=0, description="the occupancy window: longer than a wave period")
    min_fraction: float = Field(0.9, gt=0, le=1, description="a voxel held in this fraction of the window's frames is static")
    warmup_s: float = Field(4.0, ge=0, description="history needed before the mask is trusted")


def packed_voxels(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """Integer voxel coordinates packed into one int64 each (21 bits an axis)."""
    k = np.floor(points / voxel_m).astype(np.int64) + _OFF
    return (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]


def voxel_hash(packed: np.ndarray) -> np.ndarray:
    """Packed voxels -> table slots: Fibonacci hashing (the top bits of a golden-ratio product)."""
    return ((packed.astype(np.uint64) * _GOLDEN) >> np.uint64(64 - _TABLE_BITS)).astype(np.int64)


class StaticReturns:
    """Counts, per sensor-frame voxel, the frames of the window in which it held a return."""

    def __init__(self, cfg: StaticReturnsConfig | None = None) -> None:
        self.cfg = cfg or StaticReturnsConfig()
        self.counts = np.zeros(1 << _TABLE_BITS, dtype=np.int32)
        self.frames: deque[tuple[float, np.ndarray]] = deque()  # (t, the frame's voxels)
        self.t_first: float | None = None

    def _slots(self, points_sensor: np.ndarray) -> np.ndarray:
        return voxel_hash(packed_voxels(points_sensor, self.cfg.voxel_m))

    def _dilated_slots(self, keys: np.ndarray) -> np.ndarray:
        return voxel_hash((keys[:, None] + _NEIGHBOURS[None]).ravel())

    def add(self, t_s: float, points_sensor: np.ndarray) -> None:
        """Count one frame's returns (finite points, sensor frame). `counts[slots] += 1` adds one
        per distinct slot however often it repeats (numpy's buffered fancy add): a frame counts
        a voxel once, with no sort of the dilated slots; the frame keeps its voxels, not its
        slots, to take them off again when it leaves the window."""
        keys = np.unique(packed_voxels(points_sensor, self.cfg.voxel_m))  # 1-D: a sort, not a lexsort
        self.counts[self._dilated_slots(keys)] += 1
        self.frames.append((t_s, keys))
        self.t_first = t_s if self.t_first is None else self.t_first
        while self.frames and self.frames[0][0] < t_s - self.cfg.window_s:
            _, old = self.frames.popleft()
            self.counts[self._dilated_slots(old)] -= 1

    @property
    def ready(self) -> bool:
        """Enough history that a voxel the deck crossed has been left again."""
        return bool(self.frames) and self.frames[-1][0] - self.t_first >= self.cfg.warmup_s

    def static_mask(self, points_sensor: np.ndarray) -> np.ndarray:
        """True where a point falls in a voxel held in min_fraction of the window's frames."""
        need = max(2, int(np.ceil(self.cfg.min_fraction * len(self.frames))))
        return self.counts[self._slots(points_sensor)] >= need
