"""Deck detection (document 000, 4.1.1): the feeder deck plane in the sensor frame, then D
by intersecting the wire (straight down from the boom tip) with it (eq. 4.8)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from perception.geometry import heave_distance
from perception.plane import MultiPlaneConfig, PlaneFit, RansacConfig, multi_plane_deck
from perception.preprocess import PreprocessConfig, preprocess
from perception.timing import StageTimes


class DeckConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    preprocess: PreprocessConfig = PreprocessConfig(min_range_m=2.0)
    multi_plane: MultiPlaneConfig = MultiPlaneConfig()
    min_points: int = Field(50, ge=3, description="fewer points after preprocessing: no measurement")


# LiDAR: dense and precise (cm noise). A 0.3 m voxel grid keeps ~1 point per beam footprint
# near the nadir and thins the far field, where the deck is already seen obliquely.
LIDAR_DECK = DeckConfig(
    preprocess=PreprocessConfig(min_range_m=2.0, voxel_size_m=0.3),
    multi_plane=MultiPlaneConfig(ransac=RansacConfig(distance_threshold_m=0.08, subsample_size=1500, refit_iterations=2)),
)
# Radar: sparse (hundreds of points) and noisy (0.1-0.2 m): a wider inlier band, no voxels.
RADAR_DECK = DeckConfig(
    preprocess=PreprocessConfig(min_range_m=2.0, max_range_m=150.0),
    multi_plane=MultiPlaneConfig(
        ransac=RansacConfig(distance_threshold_m=0.45, subsample_size=1000, min_inliers=20, refit_iterations=3),
        min_inliers=20, merge_distance_m=1.0,
    ),
    min_points=20,
)


@dataclass
class DeckResult:
    D_m: float
    plane_sensor: np.ndarray | None
    fit: PlaneFit | None
    points_used: np.ndarray
    status: str  # "ok" or why there is no measurement


def detect_deck(
    points_sensor: np.ndarray,
    wire_dir_sensor: np.ndarray,
    p_tip_sensor: np.ndarray,
    cfg: DeckConfig,
    rng: np.random.Generator,
    times: StageTimes,
    prefix: str = "deck",
) -> DeckResult:
    with times.stage(f"{prefix}.preprocess"):
        pts, _, _ = preprocess(points_sensor, None, cfg.preprocess, rng)
    if len(pts) < cfg.min_points:
        return DeckResult(float("nan"), None, None, pts, f"too few points ({len(pts)} < {cfg.min_points})")
    with times.stage(f"{prefix}.planes"):
        result = multi_plane_deck(pts, -wire_dir_sensor, cfg.multi_plane, rng)
    if result is None:
        return DeckResult(float("nan"), None, None, pts, "no deck plane")
    with times.stage(f"{prefix}.intersect"):
        D = heave_distance(result.deck.plane, wire_dir_sensor, p_tip_sensor)
    if not np.isfinite(D) or D <= 0:
        return DeckResult(float("nan"), result.deck.plane, result.deck, pts, "wire does not meet the deck plane")
    return DeckResult(D, result.deck.plane, result.deck, pts, "ok")
