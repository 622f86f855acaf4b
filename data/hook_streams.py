"""The streams a hook estimate is made from, as time-stamped arrays: the LiDAR's block fixes
(and rope directions), the crane's encoders and the MRU. Made by the hook chain from real
clouds, or by the simulator from the crane's truth; read by the hook filter."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

__all__ = ["HookMeasurements", "TIMES_OF"]


# each stream's time stamps: the rows of a field follow these
TIMES_OF = {"t_lidar": "t_lidar", "lidar_p_rel_tip_world": "t_lidar", "lidar_sigma_m": "t_lidar", "lidar_cov_m2": "t_lidar",
            "lidar_model_fit": "t_lidar", "rope_direction": "t_lidar", "rope_cov": "t_lidar",
            "t_encoders": "t_encoders", "encoders": "t_encoders", "t_mru": "t_mru", "mru": "t_mru"}


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

    def until(self, t_s: float) -> "HookMeasurements":
        """The samples up to t_s (inclusive) of every stream, in whatever order its stamps come:
        what an estimate that stops there is made from."""
        kept = {times: np.asarray(getattr(self, times)) <= t_s for times in set(TIMES_OF.values())}
        return HookMeasurements(**{f.name: None if getattr(self, f.name) is None else getattr(self, f.name)[kept[TIMES_OF[f.name]]]
                                   for f in fields(self)})
