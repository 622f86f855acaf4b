"""Reflector detection (document 000, 4.1.2): retro-reflective deck markers are far brighter
than anything diffuse. Keep the bright points, group them into markers, find the markers
that share one plane, fit the deck plane through their points, then D by the same wire
intersection.

Written for speed (it is the cheap method): a frame has ~10k points but only ~100 bright
ones, so after the threshold everything works on markers, not points: a grid groups
the bright points into markers, and RANSAC runs over marker centroids with the triplets
scored at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from perception.geometry import fit_plane_heave
from perception.timing import StageTimes

INTENSITY_REFERENCE_RANGE_M = 50.0  # the simulator's (and a calibrated sensor's) 1.0 = white diffuse here


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
    cluster_cell_m: float = Field(2.0, gt=0, description="grid cell grouping bright points into markers")
    max_bright_points: int = Field(2000, ge=3, description="more bright points than this: the threshold is wrong")
    plane_threshold_m: float = Field(0.15, gt=0, description="marker centroids within this of the plane agree")
    min_markers: int = Field(3, ge=3)
    min_spread_m: float = Field(2.0, gt=0, description="markers must span this much across their main axis")
    max_markers_ransac: int = Field(40, ge=3, description="markers used for the triplet search (largest first)")
    marker_height_m: float = Field(
        0.0, ge=0, description="the markers' height above the deck (installation); the deck plane lies this far below theirs"
    )


@dataclass
class ReflectorResult:
    D_m: float
    plane_sensor: np.ndarray | None
    marker_centroids: np.ndarray  # (M,3) markers on the plane
    bright_points: np.ndarray  # (B,3) all points above the threshold
    threshold: float
    status: str
    sigma_m: float = float("nan")


def intensity_threshold(intensity_comp: np.ndarray, cfg: ReflectorConfig) -> float:
    """Threshold on range-compensated intensity: fixed, or just above the brightest diffuse
    return (markers are ~1 % of a frame, so the 99th percentile is still diffuse)."""
    if cfg.intensity_threshold is not None:
        return cfg.intensity_threshold
    sample = intensity_comp[:: max(1, len(intensity_comp) // 2000)]  # a percentile needs no 10k points
    sample = sample[np.isfinite(sample)]
    k = int(0.99 * (len(sample) - 1))
    p99 = float(np.partition(sample, k)[k]) if len(sample) else 0.0
    return float(max(cfg.diffuse_max, cfg.tail_factor * p99))


def group_markers(points: np.ndarray, cell_m: float) -> tuple[np.ndarray, int]:
    """Group bright points into markers by a coarse grid: markers are ~1 m patches metres
    apart, so points sharing a cell belong to one marker. A marker cut by a cell boundary
    becomes two centroids, both still on the deck plane, which the plane search tolerates."""
    n = len(points)
    if n == 0:
        return np.zeros(0, dtype=int), 0
    cells = np.floor(points / cell_m).astype(np.int64)
    cells -= cells.min(axis=0)
    span = cells.max(axis=0) + 1
    key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    _, labels = np.unique(key, return_inverse=True)
    return labels, int(labels.max()) + 1


@lru_cache(maxsize=64)
def _triplets(m: int, at_most: int = 128) -> np.ndarray:
    """Triplets of m markers, spread evenly over all C(m,3) when there are more than
    `at_most`: with at least half the markers on the deck a triplet is all-inlier with
    probability >= 1/8, so 128 of them miss with probability ~1e-7."""
    tri = np.array(list(combinations(range(m), 3)), dtype=np.intp).reshape(-1, 3)
    if len(tri) > at_most:
        tri = tri[np.linspace(0, len(tri) - 1, at_most).astype(np.intp)]
    return tri


def plane_through_markers(centroids: np.ndarray, threshold_m: float) -> np.ndarray:
    """RANSAC over marker centroids, the triplets scored at once: the inlier mask of the best plane."""
    m = len(centroids)
    tri = _triplets(m)
    a = centroids[tri[:, 0]]
    n = np.cross(centroids[tri[:, 1]] - a, centroids[tri[:, 2]] - a)
    with np.errstate(invalid="ignore", divide="ignore"):
        n /= np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]  # a degenerate triplet gives NaN: no inliers
    d = -np.einsum("ij,ij->i", n, a)
    inl = np.abs(centroids @ n.T + d) < threshold_m  # (m, T)
    return inl[:, int(np.argmax(inl.sum(axis=0)))]


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
        r2 = np.einsum("ij,ij->i", points_sensor, points_sensor)
        comp = intensity * (r2 / INTENSITY_REFERENCE_RANGE_M**2) if cfg.range_compensate else intensity
        thr = intensity_threshold(comp, cfg)
        bright = points_sensor[(comp > thr) & (comp < np.inf)]  # NaN compares False; inf points are garbage
    if len(bright) < 3:
        return ReflectorResult(float("nan"), None, empty, bright, thr, f"no reflectors ({len(bright)} bright points)")
    if len(bright) > cfg.max_bright_points:
        return ReflectorResult(float("nan"), None, empty, bright[:0], thr,
                               f"{len(bright)} bright points: intensity threshold {thr:.3g} lets diffuse returns through")
    with times.stage("reflectors.markers"):
        labels, n_markers = group_markers(bright, cfg.cluster_cell_m)
        counts = np.bincount(labels, minlength=n_markers)
        centroids = np.stack([np.bincount(labels, weights=bright[:, k], minlength=n_markers) for k in range(3)], 1) / counts[:, None]
        if n_markers < cfg.min_markers:
            return ReflectorResult(float("nan"), None, centroids, bright, thr, f"too few markers ({n_markers} < {cfg.min_markers})")
        order = np.argsort(-counts)[: cfg.max_markers_ransac]
        on_plane = np.zeros(n_markers, dtype=bool)
        on_plane[order[plane_through_markers(centroids[order], cfg.plane_threshold_m)]] = True
        good = centroids[on_plane]
    if len(good) < cfg.min_markers:
        return ReflectorResult(float("nan"), None, good, bright, thr, f"too few markers on one plane ({len(good)} < {cfg.min_markers})")
    # Markers on one line (one deck edge only) do not fix the plane's roll about that line.
    c = good - good.mean(axis=0)
    spread = 2 * np.sqrt(np.linalg.eigvalsh(c.T @ c)[1] / len(c))
    if spread < cfg.min_spread_m:
        return ReflectorResult(float("nan"), None, good, bright, thr, f"markers collinear (spread {spread:.2f} m)")
    with times.stage("reflectors.plane"):
        plane, D, sigma = fit_plane_heave(bright[on_plane[labels]], wire_dir_sensor, p_tip_sensor,
                                          offset_m=cfg.marker_height_m)
    return ReflectorResult(D, plane, good, bright, thr, "ok" if np.isfinite(D) else "wire parallel to the plane", sigma)
