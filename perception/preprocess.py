"""Point-cloud preprocessing for the boom-tip LiDAR / radar (document 000 section 4.1.1, Fig. 4.3).

All points are numpy float64 (N, 3) in the SENSOR frame, metres; ranges are measured from the sensor
origin. Per-point attributes (intensity, label, time, range rate, ...) are numpy arrays whose first
dimension is N; every step keeps them aligned with the points.

Pipeline of :func:`preprocess` (each step optional except the first):
  1. drop non-finite points and zero-range points (sensor "no return"), FIRST: NaN poisons voxel
     keys and neighbour statistics (LIBRARIES.md: Open3D's voxel_down_sample collapses 100k points
     with 0.1 % NaN to one NaN point);
  2. range crop [min_range_m, max_range_m];
  3. axis-aligned box crop in the sensor frame;
  4. random downsampling to a fraction (document 000's pcdownsample 'random');
  5. voxel downsampling: one point per occupied voxel;
  6. statistical outlier removal (document 000's pcdenoise).

Implementation choices (see the docstrings of ``voxel_downsample`` and ``statistical_outlier_mask``):
  * voxel: a numpy voxel hash (int64 voxel keys packed with the point index, one ``np.sort``,
    ``np.bincount`` centroids). It is several times faster than Open3D and keeps attributes EXACTLY:
    attributes come from a real point of the
    voxel (the first one in input order), so a label stays a label. Open3D's tensor
    ``voxel_down_sample`` averages every attribute (a mean label is meaningless) and the legacy
    ``voxel_down_sample_and_trace`` returns Python lists of indices that are slow to convert.
  * statistical outliers: Open3D's ``remove_statistical_outlier`` (faster than a scipy cKDTree
    query with the same statistic on the 128 x 1024 LiDAR's frames), its kept indices returned
    as a mask so attributes stay aligned.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from boomtip.perception.cloud import as_points
from boomtip.perception.multi_plane import MultiPlaneConfig, MultiPlaneResult, select_deck_plane
from boomtip.perception.plane import PlaneFit, RansacConfig, orient_plane_towards

__all__ = [
    "PreprocessConfig",
    "preprocess",
    "voxel_downsample",
    "statistical_outlier_mask",
    "open3d_baseline_preprocess",
    "open3d_baseline_multi_plane",
]


class PreprocessConfig(BaseModel):
    """Preprocessing parameters (sensor frame, metres). ``None`` switches a step off."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    min_range_m: float = Field(0.5, ge=0, description="drop points closer than this to the sensor origin")
    max_range_m: float = Field(300.0, gt=0, description="drop points farther than this")
    crop_box_min: tuple[float, float, float] | None = Field(None, description="box crop lower corner, sensor frame")
    crop_box_max: tuple[float, float, float] | None = Field(None, description="box crop upper corner, sensor frame")
    voxel_size_m: float | None = Field(None, gt=0, description="voxel edge; None = off")
    voxel_reduce: Literal["mean", "first"] = Field(
        "mean", description="point per voxel: centroid ('mean') or the first point in input order"
    )
    random_fraction: float | None = Field(None, gt=0, le=1, description="keep this fraction at random; None = off")
    outlier_nb_neighbors: int | None = Field(None, ge=1, description="k of the statistical outlier filter; None = off")
    outlier_std_ratio: float = Field(2.0, gt=0, description="keep mean k-NN distance <= mean + ratio * std")
    seed: int | None = Field(0, description="seed of the random downsampling when no rng is passed")

    @model_validator(mode="after")
    def _check(self) -> "PreprocessConfig":
        if self.max_range_m <= self.min_range_m:
            raise ValueError("max_range_m must exceed min_range_m")
        if (self.crop_box_min is None) != (self.crop_box_max is None):
            raise ValueError("crop_box_min and crop_box_max must be given together")
        return self


