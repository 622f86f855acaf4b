"""Has the load landed? Latched once every frame's measured clearance has stayed at zero
(within its sigmas) for a while.

At touchdown the load stops following the rope and lies down on the deck: a step no smooth
motion model follows. Past it the clearance's filters would only report the step as an
inconsistency, so the lift chain stops them and says "landed". A load that hovers within a few
centimetres of the deck for as long, through the waves, is for the crane landed too.
"""

from __future__ import annotations

import math

__all__ = ["TouchdownDetector"]


class TouchdownDetector:
    """Landed (from the first of them) once every frame for `hold_s` has had its measured
    clearance within `sigmas` of its sigma (or `floor_m`) of zero."""

    def __init__(self, hold_s: float, sigmas: float = 3.0, floor_m: float = 0.03) -> None:
        self.hold_s, self.sigmas, self.floor_m = hold_s, sigmas, floor_m
        self.since_s: float | None = None  # the first frame of the present run of frames at the deck
        self.landed_s: float | None = None

    def update(self, t_s: float, clearance_m: float, sigma_m: float) -> bool:
        """One frame's measured clearance and its sigma; True once landed."""
        if self.landed_s is not None:
            return True
        at_deck = math.isfinite(clearance_m) and abs(clearance_m) <= max(self.sigmas * sigma_m, self.floor_m)
        if not at_deck:
            self.since_s = None
            return False
        if self.since_s is None:
            self.since_s = t_s
        if t_s - self.since_s >= self.hold_s:
            self.landed_s = self.since_s
        return self.landed_s is not None
