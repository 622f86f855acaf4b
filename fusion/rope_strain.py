"""The rope's length beyond what the hoist encoder reads, from the LiDAR's block fixes: the
encoder reads the rope paid out and the pendulum is that stretched by the hook's weight, but a
reeving softer than the rope maker's EA (wear, a heavier load, the sheaves) stretches it by
centimetres at 100 m more, and the block's fitted point may sit off the rope's end by a fixed
length. Both the crane model cannot see. A two-state Kalman filter on the extra length
`offset + strain x hoist` (true length = hoist + offset + strain x hoist; both random walks),
fed by each fix's length along the rope; the offset and the strain part as the hoist changes.
Causal: the length at time t comes from the fixes before it. The hook filter then takes the
hoist so corrected and reports the correction's sigma along the rope.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["APPLY_AFTER_S", "RopeLength", "rope_length"]

GATE_NIS = 15.1  # chi-square 1 dof, 99.99 %: a fix this far off its length is not a length
# a fix's estimate applies from this long after it: an encoder sample stamped with the fix gets
# the estimate from before it however a recording rounded the two stamps (a CSV keeps 6 digits)
APPLY_AFTER_S = 1e-3


class RopeLength:
    """The causal estimate after each fix: t (K,), state (K, 2) = offset m, strain, cov (K, 2, 2)."""

    def __init__(self, t_s: np.ndarray, state: np.ndarray, cov: np.ndarray, prior_cov: np.ndarray) -> None:
        self.t_s, self.state, self.cov, self.prior_cov = t_s, state, cov, prior_cov

    def correction(self, t_s: np.ndarray, hoist_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(extra length m, its 1-sigma m) at each time for the hoist there: the estimate after
        the last fix at least APPLY_AFTER_S before it (the prior before the first)."""
        t = np.asarray(t_s, dtype=float)
        h = np.broadcast_to(np.asarray(hoist_m, dtype=float), t.shape)
        i = np.searchsorted(self.t_s, t - APPLY_AFTER_S, side="right") - 1
        have = i >= 0
        k = np.maximum(i, 0)
        x = np.where(have[:, None], self.state[k] if len(self.t_s) else 0.0, 0.0)
        P = np.where(have[:, None, None], self.cov[k] if len(self.t_s) else self.prior_cov, self.prior_cov)
        var = P[:, 0, 0] + 2.0 * h * P[:, 0, 1] + h * h * P[:, 1, 1]
        return x[:, 0] + x[:, 1] * h, np.sqrt(np.maximum(var, 0.0))


def rope_length(t_fix: np.ndarray, p_rel: np.ndarray, along_sigma_m: np.ndarray, t_enc: np.ndarray, hoist_m: np.ndarray,
                offset_sigma_m: float, strain_sigma: float, offset_walk_m_per_sqrt_s: float,
                strain_walk_per_sqrt_s: float) -> RopeLength:
    """The extra length after each fix. p_rel (K, 3): the fixes relative to the tip (NaN rows:
    none), along_sigma_m (K,): their 1-sigma along the rope; the hoist (as the filter takes it)
    interpolated at the fixes' times (a look-ahead of one encoder period, 10 ms at 100 Hz: a
    sample's choice would move it by the hoisting speed times that period). A loop over fixes
    (a few per second), not over points."""
    t_fix = np.asarray(t_fix, dtype=float)
    length = np.linalg.norm(np.asarray(p_rel, dtype=float), axis=1)
    hoist = np.interp(t_fix, t_enc, hoist_m) if len(t_enc) else np.full(len(t_fix), np.nan)
    z = length - hoist  # the extra length this fix says
    r = np.asarray(along_sigma_m, dtype=float) ** 2
    ok = np.isfinite(z) & np.isfinite(r) & (r > 0) & np.isfinite(hoist)
    prior = np.diag([offset_sigma_m ** 2, strain_sigma ** 2])
    walk = np.array([offset_walk_m_per_sqrt_s ** 2, strain_walk_per_sqrt_s ** 2])
    x, P, t_last = np.zeros(2), prior.copy(), -math.inf
    out_x, out_P = np.empty((len(t_fix), 2)), np.empty((len(t_fix), 2, 2))
    for k in range(len(t_fix)):
        if ok[k]:
            if math.isfinite(t_last):
                P = P + np.diag(walk * max(t_fix[k] - t_last, 0.0))
            t_last = t_fix[k]
            H = np.array([1.0, hoist[k]])
            PH = P @ H
            s = float(H @ PH) + r[k]
            y = z[k] - float(H @ x)
            if y * y / s <= GATE_NIS:
                K = PH / s
                x = x + K * y
                P = P - np.outer(K, PH)
                P = 0.5 * (P + P.T)
        out_x[k], out_P[k] = x, P
    return RopeLength(t_fix, out_x, out_P, prior)
