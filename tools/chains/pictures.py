"""Which frames a run's detections picture shows, chosen while the frames go by (their clouds are
not kept): a representative one, the first LiDAR frame from the middle of the run on; and the
worst, by the chain's own `frame_score` (the largest error in its stated sigmas where the run has
truth, else the first frame whose detection failed or the least certain one). The worst is held,
cloud and all, by the process that perceives the frames (a worker gives it back at the end)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from boomtip.data.frames import FrameSource

__all__ = ["FramePictures", "Picked", "output_time"]


def output_time(output) -> float | None:
    """A chain's output's frame time: a perception result's frame's, or its own `t_s`."""
    frame = getattr(output, "frame", None)
    return frame.t_s if frame is not None else getattr(output, "t_s", None)


@dataclass
class Picked:
    output: object  # the chain's output of the frame, with its cloud and detections
    why: str  # what the picture's title says of the frame


class FramePictures:
    def __init__(self, source: FrameSource, score: Callable[[object], tuple[float, str] | None] | None = None) -> None:
        self.t_mid_s = source.meta.t_start_s + max(source.duration_s, 0.0) / 2.0
        self.score = score
        self.middle = None
        self.worst: Picked | None = None
        self._worst_score = -math.inf
        self._wanted = False  # the middle frame has been chosen (in this process's view of the frames)

    def wants(self, sensor: str, t_s: float) -> bool:
        """The frame is the middle one: its cloud is kept through a worker."""
        if self._wanted or sensor != "lidar" or t_s < self.t_mid_s:
            return False
        self._wanted = True
        return True

    def offer(self, sensor: str, output) -> None:
        """The chain's output of a frame, in order: kept if it is the middle one."""
        if self.middle is None and output is not None and sensor == "lidar":
            t_s = output_time(output)
            if t_s is not None and t_s >= self.t_mid_s:
                self.middle = output

    def consider(self, output) -> None:
        """A frame's whole output (where it was perceived): held if it scores worse than the worst so far."""
        scored = self.score(output) if self.score is not None and output is not None else None
        if scored is not None and scored[0] > self._worst_score:
            self._worst_score = scored[0]
            self.worst = Picked(output, scored[1])

    def adopt(self, worst: Picked | None) -> None:
        """The worst a worker held (it saw every frame): it replaces this process's."""
        self.worst = worst

    def frames(self, convert: Callable[[object], object] = lambda output: output) -> list[Picked]:
        """The pictures' frames: the middle one, and the worst when it is another frame."""
        picked = [Picked(convert(self.middle), "a representative frame (the first from the middle of the run)")] \
            if self.middle is not None else []
        if self.worst is not None and (self.middle is None or output_time(self.worst.output) != output_time(self.middle)):
            picked.append(Picked(convert(self.worst.output), self.worst.why))
        return picked
