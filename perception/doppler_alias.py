"""Doppler ambiguity: an FMCW radar reports each range rate wrapped into [-v, v), v its
unambiguous range rate (a data-sheet figure; the TI mmWave demo's is about 1.25 m/s), so a deck
coming up at v + e reads -v + e. Before the velocity fit the rates are put back on the branch
nearest what a prior velocity predicts for each beam; the prior is the last scan's velocity,
its vertical part from the last two deck distances when they are recent (the LiDAR's, else the
radar's: a distance is unambiguous). Without either the scan's alias is not known and it gives
no velocity, for the first WAIT_S of the radar's scans (a deck is normally seen by then); a
radar that has never had a prior by then (handheld, or no deck in its view) takes the rates as
reported, the branch around zero, and tracks from there. Once a prior has been had, a scan
without one gives no velocity. A wrap is then never a jump in D-dot, as long as the prior is within v of the
truth: 1.25 m/s is several seconds of the sea's acceleration, or the LiDAR's D-dot noise many
times over."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["PRIOR_MAX_AGE_S", "WAIT_S", "alias_prior_level", "deck_rate", "unwrap_range_rates"]

PRIOR_MAX_AGE_S = 0.3  # a scan's velocity or a LiDAR deck older than this is no prior (s)
WAIT_S = 1.0  # without a prior this long after the radar's first scan: the branch around zero


def unwrap_range_rates(points_sensor: np.ndarray, range_rate_mps: np.ndarray, unambiguous_mps: float,
                       u_prior_sensor: np.ndarray) -> np.ndarray:
    """Each range rate moved by the multiple of 2 v that brings it nearest b . u_prior (b the
    detection's unit direction, sensor frame)."""
    if unambiguous_mps <= 0:
        return range_rate_mps
    p = np.asarray(points_sensor, dtype=np.float64)
    norm = np.sqrt(np.einsum("ij,ij->i", p, p))
    expected = (p @ np.asarray(u_prior_sensor, dtype=np.float64)) / np.where(norm > 0, norm, 1.0)
    span = 2.0 * unambiguous_mps
    return range_rate_mps + span * np.round((expected - range_rate_mps) / span)


def deck_rate(t_s: float, decks: list[tuple[float, float]], max_age_s: float = PRIOR_MAX_AGE_S) -> float | None:
    """D-dot from the last two decks (t, D) when both are recent, else None."""
    if len(decks) < 2:
        return None
    (t0, D0), (t1, D1) = decks[-2], decks[-1]
    if t1 > t0 and abs(t_s - t1) <= max_age_s and t1 - t0 <= max_age_s and math.isfinite(D1 - D0):
        return (D1 - D0) / (t1 - t0)
    return None


def alias_prior_level(t_s: float, last_velocity: tuple[float, np.ndarray] | None,
                      decks_by_sensor: list[list[tuple[float, float]]], unambiguous_mps: float = 0.0,
                      max_age_s: float = PRIOR_MAX_AGE_S) -> np.ndarray | None:
    """The relative velocity expected at t_s in level axes (m/s): the last scan's (t, u_level)
    when recent; its vertical part from the D-dot of the first sensor's last two recent decks
    (D grows downwards: u_z = -D-dot) when there is no recent scan, or when the two disagree by
    more than half the branch width `unambiguous_mps` (the scan's own branch went wrong: the
    distances say so; two distances' rate is noisier than a scan's velocity otherwise). None
    when neither is known."""
    recent = last_velocity is not None and abs(t_s - last_velocity[0]) <= max_age_s
    u = np.array(last_velocity[1], dtype=float) if recent else np.zeros(3)
    for decks in decks_by_sensor:
        rate = deck_rate(t_s, decks, max_age_s)
        if rate is not None:
            if not recent or abs(-rate - u[2]) > 0.5 * unambiguous_mps:
                u[2] = -rate
            return u
    return u if recent else None
