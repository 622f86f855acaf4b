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

import math
from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.perception.cloud import as_points
from boomtip.perception.geometry import fit_plane_heave, sym3_eigvals
from boomtip.perception.timing import StageTimes

INTENSITY_REFERENCE_RANGE_M = 50.0  # the simulator's (and a calibrated sensor's) 1.0 = white diffuse here
_CELL_OFFSET = 1 << 20  # marker grid cells are keyed from -2^20 to 2^20 per axis
_CELL_RADIX = 1 << 21
_ROLL1, _ROLL2 = np.array([1, 2, 0]), np.array([2, 0, 1])  # axes rolled by one and by two


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
    """Result of :func:`detect_reflectors` (sensor frame, metres)."""

    D_m: float  # distance from the tip down the wire to the deck, NaN without a measurement
    plane_sensor: np.ndarray | None  # the deck plane [a, b, c, d], unit normal towards the sensor
    marker_centroids: np.ndarray  # (M,3) markers on the plane
    bright_points: np.ndarray  # (B,3) all points above the threshold
    threshold: float
    status: str  # "ok" or why there is no measurement
    sigma_m: float = float("nan")  # 1-sigma of D from the fit


def intensity_threshold(intensity_comp: np.ndarray, cfg: ReflectorConfig) -> float:
    """Threshold on range-compensated intensity: fixed, or just above the brightest diffuse
    return (markers are ~1 % of a frame, so the 99th percentile is still diffuse)."""
    if cfg.intensity_threshold is not None:
        return cfg.intensity_threshold
    sample = intensity_comp[:: max(1, len(intensity_comp) // 2000)]  # a percentile needs no 10k points
    sample = sample[np.isfinite(sample)]  # a new array: partitioned in place below
    k = int(0.99 * (len(sample) - 1))
    if len(sample):
        sample.partition(k)  # the method, in place: np.partition's wrapper copies first
    p99 = float(sample[k]) if len(sample) else 0.0
    return float(max(cfg.diffuse_max, cfg.tail_factor * p99))


def group_markers(points: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Group bright points into markers by a coarse grid: markers are ~1 m patches metres
    apart, so points sharing a cell belong to one marker. A marker cut by a cell boundary
    becomes two centroids, both still on the deck plane, which the plane search tolerates.
    Returns each point's marker label (N,), the markers' centroids (M, 3) and point counts (M,).
    One sort of the cell keys gives all three (np.unique + bincounts cost twice as much)."""
    n = len(points)
    if n == 0:
        return np.zeros(0, dtype=np.intp), np.zeros((0, 3)), np.zeros(0, dtype=np.intp)
    cells = np.floor(points / cell_m).astype(np.int64)
    # One key per cell in a fixed mixed radix (cells within +-2^20 of the sensor, 2000 km at 2 m):
    # the same lexicographic order of (x, y, z) cells as a radix from the cloud's own span, without
    # the min and max passes that would find that span.
    cells += _CELL_OFFSET
    key = (cells[:, 0] * _CELL_RADIX + cells[:, 1]) * _CELL_RADIX + cells[:, 2]
    order = key.argsort(kind="stable")
    key_sorted = key[order]
    first = np.empty(n, dtype=bool)
    first[0] = True
    np.not_equal(key_sorted[1:], key_sorted[:-1], out=first[1:])
    starts = first.nonzero()[0]  # methods, not np.flatnonzero / np.cumsum: the same, without their wrappers
    labels = np.empty(n, dtype=np.intp)
    labels[order] = first.cumsum() - 1
    counts = np.empty_like(starts)
    counts[:-1] = starts[1:] - starts[:-1]
    counts[-1] = n - starts[-1]
    centroids = np.add.reduceat(points[order], starts, axis=0) / counts[:, None]
    return labels, centroids, counts


@lru_cache(maxsize=128)
def triplets(m: int, at_most: int = 128) -> np.ndarray:
    """Triplets of m markers: all C(m,3) up to `at_most` of them (m <= 10), else a fixed
    design of `at_most` triplets with distinct members, drawn once per m (enumerating
    C(40,3) = 9880 to pick from costs milliseconds, per-frame draws ~60 us). It is a
    sampling design, not per-frame randomness: with at least half the markers on the deck a
    triplet is all-inlier with probability >= 1/8, so 128 of them miss with probability ~1e-7."""
    if m * (m - 1) * (m - 2) // 6 <= at_most:
        return np.array(list(combinations(range(m), 3)), dtype=np.intp).reshape(-1, 3)
    tri = np.random.default_rng(m).integers(0, m, size=(4 * at_most, 3))
    distinct = (tri[:, 0] != tri[:, 1]) & (tri[:, 0] != tri[:, 2]) & (tri[:, 1] != tri[:, 2])
    return tri[distinct][:at_most]  # P(distinct) >= 0.72 for m > 10: 512 draws leave >= 128


def plane_through_markers(centroids: np.ndarray, threshold_m: float) -> np.ndarray:
    """RANSAC over marker centroids, the triplets scored at once: the inlier mask of the best plane."""
    tri = triplets(len(centroids))
    corners = centroids[tri]  # (T, 3 corners, 3 axes): one gather
    a = corners[:, 0]
    edges = corners[:, 1:] - a[:, None]  # (T, 2, 3): e1, e2
    # The cross product from the edges' axes rolled by one and by two (two gathers), the same
    # products and differences as written out per axis: np.cross costs ~10x more on a few hundred rows.
    r1, r2 = edges[:, :, _ROLL1], edges[:, :, _ROLL2]
    n = r1[:, 0] * r2[:, 1]
    n -= r2[:, 0] * r1[:, 1]
    sq = n * n
    norm = sq[:, 0] + sq[:, 1]
    norm += sq[:, 2]
    np.sqrt(norm, out=norm)
    # a degenerate triplet (zero normal) gets NaN: no inliers; NaN instead of a 0/0 so no
    # floating-point warning needs silencing
    norm[norm == 0.0] = np.nan
    n /= norm[:, None]
    na = n * a
    d = na[:, 0] + na[:, 1]
    d += na[:, 2]
    inl = centroids @ n.T  # (m, T)
    inl -= d  # n.x + d with d = -(n.a)
    np.abs(inl, out=inl)
    inl = inl < threshold_m
    return inl[:, int(inl.sum(axis=0).argmax())]

def detect_reflectors(
    points_sensor: np.ndarray,
    intensity: np.ndarray,
    wire_dir_sensor: np.ndarray,
    p_tip_sensor: np.ndarray,
    cfg: ReflectorConfig | None = None,
    rng: np.random.Generator | None = None,
    times: StageTimes | None = None,
) -> ReflectorResult:
    """The deck plane through the retro-reflective markers in one frame, and D along the wire.

    points_sensor: (N, 3) sensor frame, metres (or an Open3D point cloud); intensity: (N,) per
    point, 1.0 = white diffuse at 50 m (the range compensation scales it). wire_dir_sensor: (3,)
    unit wire direction (down) and p_tip_sensor: (3,) the boom tip, both in the sensor frame.
    rng is not used (the marker search is deterministic); it keeps the stages' signature.
    Returns a :class:`ReflectorResult`; without a measurement D_m is NaN and status says why.
    """
    points_sensor = as_points(points_sensor)
    intensity = np.asarray(intensity).reshape(-1)  # dtype kept: the threshold compares in it
    if len(intensity) != len(points_sensor):
        raise ValueError(f"intensity has {len(intensity)} values, points have {len(points_sensor)}")
    wire_dir_sensor = np.asarray(wire_dir_sensor, dtype=np.float64)
    p_tip_sensor = np.asarray(p_tip_sensor, dtype=np.float64)
    cfg = cfg or ReflectorConfig()
    times = times if times is not None else StageTimes()
    empty = np.zeros((0, 3))
    with times.stage("reflectors.threshold"):
        # Squared range by columns into two buffers (einsum costs ~3x more here, and each further
        # full-size temporary costs page faults on a busy machine); the range compensation is only
        # computed in full for the percentile's sample, the threshold test scales the other side.
        p = points_sensor
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        r2 = np.multiply(x, x)
        tmp = np.multiply(y, y)
        r2 += tmp
        r2 += np.multiply(z, z, out=tmp)
        if cfg.range_compensate:
            step = max(1, len(r2) // 2000)
            thr = intensity_threshold(intensity[::step] * (r2[::step] / INTENSITY_REFERENCE_RANGE_M**2), cfg)
            r2 *= intensity  # intensity x r^2, in place
            # nonzero() and count_nonzero, not np.flatnonzero and .all(): the same, without their wrappers
            idx = (r2 > thr * INTENSITY_REFERENCE_RANGE_M**2).nonzero()[0]  # NaN compares False
            product_finite = np.count_nonzero(np.isfinite(r2[idx])) == len(idx)
        else:
            thr = intensity_threshold(intensity, cfg)
            idx = (intensity > thr).nonzero()[0]
            product_finite = False
        bright = p[idx]
        if not product_finite:  # a finite intensity x r^2 means a finite point and intensity
            bright = bright[np.isfinite(bright).all(axis=1) & np.isfinite(intensity[idx])]  # inf points are garbage
    if len(bright) < 3:
        return ReflectorResult(float("nan"), None, empty, bright, thr, f"no reflectors ({len(bright)} bright points)")
    if len(bright) > cfg.max_bright_points:
        return ReflectorResult(float("nan"), None, empty, bright[:0], thr,
                               f"{len(bright)} bright points: intensity threshold {thr:.3g} lets diffuse returns through")
    with times.stage("reflectors.markers"):
        labels, centroids, counts = group_markers(bright, cfg.cluster_cell_m)
        n_markers = len(counts)
        if n_markers < cfg.min_markers:
            return ReflectorResult(float("nan"), None, centroids, bright, thr, f"too few markers ({n_markers} < {cfg.min_markers})")
        order = (-counts).argsort()[: cfg.max_markers_ransac]
        on_plane = np.zeros(n_markers, dtype=bool)
        on_plane[order[plane_through_markers(centroids[order], cfg.plane_threshold_m)]] = True
        good = centroids[on_plane]
        if len(good) < cfg.min_markers:
            return ReflectorResult(float("nan"), None, good, bright, thr, f"too few markers on one plane ({len(good)} < {cfg.min_markers})")
        # Markers on one line (one deck edge only) do not fix the plane's roll about that line.
        c = good - np.add.reduce(good, axis=0) / len(good)  # ndarray.mean's arithmetic, without its wrapper
        spread = 2 * math.sqrt(max(sym3_eigvals(c.T @ c)[1], 0.0) / len(c))
    if spread < cfg.min_spread_m:
        return ReflectorResult(float("nan"), None, good, bright, thr, f"markers collinear (spread {spread:.2f} m)")
    with times.stage("reflectors.plane"):
        plane, D, sigma = fit_plane_heave(bright[on_plane[labels]], wire_dir_sensor, p_tip_sensor,
                                          offset_m=cfg.marker_height_m)
    return ReflectorResult(D, plane, good, bright, thr, "ok" if np.isfinite(D) else "wire parallel to the plane", sigma)
