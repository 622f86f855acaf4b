"""Returns that are static in the sensor frame: the own vessel, the boom, the rope, the hook
and its load. They move with the sensor, not with the feeder, so a registration to the
feeder's model must not see them: static returns making up a tenth of a frame are enough to
bias a registration by centimetres.

Two tests, chosen by `method`:
- `rays` (the default, for a LiDAR whose beams repeat their directions frame after frame:
  spinning and grid patterns): a beam direction whose range has stayed within a band about
  this return's range in nearly every frame the beam returned anything is static. The feeder,
  moved by the waves, changes every beam's range by decimetres; the own hull keeps its range
  to the noise, even when waves at its waterline or the feeder in front take the return away
  now and then (counting against the frames the beam returned, not all frames, is what keeps
  those). It marks a tiny share of the feeder's returns static where the voxel test marks a
  large part of them (every surface within a voxel and a half of where it was), and the
  registration that is left with the whole structure is far less biased.
- `voxels` (for non-repeating patterns, e.g. rosette scanners): a sensor-frame voxel that has
  held a return in nearly every frame of the window is static; the feeder's deck crosses a
  voxel and leaves it. Each frame's occupancy is dilated by one voxel before it is counted,
  so a static surface whose noise straddles a voxel face still counts as held.

The counts live in a fixed hash table (not a dict keyed by voxel): counting a frame is one
`np.unique` and one fancy-indexed add, whatever the number of voxels. A collision can only
make a voxel look more static than it is; at 2^22 slots and ~1e5 voxels in a window, rare.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

_TABLE_BITS = 22
_OFF = 1 << 20  # voxel coordinates are packed 21 bits an axis: +-2^20 voxels of 0.3 m is 300 km
# the packed offsets of a voxel and its six face neighbours
_NEIGHBOURS = np.array([0, 1, -1, 1 << 21, -(1 << 21), 1 << 42, -(1 << 42)], dtype=np.int64)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


class StaticReturnsConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    method: Literal["rays", "voxels"] = Field("rays", description="rays: a beam whose range stays put (repeating scan "
                                              "patterns); voxels: a sensor-frame voxel held in nearly every frame")
    ray_bin_deg: float = Field(0.05, gt=0, description="beam directions are told apart at this: finer than any beam "
                               "spacing (0.1-0.5 deg), coarser than the directions' rounding")
    range_bin_m: float = Field(0.1, gt=0, description="a beam's ranges are counted in bins of this")
    range_dilation: int = Field(2, ge=0, le=10, description="bins either side that count as the same range: +-0.25 m "
                                "holds a weak grazing return's noise (sd up to 6 cm)")
    ray_min_fraction: float = Field(0.8, gt=0, le=1, description="a return is static when its beam held its range in this "
                                    "fraction of the frames the beam returned")
    ray_min_presence: float = Field(0.1, gt=0, le=1, description="a beam that returned in fewer of the window's frames "
                                    "says nothing (a feeder edge seen twice at one range is not static)")
    voxel_m: float = Field(0.5, gt=0, description="voxels: sensor-frame voxel edge (dilated by one: a heaving deck still leaves it)")
    window_s: float = Field(12.0, gt=0, description="the occupancy window: longer than a wave period")
    min_fraction: float = Field(0.9, gt=0, le=1, description="voxels: a voxel held in this fraction of the window's frames is static")
    warmup_s: float = Field(4.0, ge=0, description="history needed before the mask is trusted")


def packed_voxels(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """Integer voxel coordinates packed into one int64 each (21 bits an axis)."""
    k = np.floor(points / voxel_m).astype(np.int64) + _OFF
    return (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]


def voxel_hash(packed: np.ndarray) -> np.ndarray:
    """Packed voxels -> table slots: Fibonacci hashing (the top bits of a golden-ratio product)."""
    # views, not copies: packed keys are non-negative and slots below 2^22, the same bits either way
    slots = packed.astype(np.int64, copy=False).view(np.uint64) * _GOLDEN
    slots >>= np.uint64(64 - _TABLE_BITS)
    return slots.view(np.int64)


def _bins(values: np.ndarray, bin_size: float) -> np.ndarray:
    """floor(values / bin_size) + the offset, as int64, in place on the temporary (every new
    array of a 128 x 1024 frame's returns is 0.2 MB more to allocate and fault in)."""
    values /= bin_size
    np.floor(values, out=values)
    out = values.astype(np.int64)
    out += _OFF
    return out


def _rows(a, rows: np.ndarray | None):
    """a[rows], or each array of a tuple at rows; all of it when rows is None."""
    if rows is None:
        return a
    return tuple(k[rows] for k in a) if isinstance(a, tuple) else a[rows]


def StaticReturns(cfg: StaticReturnsConfig | None = None) -> "StaticVoxels | StaticRays":
    """The static-return test the settings name."""
    cfg = cfg or StaticReturnsConfig()
    return StaticRays(cfg) if cfg.method == "rays" else StaticVoxels(cfg)


class _Window:
    """Frames in a sliding window, each with the table slots it counted, to take them off
    again when it leaves."""

    def __init__(self, cfg: StaticReturnsConfig) -> None:
        self.cfg = cfg
        self.frames: deque[tuple[float, tuple[np.ndarray, ...]]] = deque()
        self.t_first: float | None = None

    def _push(self, t_s: float, keys: tuple[np.ndarray, ...]) -> None:
        if len(self.frames) >= np.iinfo(np.int16).max:
            raise ValueError(f"static returns: more than {np.iinfo(np.int16).max} frames in a {self.cfg.window_s} s window")
        self._count(keys, 1)
        self.frames.append((t_s, keys))
        self.t_first = t_s if self.t_first is None else self.t_first
        while self.frames and self.frames[0][0] < t_s - self.cfg.window_s:
            _, old = self.frames.popleft()
            self._count(old, -1)

    def _count(self, keys: tuple[np.ndarray, ...], sign: int) -> None:
        raise NotImplementedError

    @property
    def ready(self) -> bool:
        """Enough history that a voxel or beam the deck crossed has been left again."""
        return bool(self.frames) and self.frames[-1][0] - self.t_first >= self.cfg.warmup_s


class StaticRays(_Window):
    """Counts, per beam direction, the frames it returned in and, per (direction, range bin),
    the frames its range was in that bin or near it."""

    def __init__(self, cfg: StaticReturnsConfig | None = None) -> None:
        super().__init__(cfg or StaticReturnsConfig())
        # 16-bit counts (a window holds fewer than 32 767 frames): half the table, and the
        # gathers at random slots are what the mask costs
        self.beam_counts = np.zeros(1 << _TABLE_BITS, dtype=np.int16)
        self.range_counts = np.zeros(1 << _TABLE_BITS, dtype=np.int16)
        self._bin_rad = math.radians(self.cfg.ray_bin_deg)
        d = np.arange(-self.cfg.range_dilation, self.cfg.range_dilation + 1, dtype=np.int64)
        self._dilation = d[d != 0]  # the bin itself is counted from the frame's own slots

    def keys(self, points_sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each return's beam slot, packed (beam, range bin), and its slot: computed once a
        frame for both counting it and testing it."""
        x, y, z = points_sensor[:, 0], points_sensor[:, 1], points_sensor[:, 2]
        horiz = np.hypot(x, y)
        beam = _bins(np.arctan2(y, x), self._bin_rad)  # azimuth
        beam <<= 21
        beam |= _bins(np.arctan2(z, horiz), self._bin_rad)  # elevation
        ranges = beam << 21
        ranges |= _bins(np.hypot(horiz, z), self.cfg.range_bin_m)  # 63 bits: az and el within +-2^20 bins, range within 2^20
        return voxel_hash(beam), ranges, voxel_hash(ranges)

    def _count(self, keys: tuple[np.ndarray, ...], sign: int) -> None:
        beam_slots, range_slots = keys
        self.beam_counts[beam_slots] += sign
        self.range_counts[range_slots] += sign

    def add(self, t_s: float, points_sensor: np.ndarray) -> tuple[np.ndarray, ...]:
        """Count one frame's returns (finite points, sensor frame, as measured: a voxel's
        centroid is no beam's direction). A slot repeated in one fancy-indexed add counts once
        (numpy's buffered add), and the frame is taken off the same way: no sort is needed.
        Returns the frame's keys, for `static_mask`."""
        keys = self.keys(points_sensor)
        self._push(t_s, (keys[0], keys[2]))
        return keys

    def static_mask(self, points_sensor: np.ndarray, keys: tuple[np.ndarray, ...] | None = None,
                    rows: np.ndarray | None = None) -> np.ndarray:
        """True where the return's beam held its range in ray_min_fraction of the frames it
        returned, and returned in at least ray_min_presence of the window's frames. The band of
        range bins is summed here, not spread when counting: a beam has one range a frame, so
        the sum counts each frame once, with a fifth of the hashing at every add. `keys`: what
        `add` returned for these points; `rows`: only these of them are tested."""
        keys = self.keys(_rows(points_sensor, rows)) if keys is None else _rows(keys, rows)
        beam_slots, ranges, range_slots = keys
        held = self.beam_counts.take(beam_slots)
        at_range = self.range_counts.take(range_slots).astype(np.int32)
        for d in self._dilation:  # a few bins, each vectorised (a sum along a short axis of (N, 4) is slow in numpy)
            at_range += self.range_counts.take(voxel_hash(ranges + d))
        need = max(3, int(np.ceil(self.cfg.ray_min_presence * len(self.frames))))
        return (held >= need) & (at_range >= self.cfg.ray_min_fraction * held)


class StaticVoxels(_Window):
    """Counts, per sensor-frame voxel, the frames of the window in which it held a return."""

    def __init__(self, cfg: StaticReturnsConfig | None = None) -> None:
        super().__init__(cfg or StaticReturnsConfig())
        self.counts = np.zeros(1 << _TABLE_BITS, dtype=np.int16)

    def _dilated_slots(self, keys: np.ndarray) -> np.ndarray:
        return voxel_hash((keys[:, None] + _NEIGHBOURS[None]).ravel())

    def _count(self, keys: tuple[np.ndarray, ...], sign: int) -> None:
        self.counts[self._dilated_slots(keys[0])] += sign

    def add(self, t_s: float, points_sensor: np.ndarray) -> tuple[np.ndarray, ...]:
        """Count one frame's returns (finite points, sensor frame). `counts[slots] += 1` adds one
        per distinct slot however often it repeats (numpy's buffered fancy add): a frame counts
        a voxel once, with no sort of the dilated slots; the frame keeps its voxels, not its
        slots, to take them off again when it leaves the window."""
        packed = packed_voxels(points_sensor, self.cfg.voxel_m)
        self._push(t_s, (np.unique(packed),))  # 1-D: a sort, not a lexsort
        return (packed,)

    def static_mask(self, points_sensor: np.ndarray, keys: tuple[np.ndarray, ...] | None = None,
                    rows: np.ndarray | None = None) -> np.ndarray:
        """True where a point falls in a voxel held in min_fraction of the window's frames.
        `keys`: what `add` returned for these points; `rows`: only these of them are tested."""
        need = max(2, int(np.ceil(self.cfg.min_fraction * len(self.frames))))
        packed = _rows(keys[0], rows) if keys is not None else packed_voxels(_rows(points_sensor, rows), self.cfg.voxel_m)
        return self.counts[voxel_hash(packed)] >= need
