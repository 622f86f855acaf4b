"""A fit's residual spread pooled over frames: the noise of a surface seen from one place
changes slowly (its range, its incidence), while one frame's sample spread of a few dozen points
scatters by a tenth about it. A sigma made from each frame's own spread follows that scatter
where the frame's error does not: the frames it makes too sure of themselves outweigh the others,
and the errors come out larger than the sigmas say. Pooled over a second of frames the spread
is the sensor's, not the frame's.

The pool is the residuals' sum of squares and their degrees of freedom, each frame's weighed down
by exp(-age / memory): immutable, one per frame (`pooled`), kept by whoever sees the frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["ResidualSpread"]


@dataclass(frozen=True)
class ResidualSpread:
    sum_squares_m2: float = 0.0
    dof: float = 0.0
    t_s: float = math.nan  # the last frame's time

    def pooled(self, t_s: float, sum_squares_m2: float, dof: float, memory_s: float) -> "ResidualSpread":
        """With a frame's residuals at t_s (their sum of squares and degrees of freedom); the
        earlier frames' weighed by exp(-age / memory_s). The frame's alone when memory_s is 0,
        or when its age is not known or negative (no time, a frame before the last): a pool is of
        the frames just before, in order. A frame without a finite spread leaves the pool as it was."""
        if not (math.isfinite(sum_squares_m2) and sum_squares_m2 >= 0 and dof > 0):
            return self
        age = t_s - self.t_s
        weight = math.exp(-age / memory_s) if memory_s > 0 and math.isfinite(age) and age >= 0 else 0.0
        return ResidualSpread(weight * self.sum_squares_m2 + sum_squares_m2, weight * self.dof + dof, t_s)

    @property
    def sigma_m(self) -> float:
        """The pooled 1-sigma of one residual (NaN before any degree of freedom)."""
        return math.sqrt(self.sum_squares_m2 / self.dof) if self.dof > 0 else math.nan
