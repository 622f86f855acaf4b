"""The linear part of the hook filter's process model, for a prediction window longer than the
MRU's sample interval (the UKF's ``HookFilterConfig.ukf_window_s``, fusion/hook_kalman_core.py).

The kinematic chains (slew, luff, hoist, roll, pitch: q, q', q'') are exact constant-acceleration
extrapolations and the crane's sensors measure their states directly, so a sample taken tau
before the window's end is a linear function of the state at the end: q(T - tau) = q - q' tau +
q'' tau^2 / 2, q'(T - tau) = q' - q'' tau. The jerk that drives the chains between the sample
and the window's end is left out of that measurement's noise: over a 25 ms window it moves a
sample by under 1e-7 rad (angles) and 2e-5 rad/s (rates), against the MRU's 4e-4 rad and
5e-4 rad/s.
"""

from __future__ import annotations

import numpy as np

from boomtip.fusion.models.crane_pendulum import KIN_CHAINS

__all__ = ["accumulated_noise", "sample_rows"]


def accumulated_noise(Q_step: np.ndarray, F_step: np.ndarray, m: int) -> np.ndarray:
    """The process noise of m steps, each adding Q_step and carried by F_step to the end:
    sum_j F^j Q F^jT (the filter's per-step noise, for a window of m MRU intervals: the
    discrete white-noise models' variance per second depends on their step)."""
    Q = Q_step.copy()
    for _ in range(m - 1):
        Q = F_step @ Q @ F_step.T + Q_step
    return 0.5 * (Q + Q.T)


def sample_rows(idx, tau: float, n: int) -> np.ndarray:
    """H (len(idx), n): the chain states idx (each q, q' or q'' of a chain) measured tau before
    the state's time, as the state's constant-acceleration extrapolation back by tau."""
    H = np.zeros((len(idx), n))
    for r, i in enumerate(idx):
        order = next(i - c for c in KIN_CHAINS if 0 <= i - c < 3)
        H[r, i] = 1.0
        if order == 0:
            H[r, i + 1], H[r, i + 2] = -tau, 0.5 * tau * tau
        elif order == 1:
            H[r, i + 1] = -tau
    return H
