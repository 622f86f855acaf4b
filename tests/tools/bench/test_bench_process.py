"""`bench process`: the real-time factors of `boomtip process` (default workers, one) and of
kiss-icp's pipeline on the same frames, with the run's feeder time and accuracy."""

from __future__ import annotations

import pytest

from boomtip.tools.bench.process import bench_process


@pytest.mark.slow
def test_the_ratio_is_the_default_runs_real_time_factor_and_every_figure_is_there():
    r = bench_process(duration_s=6.0, repeats=1)  # past the feeder's 4 s warm-up
    assert r["recording_s"] == pytest.approx(6.0, abs=0.1) and r["lidar_frames"] == 120  # 20 Hz
    for key in ("default", "workers_1", "kiss_icp"):
        k = r[key]
        # both rounded to 3 decimals: the factor by up to 5e-4, and the wall time's 5e-4 s moves
        # recording / wall by up to factor / wall times that, whatever the machine's speed
        assert k["min_s"] <= k["wall_s"] <= k["max_s"]
        bound = 5e-4 * (1.0 + k["realtime_factor"] / k["wall_s"]) + 1e-9
        assert k["realtime_factor"] == pytest.approx(r["recording_s"] / k["wall_s"], abs=bound)
    assert r["ratio"] == r["default"]["realtime_factor"]
    assert r["speedup_workers"] == pytest.approx(r["workers_1"]["wall_s"] / r["default"]["wall_s"], abs=5e-4)
    assert r["feeder_apt_ms"] > 0
    assert 0 < r["accuracy"]["fused_mae_D_m"] < 0.01  # scored against the simulated truth
