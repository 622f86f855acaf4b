"""Measurement noise that widens when a stream is noisier than its installation states:
covariance matching on the stream's own innovations (Mehra 1972). A consistent filter's
innovation y has covariance S = H P H^T + R; a stream whose real noise is r R instead gives
E[y^T R^-1 y] = tr(R^-1 H P H^T) + r dof, so r is estimated from the recent innovations and the
stream's covariance used as r R. Never below the stated noise (r >= 1): a stream quieter than
its data sheet keeps the data sheet's, so the sigmas only ever err on the safe side.

Time-weighted (an exponential memory in seconds), so streams at any rate forget alike; each
innovation counts at most as one on the gate, and the widening stops at MAX_SCALE, so garbage
(a broken detector) widens a stream for a while but never for long.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["MAX_SCALE", "PRIOR_UPDATES", "NoiseMatch", "matched_ratio"]

PRIOR_UPDATES = 10.0  # the stated noise counts as this many updates of evidence at the start
# at most this factor on a stated variance (10x its sigma): a stream beyond is broken, not noisy,
# and its gate (widened this far) refuses it
MAX_SCALE = 100.0


def matched_ratio(y: np.ndarray, R: np.ndarray, HPHt: np.ndarray, gate_nis: float, scale: float = 1.0) -> float:
    """One innovation's estimate of r (its real noise over the stated R), (y^T R^-1 y -
    tr(R^-1 H P H^T)) / dof, bounded: an innovation beyond the gate on y^T S^-1 y (S the
    covariance in use, R widened by scale) counts as one on it, and no innovation claims more
    than gate_nis times the current scale (one the prediction's own uncertainty dominates would
    otherwise claim a noise of that uncertainty's size). NaN for a non-finite innovation or a
    singular R."""
    y = np.atleast_1d(np.asarray(y, dtype=float))
    R, HPHt = np.atleast_2d(R), np.atleast_2d(HPHt)
    try:
        Rinv = np.linalg.inv(R)
        nis = float(y @ np.linalg.solve(HPHt + scale * R, y))
    except np.linalg.LinAlgError:  # a stated noise of zero somewhere: nothing to match it to
        return math.nan
    if not math.isfinite(nis):
        return math.nan
    q = float(y @ Rinv @ y)
    if nis > gate_nis > 0:
        q *= gate_nis / nis
    return min((q - float(np.trace(Rinv @ HPHt))) / len(y), gate_nis * scale)


@dataclass(frozen=True, slots=True)
class NoiseMatch:
    """One stream's running estimate of r: sums decayed by exp(-dt / memory_s)."""

    weight: float = PRIOR_UPDATES
    ratio_sum: float = PRIOR_UPDATES  # the prior: r = 1, the stated noise
    t_s: float = math.nan  # the last innovation's time

    @property
    def scale(self) -> float:
        """The factor on the stated covariance: the estimated r, within [1, MAX_SCALE]."""
        r = self.ratio_sum / self.weight
        return min(max(1.0, r), MAX_SCALE) if math.isfinite(r) else 1.0

    def after(self, t_s: float, ratio: float, memory_s: float) -> "NoiseMatch":
        """With one more innovation's ratio (matched_ratio) at t_s."""
        if not (math.isfinite(ratio) and math.isfinite(t_s)) or memory_s <= 0:
            return self
        dt = t_s - self.t_s if math.isfinite(self.t_s) else 0.0
        decay = math.exp(-max(dt, 0.0) / memory_s)
        w = self.weight * decay + 1.0
        s = self.ratio_sum * decay + ratio
        return NoiseMatch(w, s, max(t_s, self.t_s) if math.isfinite(self.t_s) else t_s)
