"""The Doppler fit's gate: radar detections beyond the scan's deck plane (the sea, the sea's
ghosts of the deck) are not the deck's."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.data.meshes import Label
from boomtip.data.sim.simulator import Simulation
from boomtip.perception.doppler_gate import MIN_BEYOND_DECK_M, beyond_deck_margin_m, on_or_above_deck
from boomtip.perception.pipeline import HeavePipeline
from boomtip.tools.config.processing import Processing
from boomtip.tools.config.scenario import load_scenario


def test_the_gate_keeps_what_lies_on_or_above_the_plane_within_the_margin():
    plane = np.array([0.0, 0.0, 1.0, 20.0])  # z = -20 m, normal up towards a sensor at the origin
    pts = np.array([[0.0, 0.0, -19.0], [3.0, 1.0, -20.0], [0.0, 0.0, -21.9], [0.0, 0.0, -22.1], [5.0, 0.0, -30.0]])
    np.testing.assert_array_equal(on_or_above_deck(pts, plane, 2.0), [True, True, True, False, False])
    assert on_or_above_deck(pts, None, 2.0).all() and on_or_above_deck(pts, np.full(4, np.nan), 2.0).all()
    assert beyond_deck_margin_m(0.5) == pytest.approx(2.0) and beyond_deck_margin_m(0.01) == MIN_BEYOND_DECK_M


def test_the_seas_ghosts_lie_beyond_the_scans_deck_and_the_deck_within():
    sim = Simulation(load_scenario("sts-loaded", ["duration_s=2", "radar.multipath_probability=0.3"]))
    pipeline = HeavePipeline(sim.meta.installation, sim.mru, Processing().heave, seed=1)
    kept = {"ghost": [], "deck": []}
    for frame in sim:
        out = pipeline.process(frame)
        if frame.sensor != "radar" or out.deck_radar is None or not out.deck_radar.ok:
            continue
        label = frame.fields["label"]
        keep = on_or_above_deck(frame.points_sensor, out.deck_radar.plane_sensor, pipeline.beyond_deck_m)
        kept["ghost"].append(keep[label == int(Label.MULTIPATH)])
        kept["deck"].append(keep[label == int(Label.FEEDER_DECK)])
    ghosts, deck = np.concatenate(kept["ghost"]), np.concatenate(kept["deck"])
    assert len(ghosts) > 100 and len(deck) > 500
    assert ghosts.mean() < 0.01 and deck.mean() > 0.99
