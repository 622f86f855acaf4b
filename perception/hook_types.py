"""The hook stage's thresholds (:class:`HookConfig`) and its result (:class:`HookDetection`).

Apart from the stage's code (perception.hook) so that the segmentation, fit and ray modules it
calls can take the configuration without importing the stage.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.perception.plane import RansacConfig

__all__ = ["HookConfig", "HookDetection"]


class HookConfig(BaseModel):
    """Thresholds of :func:`detect_hook` (metres, radians unless the name says otherwise)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    # --- 1. gate ---------------------------------------------------------------------------
    prior_radius_m: float = Field(6.0, gt=0, description="gate radius around the prior (3 sigma + block size)")
    below_tip_m: float = Field(1.0, ge=0, description="keep only points at least this far below the tip")
    min_gate_points: int = Field(3, ge=1, description="fewer gated points: 'no points near the prediction'")

    # --- 2. planes and rope --------------------------------------------------------------------
    plane_ransac: RansacConfig = Field(
        default_factory=lambda: RansacConfig(distance_threshold_m=0.08, subsample_size=1500, min_inliers=20,
                                             max_iterations=300),
    )
    plane_max_tilt_deg: float = Field(10.0, ge=0, le=45, description="deck/cargo-top normals within this of up")
    max_planes: int = Field(3, ge=0, description="large planes removed at most")
    plane_min_extent_m: float = Field(
        6.0, gt=0, description="a plane patch must be wider than this (the block is at most ~2.8 m) to be removed"
    )
    plane_min_inliers: int = Field(20, ge=3)
    plane_band_m: float = Field(0.25, gt=0, description="points closer than this above a removed plane go too")
    plane_cell_min_m: float = Field(0.5, gt=0, description="grid cell of the plane patches (at least)")
    plane_cell_steps: float = Field(1.6, gt=0, description="grid cell >= this many beam spacings at the range")

    rope_radius_m: float = Field(0.25, gt=0, description="points this close to the line tip -> prior are rope")
    rope_top_margin_m: float = Field(
        0.9, ge=0,
        description="rope points must lie this far above the highest non-rope point near the line: the model's "
        "relief (sheave crown to body top, 0.75 m) + noise, so a lone crown point of a far, sparse block is kept; "
        "rope points closer to the block are excluded by the robust fit",
    )
    rope_near_radius_m: float = Field(1.6, gt=0, description="'near the line' for the block-top search")

    # --- 3. clustering ---------------------------------------------------------------------------
    cluster_method: Literal["auto", "kdtree", "dbscan"] = Field(
        "auto", description="kdtree: scipy radius graph + connected components; dbscan: Open3D cluster_dbscan "
        "(min_points=1, the same partition); auto: dbscan below cluster_auto_points points, else kdtree: dbscan is "
        "the faster on a few hundred points, kdtree on thousands",
    )
    cluster_auto_points: int = Field(500, ge=0)
    lidar_angular_step_rad: float = Field(
        math.radians(360.0 / 1024), gt=0, description="beam spacing of the LiDAR (OS1-128: 0.35 deg both ways)"
    )
    cluster_eps_steps: float = Field(2.5, gt=0, description="cluster radius in beam spacings at the prior's range")
    cluster_eps_min_m: float = Field(0.25, gt=0)
    cluster_eps_max_m: float = Field(2.5, gt=0)
    min_cluster_points: int = Field(3, ge=1, description="smaller clusters are ignored")
    min_extent_m: float = Field(0.5, ge=0, description="block-consistent cluster extent, lower bound")
    max_extent_m: float = Field(6.0, gt=0, description="block-consistent cluster extent, upper bound")

    # --- 4. model fit ------------------------------------------------------------------------------
    block_height_m: float = Field(4.0, gt=0, description="height of the known block model (data.hook_block)")
    model_points: int = Field(6000, ge=100, description="samples of the model's visible surface")
    top_band_m: float = Field(0.3, gt=0, description="'highest points': within this of the top")
    fit_max_points: int = Field(400, ge=10, description="random subsample of the cluster for the ICP")
    icp_max_correspondence_m: float = Field(0.5, gt=0, description="coarse ICP stage correspondence cut")
    icp_final_correspondence_m: float = Field(0.2, gt=0, description="fine ICP stage cut = inlier threshold")
    icp_coarse_iterations: int = Field(8, ge=0)
    icp_iterations: int = Field(30, ge=1, description="total ICP iterations at most")
    icp_tolerance_m: float = Field(5e-4, gt=0, description="stop when the reference point moves less")
    icp_good_rms_m: float = Field(
        0.035, gt=0, description="a best fit worse than this + icp_good_rms_per_m * range retries from more yaws"
    )
    icp_good_rms_per_m: float = Field(2.5e-4, ge=0, description="weak far returns are noisier (sensor model)")
    icp_retry_yaw_step_deg: float = Field(30.0, gt=0, description="yaw step of the retry starts (over 180 deg)")
    icp_retry_shift_m: float = Field(0.4, ge=0, description="shifts of the retry starts along the long axis")
    isotropic_ratio: float = Field(1.4, ge=1, description="below this horizontal eigen-ratio, also try yaw +-90 deg")
    prior_start_sigma_m: float = Field(
        0.3, gt=0, description="a filter prediction this certain (largest sigma, with prior_pick_sigma_m) is also an "
        "ICP start"
    )
    ray_refine: bool = Field(
        True, description="refine the ICP pose by ray consistency (uses free space: rays that passed the block)"
    )
    ray_refine_max_points: int = Field(
        100, ge=0, description="refine only sparse blocks (at most this many points): with more, the ICP alone is "
        "good to a few cm and the refinement would cost tens of ms"
    )
    ray_cone_margin_m: float = Field(0.4, ge=0, description="evidence rays pass within model radius + this")
    ray_max_block: int = Field(60, ge=4, description="block rays used at most (random subsample)")
    ray_max_other: int = Field(60, ge=0, description="other rays (deck beside the block) used at most")
    ray_window_steps: float = Field(1.2, gt=0, description="first grid half-width in beam spacings at the range")
    ray_window_min_m: float = Field(0.05, gt=0)
    ray_window_max_m: float = Field(0.8, gt=0)
    ray_yaw_min_deg: float = Field(2.0, gt=0, description="first grid yaw half-range, at least")
    ray_yaw_max_deg: float = Field(10.0, gt=0, description="first grid yaw half-range, at most")
    ray_grid_points: tuple[int, int, int] = Field((9, 5, 7), description="offsets per axis: coarse, local, final")
    ray_yaw_points: tuple[int, int, int] = Field((5, 3, 5), description="yaw samples: coarse, local, final")
    ray_starts: int = Field(4, ge=1, description="best coarse poses refined locally")
    ray_clip_m: float = Field(0.08, gt=0, description="residual clip: cost of a hit/miss contradiction")
    ray_occlusion_m: float = Field(0.15, gt=0, description="a non-block point this far in front: occlusion")
    ray_sigma_m: float = Field(0.03, gt=0, description="range noise for the posterior-mean weights (near)")
    ray_sigma_per_m: float = Field(
        4e-4, ge=0, description="far blocks: range noise = max(ray_sigma_m, this * range) up to ray_sigma_max_m; a "
        "weak return is noisier, and the block's return weakens as 1/range^2 (OS1 class: ~1.5 cm at 30 m, ~4.5 cm "
        "at 115 m)"
    )
    ray_sigma_max_m: float = Field(0.06, gt=0)
    min_fit_points: int = Field(
        6, ge=4, description="fewer block points: no fix (4 unknowns; with 3-5 points of a far block the error "
        "reaches decimetres)"
    )
    mask_distance_m: float = Field(0.15, gt=0, description="segmented block points: within this of the posed mesh")
    max_fit_rms_m: float = Field(0.10, gt=0, description="worse fit RMS: not the block")
    min_inlier_fraction: float = Field(0.8, gt=0, le=1, description="fewer cluster points explained: not the block")
    length_tolerance_m: float = Field(2.0, ge=0, description="|reference - tip| must match the hoist length within "
                                      "max(this, length_tolerance_fraction * l)")
    length_tolerance_fraction: float = Field(0.03, ge=0)

    # --- 5. sparse fix (a far block: too few points for the model fit) ---------------------------
    sparse: bool = Field(
        True, description="when the model fit fails and a filter prediction with its covariance is given, take "
        "the non-background points inside the predicted block volume as the block and return a loose fix from "
        "them (status 'sparse')"
    )
    sparse_max_prior_sigma_m: float = Field(
        2.5, gt=0, description="no sparse association when the prediction is less certain than this across the rope"
    )
    prior_pick_sigma_m: float = Field(
        0.1, gt=0, description="a fix's scatter within one of the block's near-symmetric copies, added to the "
        "prediction's covariance when the prediction helps pick the copy"
    )
    sparse_max_expected_points: float = Field(
        12.0, gt=0, description="sparse fixes only for a far block: one the LiDAR puts at most this many points on "
        "(footprint area / beam spacing^2; OS1-128 at 1024 columns: beyond ~80 m)"
    )
    sparse_rope_plane_m: float = Field(
        0.15, gt=0, description="points this close to the plane through the sensor and the rope: in the rope's "
        "shadow line (see sparse_block_fix)"
    )
    sparse_gate_sigmas: float = Field(3.0, gt=0, description="predicted block volume grown by this many sigmas")
    sparse_max_points_factor: float = Field(
        2.0, gt=0, description="more candidates than factor * expected + 3 (footprint area / beam spacing^2): "
        "something else is there, no sparse fix"
    )


