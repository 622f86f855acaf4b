"""Reflector detection (document 000, 4.1.2): retro-reflective deck markers are far brighter
than anything diffuse. Keep the bright points, group them into markers, fit the deck plane
through the markers that agree on one plane, then D by the same wire intersection."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from perception.geometry import heave_distance
from perception.plane import RansacConfig, fit_plane_lsq, orient_plane_towards, ransac_plane
from perception.timing import StageTimes

INTENSITY_REFERENCE_RANGE_M = 50.0


class ReflectorConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    intensity_threshold: float | None = Field(
        None, gt=0, description="fixed threshold on range-compensated intensity; None: derive from the frame"
    )
    diffuse_max: float = Field(
        1.15, gt=0, description="derived threshold floor: a white diffuse target at normal incidence reads 1.0 "
        "(range-compensated), so brighter returns are retro-reflective; 15 % margin for intensity noise",
    )
    tail_factor: float = Field(
        1.5, gt=1, description="derived threshold: at least this times the frame's 99th percentile "
        "(a sensor whose diffuse returns read high raises the threshold with them)",
    )
    range_compensate: bool = Field(True, description="scale intensity by (r / 50 m)^2 before thresholding")
    cluster_radius_m: float = Field(1.2, gt=0, description="bright points closer than this belong to one marker")
    min_markers: int = Field(3, ge=3)
    min_spread_m: float = Field(2.0, gt=0, description="markers must span this much across their main axis")
    ransac: RansacConfig = RansacConfig(distance_threshold_m=0.1, subsample_size=500, min_inliers=6, batch_size=64)


@dataclass
class ReflectorResult:
    D_m: float
    plane_sensor: np.ndarray | None
    marker_centroids: np.ndarray  # (M,3) markers on the plane
    bright_points: np.ndarray  # (B,3) all points above the threshold
    threshold: float
    status: str


def intensity_threshold(intensity_comp: np.ndarray, cfg: ReflectorConfig) -> float:
    """Threshold on range-compensated intensity: fixed, or just above the brightest diffuse
    return (markers are ~1 % of a frame, so the 99th percentile is still diffuse)."""
    if cfg.intensity_threshold is not None:
        return cfg.intensity_threshold
    return float(max(cfg.diffuse_max, cfg.tail_factor * np.percentile(intensity_comp, 99)))


def group_markers(points: np.ndarray, radius_m: float) -> tuple[np.ndarray, int]:
    """Connected components of the radius graph: one label per bright point."""
    if len(points) == 0:
        return np.zeros(0, dtype=int), 0
    pairs = cKDTree(points).query_pairs(radius_m, output_type="ndarray")
    n = len(points)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    count, labels = connected_components(graph, directed=False)
    return labels, count


def detect_reflectors(
    points_sensor: np.ndarray,
    intensity: np.ndarray,
    wire_dir_sensor: np.ndarray,
    p_tip_sensor: np.ndarray,
    cfg: ReflectorConfig,
    rng: np.random.Generator,
    times: StageTimes,
) -> ReflectorResult:
    empty = np.zeros((0, 3))
    with times.stage("reflectors.threshold"):
        finite = np.isfinite(points_sensor).all(axis=1) & np.isfinite(intensity)
        pts, inten = points_sensor[finite], intensity[finite]
        if len(pts) == 0:
            return ReflectorResult(float("nan"), None, empty, empty, float("nan"), "no points")
        comp = inten * (np.linalg.norm(pts, axis=1) / INTENSITY_REFERENCE_RANGE_M) ** 2 if cfg.range_compensate else inten
        thr = intensity_threshold(comp, cfg)
        bright = pts[comp > thr]
    if len(bright) < 3:
        return ReflectorResult(float("nan"), None, empty, bright, thr, f"no reflectors ({len(bright)} bright points)")
    with times.stage("reflectors.markers"):
        labels, n_markers = group_markers(bright, cfg.cluster_radius_m)
        # RANSAC on the bright points: false bright patches off the deck plane are outliers.
        fit = ransac_plane(bright, cfg.ransac, rng)
        if fit is None:
            return ReflectorResult(float("nan"), None, empty, bright, thr, "reflectors do not share a plane")
        on_plane = np.bincount(labels, weights=fit.inlier_mask, minlength=n_markers) / np.bincount(labels, minlength=n_markers)
        good = np.flatnonzero(on_plane > 0.5)
        keep = np.isin(labels, good) & fit.inlier_mask
        centroids = np.array([bright[(labels == m) & keep].mean(axis=0) for m in good]) if len(good) else empty
    if len(good) < cfg.min_markers:
        return ReflectorResult(float("nan"), None, centroids, bright, thr, f"too few markers ({len(good)} < {cfg.min_markers})")
    # Markers on one line (one deck edge only) do not fix the plane's roll about that line.
    c = centroids - centroids.mean(axis=0)
    spread = np.sqrt(np.linalg.svd(c, compute_uv=False)[1] ** 2 / len(c)) * 2
    if spread < cfg.min_spread_m:
        return ReflectorResult(float("nan"), None, centroids, bright, thr, f"markers collinear (spread {spread:.2f} m)")
    with times.stage("reflectors.plane"):
        plane = orient_plane_towards(fit_plane_lsq(bright[keep]))
        D = heave_distance(plane, wire_dir_sensor, p_tip_sensor)
    return ReflectorResult(D, plane, centroids, bright, thr, "ok" if np.isfinite(D) else "wire parallel to the plane")
