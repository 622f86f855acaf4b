"""The landing point: where the load's underside centre would meet the deck, horizontally.

The load hangs from the hook, so its centre lies on the rope's line continued below the hook
but for an offset that changes slowly (the slings' give, the load turning on them). The hook
tracker knows the hook to a centimetre or two; one frame's load centre is known to a fraction of
the beam spacing (several centimetres). So the offset is what is filtered: a random walk per
horizontal axis, measured each frame as the load's centre less the rope's line at its height,
and the landing point is the rope's line (this frame's) plus the filtered offset.

One frame's centre error is not independent of the next: it comes from where the beams fall on
the load's edges, which changes only as the load moves across them. Frames closer together than
that error's correlation time share it, so each is taken with its variance times the number of
frames in that time: averaging them is not taken to beat it down.

Two independent scalar random walks: a Kalman filter of one state per axis, written out (the
predict is P += q dt, the update a scalar gain).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["LandingOffsetFilter"]

GATE_SIGMAS = 5.0  # an offset beyond this many sigmas of the prediction is another object's, not taken


class LandingOffsetFilter:
    """The load centre's horizontal offset (m, levelled frame) from the rope's line."""

    def __init__(self, rate_sigma_mps: float, error_correlation_s: float = 0.0) -> None:
        self.q = rate_sigma_mps**2
        self.error_correlation_s = error_correlation_s
        self.x = np.full(2, np.nan)  # until the first offset, which sets it with its own variance
        self.P = math.inf
        self.t_s = math.nan

    def update(self, t_s: float, offset_m: np.ndarray, sigma_m: float) -> bool:
        """One frame's offset and its 1-sigma per axis; False when gated out or not finite."""
        if not (np.all(np.isfinite(offset_m)) and math.isfinite(sigma_m) and sigma_m > 0):
            return False
        if not np.all(np.isfinite(self.x)):
            self.x, self.P, self.t_s = np.asarray(offset_m, float).copy(), sigma_m**2, t_s
            return True
        P = self.predicted_var(t_s)
        if np.any(np.abs(offset_m - self.x) > GATE_SIGMAS * math.sqrt(P + sigma_m**2)):
            return False
        shared = max(1.0, self.error_correlation_s / max(t_s - self.t_s, 1e-9))  # the frames sharing its error
        k = P / (P + shared * sigma_m**2)
        self.x = self.x + k * (np.asarray(offset_m, float) - self.x)
        self.P, self.t_s = (1.0 - k) * P, t_s
        return True

    def predicted_var(self, t_s: float) -> float:
        """The offset's variance per axis at t_s (it grows while no frame comes)."""
        return self.P + self.q * max(t_s - self.t_s, 0.0) if math.isfinite(self.t_s) else math.inf
