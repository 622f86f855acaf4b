"""`bench lift`: the lift chain's real-time factor beside the hook chain alone and one worker."""

from __future__ import annotations

import pytest

from boomtip.tools.bench.lift import bench_lift


@pytest.mark.slow
def test_the_ratio_is_the_lift_chains_real_time_factor_and_every_figure_is_there():
    r = bench_lift(duration_s=3.0, repeats=1)
    assert r["recording_s"] == pytest.approx(3.0, abs=0.1)
    for key in ("lift", "hook_alone", "lift_workers_1"):
        k = r[key]
        # both rounded to 3 decimals: the factor by up to 5e-4, and the wall time's 5e-4 s moves
        # recording / wall by up to factor / wall times that, whatever the machine's speed
        assert k["min_s"] <= k["wall_s"] <= k["max_s"]
        bound = 5e-4 * (1.0 + k["realtime_factor"] / k["wall_s"]) + 1e-9
        assert k["realtime_factor"] == pytest.approx(r["recording_s"] / k["wall_s"], abs=bound)
    assert r["ratio"] == r["lift"]["realtime_factor"]
    assert r["lift_over_hook"] == pytest.approx(r["lift"]["wall_s"] / r["hook_alone"]["wall_s"], abs=5e-4)
    assert r["frame_ms"] > 0