@dataclass
class HookDetection:
    """Result of :func:`detect_hook` (levelled frame, origin at the boom tip, metres)."""

    position_m: np.ndarray  # (3,) reference point (rope attachment), NaN when not found
    points_mask: np.ndarray  # (N,) bool over the input points: the block's points (model inliers)
    n_points: int  # points in the mask
    fit_rms_m: float  # RMS of the model inliers' point-to-model distances, NaN when no fit
    status: str  # "ok" or the reason for no fix
    cluster_extent_m: float  # extent of the chosen cluster (NaN if none)
    yaw_rad: float = float("nan")  # block yaw about the rope direction (mod pi: the visible top is symmetric)
    R_level_block: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))  # block orientation
    sigma_across_m: float = float("nan")  # posterior std across the rope from the ray refinement (larger axis)
    plane_mask: np.ndarray | None = None  # (N,) points removed as deck / large cargo-top planes
    rope_mask: np.ndarray | None = None  # (N,) points removed as rope
    cov_m2: np.ndarray | None = None  # (3, 3) covariance of a sparse fix (None: the caller's sigma model)

    @property
    def ok(self) -> bool:
        """A model fit: the reference point from the block's shape."""
        return self.status == "ok"

    @property
    def has_fix(self) -> bool:
        """A position, from the model fit or (status 'sparse') from a few points the prediction associated."""
        return self.status in ("ok", "sparse")

