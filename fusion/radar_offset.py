"""The radar registration's offset from the LiDAR's, learnt while both register the feeder, and
the settings of how the radar's registration is used."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["RadarOffset", "RadarOffsetConfig"]


@dataclass(frozen=True)
class RadarOffsetConfig:
    """How the radar's registration is used (from perception's RadarRegistrationConfig): its
    offset from the LiDAR's learnt from every `learn_every`-th radar frame while the LiDAR
    registers, over at most `offset_frames`; with the LiDAR out for `after_s`, an update once the
    offset has `min_offset_frames`, only along directions known better than `max_sigma_m`."""

    enabled: bool
    after_s: float
    learn_every: int
    offset_frames: int
    min_offset_frames: int
    max_sigma_m: float



class RadarOffset:
    """The radar registration's offset from the LiDAR's (x, y, yaw), learnt while both see the
    feeder: the radar's mount error (0.05 deg is 2 cm at 25 m) and its noise's bias along
    the model's edges. A running mean over at most `frames` samples, with its spread."""

    def __init__(self, frames: int) -> None:
        self.frames = frames
        self.n = 0
        self.mean = np.zeros(3)
        self.mean_square = np.zeros(3)

    def add(self, radar_x_y_yaw: np.ndarray, lidar_x_y_yaw: np.ndarray) -> None:
        d = np.asarray(radar_x_y_yaw, dtype=float) - lidar_x_y_yaw
        d[2] = (d[2] + math.pi) % (2.0 * math.pi) - math.pi
        self.n += 1
        a = 1.0 / min(self.n, self.frames)
        self.mean += a * (d - self.mean)
        self.mean_square += a * (d * d - self.mean_square)

    def covariance(self) -> np.ndarray:
        """Of the mean: the samples' spread over their (capped) count."""
        spread = np.maximum(self.mean_square - self.mean * self.mean, 0.0)
        return np.diag(spread / max(min(self.n, self.frames), 1))
