"""The streams a hook estimate is made from, as time-stamped arrays: the LiDAR's block fixes
(and rope directions), the crane's encoders and the MRU. Made by the hook chain from real
clouds, or by the simulator from the crane's truth; read by the hook filter."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HookMeasurements"]


@dataclass
class HookMeasurements:
    """Time-stamped sensor streams.  A LiDAR row of NaN means "no detection"."""

    t_lidar: np.ndarray
    lidar_p_rel_tip_world: np.ndarray  # (K, 3)
    t_encoders: np.ndarray
    encoders: np.ndarray  # (K, 3): slew rad, luff rad, hoist m
    t_mru: np.ndarray
    mru: np.ndarray  # (K, 4): roll, pitch, roll rate, pitch rate
    lidar_sigma_m: np.ndarray | None = None  # (K,) per-fix 1-sigma; None: the config's
    lidar_cov_m2: np.ndarray | None = None  # (K, 3, 3) per-fix covariance; rows with NaN: lidar_sigma_m
    # the rope's direction in the same LiDAR frames (perception.rope), applied before the frame's
    # block fix: (K, 3) unit vectors, world axes (NaN rows: no rope fit), and (K, 3, 3) covariances
    # (K,) bool: the fix is the block model fitted (not a far block's few points, whose point on
    # the block is not the model's); None: every fix is
    lidar_model_fit: np.ndarray | None = None
    rope_direction: np.ndarray | None = None
    rope_cov: np.ndarray | None = None
