"""Randomized worlds: every deviation of the world from its installation (`world.mismatch`)
drawn from documented distributions, so a study is over worlds, not over one world.

Distributions at `scale` 1 (each one's width times `scale`; 0 is the nominal world, no mismatch):
- each sensor's mount, per axis: normal, 1-sigma its surveyed accuracy (`installation.<sensor>.mount.accuracy_deg`);
- the MRU's bias, roll, pitch and yaw: normal, 1-sigma its static accuracy (`installation.mru.bias_accuracy_deg`);
- the MRU's unstated lag: uniform 0-5 ms;
- each sensor's clock offset: normal, 1-sigma its stated time-stamp accuracy (`installation.<sensor>.clock_sigma_s`);
- boom stiffness, boom damping, hook and load mass, boom mass: nominal x uniform 0.9-1.1;
- the reeving's axial stiffness EA: log-uniform 1e10-1e11 N;
- wind on block and load: mean speed uniform 0-15 m/s, direction uniform, with the offshore gust
  spectrum's gusts (`data/sim/wind.py`);
- encoder biases (slew, luff): normal, 1-sigma 0.005 deg;
- the true noise of the LiDAR and of the radar: stated x uniform 0.7-1.5.
The draws are the run's (`world.randomize.seed`, by default the run's own seed): the same seed,
the same world. Processing never sees them: they are the world's, as a real rig's are.
"""

from __future__ import annotations

import math

import numpy as np

from boomtip.data.installation import Installation
from boomtip.data.sim.world import EncoderBias, Mismatch, World

__all__ = ["LAG_MAX_S", "draw_mismatch", "randomized_world"]

LAG_MAX_S = 0.005
CRANE_FACTOR_HALF_WIDTH = 0.1  # boom stiffness and damping, masses: nominal x (1 +- this)
EA_LOG10_N = (10.0, 11.0)
WIND_MAX_MPS = 15.0
ENCODER_BIAS_SIGMA_DEG = 0.005
NOISE_SCALE_RANGE = (0.7, 1.5)


def draw_mismatch(installation: Installation, seed: int, scale: float) -> Mismatch:
    """One world's deviations from `installation` (the module's distributions, widths x scale)."""
    if scale <= 0:
        return Mismatch()
    rng = np.random.default_rng([seed, 0x5EED])
    inst = installation
    normal3 = lambda sigma: tuple(float(v) for v in rng.normal(0.0, sigma * scale, 3))
    factor = lambda: float(1.0 + scale * rng.uniform(-CRANE_FACTOR_HALF_WIDTH, CRANE_FACTOR_HALF_WIDTH))
    lo, hi = NOISE_SCALE_RANGE
    noise = lambda: float(1.0 + scale * rng.uniform(lo - 1.0, hi - 1.0))
    wind_speed, wind_dir = WIND_MAX_MPS * scale * rng.uniform(), rng.uniform(0.0, 2.0 * math.pi)
    return Mismatch(
        lidar_mount_rpy_deg=normal3(inst.lidar.mount.accuracy_deg),
        radar_mount_rpy_deg=normal3(inst.radar.mount.accuracy_deg),
        mru_bias_deg=normal3(inst.mru.bias_accuracy_deg),
        mru_lag_s=float(LAG_MAX_S * scale * rng.uniform()),
        lidar_clock_offset_s=float(np.clip(rng.normal(0.0, inst.lidar.clock_sigma_s * scale), -1.0, 1.0)),
        radar_clock_offset_s=float(np.clip(rng.normal(0.0, inst.radar.clock_sigma_s * scale), -1.0, 1.0)),
        boom_stiffness=factor(), boom_damping=factor(), hook_mass=factor(), boom_mass=factor(),
        rope_ea_n=float(10.0 ** (EA_LOG10_N[1] - scale * (EA_LOG10_N[1] - EA_LOG10_N[0]) * rng.uniform())),
        wind_mps=(float(wind_speed * math.cos(wind_dir)), float(wind_speed * math.sin(wind_dir))), wind_gusts=True,
        encoder_bias_deg=EncoderBias(slew=float(rng.normal(0.0, ENCODER_BIAS_SIGMA_DEG * scale)),
                                     luff=float(rng.normal(0.0, ENCODER_BIAS_SIGMA_DEG * scale))),
        lidar_noise_scale=noise(), radar_noise_scale=noise(),
    )


def randomized_world(world: World, installation: Installation, run_seed: int) -> World:
    """The world with its mismatch drawn, when `world.randomize.enabled`; else as it is."""
    r = world.randomize
    if not r.enabled:
        return world
    seed = run_seed if r.seed is None else r.seed
    return world.model_copy(update={"mismatch": draw_mismatch(installation, seed, r.scale)})
