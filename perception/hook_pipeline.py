"""The hook's perception per LiDAR frame (document 002's measurement, from real clouds):

    frame -> levelled with the given tip attitude (the tracking filter's: MRU and encoders
             filtered, boom deflection included) -> the rope's direction fitted about the
             predicted one (perception.rope) -> the lower block segmented and fitted with its
             known model about a prior (perception.hook), with its covariance

The prior is the tracker's prediction when it is certain enough to associate a sparse block,
else the last detection when recent (the hook moves < 1 m in 0.5 s), else straight below the tip
at the hoist length. Built from the installation (the LiDAR's mount and spec, the rope's radius,
the block's height) and the settings; never from the simulated world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from boomtip.data.installation import Installation, LidarSpec
from boomtip.data.poses import rpy_matrix
from boomtip.perception.hook import HookDetection, detect_hook
from boomtip.perception.hook_types import HookConfig
from boomtip.perception.rope import RopeConfig, RopeFix, fit_rope
from boomtip.perception.timing import StageTimes

__all__ = ["HookPipeline", "LevelledFrame", "detection_sigma_m", "level_at_tip", "sigma_across"]

HOOK_SEED_SALT = 7  # the run's seed, this and the frame's index: the block fit's random draws
ROPE_SEED_SALT = 8  # likewise for the rope's
RECENT_DETECTION_S = 0.5  # a detection this recent is the prior when the prediction is too loose
MIN_SIGMA_M = 0.005  # no block fix is better than this per axis, whatever the beams


def detection_sigma_m(position_m: np.ndarray, lidar: LidarSpec) -> float:
    """1-sigma per axis of a block fix. Across the beams, the block's position is fixed by its
    two edges, and each edge is only known to within one beam spacing s = r * dtheta (uniform:
    s / sqrt(12)); the points inside the outline do not sharpen the edges, so the two edges give
    s / sqrt(24) whatever the point count. Never better than the specified range noise."""
    r = float(np.linalg.norm(position_m))
    return float(max(lidar.range_noise_m, MIN_SIGMA_M, r * lidar.angular_step_rad / math.sqrt(24.0)))


def sigma_across(cov_m2: np.ndarray) -> float:
    """Largest horizontal 1-sigma of a hook position covariance (m): across the rope."""
    return float(np.sqrt(max(np.linalg.eigvalsh(cov_m2[:2, :2])[-1], 0.0)))


@dataclass
class LevelledFrame:
    """A frame's points levelled at the tip (z up, x along the heading), and the sensor's place."""

    points_level: np.ndarray
    sensor_level: np.ndarray


def level_at_tip(points_sensor: np.ndarray, T_tip_sensor: np.ndarray, roll_rad: float, pitch_rad: float,
                 heading_rad: float) -> LevelledFrame:
    """A sensor's points in the levelled frame at the tip (z up, world axes), from its mount on
    the tip and the tip's attitude."""
    R_tip = rpy_matrix(np.array([roll_rad, pitch_rad, 0.0])) @ rpy_matrix(np.array([0.0, 0.0, heading_rad]))
    T = T_tip_sensor
    return LevelledFrame(points_sensor @ (R_tip @ T[:3, :3]).T + R_tip @ T[:3, 3], R_tip @ T[:3, 3])


class HookPipeline:
    def __init__(self, installation: Installation, detector: HookConfig | None = None, rope: RopeConfig | None = None,
                 seed: int = 0, detect: Callable[..., HookDetection] = detect_hook) -> None:
        self.lidar = installation.lidar
        cfg, rope_cfg = detector or HookConfig(), rope or RopeConfig()
        if "radius_m" not in rope_cfg.model_fields_set:  # the rope as installed
            rope_cfg = rope_cfg.model_copy(update={"radius_m": installation.crane.rope_radius_m})
        if "block_height_m" not in cfg.model_fields_set:
            cfg = cfg.model_copy(update={"block_height_m": installation.crane.block_height_m})
        self.cfg, self.rope_cfg = cfg, rope_cfg
        self.seed = seed
        self.T_tip_sensor = installation.lidar.mount.matrix()
        self.detect = detect  # the block's segmentation and fit (a benchmark may wrap it)
        self.last: tuple[float, np.ndarray] | None = None  # the last detection (t, position)

    def level(self, points_sensor: np.ndarray, roll_rad: float, pitch_rad: float, heading_rad: float) -> LevelledFrame:
        """The frame's points in the levelled frame at the tip, from the tip's attitude."""
        return level_at_tip(points_sensor, self.T_tip_sensor, roll_rad, pitch_rad, heading_rad)

    def rope(self, frame: LevelledFrame, p_pred: np.ndarray, sigma_across_m: float, hoist_m: float, index: int,
             times: StageTimes) -> RopeFix:
        """The rope's direction, searched about the predicted hook's (its across sigma)."""
        range_m = float(np.linalg.norm(p_pred))
        rng = np.random.default_rng([self.seed, ROPE_SEED_SALT, index])
        return fit_rope(frame.points_level, p_pred / range_m, sigma_across_m / range_m, hoist_m, self.rope_cfg, rng, times)

    def block(self, frame: LevelledFrame, t_s: float, p_pred: np.ndarray, cov_pred: np.ndarray, hoist_m: float,
              index: int, times: StageTimes) -> tuple[HookDetection, np.ndarray, np.ndarray]:
        """The block's fix about the prior (see the module), its covariance (NaN without a fix),
        and the prior it was searched about."""
        tracked = bool(np.all(np.isfinite(p_pred)) and sigma_across(cov_pred) <= self.cfg.sparse_max_prior_sigma_m)
        if tracked:
            prior = p_pred
        elif self.last is not None and t_s - self.last[0] <= RECENT_DETECTION_S:
            prior = self.last[1]
        else:
            prior = np.array([0.0, 0.0, -hoist_m])
        rng = np.random.default_rng([self.seed, HOOK_SEED_SALT, index])
        det = self.detect(frame.points_level, prior, hoist_m, self.cfg, rng, times, sensor_position_m=frame.sensor_level,
                          prior_cov_m2=cov_pred if tracked else None)
        cov = np.full((3, 3), np.nan)
        if det.has_fix:
            cov = det.cov_m2 if det.cov_m2 is not None else np.eye(3) * detection_sigma_m(det.position_m, self.lidar) ** 2
            self.last = (t_s, det.position_m)
        return det, cov, prior
