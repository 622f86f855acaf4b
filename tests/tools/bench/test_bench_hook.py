"""The hook bench's baseline: the block stage run again on the same inputs with the reference
block fit and ray steps (tools/bench/references/hook.py), timed, and its fixes compared."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.perception.hook import detect_hook
from boomtip.perception.hook_block import block_model, hanging_pose
from boomtip.perception.hook_types import HookConfig
from boomtip.perception.timing import StageTimes
from boomtip.tools.bench.references import hook as hook_reference
from boomtip.tools.bench.hook import _with_reference


def _cloud(t: np.ndarray, yaw: float, seed: int) -> np.ndarray:
    cfg = HookConfig()
    model = block_model(cfg.block_height_m, cfg.model_points)
    rng = np.random.default_rng(seed)
    q = model.points[rng.choice(len(model.points), 150, replace=False)]
    return q @ hanging_pose(t, yaw).T + t + rng.normal(0, 0.01, (150, 3))


def test_the_baseline_runs_on_the_same_inputs_and_its_fixes_are_compared():
    cfg = HookConfig()
    ref = {"current_cpu_s": 0.0, "reference_cpu_s": 0.0, "reference_wall_s": 0.0, "frames": 0, "same": 0}
    timed = _with_reference(detect_hook, ref)
    import boomtip.perception.hook as stage

    for k, t in enumerate((np.array([0.5, 0.3, -20.0]), np.array([-0.4, 0.2, -30.0]), np.array([0.1, 0.1, -25.0]))):
        pts = _cloud(t, 0.3 * k, k)
        times = StageTimes()
        det = timed(pts, t + [0.2, -0.1, 0.2], float(np.linalg.norm(t)), cfg, np.random.default_rng(k), times)
        alone = detect_hook(pts, t + [0.2, -0.1, 0.2], float(np.linalg.norm(t)), cfg, np.random.default_rng(k))
        assert det.ok and np.array_equal(det.position_m, alone.position_m)  # the chain gets the current stage's fix
        assert np.abs(det.position_m - t).max() < 0.05
        assert "hook.fit" in times.ms
    # the reference steps come in as detect_hook's argument: the stage's own are untouched
    assert stage.BLOCK_STEPS == (stage.fit_block, stage.ray_pick, stage.ray_refine)
    assert all(ref is not cur for ref, cur in zip(hook_reference.REFERENCE_STEPS, stage.BLOCK_STEPS))
    assert ref["frames"] == 2 and ref["same"] == 2  # the first frame (the model's build) is not compared
    assert ref["current_cpu_s"] > 0 and ref["reference_cpu_s"] > 0 and ref["reference_wall_s"] > 0


@pytest.mark.slow
def test_the_whole_bench_runs_and_the_integrators_agree():
    """One simulated second end to end: every part timed, and RK4 against the chain's midpoint
    rule on two runs that keep their samples (the chain's own streams them to its store)."""
    from boomtip.tools.bench.hook import bench_hook

    r = bench_hook("hook-2", 1.0, [])
    assert r["lidar_frames"] == 20 and r["realtime_factor"]["end_to_end"] > 0
    for name in ("ekf_flexible", "ekf_rigid", "ukf_flexible", "ukf_rigid"):
        rk4 = r["estimators_against_rk4"][name]
        # the integrators differ by the midpoint rule's error: 11 um at most in this first second's
        # transient (the flexible UKF, stepped over 25 ms windows), against centimetres of hook error
        assert rk4["max_pos_difference_m"] < 2e-5 and rk4["cpu_s"] > 0
    assert r["block_against_reference"]["same_fix"] == r["block_against_reference"]["frames"] > 0
    two = r["end_to_end_two_cores"]  # the run timed serial and on two cores: the same outputs
    assert two["same_outputs"] == {"hook_estimates.csv": True, "hook_measurements.csv": True, "kpis.json": True}
    assert all(len(v) == 2 and min(v) > 0 for v in two["wall_s_each"].values())
    c = r["command"]  # the ratio is the whole `boomtip run`'s, start-up included
    assert len(c["wall_s_each"]) == 2 and r["ratio"] == pytest.approx(1.0 / c["wall_s"])
    assert set(r["accuracy"]) == {"ekf_flexible", "ekf_rigid", "ukf_flexible", "ukf_rigid"}
    assert r["accuracy_same_in_process"]  # the timed command's run is the bench's, figure for figure
    assert all(0 < max(a["rmse_pos_m"]) < 0.15 for a in r["accuracy"].values())  # the first second: 10-11 cm in x
    assert 0 < two["cpu_s_own"]["two_cores"] < two["cpu_s_with_children"]["two_cores"]


def test_bench_hook_on_a_scenario_without_the_hook_chain_says_so():
    from typer.testing import CliRunner

    from boomtip.tools.cli.commands import app

    r = CliRunner().invoke(app, ["bench", "hook", "-s", "sts-loaded", "--duration", "1"])
    assert r.exit_code == 2 and "not a hook scenario" in r.output and "Traceback" not in r.output
