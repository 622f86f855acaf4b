"""Steps 2-3 of the hook stage (perception.hook): the background (large near-horizontal planes,
the rope) is masked out, the rest is clustered by single linkage. Levelled frame, origin at the
boom tip, z up, metres."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from boomtip.perception.hook_types import HookConfig
from boomtip.perception.plane import ransac_plane

__all__ = ["cluster_extent", "large_plane_mask", "rope_line_mask", "cluster_labels"]


def _extent_xy(xy: np.ndarray, lo: float = 1.0, hi: float = 99.0) -> float:
    """Length of a 2-D point set along its principal axis (percentile range, robust to strays)."""
    if len(xy) < 2:
        return 0.0
    c = xy - xy.mean(axis=0)
    _, vecs = np.linalg.eigh(c.T @ c)
    s = c @ vecs[:, -1]
    a, b = np.percentile(s, [lo, hi])
    return float(b - a)


def cluster_extent(p: np.ndarray) -> float:
    """Diagonal of the cluster's box in its horizontal principal axes and z (metres)."""
    if len(p) < 2:
        return 0.0
    c = p[:, :2] - p[:, :2].mean(axis=0)
    _, vecs = np.linalg.eigh(c.T @ c)
    s = c @ vecs
    ext = np.ptp(s, axis=0)
    return float(math.sqrt(ext[0] ** 2 + ext[1] ** 2 + np.ptp(p[:, 2]) ** 2))


def large_plane_mask(p: np.ndarray, cfg: HookConfig, cell_m: float, rng: np.random.Generator) -> np.ndarray:
    """Mask (over p) of deck / big cargo-top points: band + below of large horizontal planes.

    Sequential RANSAC constrained to near-horizontal normals. A plane is 'large' when one
    8-connected patch of its inliers on a horizontal grid (cell ~1.6 beam spacings, so a sparse far
    deck stays connected) is wider than the block can be; only such patches count, so block points
    that happen to lie at a cargo top's height form their own small patch and stay. Removal is
    restricted to the grid cells of the large patches: the block hangs in the plane's shadow, where
    the plane has no points, so neither band nor 'below' can reach it.
    """
    removed = np.zeros(len(p), dtype=bool)
    up = np.array([0.0, 0.0, 1.0])
    for _ in range(cfg.max_planes):
        rem = np.flatnonzero(~removed)
        if len(rem) < cfg.plane_min_inliers:
            break
        q = p[rem]
        fit = ransac_plane(q, cfg.plane_ransac, rng, axis=up, max_axis_angle_deg=cfg.plane_max_tilt_deg)
        if fit is None or fit.n_inliers < cfg.plane_min_inliers:
            break
        inl = q[fit.inlier_mask]
        # Patches of the inliers on a grid over the remaining points' footprint.
        origin = q[:, :2].min(axis=0)
        cells = np.floor((q[:, :2] - origin) / cell_m).astype(np.int64)
        shape = cells.max(axis=0) + 1
        grid = np.zeros(shape, dtype=bool)
        ci = cells[fit.inlier_mask]
        grid[ci[:, 0], ci[:, 1]] = True
        lab, n_lab = ndimage.label(grid, structure=np.ones((3, 3), dtype=int))
        inl_lab = lab[ci[:, 0], ci[:, 1]]
        large = np.zeros(n_lab + 1, dtype=bool)
        # A handful of patches per plane: loop over patches, not points.
        for k in np.unique(inl_lab):
            sel = inl_lab == k
            large[k] = sel.sum() >= cfg.plane_min_inliers and _extent_xy(inl[sel, :2]) > cfg.plane_min_extent_m
        if not large.any():
            break  # the largest horizontal plane left is no bigger than the block: keep everything
        # Signed height above the plane (ransac_plane orients the normal towards the tip, i.e. up).
        s = q @ fit.plane[:3] + fit.plane[3]
        in_large = large[lab[cells[:, 0], cells[:, 1]]]
        removed[rem[(s < cfg.plane_band_m) & in_large]] = True
    return removed


def rope_line_mask(p: np.ndarray, u: np.ndarray, cfg: HookConfig) -> np.ndarray:
    """Mask (over p) of rope points: within rope_radius of the line from the tip along u, and
    more than rope_top_margin above the highest non-rope point near that line (the block top)."""
    t = p @ u  # distance along the line from the tip
    perp = np.linalg.norm(p - t[:, None] * u[None], axis=1)
    cand = perp < cfg.rope_radius_m
    near = ~cand & (perp < cfg.rope_near_radius_m)
    if np.count_nonzero(near) >= 2:
        t_top = float(np.partition(t[near], 1)[1])  # 2nd highest: one noisy point does not decide
    else:
        t_top = np.inf  # no block beside the line: everything on the line is rope
    return cand & (t < t_top - cfg.rope_top_margin_m)


def cluster_labels(p: np.ndarray, eps: float, method: str, auto_points: int = 500) -> np.ndarray:
    """Cluster labels (single linkage at eps), -1 for none."""
    if len(p) == 0:
        return np.zeros(0, dtype=np.int64)
    if method == "dbscan" or (method == "auto" and len(p) < auto_points):
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
        # min_points=1: DBSCAN degenerates to single linkage, the same partition as the kdtree route;
        # Open3D links points closer than eps, scipy's pairs within it: the next float up joins them
        return np.asarray(pc.cluster_dbscan(eps=float(np.nextafter(eps, np.inf)), min_points=1, print_progress=False),
                          dtype=np.int64)
    pairs = cKDTree(p).query_pairs(eps, output_type="ndarray")
    n = len(p)
    g = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    return lab.astype(np.int64)