# --------------------------------------------------------------------------------------
# Building blocks
# --------------------------------------------------------------------------------------
def voxel_downsample(
    points: np.ndarray, voxel_size_m: float, reduce: Literal["mean", "first"] = "mean"
) -> tuple[np.ndarray, np.ndarray]:
    """One point per occupied voxel (sensor frame, m). Points must be finite.

    Returns ``(points_out, rep_index)``: ``rep_index[j]`` is the index (into ``points``) of the FIRST
    input point of voxel j; use it to carry attributes. ``points_out[j]`` is the voxel centroid
    (``reduce="mean"``) or that first point. Output order follows the first occurrence in the input.
    The grid is anchored at the componentwise minimum of the points.

    Method: integer voxel keys packed with the point index into one int64 (``key << b | i``) and
    sorted with ``np.sort`` (SIMD sort, no argsort); group starts give the first point of every
    voxel, ``np.bincount`` the centroids. When the packed value could overflow, ``np.argsort`` of
    the keys is used instead (same result).

    Faster than ``np.unique(return_index, return_inverse)`` + bincount, and several times faster
    than Open3D: the legacy ``voxel_down_sample`` carries no attributes, the tensor one AVERAGES
    every attribute (a mean label is meaningless) and is slower still, and the legacy
    ``voxel_down_sample_and_trace`` returns Python lists of indices. Hence numpy.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(pts)
    if n == 0:
        return pts.copy(), np.zeros(0, dtype=np.int64)
    cols = np.ascontiguousarray(pts.T)  # (3, N): per-axis reductions on contiguous rows are fast
    lo = cols.min(axis=1)
    f = cols - lo[:, None]
    f *= 1.0 / voxel_size_m
    np.floor(f, out=f)
    q = f.astype(np.int64)
    dims = q.max(axis=1) + 1
    n_keys = float(dims[0]) * float(dims[1]) * float(dims[2])
    if n_keys >= 2.0**62:
        raise ValueError("voxel grid too fine for the extent of the cloud (more than 2^62 voxels)")
    key = (q[0] * dims[1] + q[1]) * dims[2] + q[2]
    bits = max(int(n - 1).bit_length(), 1)
    if n_keys * 2.0**bits < 2.0**62:
        # (key << bits) | index: one SIMD sort orders by key, then by index (shifts, no division)
        packed = np.sort((key << bits) | np.arange(n, dtype=np.int64))
        order = packed & ((1 << bits) - 1)
        key_sorted = packed >> bits
    else:
        order = np.argsort(key, kind="stable")
        key_sorted = key[order]
    new_group = np.empty(n, dtype=bool)
    new_group[0] = True
    np.not_equal(key_sorted[1:], key_sorted[:-1], out=new_group[1:])
    # first point of each voxel: smallest index in the group = first element after the sort
    first_sorted_by_key = order[new_group]
    # renumber voxels by first occurrence in the input (scan order preserved), O(N), no argsort
    is_first = np.zeros(n, dtype=bool)
    is_first[first_sorted_by_key] = True
    first = np.flatnonzero(is_first)  # increasing input index = first-occurrence order
    if reduce == "first":
        return pts[first], first
    rank_of_point = np.cumsum(is_first) - 1  # for a first point: its voxel's output position
    group_rank = rank_of_point[first_sorted_by_key]  # output position of each key-sorted group
    vid = np.empty(n, dtype=np.int64)
    vid[order] = group_rank[np.cumsum(new_group) - 1]
    m = len(first)
    counts = np.bincount(vid, minlength=m).astype(np.float64)
    cen = np.empty((m, 3))
    for j in range(3):  # three axes, not a loop over points
        cen[:, j] = np.bincount(vid, weights=cols[j], minlength=m) / counts
    return cen, first


def statistical_outlier_mask(points: np.ndarray, nb_neighbors: int, std_ratio: float) -> np.ndarray:
    """Keep-mask of a statistical outlier filter (sensor frame, m): Open3D's
    ``remove_statistical_outlier``, its kept indices as a mask so attributes stay aligned.

    For each point, the mean distance to its ``nb_neighbors`` nearest neighbours (the point itself
    included); keep points whose mean is below ``mean + std_ratio * std`` of those means (sample
    std, ddof=1). Points whose mean is exactly 0 (``nb_neighbors`` identical returns) are dropped
    and left out of the statistic's sums, though not out of its counts (Open3D's arithmetic; a
    cloud without such stacks is judged exactly as above). Fewer than 2 points: all kept.

    Open3D's own call, because it is the faster one here: on a spinning LiDAR's frames it beats
    the scipy cKDTree query with the same statistic (``workers=-1``), which keeps the same points;
    Open3D's tensor k-NN search is no faster than cKDTree.
    """
    import open3d as o3d  # only this filter needs it here

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(pts)
    if n < 2:
        return np.ones(n, dtype=bool)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    _, kept = pcd.remove_statistical_outlier(int(nb_neighbors), float(std_ratio))
    mask = np.zeros(n, dtype=bool)
    mask[np.asarray(kept, dtype=np.intp)] = True
    return mask


# --------------------------------------------------------------------------------------
# Pipeline
# --------------------------------------------------------------------------------------
def _compose(idx: np.ndarray | None, sel: np.ndarray) -> np.ndarray:
    """Indices into the original arrays of `sel` (indices into the current ones)."""
    return sel if idx is None else idx[sel]


def preprocess(
    points: np.ndarray,
    attributes: dict[str, np.ndarray] | None = None,
    cfg: PreprocessConfig | None = None,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, int]]:
    """Clean and thin a sensor-frame point cloud; attributes stay aligned with the points.

    ``points`` (N, 3) float or an Open3D point cloud, sensor frame, metres; ``attributes`` maps names
    to arrays of first dimension N. ``rng`` drives the random downsampling (default: ``default_rng(cfg.seed)``).
    Returns ``(points_out, attributes_out, stats)`` where ``stats`` holds the point count after each
    step: input, finite, range, box, random, voxel, outlier (a skipped step repeats the previous count).
    Empty (or all-invalid) input gives empty output, never an exception. ``points_out`` is a new
    array; when only the finite/range steps ran it is the transpose of a (3, M) C-contiguous one,
    so ``points_out.T`` gives the column layout without a copy.
    """
    pts = as_points(points)
    cfg = cfg or PreprocessConfig()
    attributes = attributes or {}
    n0 = len(pts)
    for name, a in attributes.items():
        if len(a) != n0:
            raise ValueError(f"attribute {name!r} has {len(a)} rows, points have {n0}")
    stats: dict[str, int] = {"input": n0}
    # ``idx`` (set below) indexes the ORIGINAL arrays and is carried through every step, so the
    # attributes are gathered once at the end

    # 1. non-finite and zero-range points, before anything else. The arithmetic runs on a (3, N)
    # copy, one contiguous row per axis, into two buffers: products over (N, 3) rows stride
    # through memory, and each further full-size temporary costs page faults on a busy machine.
    # The kept points are returned as the transpose of that copy (an (N, 3) view).
    cols = np.ascontiguousarray(pts.T)
    r2, tmp = np.empty(n0), np.empty(n0)
    with np.errstate(over="ignore", invalid="ignore"):
        # non-finite iff a coordinate is (or it overflows: beyond range); (x x + y y) + z z
        np.multiply(cols[0], cols[0], out=r2)
        r2 += np.multiply(cols[1], cols[1], out=tmp)
        r2 += np.multiply(cols[2], cols[2], out=tmp)
    # 2. range crop (same pass). With a minimum range, r2 >= min^2 > 0 already refuses NaN and
    # zero range, and r2 <= max^2 refuses inf: two comparisons instead of four, and the finite
    # count for the stats is only taken when a point was dropped.
    lo2, hi2 = cfg.min_range_m**2, cfg.max_range_m**2
    if lo2 > 0.0:
        keep = r2 >= lo2
        keep &= r2 <= hi2
        n_keep = int(np.count_nonzero(keep))
        stats["finite"] = n0 if n_keep == n0 else int(np.count_nonzero(np.isfinite(r2) & (r2 > 0.0)))
    else:
        keep = np.isfinite(r2)
        keep &= r2 > 0.0
        stats["finite"] = int(np.count_nonzero(keep))
        keep &= r2 >= lo2
        keep &= r2 <= hi2
        n_keep = int(np.count_nonzero(keep))
    idx = None  # None: every input point, in order
    if n_keep < n0:
        idx = keep.nonzero()[0]
        cols = cols.take(idx, axis=1)  # take is 3x faster than boolean indexing
    pts = cols.T
    stats["range"] = len(pts)

    # 3. box crop (sensor frame)
    if cfg.crop_box_min is not None and len(pts):
        lo, hi = np.asarray(cfg.crop_box_min), np.asarray(cfg.crop_box_max)
        keep = np.flatnonzero(np.all((pts >= lo) & (pts <= hi), axis=1))
        pts, idx = pts[keep], _compose(idx, keep)
    stats["box"] = len(pts)

    # 4. random downsampling (exact count, input order preserved)
    if cfg.random_fraction is not None and cfg.random_fraction < 1.0 and len(pts):
        rng = rng if rng is not None else np.random.default_rng(cfg.seed)
        m = int(round(cfg.random_fraction * len(pts)))
        sel = np.sort(rng.choice(len(pts), size=m, replace=False))
        pts, idx = pts[sel], _compose(idx, sel)
    stats["random"] = len(pts)

    # 5. voxel downsampling; attributes from the first point of each voxel
    if cfg.voxel_size_m is not None and len(pts):
        pts, rep = voxel_downsample(pts, cfg.voxel_size_m, cfg.voxel_reduce)
        idx = _compose(idx, rep)
    stats["voxel"] = len(pts)

    # 6. statistical outlier removal
    if cfg.outlier_nb_neighbors is not None and len(pts):
        keep = np.flatnonzero(statistical_outlier_mask(pts, cfg.outlier_nb_neighbors, cfg.outlier_std_ratio))
        pts, idx = pts[keep], _compose(idx, keep)
    stats["outlier"] = len(pts)

    attrs_out = {name: np.asarray(a)[idx] if idx is not None else np.array(a) for name, a in attributes.items()}
    return pts, attrs_out, stats


# --------------------------------------------------------------------------------------
# Open3D baselines (benchmarks only)
# --------------------------------------------------------------------------------------
def open3d_baseline_preprocess(
    points: np.ndarray, voxel: float | None, nb: int | None, std: float = 2.0
) -> np.ndarray:
    """Benchmark baseline with Open3D's own calls (legacy PointCloud): ``remove_non_finite_points``,
    ``voxel_down_sample(voxel)`` (if voxel), ``remove_statistical_outlier(nb, std)`` (if nb).
    Returns the (M, 3) sensor-frame points; attributes are not carried."""
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64).reshape(-1, 3)))
    pcd = pcd.remove_non_finite_points()
    if voxel is not None and len(pcd.points):
        pcd = pcd.voxel_down_sample(float(voxel))
    if nb is not None and len(pcd.points) > nb:
        pcd, _ = pcd.remove_statistical_outlier(int(nb), float(std))
    return np.asarray(pcd.points).copy()


def open3d_baseline_multi_plane(
    points: np.ndarray,
    up_sensor: np.ndarray,
    n_planes: int = 6,
    threshold: float = 0.05,
    *,
    num_iterations: int = 1000,
    cfg: MultiPlaneConfig | None = None,
    seed: int | None = 0,
) -> MultiPlaneResult | None:
    """Benchmark baseline: document 000's Algorithm 3 with Open3D's ``segment_plane`` called
    ``n_planes`` times (removing inliers each time), then the SAME selection metric as
    :func:`perception.multi_plane.multi_plane_deck` (:func:`perception.multi_plane.select_deck_plane`).
    Sensor frame, metres. ``seed`` seeds Open3D's global RNG (None leaves it alone)."""
    import open3d as o3d

    cfg = cfg or MultiPlaneConfig(max_planes=n_planes, ransac=RansacConfig(distance_threshold_m=threshold))
    if seed is not None:
        o3d.utility.random.seed(int(seed))
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n_all = len(pts)
    remaining = np.arange(n_all)
    candidates: list[PlaneFit] = []
    for _ in range(n_planes):
        if len(remaining) < max(cfg.min_inliers, 3):
            break
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[remaining]))
        model, inl = pcd.segment_plane(float(threshold), 3, int(num_iterations))
        inl = np.asarray(inl, dtype=np.int64)
        if len(inl) < 3:
            break
        plane = np.asarray(model, dtype=np.float64)
        plane = orient_plane_towards(plane / np.linalg.norm(plane[:3]))
        mask = np.zeros(n_all, dtype=bool)
        mask[remaining[inl]] = True
        r = pts[mask] @ plane[:3] + plane[3]
        candidates.append(
            PlaneFit(
                plane=plane,
                inlier_mask=mask,
                inlier_ratio=len(inl) / len(remaining),
                rms_m=float(np.sqrt(np.mean(r * r))),
                iterations=int(num_iterations),
            )
        )
        keep = np.ones(len(remaining), dtype=bool)
        keep[inl] = False
        remaining = remaining[keep]
    return select_deck_plane(pts, candidates, up_sensor, cfg)
