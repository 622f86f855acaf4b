"""What a simulation keeps compactly (data/sim/stored.py): the frame schedule as arrays, and its
truth made a chunk at a time, the same numbers as the whole arrays."""

from __future__ import annotations

import numpy as np

from boomtip.data.frames import TRUTH_COLUMNS
from boomtip.data.sim import stored
from boomtip.data.stored_truth import StoredTruth


def test_frame_schedule_as_arrays_gives_the_same_items(monkeypatch):
    """The compact schedule iterates (across its chunks), indexes and slices as the list of
    tuples it was made from: the same values and Python types, sensors apart, ties in order."""
    monkeypatch.setattr(stored, "TRUTH_CHUNK", 4)  # 11 items: 3 chunks
    items = sorted([(0.05 * k, "lidar", k) for k in range(6)] + [(0.1 * k, "radar", k) for k in range(5)])
    sched = stored.FrameSchedule(items)
    assert len(sched) == 11
    got = list(sched)
    assert got == items and [tuple(map(type, g)) for g in got] == [(float, str, int)] * 11
    assert sched[7] == items[7] and sched[-1] == items[-1] and sched[2:9] == items[2:9]
    assert list(stored.FrameSchedule([])) == []


def test_a_ship_simulations_truth_in_chunks_is_the_whole_arrays(monkeypatch):
    """The ship-to-ship truth table, made a chunk at a time onto disk, holds the numbers the whole
    run's states give at once, every column, to the last bit."""
    from boomtip.tools.config.scenario import load_scenario
    from boomtip.data.sim import simulator

    scenario = load_scenario("sts-irregular", ["duration_s=6"])
    monkeypatch.setattr(simulator, "TRUTH_CHUNK", 257)  # several chunks, the last one short
    chunked = simulator.Simulation(scenario).truth
    monkeypatch.setattr(simulator, "TRUTH_CHUNK", 10**9)
    whole = simulator.Simulation(scenario).truth
    assert isinstance(chunked, StoredTruth) and list(chunked.columns) == list(TRUTH_COLUMNS)
    assert len(chunked.t_s) == 1201
    for name in TRUTH_COLUMNS:
        np.testing.assert_array_equal(chunked.columns[name], whole.columns[name])
