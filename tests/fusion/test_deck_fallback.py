"""The radar's deck through a LiDAR outage: its offset from the LiDAR's learnt while both see
the deck, applied once the LiDAR is silent, causally."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.fusion.deck_fallback import radar_deck_bridge
from boomtip.fusion.heave_filter import Measurement


def _streams(offset: float = 0.03, outage=(30.0, 40.0), seed: int = 3):
    rng = np.random.default_rng(seed)
    D = lambda t: 45.0 + 2.0 * np.sin(2 * np.pi * t / 10)
    t_l = np.arange(0, 60, 0.1)
    t_l = t_l[(t_l < outage[0]) | (t_l >= outage[1])]
    t_r = np.arange(0, 60, 0.05) + 0.013
    lidar = [Measurement(t, t, "D", D(t) + rng.normal(0, 0.002), 0.002, "deck_lidar") for t in t_l]
    radar = [Measurement(t, t, "D", D(t) + offset + rng.normal(0, 0.008), 0.008, "deck_radar") for t in t_r]
    return lidar + radar, D


def test_the_radar_deck_joins_only_through_the_outage_with_its_offset_removed():
    meas, D = _streams()
    got = radar_deck_bridge(meas, ("deck_lidar",), "deck_radar", 0.5, 30.0)
    t = np.array([m.t_acq_s for m in got])
    assert t.min() > 30.4 and t.max() < 40.0 and len(got) > 150  # 0.5 s after the LiDAR's last, until it is back
    err = np.array([m.value - D(m.t_acq_s) for m in got])
    assert abs(err.mean()) < 0.002 and all(m.source == "deck_radar_bridged" for m in got)
    assert 0 < got[0].sigma_systematic < 0.002  # the offset's standard error


def test_no_bridge_without_enough_pairs_before_or_without_a_lidar():
    meas, _ = _streams(outage=(0.5, 40.0))  # the LiDAR lost almost at once: no offset learnt yet
    assert radar_deck_bridge(meas, ("deck_lidar",), "deck_radar", 0.5, 30.0) == []
    radar_only = [m for m in meas if m.source == "deck_radar"]
    assert radar_deck_bridge(radar_only, ("deck_lidar",), "deck_radar", 0.5, 30.0) == []


def test_a_later_offset_does_not_reach_back():
    """Causal: the offset a bridged frame uses comes from pairs before the outage only."""
    meas, _ = _streams()
    late = [m if m.t_acq_s < 40 or m.source != "deck_radar" else Measurement(m.t_acq_s, m.t_arrival_s, "D", m.value + 1.0,
                                                                              m.sigma, m.source) for m in meas]
    a = radar_deck_bridge(meas, ("deck_lidar",), "deck_radar", 0.5, 30.0)
    b = radar_deck_bridge(late, ("deck_lidar",), "deck_radar", 0.5, 30.0)
    assert [m.value for m in a] == pytest.approx([m.value for m in b], abs=1e-12)
