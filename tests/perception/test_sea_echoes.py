"""The radar's deck among the sea's echoes: the ghosts mirrored below the waterline make a plane
below the deck, and the deck stage takes the deck (the latest deck of either sensor is its prior),
not the lowest plane. A radar alone has no prior at its first frame: the mirror image lies below
the sea, beyond the tip's height above the calm waterline, and is never taken for the deck."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.data.sim.simulator import Simulation
from boomtip.perception.pipeline import HeavePipeline
from boomtip.tools.config.processing import Processing
from boomtip.tools.config.scenario import load_scenario


@pytest.mark.parametrize("lidar, echoed", [(True, 0.5), (False, 0.1), (False, 0.5)])
def test_the_radar_deck_is_the_deck_not_its_mirror_image(lidar, echoed):
    keys = ["duration_s=4", f"radar.multipath_probability={echoed}", f"installation.lidar.enabled={str(lidar).lower()}"]
    sim = Simulation(load_scenario("sts-loaded", keys))
    pipeline = HeavePipeline(sim.meta.installation, sim.mru, Processing().heave, seed=1)
    rows = [r for f in sim for r in pipeline.process(f).measurements if r.method == "deck_radar" and r.ok]
    t = np.array([r.t_s for r in rows])
    error = np.array([r.value for r in rows]) - sim.truth.at("D", t)
    assert len(rows) > 70  # of 80 radar frames
    # the mirror image lies twice the freeboard (metres) below the deck; the deck stage's own error is centimetres
    assert np.max(np.abs(error)) < 0.15
