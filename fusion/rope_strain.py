"""The rope's stretch beyond its nominal, from the LiDAR's block fixes: the hoist encoder reads
the rope paid out, the pendulum is that stretched by the hook's weight, and a reeving softer
than the rope maker's EA (wear, a heavier load, the sheaves) leaves a length error of
centimetres at 100 m that the crane model cannot see. A scalar Kalman filter on the extra
strain e (true length = hoist x (1 + e)), a random walk, fed by each fix's length along the
rope; causal: the strain at time t comes from the fixes up to t. The hook filter then takes the
hoist times (1 + e) and reports e's sigma times the length along the rope.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["RopeStrain", "rope_strain"]

GATE_NIS = 15.1  # chi-square 1 dof, 99.99 %: a fix this far off its length is not a length
# a fix's strain applies from this long after it: an encoder sample stamped with the fix gets
# the strain from before it however a recording rounded the two stamps (a CSV keeps 6 digits)
APPLY_AFTER_S = 1e-3


class RopeStrain:
    """The causal strain estimate at the fixes' times: t (K,), e (K,), sigma (K,)."""

    def __init__(self, t_s: np.ndarray, strain: np.ndarray, sigma: np.ndarray, prior_sigma: float) -> None:
        self.t_s, self.strain, self.sigma, self.prior_sigma = t_s, strain, sigma, prior_sigma

    def at(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(e, sigma) at each time: the estimate after the last fix at least APPLY_AFTER_S
        before it (the prior before the first)."""
        i = np.searchsorted(self.t_s, np.asarray(t_s, dtype=float) - APPLY_AFTER_S, side="right") - 1
        have = i >= 0
        e = np.where(have, self.strain[np.maximum(i, 0)] if len(self.t_s) else 0.0, 0.0)
        s = np.where(have, self.sigma[np.maximum(i, 0)] if len(self.t_s) else self.prior_sigma, self.prior_sigma)
        return e, s


def rope_strain(t_fix: np.ndarray, p_rel: np.ndarray, along_sigma_m: np.ndarray, t_enc: np.ndarray, hoist_m: np.ndarray,
                prior_sigma: float, walk_per_sqrt_s: float) -> RopeStrain:
    """The extra strain after each fix. p_rel (K, 3): the fixes relative to the tip (NaN rows:
    none), along_sigma_m (K,): their 1-sigma along the rope; the hoist (as the filter takes
    it) interpolated at the fixes' times. A loop over fixes (a few per second), not
    over points."""
    t_fix = np.asarray(t_fix, dtype=float)
    length = np.linalg.norm(np.asarray(p_rel, dtype=float), axis=1)
    # interpolated between the encoder's samples around each fix (a look-ahead of one encoder
    # period, 10 ms at 100 Hz: a sample's choice would move the hoist by the hoisting speed
    # times that period, centimetres)
    hoist = np.interp(t_fix, t_enc, hoist_m) if len(t_enc) else np.full(len(t_fix), np.nan)
    z = length / hoist - 1.0  # the strain this fix says
    r = (np.asarray(along_sigma_m, dtype=float) / hoist) ** 2
    ok = np.isfinite(z) & np.isfinite(r) & (r > 0) & (hoist > 0)
    e, var, t_last = 0.0, prior_sigma ** 2, -math.inf
    out_e, out_s = np.empty(len(t_fix)), np.empty(len(t_fix))
    for k in range(len(t_fix)):
        if ok[k]:
            if math.isfinite(t_last):
                var += walk_per_sqrt_s ** 2 * max(t_fix[k] - t_last, 0.0)
            t_last = t_fix[k]
            y, s = z[k] - e, var + r[k]
            if y * y / s <= GATE_NIS:
                gain = var / s
                e, var = e + gain * y, (1.0 - gain) * var
        out_e[k], out_s[k] = e, math.sqrt(var)
    return RopeStrain(t_fix, out_e, out_s, prior_sigma)
