"""How a run uses the machine: memory and cores. One small strategy the chains ask, so that the
per-frame code never decides it.

`RunResources()` (a library user's default) keeps everything in this process's memory and
runs everything here, leaving the C allocator as the process has it. `RunResources(lean=True)` (the
command line's runs) keeps a run's memory flat in its length and uses both cores:
  - per-run tables (encoders, MRU) on disk, read back by row slices (chains.hook_rows.DiskTable),
    and the per-frame records (the heave chain's measurement rows, the feeder's states) too
    (data.io.blocks.DiskBlocks);
  - a simulation's frames made in a forked child while this process perceives, and independent
    estimators shared between two forked children (chains.workers); the children run exactly
    the code a serial run would, so outputs do not depend on it;
  - glibc's free heap returned to the system every TRIM_EVERY_FRAMES frames and before forks
    (malloc_trim), and freed frames kept for the next one (mallopt: keep_freed_memory).
"""

from __future__ import annotations

import ctypes
import itertools
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence

import numpy as np

from boomtip.data.frames import Frame, FrameSource
from boomtip.data.io.blocks import DiskBlocks
from boomtip.data.sim.simulator import Simulation
from boomtip.tools.chains import workers
from boomtip.tools.chains.pictures import FramePictures
from boomtip.tools.report.hook_rows import DiskTable

__all__ = ["RunResources", "keep_freed_memory", "release_free_memory", "TRIM_EVERY_FRAMES"]

TRIM_EVERY_FRAMES = 200  # the heap's free pages returned every this many frames (10 s at 20 Hz)
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters (malloc.h)
KEEP_MMAP_THRESHOLD_BYTES = 16 << 20
KEEP_TRIM_THRESHOLD_BYTES = 64 << 20


def _libc(name: str):
    try:  # the process's own symbols: glibc's where the process has it
        return getattr(ctypes.CDLL(None), name)
    except (OSError, AttributeError, TypeError):  # not glibc (macOS, musl, Windows)
        return None


def keep_freed_memory(mmap_threshold_bytes: int = KEEP_MMAP_THRESHOLD_BYTES,
                      trim_threshold_bytes: int = KEEP_TRIM_THRESHOLD_BYTES) -> bool:
    """Have glibc serve arrays below ``mmap_threshold_bytes`` from its heap and keep up to
    ``trim_threshold_bytes`` of freed heap, process-wide. By default glibc maps large blocks
    (above 128 KiB, a threshold it raises as they are freed) from the system and trims freed heap
    back to it, so frame after frame the large arrays (a 128 x 1024 frame's columns, ranges and
    masks: 0.2-0.7 MB each) are faulted in afresh: hundreds of page faults and up to a
    millisecond of CPU per LiDAR frame. Frames of one sensor have the same size, so the heap
    settles after the first few. False where there is no glibc
    mallopt: the allocator's defaults stay."""
    mallopt = _libc("mallopt")
    if mallopt is None:
        return False
    mapped = mallopt(M_MMAP_THRESHOLD, int(mmap_threshold_bytes))
    return bool(mapped) and bool(mallopt(M_TRIM_THRESHOLD, int(trim_threshold_bytes)))


_MALLOC_TRIM = _libc("malloc_trim")
if _MALLOC_TRIM is not None:
    _MALLOC_TRIM.argtypes, _MALLOC_TRIM.restype = [ctypes.c_size_t], ctypes.c_int  # int malloc_trim(size_t pad)


def release_free_memory() -> None:
    """Give the heap's free pages back to the system (glibc's malloc_trim; nothing elsewhere).
    glibc keeps what a run freed inside its heap, and once its threshold for mapping blocks on
    their own has risen (to the largest block freed, up to 32 MB) a run's arrays come from that
    heap: the freed holes a long run leaves then stay in its memory to the end, the report's
    peak included. Freed pages are returned, not the heap's layout: a few ms a call."""
    if _MALLOC_TRIM is not None:
        _MALLOC_TRIM(0)


