"""The LiDAR's levelling error, estimated online from the deck plane and the MRU.

The level frame is built from the surveyed mount and the MRU's roll and pitch; a mount
rotation error (or an MRU bias) tilts it by a small, fixed rotation. A floating feeder's deck
normal, in a truly levelled frame, averages to the vertical over the waves (its roll and pitch
are zero-mean: the assumption, stated in the report); in the tilted frame it averages to the
tilt. The average is Hann-weighted over the whole history: a plain mean of a wave of period T
over a window W leaves an error of order T / W of its amplitude, the Hann window's of order
(T / W)^3.

Only the two tilt angles are observable this way. The rotation about the vertical is, from the
own vessel: its hull side, static in the sensor frame, is a long straight edge along the crane
vessel's heading (the assumption: a parallel midbody), and its direction in the level frame is
that rotation (`with_heading`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from boomtip.fusion.attitude_filter import gap_free_segments


@dataclass
class Tilt:
    """Small rotation (about the level x and y axes, rad) that takes the tilted level frame
    to the true one, and its 1-sigma."""

    rx_rad: float
    ry_rad: float
    sigma_rad: float
    span_s: float
    rz_rad: float = 0.0  # about the vertical, from the own hull's edge (with_heading)
    rz_sigma_rad: float | None = None  # None: not calibrated, the survey's accuracy stands


def median_and_sigma(values: np.ndarray) -> tuple[float, float]:
    """The median of per-frame measurements of a constant and its 1-sigma: 1.25 sigma / sqrt(n),
    sigma from the median absolute deviation (robust to a frame that took the wrong edge)."""
    m = float(np.median(values))
    return m, 1.2533 * 1.4826 * float(np.median(np.abs(values - m))) / float(np.sqrt(len(values)))


def with_heading(tilt: Tilt | None, hull_yaws_rad: np.ndarray) -> Tilt | None:
    """The calibration with its rotation about the vertical: minus the median direction of the
    own hull's edge in the level frame over frames (median_and_sigma). Needs three frames' edges."""
    if tilt is None or len(hull_yaws_rad) < 3:
        return tilt
    m, sigma = median_and_sigma(hull_yaws_rad)
    return Tilt(tilt.rx_rad, tilt.ry_rad, tilt.sigma_rad, tilt.span_s, -m, sigma)


def hann_mean(t_s: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Mean of values (N, k) under a Hann window spanning the samples' times."""
    span = t_s[-1] - t_s[0]
    w = 0.5 - 0.5 * np.cos(2 * np.pi * (t_s - t_s[0]) / span) if span > 0 else np.ones(len(t_s))
    return (w[:, None] * values).sum(0) / w.sum()


def tilt_from_normals(t_s: np.ndarray, normals_level: np.ndarray, min_span_s: float, max_gap_s: float = 2.0) -> Tilt | None:
    """The tilt from deck normals (N, 3) in the (tilted) level frame, or None before min_span_s
    of history. The correction rotates the mean normal m onto e_z: rx = m_y, ry = -m_x.

    A gap in the normals (a LiDAR outage, the deck lost) splits them: one window across a gap
    weighs the waves on either side unevenly and leaves part of a wave in the mean, so each
    gap-free stretch of at least min_span_s gets its own Hann mean, and the stretches are
    averaged by their length."""
    t_s = np.asarray(t_s, dtype=float)
    n = normals_level / np.linalg.norm(normals_level, axis=1, keepdims=True)
    means, spans, sigmas = [], [], []
    for seg in gap_free_segments(t_s, max_gap_s):
        span = float(t_s[seg[-1]] - t_s[seg[0]]) if len(seg) else 0.0
        if len(seg) < 10 or span < min_span_s:
            continue
        ns = n[seg]
        means.append(hann_mean(t_s[seg], ns))
        spans.append(span)
        # The mean's spread: what is left of the wave in a window of this span, from the
        # normals' own spread (a conservative (T/W) ~ 1/span in units of the dominant period 10 s).
        spread = float(np.std(ns[:, :2], axis=0).max())
        sigmas.append(spread * (10.0 / span) ** 3 + float(np.std(np.diff(ns[:, :2], axis=0))) / np.sqrt(len(seg)))
    if not means:
        return None
    w = np.array(spans) / sum(spans)
    m = w @ np.array(means)
    return Tilt(float(m[1]), float(-m[0]), float(w @ np.array(sigmas)), float(sum(spans)))


def within_the_survey(tilt: Tilt | None, prior_sigma_rad: float, k: float = 4.0) -> tuple[Tilt | None, str | None]:
    """The tilt if the surveyed mount and the MRU's stated accuracy allow it (within k of their
    combined 1-sigma, plus the estimate's own), else no tilt with the survey's 1-sigma, and why.
    A feeder with a steady list or trim breaks the zero-mean assumption: its deck averages to
    that list, which the deck alone cannot tell from a mount error. A mean tilt far beyond the
    survey's is taken as the feeder's, not the installation's: the survey stands for the two
    tilts (the rotation about the vertical, from the own hull, is another matter). A smaller
    list, within the bound, is still taken as a levelling error."""
    if tilt is None:
        return None, None
    size = float(np.hypot(tilt.rx_rad, tilt.ry_rad))
    bound = k * float(np.hypot(prior_sigma_rad, tilt.sigma_rad))
    if size <= bound:
        return tilt, None
    return Tilt(0.0, 0.0, prior_sigma_rad, tilt.span_s), (f"the deck's mean tilt, {np.degrees(size):.3f} deg, is beyond what the mount survey and the MRU allow "
                  f"({k:g} sigma: {np.degrees(bound):.3f} deg): taken as the feeder's own list or trim, not a levelling error; "
                  "the surveyed mount stands for roll and pitch")


def correction(tilt: Tilt | None) -> np.ndarray:
    """3x3 rotation that takes the tilted level frame to the corrected one."""
    if tilt is None:
        return np.eye(3)
    rx, ry, rz = tilt.rx_rad, tilt.ry_rad, tilt.rz_rad
    K = np.array([[0.0, -rz, ry], [rz, 0.0, -rx], [-ry, rx, 0.0]])
    # exact rotation from the small axis-angle (rx, ry, rz)
    th = float(np.sqrt(rx * rx + ry * ry + rz * rz))
    if th == 0:
        return np.eye(3)
    return np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th ** 2 * (K @ K)
