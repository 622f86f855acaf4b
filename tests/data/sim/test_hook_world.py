"""The hook simulation's logs (data/sim/hook_world.py): made a chunk at a time, kept on disk, the
same numbers as the whole arrays in memory."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.data.frames import MruLog


@pytest.mark.parametrize("outages", [[], [[3.0, 7.5]]])
def test_mru_log_in_chunks_is_the_whole_arrays(monkeypatch, outages):
    """The MRU log, its vessel states made a chunk at a time, is the one made at once to the last
    bit: the same states, the same noise draws, the same outages."""
    from boomtip.tools.config.scenario import load_scenario
    from boomtip.data.sim import hook_world, simulator

    scenario = load_scenario("hook-2", ["duration_s=12", f"mru.outages_s={outages}"])
    monkeypatch.setattr(simulator, "TRUTH_CHUNK", 997)  # several chunks, the last one short
    sim = hook_world.HookSimulation(scenario)
    monkeypatch.setattr(simulator, "TRUTH_CHUNK", 10**9)
    whole = simulator.Simulation._mru_log(sim)
    assert len(sim.mru.t_s) == len(whole.t_s) == 2401 - (900 if outages else 0)
    for k in ("t_s", "rpy_rad", "rpy_rate_radps"):
        np.testing.assert_array_equal(getattr(sim.mru, k), getattr(whole, k))
    assert sim.mru.max_gap_s == whole.max_gap_s
    with pytest.raises(AttributeError, match="made once"):
        sim.encoders = sim.encoders
    screened = MruLog(whole.t_s[::2], whole.rpy_rad[::2], whole.rpy_rate_radps[::2], max_gap_s=0.2)
    sim.mru = screened  # processing's screen replaces the log: the files hold the new one, not both
    for k in ("t_s", "rpy_rad", "rpy_rate_radps"):
        np.testing.assert_array_equal(getattr(sim.mru, k), getattr(screened, k))
    assert sim.mru.max_gap_s == 0.2