@dataclass(frozen=True)
class RunResources:
    lean: bool = False
    workers: int = 1  # processes a run may use: above 1, the work that can go ahead goes to a child

    @property
    def parallel(self) -> bool:
        return self.workers > 1 and workers.parallel_enabled()

    def start(self) -> None:
        """At the start of a run: the allocator keeps freed frames for the next (lean only)."""
        if self.lean:
            keep_freed_memory()

    def table(self, array: np.ndarray) -> np.ndarray | DiskTable:
        """A per-run table read by row slices: on disk when lean."""
        return DiskTable(array) if self.lean else np.asarray(array, float)

    def block_store(self, prefix: str) -> DiskBlocks | None:
        """Where a run's per-frame records go (fusion.records): on disk when lean, else in memory (None)."""
        return DiskBlocks(prefix) if self.lean else None

    def frames(self, source: FrameSource) -> Iterator[Frame]:
        """The source's frames; a simulation's made ahead in a forked child when parallel."""
        if self.parallel and isinstance(source, Simulation):
            return workers.frames_in_child(source)
        return iter(source)

    def processed(self, chain, source: FrameSource, pictures: FramePictures, keep_clouds: bool) -> Iterator[tuple[str, object]]:
        """(sensor, chain's output) for each of the source's frames in order. A chain that splits
        its work per frame (`perceive` ahead, `fuse` in order) has its perception made in a
        forked child when parallel, and its outputs come without their clouds unless
        `keep_clouds` (a visualiser) or `pictures` wants one; `pictures` considers every
        frame's whole output where it is made. The same calls in the same order either way:
        the same outputs."""
        frames = chain.frames(source)
        if self.parallel and hasattr(chain, "perceive"):
            yield from self._perceived_in_child(chain, source, frames, pictures, keep_clouds)
            return
        for frame in frames:
            output = chain.process(frame)
            pictures.consider(output)
            yield frame.sensor, output

    def _perceived_in_child(self, chain, source: FrameSource, frames: Iterator[Frame], pictures: FramePictures,
                            keep_clouds: bool) -> Iterator[tuple[str, object]]:
        made = itertools.count(1)

        def perceive(frame: Frame) -> tuple[str, object]:  # in the child: its heap trimmed as this one's
            perceived = chain.perceive(frame)
            pictures.consider(perceived)
            if not (keep_clouds or pictures.wants(frame.sensor, frame.t_s)):
                perceived = chain.without_clouds(perceived)
            self.frame_done(next(made))
            return frame.sensor, perceived

        def at_end() -> tuple[None, tuple[list[str], object, object]]:
            # what the child's copies gathered: the notes its reading added to the source, what
            # its pipeline still holds (frames held back by a warm-up longer than the run), and
            # the worst frame it saw
            held = chain.finish_perception() if hasattr(chain, "finish_perception") else None
            return None, (list(source.meta.notes), held, pictures.worst)

        for sensor, perceived in workers.mapped_in_child(frames, perceive, at_end):
            if sensor is not None:
                yield sensor, chain.fuse(perceived)
                continue
            notes, held, worst = perceived
            source.meta.notes[:] = notes  # the same list, grown in the child
            pictures.adopt(worst)
            if held:
                chain.finish_fusion(held)

    def map_split(self, names: Sequence[str], costs: dict[str, float], work: Callable[[str], object]) -> dict[str, object]:
        """{name: work(name)}: shared by cost between two forked children when parallel."""
        if self.parallel:
            return workers.run_split(names, costs, work)
        return {name: work(name) for name in names}

    def frame_done(self, frames: int) -> None:
        if self.lean and frames % TRIM_EVERY_FRAMES == 0:
            release_free_memory()

    def release(self) -> None:
        """Before a fork or a run's peak (its outputs): freed heap back to the system (lean only)."""
        if self.lean:
            release_free_memory()
