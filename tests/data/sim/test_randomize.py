"""Randomized worlds: the draws follow their documented distributions, a seed is a world, the
simulator sees the drawn world, and a scale outside [0, 3] is refused with its key."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.data.sim.randomize import draw_mismatch
from boomtip.data.sim.world import Mismatch
from boomtip.tools.config.scenario import ScenarioError, load_scenario


def test_the_draws_follow_the_installation_s_stated_accuracies():
    inst = load_scenario("sts-loaded").installation  # LiDAR survey 0.03 deg, radar 0.05, MRU bias 0.02, clocks 1 ms
    draws = [draw_mismatch(inst, seed, 1.0) for seed in range(400)]
    lidar = np.array([d.lidar_mount_rpy_deg for d in draws])
    mru = np.array([d.mru_bias_deg for d in draws])
    clock = np.array([d.lidar_clock_offset_s for d in draws])
    assert lidar.std() == pytest.approx(0.03, rel=0.1) and mru.std() == pytest.approx(0.02, rel=0.1)
    assert clock.std() == pytest.approx(inst.lidar.clock_sigma_s, rel=0.1)
    ea = np.array([d.rope_ea_n for d in draws])
    assert ea.min() >= 1e10 and ea.max() <= 1e11 and np.median(np.log10(ea)) == pytest.approx(10.5, abs=0.1)
    wind = np.hypot(*np.array([d.wind_mps for d in draws]).T)
    assert wind.max() <= 15.0 and wind.max() > 13.0
    for key in ("boom_stiffness", "boom_damping", "hook_mass", "boom_mass"):
        v = np.array([getattr(d, key) for d in draws])
        assert v.min() >= 0.9 and v.max() <= 1.1
    noise = np.array([d.radar_noise_scale for d in draws])
    assert noise.min() >= 0.7 and noise.max() <= 1.5


def test_a_seed_is_a_world_and_scale_zero_is_the_nominal_one():
    inst = load_scenario("sts-loaded").installation
    assert draw_mismatch(inst, 3, 1.0) == draw_mismatch(inst, 3, 1.0) != draw_mismatch(inst, 4, 1.0)
    assert draw_mismatch(inst, 3, 0.0) == Mismatch()
    half, full = draw_mismatch(inst, 3, 0.5), draw_mismatch(inst, 3, 1.0)
    assert half.lidar_mount_rpy_deg == pytest.approx(np.array(full.lidar_mount_rpy_deg) / 2)


def test_the_run_and_its_simulator_see_the_drawn_world():
    from boomtip.data.sim.simulator import Simulation

    s = load_scenario("sts-empty", ["world.randomize.enabled=true", "seed=11", "duration_s=1"])
    drawn = draw_mismatch(s.installation, 11, 1.0)
    assert s.world.mismatch == drawn
    assert load_scenario("sts-empty", ["world.randomize.enabled=true", "world.randomize.seed=12"]).world.mismatch == \
        draw_mismatch(s.installation, 12, 1.0)
    sim = Simulation(s)
    assert sim.clock_offset_s == {"lidar": drawn.lidar_clock_offset_s, "radar": drawn.radar_clock_offset_s}
    assert type(s).model_validate(s.model_dump()).world.mismatch == drawn  # validating again draws the same


@pytest.mark.parametrize("scale", ["-0.5", "3.5", "nan"])
def test_a_scale_outside_zero_to_three_is_refused_with_its_key(scale):
    with pytest.raises(ScenarioError, match="world.randomize.scale"):
        load_scenario("sts-loaded", [f"world.randomize.scale={scale}"])
