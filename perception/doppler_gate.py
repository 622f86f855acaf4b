"""The Doppler fit's detections: those on or above the deck, within its band of range rates. A radar detection beyond the deck
plane, seen from the sensor, is not of the deck nor of anything it carries: it is the sea beside
the hull, or an echo by way of the sea (a ghost at the deck's mirror image below the waterline,
moving as the image does: its vertical velocity reversed). Either would pull the rigid-deck
velocity fit; the deck plane the same scan gave separates them."""

from __future__ import annotations

import math

import numpy as np

BEYOND_DECK_SIGMAS = 4.0  # of the radar's stated range noise: farther beyond the deck plane is not the deck
MIN_BEYOND_DECK_M = 1.0  # never nearer the plane than this (its own tilt and fit error across the scan)


def beyond_deck_margin_m(range_noise_m: float, range_bin_m: float = 0.0) -> float:
    """How far beyond the deck plane a detection may lie and still be the deck's: a number of
    its range sigmas (the noise and the bin's uniform error, bin / sqrt(12))."""
    return max(MIN_BEYOND_DECK_M, BEYOND_DECK_SIGMAS * math.hypot(range_noise_m, range_bin_m / math.sqrt(12.0)))


def on_or_above_deck(points_sensor: np.ndarray, plane_sensor: np.ndarray | None, margin_m: float) -> np.ndarray:
    """(N,) which detections lie no more than `margin_m` beyond the deck plane [a, b, c, d] (unit
    normal towards the sensor, sensor frame): all of them without a plane."""
    if plane_sensor is None or not np.all(np.isfinite(plane_sensor)):
        return np.ones(len(points_sensor), bool)
    return points_sensor @ plane_sensor[:3] + plane_sensor[3] >= -margin_m


def doppler_band_mps(radar, sigmas: float, floor_mps: float) -> float:
    """Half-width of the Doppler inlier band from the radar's data sheet: `sigmas` times its
    range-rate noise and Doppler bin (a uniform error of bin / sqrt(12)), never below `floor_mps`
    (what the rigid-deck model leaves unexplained)."""
    sigma = math.hypot(radar.range_rate_noise_mps, radar.range_rate_resolution_mps / math.sqrt(12.0))
    return max(floor_mps, sigmas * sigma)


def above_deck_only(points_sensor: np.ndarray, range_rate_mps: np.ndarray, deck, margin_m: float):
    """The detections (points, range rates) on or above `deck`'s plane (the scan's DeckResult;
    every one of them without a deck found)."""
    keep = on_or_above_deck(points_sensor, deck.plane_sensor if deck is not None and deck.ok else None, margin_m)
    return points_sensor[keep], range_rate_mps[keep]
