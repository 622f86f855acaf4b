"""The radar's deck through a LiDAR outage: the fused solution takes the LiDAR's distances and
the radar's D-dot, so a LiDAR outage leaves it integrating D-dot, a drift of about a
centimetre in 10 s. The radar's own deck distance is there all along, but off the LiDAR's by
its mount's and its plane fit's bias (millimetres to centimetres). While both see the deck
that offset is learnt (the mean radar-minus-LiDAR difference over the last `window_s`, each
radar distance against the LiDAR's interpolated between the two around it); once the LiDAR
has been silent `after_s`, the radar's distances, so corrected, join the fused solution, with
the offset's standard error as a systematic sigma (its differences taken as independent only
a second apart: the decks' errors follow the waves).
Causal: a radar frame uses only the pairs before the LiDAR's last distance before it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from boomtip.fusion.heave_filter import Measurement

__all__ = ["PAIR_GAP_S", "radar_deck_bridge"]

# a radar distance between two LiDAR distances at most this far apart is paired with their
# interpolation (over 0.15 s the deck's acceleration bends it by about 3 mm at most)
PAIR_GAP_S = 0.15
MIN_PAIRS = 20  # fewer pairs in the window: no offset known, no bridge
PAIRS_PER_INDEPENDENT = 20  # a second of a 20 Hz radar's pairs counts as one independent difference


def radar_deck_bridge(measurements: list[Measurement], lidar_sources: tuple[str, ...], radar_source: str,
                      after_s: float, window_s: float) -> list[Measurement]:
    """The radar distances to add to a fused solution: those more than after_s after the
    LiDAR's last distance, moved by the learnt offset (source renamed `<radar>_bridged`)."""
    ok = lambda m: m.quantity == "D" and np.isfinite(m.value)
    lid_all = [m for m in measurements if m.source in lidar_sources and ok(m)]
    # the offset against one LiDAR method (the first of lidar_sources present): two methods' own
    # biases would enter it with a weight that follows their frames' phases
    first = next((s for s in lidar_sources if any(m.source == s for m in lid_all)), None)
    silence = sorted(m.t_acq_s for m in lid_all)  # any LiDAR distance ends a silence
    lid = sorted((m for m in lid_all if m.source == first), key=lambda m: m.t_acq_s)
    rad = sorted((m for m in measurements if m.source == radar_source and ok(m)), key=lambda m: m.t_acq_s)
    if len(lid) < 2 or not rad:
        return []
    t_l = np.array([m.t_acq_s for m in lid])
    v_l = np.array([m.value for m in lid])
    t_r = np.array([m.t_acq_s for m in rad])
    v_r = np.array([m.value for m in rad])
    # each radar distance's LiDAR partner: interpolated between the two around it, when both are near
    j = np.clip(np.searchsorted(t_l, t_r), 1, len(t_l) - 1)
    t0, t1 = t_l[j - 1], t_l[j]
    near = (t1 - t0 <= PAIR_GAP_S) & (t0 <= t_r) & (t_r <= t1)
    w = np.where(t1 > t0, (t_r - t0) / np.maximum(t1 - t0, 1e-12), 0.0)
    diff = np.where(near, v_r - (v_l[j - 1] + w * (v_l[j] - v_l[j - 1])), 0.0)
    cs, cs2, cn = (np.r_[0.0, np.cumsum(a)] for a in (diff, diff * diff, near.astype(float)))
    t_any = np.array(silence)
    last_lidar = t_any[np.maximum(np.searchsorted(t_any, t_r, side="right") - 1, 0)]
    silent = (t_r - last_lidar > after_s) & (t_r >= t_any[0])
    out = []
    for k in np.flatnonzero(silent):
        hi = np.searchsorted(t_r, last_lidar[k], side="right")  # the pairs up to the LiDAR's last distance
        lo = np.searchsorted(t_r, last_lidar[k] - window_s, side="left")
        n = cn[hi] - cn[lo]
        if n < MIN_PAIRS:
            continue
        mean = (cs[hi] - cs[lo]) / n
        var = max((cs2[hi] - cs2[lo]) / n - mean * mean, 0.0)
        m = rad[k]
        sys = float(np.hypot(m.sigma_systematic, np.sqrt(var / max(n / PAIRS_PER_INDEPENDENT, 1.0))))
        out.append(replace(m, value=m.value - mean, source=f"{radar_source}_bridged", sigma_systematic=sys))
    return out
