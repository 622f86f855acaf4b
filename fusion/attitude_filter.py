"""The crane MRU's attitude, its noise filtered with its own rates: a complementary filter
(low-pass of the angles, high-pass of the integrated Euler rates, one time constant).

Why: levelling a frame with one raw MRU sample turns it by the sample's angle noise about the
boom tip; 0.02 deg at the deck's 45 m is 1.6 cm sideways, every frame, and the registration of
a keyframe levelled so carries its sample's error for the rest of the run. Angles and rates
agree on the true motion, so the filter passes it without lag; the angle noise is averaged over
the time constant and the rate noise integrates only over it (0.02 deg and 0.025 deg/s at
200 Hz: about 0.002 deg). A constant bias passes through, as it must (the calibration's job).
"""

from __future__ import annotations

import numpy as np
from boomtip.data.frames import MruLog
from scipy.ndimage import uniform_filter1d
from scipy.signal import lfilter


def gap_free_segments(t_s: np.ndarray, max_gap_s: float) -> list[np.ndarray]:
    """Index arrays of the stretches of t_s with no step longer than max_gap_s."""
    return np.split(np.arange(len(t_s)), np.flatnonzero(np.diff(t_s) > max_gap_s) + 1)


def complementary_attitude(log: MruLog, tau_s: float) -> MruLog:
    """The log with its angles filtered; rates unchanged. Runs per gap-free segment (a gap
    restarts the filter from the angles), at the segment's median sample period."""
    t, rpy = log.t_s, log.rpy_rad
    if len(t) < 3 or not np.isfinite(log.max_gap_s):
        return log
    out = rpy.copy()
    for seg in gap_free_segments(t, log.max_gap_s):  # a loop over segments, not samples
        if len(seg) < 3:
            continue
        dt = float(np.median(np.diff(t[seg])))
        a = tau_s / (tau_s + dt)
        m, r = np.unwrap(rpy[seg], axis=0), log.rpy_rate_radps[seg]
        # a_k = a (a_{k-1} + r_k dt) + (1 - a) m_k, started where the same filter run backwards
        # from the segment's end arrives: started at the first angle alone, the first seconds
        # carry that sample's noise (0.02 deg at the first LiDAR frame, 19 mm of the deck 48 m
        # below: the feeder frame is defined there)
        back, _ = lfilter([1.0], [1.0, -a], (-a * r * dt + (1.0 - a) * m)[::-1], axis=0, zi=(a * m[-1])[None, :])
        start = back[-1] if (t[seg[-1]] - t[seg[0]]) >= 5.0 * tau_s else m[0]
        u = a * r * dt + (1.0 - a) * m
        zi = (a * start)[None, :]
        filt, _ = lfilter([1.0], [1.0, -a], u, axis=0, zi=zi)
        out[seg] = (filt + np.pi) % (2 * np.pi) - np.pi
    return MruLog(t, out, log.rpy_rate_radps, log.max_gap_s)


def complementary_angle_sigma(angle_sigma_rad: float, rate_sigma_radps: float, tau_s: float, dt_s: float) -> float:
    """1-sigma of `complementary_attitude`'s angles from white angle and rate noise: the angle
    noise through the low-pass (1 - a) / (1 - a z^-1), variance gain (1 - a) / (1 + a), and the
    rate noise integrated through a dt / (1 - a z^-1), gain a^2 dt^2 / (1 - a^2); a = tau / (tau + dt).
    The error is correlated over about tau, not white from frame to frame."""
    if tau_s <= 0 or dt_s <= 0:
        return angle_sigma_rad
    a = tau_s / (tau_s + dt_s)
    return float(np.sqrt(angle_sigma_rad ** 2 * (1 - a) / (1 + a) + rate_sigma_radps ** 2 * a * a * dt_s * dt_s / (1 - a * a)))


def averaged_rates(log: MruLog, half_window_s: float) -> tuple[MruLog, int]:
    """The log with each rate the mean of the samples within +-half_window_s (angles
    unchanged), and how many samples that mean takes. Why: the tip's velocity is the rate times
    the boom's lever (0.025 deg/s at 66 m is 3 cm/s a sample) while the wave motion changes
    over seconds: a centred 0.1 s mean of 200 Hz samples cuts the noise 4.5 times and moves a
    10 s wave's rate by 7e-5 of itself. Runs per gap-free segment; offline, or live with
    half_window_s of latency."""
    t = log.t_s
    if len(t) < 3 or half_window_s <= 0 or not np.isfinite(log.max_gap_s):
        return log, 1
    rates = log.rpy_rate_radps.copy()
    n_used = []
    for seg in gap_free_segments(t, log.max_gap_s):  # a loop over segments, not samples
        dt = float(np.median(np.diff(t[seg]))) if len(seg) > 1 else 0.0
        k = int(half_window_s / dt) if dt > 0 else 0
        if k < 1 or len(seg) < 2 * k + 1:
            continue
        rates[seg] = uniform_filter1d(log.rpy_rate_radps[seg], 2 * k + 1, axis=0, mode="nearest")
        n_used.append(2 * k + 1)
    return MruLog(t, log.rpy_rad, rates, log.max_gap_s), min(n_used) if n_used else 1
