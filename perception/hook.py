"""Hook (lower block) segmentation and reference point from a boom-tip LiDAR frame (document 002).

Frames and units
----------------
Input points are (N, 3) float, metres, in a GRAVITY-LEVELLED frame with its origin at the boom
tip (the rope's suspension point), z up: the caller rotates the sensor points with the MRU
attitude and the mount and adds the sensor's offset from the tip. The prior ``p_prior`` and the
output ``position_m`` are in the same frame. The block model (``data.hook_block``) lives in the
BLOCK frame: origin = the reference point (rope attachment, top centre), z up along the rope,
x along the block's long axis, y along the sheave axle.

Chain (``detect_hook``), every step vectorised over points
------------------------------------------------------------
1. ``hook.gate``: points within ``prior_radius_m`` of the prior and below the tip.
2. ``hook.planes``: large near-horizontal planes (deck, big cargo tops) and the rope are removed.
   A plane only counts when one 2-D connected patch of its inliers is wider than the block can be
   (``plane_min_extent_m``), so the block's own flat top never qualifies; points in its band and
   below it are removed only in grid cells the patch covers, so the block, which hangs in the
   plane's shadow (no plane points under it), is never eaten.
   Rope: points near the line tip -> prior, clearly above the block's top.
3. ``hook.cluster``: single-linkage clustering (radius = a few beam spacings at the prior's
   range), then the cluster with a block-sized extent nearest to the prior.
4. ``hook.fit``: the known block model is fitted and its origin is the reference point. NOT the
   centroid of the visible points: from above one sees the sheave crowns and the body top,
   0.05-0.8 m below the rope attachment, and under occlusion the centroid slides sideways too.
   a. 4-DOF point-to-point ICP (yaw about the rope + translation; the block hangs along the line
      from the tip to its reference point) against the model's visible surface, from the
      cluster's highest points and its principal axis (more starts if the fit is poor);
   b. re-association: the block's points are the gated points within ``mask_distance_m`` of the
      posed full mesh; one more ICP pass on them;
   c. ray consistency (the rays, not just the points: which beams hit the block, which passed it
      to the deck): pick between the fit and its copies shifted by one sheave pitch (a partly
      hidden block fits equally well one pitch off), and, for a sparse block (far away), refine
      the pose on grids and return the posterior mean.

Accuracy and speed (simulated OS1-128, 1024 columns, 1.5 cm noise growing for weak returns, sensor
0.85 m from the rope; 2 shared cores): see the report of tests/test_hook_segmentation.py. About
10 ms per frame at 20 m (ICP only), 15-25 ms for a sparse far block (ray refinement).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import open3d as o3d
from pydantic import BaseModel, ConfigDict, Field
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from boomtip.data.block_model import (
    AMBIGUOUS_SHIFTS_M,
    BODY_TOP_Z_M,
    BODY_XY_M,
    SHEAVE_CROWN_Z_M,
    lower_block_mesh,
    visible_model_points,
)
from boomtip.data.meshes import Label
from boomtip.perception.plane import RansacConfig, ransac_plane
from boomtip.perception.timing import StageTimes

__all__ = [
    "HookConfig",
    "HookDetection",
    "detect_hook",
    "segmentation_scores",
    "sparse_block_fix",
    "block_footprint",
    "block_model",
    "rotation_hanging",
]


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
        "(min_points=1, the same partition); auto: dbscan below cluster_auto_points points, else kdtree. Measured "
        "(2 shared cores): 23-170 points dbscan 0.03-0.2 ms vs kdtree 0.4-0.6 ms; 1k/5k/20k points dbscan "
        "3.2/17/54 ms vs kdtree 2.6/12/36 ms",
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
        "good to ~2-3 cm and the refinement would cost ~20 ms"
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
        "reached 35 cm in simulation)"
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


# --------------------------------------------------------------------------------------
# Model
# --------------------------------------------------------------------------------------
class BlockModel:
    """The visible model points of the known block (block frame) with two nearest-point indices.

    ``nearest`` is an exact KD-tree query; ``nearest_grid`` looks the nearest model point up in a
    precomputed voxel grid (cell ``grid_cell_m``, out to ``margin_m`` around the model): O(1) per
    point, about 20x faster than the tree for a few hundred points, which is what makes tens of
    ICP iterations affordable per frame. The grid answer is the model point nearest to the cell
    centre: at most one cell diagonal worse than the true nearest (used inside the ICP; residuals
    and inlier tests use the exact tree).
    """

    def __init__(self, height_m: float = 4.0, n: int = 6000, grid_cell_m: float = 0.03, margin_m: float = 0.55):
        self.points = visible_model_points(lower_block_mesh(height_m), n)
        self.tree = cKDTree(self.points)
        self.radius_m = float(np.linalg.norm(self.points, axis=1).max())  # reach from the reference point
        mesh = lower_block_mesh(height_m)
        self.scene = o3d.t.geometry.RaycastingScene()  # the full mesh, for ray consistency
        self.scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                                 o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
        self.cell = grid_cell_m
        self.lo = self.points.min(axis=0) - margin_m
        self.shape = np.ceil((self.points.max(axis=0) + margin_m - self.lo) / grid_cell_m).astype(np.int64) + 1
        axes = [self.lo[i] + (np.arange(self.shape[i]) + 0.5) * grid_cell_m for i in range(3)]
        centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        d, idx = self.tree.query(centres, distance_upper_bound=margin_m + grid_cell_m, workers=-1)
        self.grid = np.where(np.isfinite(d), idx, -1).astype(np.int32).reshape(tuple(self.shape))

    def mesh_distance(self, q: np.ndarray) -> np.ndarray:
        """Distance of each row of q (block frame) to the FULL mesh (any face, seen or not)."""
        return self.scene.compute_distance(o3d.core.Tensor(q.astype(np.float32))).numpy().astype(np.float64)

    def nearest(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact: (distance, index) of the nearest model point for each row of q (block frame)."""
        return self.tree.query(q)

    def nearest_grid(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Grid lookup: (distance, index); distance inf and index -1 outside the grid's reach."""
        c = np.floor((q - self.lo) / self.cell).astype(np.int64)
        inside = np.all((c >= 0) & (c < self.shape), axis=1)
        idx = np.full(len(q), -1, dtype=np.int64)
        ci = c[inside]
        idx[inside] = self.grid[ci[:, 0], ci[:, 1], ci[:, 2]]
        d = np.full(len(q), np.inf)
        ok = idx >= 0
        diff = q[ok] - self.points[idx[ok]]
        d[ok] = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        return d, idx


@functools.lru_cache(maxsize=8)
def block_model(height_m: float = 4.0, n: int = 6000) -> BlockModel:
    """The known block's visible-surface model and indices (cached: ~0.5 s to build once)."""
    return BlockModel(height_m, n)


@dataclass(frozen=True)
class BlockFootprint:
    """Where beams from above land on the block (block frame, metres): what one LiDAR point on a
    far block tells about the reference point when the point's place on the block is unknown."""

    mean_m: np.ndarray  # (3,) mean hit relative to the reference point (x, y ~ 0 by symmetry)
    var_long_m2: float  # hit variance along the block's long axis (the worse one: yaw unknown)
    var_vertical_m2: float  # hit height variance (sheave crowns to body top)
    area_m2: float  # footprint area seen from above
    reach_m: float  # farthest hit from the rope axis


@functools.lru_cache(maxsize=8)
def block_footprint(height_m: float = 4.0, cell_m: float = 0.01) -> BlockFootprint:
    """Cast a fine vertical grid of rays down on the known block mesh (once, cached)."""
    model = block_model(height_m)
    half = np.abs(model.points[:, :2]).max(axis=0) + 0.1
    # symmetric about the rope, cell centres off the mesh's edges (which sit on round numbers)
    ax = [(np.arange(2 * int(h / cell_m)) - int(h / cell_m) + 0.5) * cell_m for h in half]
    gx, gy = np.meshgrid(*ax, indexing="ij")
    n = gx.size
    rays = np.zeros((n, 6), np.float32)
    rays[:, 0], rays[:, 1], rays[:, 2], rays[:, 5] = gx.ravel(), gy.ravel(), 2.0, -1.0
    t = model.scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    hit = np.isfinite(t)
    q = np.column_stack([rays[hit, 0], rays[hit, 1], 2.0 - t[hit]]).astype(np.float64)
    var = q.var(axis=0)
    return BlockFootprint(q.mean(axis=0), float(var[:2].max()), float(var[2]), float(hit.sum() * cell_m**2),
                          float(np.sqrt(np.einsum("ij,ij->i", q[:, :2], q[:, :2])).max()))


def rotation_hanging(u: np.ndarray) -> np.ndarray:
    """The minimal rotation taking the block's +z to -u (u: unit vector tip -> block, downward).

    Continuous for any sway below 90 deg; the block's yaw is a further rotation about its z.
    """
    u = np.asarray(u, float)
    b = -u / math.sqrt(float(u @ u))
    # a = (0, 0, 1): v = a x b = (-b_y, b_x, 0), c = a . b = b_z
    vx = np.array([[0.0, 0.0, b[0]], [0.0, 0.0, b[1]], [-b[0], -b[1], 0.0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + b[2])


def _rot_z(psi: float) -> np.ndarray:
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# --------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------
def _extent_xy(xy: np.ndarray, lo: float = 1.0, hi: float = 99.0) -> float:
    """Length of a 2-D point set along its principal axis (percentile range, robust to strays)."""
    if len(xy) < 2:
        return 0.0
    c = xy - xy.mean(axis=0)
    _, vecs = np.linalg.eigh(c.T @ c)
    s = c @ vecs[:, -1]
    a, b = np.percentile(s, [lo, hi])
    return float(b - a)


def _cluster_extent(p: np.ndarray) -> float:
    """Diagonal of the cluster's box in its horizontal principal axes and z (metres)."""
    if len(p) < 2:
        return 0.0
    c = p[:, :2] - p[:, :2].mean(axis=0)
    _, vecs = np.linalg.eigh(c.T @ c)
    s = c @ vecs
    ext = np.ptp(s, axis=0)
    return float(math.sqrt(ext[0] ** 2 + ext[1] ** 2 + np.ptp(p[:, 2]) ** 2))


def _remove_planes(p: np.ndarray, cfg: HookConfig, cell_m: float, rng: np.random.Generator) -> np.ndarray:
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


def _rope_mask(p: np.ndarray, u: np.ndarray, cfg: HookConfig) -> np.ndarray:
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


def _clusters(p: np.ndarray, eps: float, method: str, auto_points: int = 500) -> np.ndarray:
    """Cluster labels (single linkage at eps), -1 for none."""
    if len(p) == 0:
        return np.zeros(0, dtype=np.int64)
    if method == "dbscan" or (method == "auto" and len(p) < auto_points):
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
        # min_points=1: DBSCAN degenerates to single linkage, the same partition as the kdtree route
        return np.asarray(pc.cluster_dbscan(eps=eps, min_points=1, print_progress=False), dtype=np.int64)
    pairs = cKDTree(p).query_pairs(eps, output_type="ndarray")
    n = len(p)
    g = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    return lab.astype(np.int64)


@dataclass
class _Fit:
    t: np.ndarray  # reference point, levelled frame
    yaw: float
    R: np.ndarray  # block orientation, levelled <- block
    rms: float  # RMS of the inliers' distances to the model
    inliers: np.ndarray  # bool over the points scored


def _pose(t: np.ndarray, yaw: float) -> np.ndarray:
    return rotation_hanging(t) @ _rot_z(yaw)


def _icp_4dof(p: np.ndarray, t0: np.ndarray, yaw0: float, model: BlockModel, cfg: HookConfig,
              coarse_iterations: int, max_iterations: int | None = None) -> tuple[np.ndarray, float]:
    """Point-to-point ICP with the block hanging along the rope: unknowns yaw + translation.

    Pose: x_level = R_u(t) Rz(yaw) m + t, with R_u the hanging rotation for u = t / |t| (the block
    hangs along the line from the tip to its reference point, the pendulum model). With R_u fixed
    per iteration the best yaw and translation have a closed form: a 2-D Procrustes in the rope
    frame's xy plane plus the mean offset along the rope. Two stages: a coarse correspondence cut
    (pulls in from a rough start), then the final inlier cut (drops stray rope / clutter points).
    Correspondences from the model's voxel grid. Returns (t, yaw).
    """
    t = t0.copy()
    yaw = yaw0
    for it in range(cfg.icp_iterations if max_iterations is None else max_iterations):
        coarse = it < coarse_iterations
        thr = cfg.icp_max_correspondence_m if coarse else cfg.icp_final_correspondence_m
        Ru = rotation_hanging(t)
        pr = p @ Ru  # points in the rope frame (absolute)
        q = (pr - Ru.T @ t) @ _rot_z(yaw)  # model frame: Rz^T (pr - tr)
        d, idx = model.nearest_grid(q)
        ok = d < thr
        if np.count_nonzero(ok) < 3:
            break
        m, x = model.points[idx[ok]], pr[ok]
        mc, xc = m.mean(axis=0), x.mean(axis=0)
        m0, x0 = m[:, :2] - mc[:2], x[:, :2] - xc[:2]
        yaw_new = math.atan2(float(np.sum(m0[:, 0] * x0[:, 1] - m0[:, 1] * x0[:, 0])),
                             float(np.sum(m0[:, 0] * x0[:, 0] + m0[:, 1] * x0[:, 1])))
        t_new = Ru @ (xc - _rot_z(yaw_new) @ mc)
        step = float(np.linalg.norm(t_new - t))
        t, yaw = t_new, yaw_new
        if step < cfg.icp_tolerance_m and not coarse:
            break
    return t, yaw


def _score(p: np.ndarray, t: np.ndarray, yaw: float, model: BlockModel, cfg: HookConfig) -> _Fit:
    """Exact residuals of p against the posed model; inliers within the final correspondence cut."""
    R = _pose(t, yaw)
    d, _ = model.nearest((p - t) @ R)
    inl = d < cfg.icp_final_correspondence_m
    rms = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    return _Fit(t, yaw, R, rms, inl)


def _initial_guesses(p: np.ndarray, cfg: HookConfig) -> list[tuple[np.ndarray, float]]:
    """Starting poses (t, yaw) from the cluster: its highest points and its long axis."""
    # Hanging direction: tip -> cluster centroid (off the rope by at most the block's size / range).
    u0 = p.mean(axis=0)
    u0 = u0 / np.linalg.norm(u0)
    h = -(p @ u0)  # height along the rope (up = -u0)
    Ru0 = rotation_hanging(u0)
    # Yaw: the principal axis in the plane normal to the rope = the block's long axis. The visible
    # top is symmetric under a 180 deg yaw (the asymmetric hook is hidden under the body), so one
    # yaw suffices; a near-isotropic cluster (a few far points) also tries the perpendicular one.
    xy = (p @ Ru0)[:, :2]
    xy = xy - xy.mean(axis=0)
    w, vecs = np.linalg.eigh(xy.T @ xy)
    yaw_pca = math.atan2(vecs[1, -1], vecs[0, -1])
    yaws = [yaw_pca]
    if w[0] <= 0 or w[1] / max(w[0], 1e-12) < cfg.isotropic_ratio**2:
        yaws.append(yaw_pca + math.pi / 2)
    # Reference point: the centre of the highest points (the sheave crowns), raised by the crown's
    # depth below the rope attachment. If the highest point stands alone well above the next one
    # (a stray rope point, or a lone crown point of a far block), also start from the 2nd highest.
    hs = np.sort(h)[::-1]
    tops = [hs[0]] + ([hs[1]] if len(hs) > 1 and hs[0] - hs[1] > 0.15 else [])
    out = []
    for h_top in tops:
        sel = (h >= h_top - cfg.top_band_m) & (h <= h_top + 1e-9)
        c = p[sel].mean(axis=0)
        t0 = c + (h_top - SHEAVE_CROWN_Z_M - float(-(c @ u0))) * (-u0)
        out += [(t0, y) for y in yaws]
    return out


def _fit_block(p: np.ndarray, cfg: HookConfig, rng: np.random.Generator, prior_t: np.ndarray | None = None) -> _Fit:
    """Fit the known block model to the cluster points p (levelled frame); the best of a few
    starts (most inliers, then lowest RMS). ``prior_t``, a precise prediction of the reference
    point, adds starts there (the cluster's yaw and the perpendicular one): a far block's 8-10
    points start the ICP in a wrong basin about one frame in 25 (hook-1 at 80 m), with 6 of 10
    points explained.

    If none fits well (RMS above icp_good_rms_m + icp_good_rms_per_m * range), e.g. a partly
    occluded block, whose visible part is nearly square (poor principal axis) and whose top
    centroid is off-centre, retry from yaws every icp_retry_yaw_step_deg combined with shifts of
    +-icp_retry_shift_m along the block's long axis: each start runs the coarse ICP stage only, the
    two best then run to convergence.
    """
    model = block_model(cfg.block_height_m, cfg.model_points)
    ps = p if len(p) <= cfg.fit_max_points else p[rng.choice(len(p), cfg.fit_max_points, replace=False)]

    def better(a: _Fit | None, b: _Fit) -> bool:
        return a is None or (b.inliers.sum(), -b.rms) > (a.inliers.sum(), -a.rms)

    best: _Fit | None = None
    starts = _initial_guesses(ps, cfg)
    if prior_t is not None:
        starts += [(np.asarray(prior_t, float), starts[0][1] + dy) for dy in (0.0, math.pi / 2)]
    for t0, y0 in starts:
        t, yaw = _icp_4dof(ps, t0, y0, model, cfg, cfg.icp_coarse_iterations)
        cand = _score(p, t, yaw, model, cfg)
        if better(best, cand):
            best = cand
    assert best is not None
    t_top = starts[0][0]
    if best.rms <= cfg.icp_good_rms_m + cfg.icp_good_rms_per_m * float(np.linalg.norm(t_top)):
        return best
    step = math.radians(cfg.icp_retry_yaw_step_deg)
    Ru = rotation_hanging(t_top)
    coarse = []
    for k in range(int(round(math.pi / step))):
        y = starts[0][1] + k * step
        ax = Ru @ np.array([math.cos(y), math.sin(y), 0.0])  # the block's long axis
        for sh in (0.0, -cfg.icp_retry_shift_m, cfg.icp_retry_shift_m):
            t, yaw = _icp_4dof(ps, t_top + sh * ax, y, model, cfg, cfg.icp_coarse_iterations,
                               max_iterations=cfg.icp_coarse_iterations)
            coarse.append(_score(ps, t, yaw, model, cfg))
    coarse.sort(key=lambda f: (-f.inliers.sum(), f.rms))
    for c in coarse[:2]:
        t, yaw = _icp_4dof(ps, c.t, c.yaw, model, cfg, 0)
        cand = _score(p, t, yaw, model, cfg)
        if better(best, cand):
            best = cand
    return best


def _ray_costs(model: BlockModel, t_c: np.ndarray, yaw_c: float, offs: np.ndarray, dyaw: np.ndarray,
               s: np.ndarray, d: np.ndarray, r: np.ndarray, blk: np.ndarray, cfg: HookConfig):
    """Ray-consistency cost of P x Y poses around (t_c, yaw_c): offsets (P, 2) across the rope,
    yaw offsets (Y,). Rays: origin s, unit directions d (K, 3), measured ranges r (K,), blk (K,)
    True for the block's points. One Open3D cast for all poses and rays.

    Per pose the offset along the rays (~ along the rope) is solved in closed form (mean range
    residual of the block rays that hit). Cost per ray, clipped at c = ray_clip_m:
      block ray, model hit: min(e^2, c^2), e = measured - model range; block ray, model miss: c^2
      other ray, model hit: min(e^2, c^2) unless the point is well in front (occlusion: 0), so a
      ray that went PAST where the model puts the block (a deck point beside it) is a contradiction
      other ray, model miss: 0.
    Returns cost (Y*P,), reference points (Y*P, 3), yaws (Y*P,).
    """
    Ru = rotation_hanging(t_c)
    T = t_c[None] + offs @ Ru[:, :2].T  # (P, 3)
    yaws = yaw_c + dyaw
    Rys = np.stack([Ru @ _rot_z(y) for y in yaws])  # (Y, 3, 3)
    o = np.einsum("yji,pj->ypi", Rys, s[None] - T)  # ray origins, block frame
    db = np.einsum("yji,kj->yki", Rys, d)  # ray directions, block frame
    Y, P, K = len(yaws), len(T), len(d)
    rays = np.empty((Y, P, K, 6), dtype=np.float32)
    rays[..., :3] = o[:, :, None, :]
    rays[..., 3:] = db[:, None, :, :]
    th = model.scene.cast_rays(o3d.core.Tensor(rays.reshape(-1, 6)))["t_hit"].numpy().reshape(Y * P, K)
    hit = np.isfinite(th)
    e = np.where(hit, r[None] - np.where(hit, th, 0.0), 0.0)
    use = hit & blk[None] & (np.abs(e) < 0.3)
    n_use = use.sum(axis=1)
    dz = np.where(n_use > 0, (e * use).sum(axis=1) / np.maximum(n_use, 1), 0.0)
    e = e - dz[:, None]
    c2 = cfg.ray_clip_m**2
    sq = np.minimum(e * e, c2)
    occluded = ~blk[None] & (e < -cfg.ray_occlusion_m)
    cost = np.where(hit & ~occluded, sq, 0.0).sum(axis=1) + c2 * (~hit & blk[None]).sum(axis=1)
    dm = d.mean(axis=0)
    refs = np.tile(T, (Y, 1)) + dz[:, None] * dm[None]
    return cost, refs, np.repeat(yaws, P)


@dataclass
class _Rays:
    s: np.ndarray  # (3,) sensor origin
    d: np.ndarray  # (K, 3) unit directions
    r: np.ndarray  # (K,) measured ranges
    blk: np.ndarray  # (K,) True for the block's points


def _ray_evidence(pts: np.ndarray, blk_mask: np.ndarray, t0: np.ndarray, yaw0: float, s: np.ndarray,
                  reach_m: float, model: BlockModel, cfg: HookConfig, rng: np.random.Generator) -> _Rays:
    """The rays that can tell poses near (t0, yaw0) apart: every input point whose ray (from the
    sensor) passes within the model's reach of t0 and that is not far in front of it (occluders and
    rope carry nothing). Non-block rays only if they pass (at mid-height of the visible top, block
    frame of the given pose) within reach_m of the block's footprint: only those can be hit by a
    pose in the search. Subsampled to ray_max_block + ray_max_other."""
    a = t0 - s
    ra = float(np.linalg.norm(a))
    v = pts - s
    r = np.sqrt(np.einsum("ij,ij->i", v, v))
    cos_lim = math.cos((model.radius_m + cfg.ray_cone_margin_m) / ra)
    ev = (v @ (a / ra) > cos_lim * r) & (r > ra - 1.0)
    ib = np.flatnonzero(ev & blk_mask)
    io = np.flatnonzero(ev & ~blk_mask)
    R0 = _pose(t0, yaw0)
    ob = R0.T @ (s - t0)
    db = (v[io] / r[io, None]) @ R0
    lam = (0.5 * (SHEAVE_CROWN_Z_M + BODY_TOP_Z_M) - ob[2]) / np.minimum(db[:, 2], -1e-6)
    xy = ob[None, :2] + lam[:, None] * db[:, :2]
    out = np.maximum(np.abs(xy) - 0.5 * np.asarray(BODY_XY_M), 0.0)
    io = io[np.hypot(out[:, 0], out[:, 1]) < reach_m + 0.15]
    if len(ib) > cfg.ray_max_block:
        ib = rng.choice(ib, cfg.ray_max_block, replace=False)
    if len(io) > cfg.ray_max_other:
        io = rng.choice(io, cfg.ray_max_other, replace=False)
    idx = np.concatenate([ib, io])
    blk = np.zeros(len(idx), dtype=bool)
    blk[: len(ib)] = True
    return _Rays(s, v[idx] / r[idx, None], r[idx], blk)


def _ray_sigma(cfg: HookConfig, t: np.ndarray) -> float:
    """Range noise of the block's returns at the block's range (see ``ray_sigma_per_m``)."""
    r = float(np.linalg.norm(t))
    return max(cfg.ray_sigma_m, min(cfg.ray_sigma_per_m * r, cfg.ray_sigma_max_m))


def _prior_nats(refs: np.ndarray, prior: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """-log N(ref; prior) up to a constant for each row of refs (0 without a prior)."""
    if prior is None:
        return np.zeros(len(refs))
    d = refs - prior[0]
    return 0.5 * np.einsum("ij,ij->i", d, np.linalg.solve(prior[1], d.T).T)


def _ray_pick(rays: _Rays, t: np.ndarray, yaw: float, model: BlockModel, cfg: HookConfig,
              prior: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, float]:
    """Of the fitted pose and its near-symmetric copies (AMBIGUOUS_SHIFTS_M, one sheave pitch along
    the axle: a partly hidden block can be fitted one pitch off, with the same point-to-model RMS),
    the one the rays agree with best: the wrong copy puts the block on rays that went past it.
    With a sparse block the rays often cannot tell (on hook-2 at 115 m one fix in four was a pitch
    off); a filter prediction ``prior`` = (mean, covariance) then joins the choice: the copy with
    the least ray cost / (2 ray_sigma^2) + Mahalanobis^2 / 2. The prior only picks the copy; the
    fix itself comes from the rays and points (no double counting in the filter)."""
    R = _pose(t, yaw)
    cands = [t] + [t + R @ np.asarray(sh) for sh in AMBIGUOUS_SHIFTS_M]
    costs = [_ray_costs(model, c, yaw, np.zeros((1, 2)), np.zeros(1), rays.s, rays.d, rays.r, rays.blk, cfg)
             for c in cands]
    refs = np.array([c[1][0] for c in costs])
    nats = np.array([c[0][0] for c in costs]) / (2 * _ray_sigma(cfg, t) ** 2) + _prior_nats(refs, prior)
    k = int(np.argmin(nats))
    return (t, yaw) if k == 0 else (refs[k], yaw)


def _ray_refine(rays: _Rays, t0: np.ndarray, yaw0: float, half1: float, model: BlockModel,
                cfg: HookConfig, prior: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, float, float]:
    """Refine the pose by ray consistency; returns the posterior mean (reference point, yaw) and
    the posterior standard deviation across the rope (m, the larger axis).

    The ICP only pulls points onto the model surface; with a few tens of points (far block) many
    poses fit about equally well, up to a beam spacing apart, and the ICP stops at any of them. The
    rays hold more: which beams hit the block, which went past it to the deck, and at what range.
    Search over (offset across the rope, yaw), the offset along the rope solved per pose:
      1. a coarse grid around the ICP pose, half-width half1 ~ one beam spacing (the ICP's error),
         yaw +- what that spacing means at the block's ends;
      2. the cost is rough (hits and misses flip in steps of a few cm and ~1 deg), so the coarse
         minimum need not hold the best basin: the ray_starts best coarse poses are refined on a
         local grid, the best kept (with a filter prediction ``prior``, by ray cost plus prior
         Mahalanobis distance, as in :func:`_ray_pick`: the coarse grid spans a sheave pitch);
      3. a fine grid around it: the estimate is its posterior mean, weights exp(-cost / 2 sigma^2),
         the centre of the poses the rays cannot tell apart rather than an arbitrary one of them.
    """
    inv2s2 = 1.0 / (2 * _ray_sigma(cfg, t0) ** 2)

    def grid(t_c, yaw_c, half, n, yaw_half, n_yaw):
        g = np.linspace(-half, half, n)
        offs = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
        dy = np.linspace(-yaw_half, yaw_half, n_yaw) if n_yaw > 1 else np.zeros(1)
        return _ray_costs(model, t_c, yaw_c, offs, dy, rays.s, rays.d, rays.r, rays.blk, cfg)

    yaw1 = float(np.clip(0.5 * half1 / (0.5 * BODY_XY_M[0]), math.radians(cfg.ray_yaw_min_deg),
                         math.radians(cfg.ray_yaw_max_deg)))
    (n1, n2, n3), (ny1, ny2, ny3) = cfg.ray_grid_points, cfg.ray_yaw_points
    cost, refs, yaws = grid(t0, yaw0, half1, n1, yaw1, ny1)
    step1, ystep1 = 2 * half1 / (n1 - 1), 2 * yaw1 / max(ny1 - 1, 1)
    best = (np.inf, t0, yaw0)
    for k in np.argsort(cost * inv2s2 + _prior_nats(refs, prior))[: cfg.ray_starts]:
        c2, r2, y2 = grid(refs[k], float(yaws[k]), step1, n2, ystep1, ny2)
        j = int(np.argmin(c2))
        score = float(c2[j]) * inv2s2 + float(_prior_nats(r2[j:j + 1], prior)[0])
        if score < best[0]:
            best = (score, r2[j], float(y2[j]))
    step2, ystep2 = 2 * step1 / (n2 - 1), 2 * ystep1 / max(ny2 - 1, 1)
    cost, refs, yaws = grid(best[1], best[2], 1.5 * step2, n3, 1.5 * ystep2, ny3)
    w = np.exp(-(cost - cost.min()) * inv2s2)
    w /= w.sum()
    t_m = w @ refs
    E = rotation_hanging(t_m)[:, :2]
    sd = float(np.sqrt(np.max(w @ (((refs - t_m) @ E) ** 2))))
    return t_m, float(w @ yaws), sd


# --------------------------------------------------------------------------------------
# Main entry
# --------------------------------------------------------------------------------------
def _fail(n: int, status: str, extent: float = float("nan"), rms: float = float("nan"), n_pts: int = 0,
          plane_mask: np.ndarray | None = None, rope_mask: np.ndarray | None = None) -> HookDetection:
    return HookDetection(np.full(3, np.nan), np.zeros(n, dtype=bool), n_pts, rms, status, extent,
                         plane_mask=plane_mask, rope_mask=rope_mask)


def detect_hook(
    points_level: np.ndarray,
    p_prior: np.ndarray,
    hoist_length_m: float,
    cfg: HookConfig | None = None,
    rng: np.random.Generator | None = None,
    times: StageTimes | None = None,
    *,
    sensor_position_m: np.ndarray | None = None,
    prior_cov_m2: np.ndarray | None = None,
) -> HookDetection:
    """Segment the lower block in one LiDAR frame and estimate its reference point.

    points_level: (N, 3) levelled frame, origin at the boom tip, z up (metres).
    p_prior: (3,) predicted reference point, same frame (filter prediction, or (0, 0, -l) before
        the filter has converged).
    hoist_length_m: rope length l from the hoist encoder: sets the expected range (cluster radius)
        and a plausibility check (|reference| ~ l).
    sensor_position_m: (3,) the LiDAR's origin in the same frame (the mount offset from the tip),
        for the ray-consistency refinement; default the tip itself (about 1 cm worse at 60 m for a
        1 m offset).
    prior_cov_m2: (3, 3) covariance of p_prior when it is a filter prediction. With it, a frame
        whose block is too sparse for the model fit (a far block: 1-5 points) still gives its
        points and a loose fix, status "sparse" (:func:`sparse_block_fix`).
    Returns a :class:`HookDetection`; on failure position_m is NaN and status gives the reason.
    """
    cfg = cfg or HookConfig()
    times = times if times is not None else StageTimes()
    pts = np.asarray(points_level, dtype=np.float64).reshape(-1, 3)
    # The prediction resolves the block's near-symmetric copies (a sheave pitch apart); its
    # covariance is widened by the fix's own scatter within one copy.
    prior = None
    if prior_cov_m2 is not None:
        prior = (np.asarray(p_prior, float), np.asarray(prior_cov_m2, float) + cfg.prior_pick_sigma_m**2 * np.eye(3))
    det = _detect_by_model_fit(pts, p_prior, hoist_length_m, cfg, rng, times, sensor_position_m, prior)
    if det.ok or not cfg.sparse or prior_cov_m2 is None:
        return det
    with times.stage("hook.sparse"):
        background = np.zeros(len(pts), dtype=bool)
        for m in (det.plane_mask, det.rope_mask):
            if m is not None:
                background |= m
        sparse = sparse_block_fix(pts, background, np.asarray(p_prior, float), np.asarray(prior_cov_m2, float),
                                  hoist_length_m, cfg, sensor_position_m)
    if isinstance(sparse, str):
        det.status = f"{det.status}; no sparse fix: {sparse}"
        return det
    sparse.plane_mask, sparse.rope_mask = det.plane_mask, det.rope_mask
    return sparse


def sparse_block_fix(
    points_level: np.ndarray,
    background: np.ndarray,
    p_prior: np.ndarray,
    prior_cov_m2: np.ndarray,
    hoist_length_m: float,
    cfg: HookConfig,
    sensor_position_m: np.ndarray | None = None,
) -> HookDetection | str:
    """A loose fix from the few points a far block gets, associated by the filter's prediction.

    The block's points are the non-background points inside the predicted block volume (a
    cylinder about the rope direction: footprint reach + k sigma across, block height + k sigma
    along). Each is a beam that landed somewhere on the block's top: the reference point is
    their mean minus the footprint's mean hit (:func:`block_footprint`). Its covariance, in the
    block frame: across the rope, the mean of grid samples on a footprint of width W is off by
    at most half a beam spacing s, and by W / sqrt(12) when one beam hits: min(W^2, s^2) / 12 per
    axis (W the long axis: yaw is unknown); along the rope, the hit heights (sheave crowns or
    body top) vary independently: var_z / n. Plus the range noise. The fix does not use the
    prior's value, only its direction (the block hangs along it) and the association volume.

    The rope's shadow: the LiDAR sits beside the rope, so the beams in the plane through the
    sensor and the rope cross the rope before they reach the block's far half, which they never
    hit. When every point lies within ``sparse_rope_plane_m`` of that plane (one scan line
    along it: the usual case with 1-3 points), the hits sample only the near half and their
    mean is off by a quarter of the block (~0.3 m, measured on hook-2). Such frames keep their
    segmentation but give no fix (status "segmented: ...").
    Returns the detection, or a reason string.
    """
    fp = block_footprint(cfg.block_height_m)
    P = np.asarray(prior_cov_m2, float).reshape(3, 3)
    sig_across = math.sqrt(max(float(np.linalg.eigvalsh(P[:2, :2])[-1]), 0.0))
    if sig_across > cfg.sparse_max_prior_sigma_m:
        return f"prediction too uncertain ({sig_across:.1f} m across the rope)"
    sig_along = math.sqrt(max(float(P[2, 2]), 0.0))
    range_m = max(float(np.linalg.norm(p_prior)), 1.0)
    step_m = cfg.lidar_angular_step_rad * range_m
    R = rotation_hanging(p_prior / range_m)  # block frame -> level frame
    q = (points_level - p_prior) @ R  # block frame, origin at the predicted reference point
    k = cfg.sparse_gate_sigmas
    radius = min(fp.reach_m + k * sig_across + 0.5 * step_m, cfg.prior_radius_m)
    z_hi, z_lo = 0.3 + k * sig_along, -cfg.block_height_m - 0.3 - k * sig_along
    cand = ((~background) & (points_level[:, 2] < -cfg.below_tip_m)
            & (np.einsum("ij,ij->i", q[:, :2], q[:, :2]) < radius**2) & (q[:, 2] < z_hi) & (q[:, 2] > z_lo))
    n = int(np.count_nonzero(cand))
    if n == 0:
        return "no points in the predicted block volume"
    n_expected = fp.area_m2 / step_m**2
    if n_expected > cfg.sparse_max_expected_points:
        # A near block that gives too few points is hidden or not there; its few points would
        # be a biased sample (and clutter of block size looks the same): no sparse fix.
        return f"a block at {range_m:.0f} m gives ~{n_expected:.0f} points: too near for a sparse fix"
    n_max = cfg.sparse_max_points_factor * n_expected + 3
    if n > n_max:
        return f"{n} points in the predicted block volume, a far block gives at most {n_max:.0f}"
    pc = points_level[cand]
    qc = q[cand]
    extent = float(np.ptp(qc[:, :2], axis=0).max()) if n > 1 else 0.0
    if extent > 2 * fp.reach_m + step_m:
        return f"points in the predicted block volume spread over {extent:.1f} m: not one block"
    mask = np.zeros(len(points_level), dtype=bool)
    mask[cand] = True
    s_pos = np.zeros(3) if sensor_position_m is None else np.asarray(sensor_position_m, float)
    normal = np.cross(s_pos, p_prior)  # the plane through the rope (tip -> block) and the sensor
    nn = float(np.linalg.norm(normal))
    if nn > 1e-9 and np.all(np.abs(pc @ (normal / nn)) < cfg.sparse_rope_plane_m):
        return HookDetection(np.full(3, np.nan), mask, n, float("nan"),
                             f"segmented: {n} points along the rope's shadow plane, no fix", extent)
    position = pc.mean(axis=0) - R @ fp.mean_m
    tol = max(cfg.length_tolerance_m, cfg.length_tolerance_fraction * hoist_length_m)
    if abs(float(np.linalg.norm(position)) - hoist_length_m) > tol:
        return f"sparse fix at {np.linalg.norm(position):.1f} m from the tip, hoist length {hoist_length_m:.1f} m"
    noise2 = _ray_sigma(cfg, p_prior) ** 2
    var_across = min(12.0 * fp.var_long_m2, step_m**2) / 12.0 + noise2
    var_along = fp.var_vertical_m2 + noise2  # not / n: the hits of one scan line share a surface
    cov = R @ np.diag([var_across, var_across, var_along]) @ R.T
    return HookDetection(position, mask, n, float("nan"), "sparse", extent, cov_m2=cov)


def _detect_by_model_fit(pts: np.ndarray, p_prior: np.ndarray, hoist_length_m: float, cfg: HookConfig,
                         rng: np.random.Generator | None, times: StageTimes,
                         sensor_position_m: np.ndarray | None,
                         pick_prior: tuple[np.ndarray, np.ndarray] | None = None) -> HookDetection:
    """Steps 1-4 of the module docstring (gate, background, clusters, model fit)."""
    rng = rng if rng is not None else np.random.default_rng()
    n_all = len(pts)
    prior = np.asarray(p_prior, dtype=np.float64).reshape(3)
    range_m = max(float(np.linalg.norm(prior)), 1.0)
    step_m = cfg.lidar_angular_step_rad * range_m  # beam spacing at the block

    # 1. Gate: a sphere around the prior (3 sigma of the prediction + the block's size), and below
    # the tip (nothing of the block can be above it; removes the boom and the sensor's own mount).
    with times.stage("hook.gate"):
        d2 = np.einsum("ij,ij->i", pts - prior, pts - prior)
        gate = np.flatnonzero((d2 < cfg.prior_radius_m**2) & (pts[:, 2] < -cfg.below_tip_m))
        p = pts[gate]
    if len(p) < cfg.min_gate_points:
        return _fail(n_all, "no points near the prediction")

    # 2. Background: large horizontal planes (deck, big cargo tops), then the rope.
    with times.stage("hook.planes"):
        cell = max(cfg.plane_cell_min_m, cfg.plane_cell_steps * step_m)
        planes = _remove_planes(p, cfg, cell, rng) if cfg.max_planes > 0 else np.zeros(len(p), dtype=bool)
        rope = _rope_mask(p, prior / range_m, cfg) & ~planes
        plane_mask = np.zeros(n_all, dtype=bool)
        plane_mask[gate[planes]] = True
        rope_mask = np.zeros(n_all, dtype=bool)
        rope_mask[gate[rope]] = True
        keep = np.flatnonzero(~(planes | rope))
        p, gate = p[keep], gate[keep]
    bgm = dict(plane_mask=plane_mask, rope_mask=rope_mask)
    if len(p) < cfg.min_gate_points:
        return _fail(n_all, "only deck / cargo-top / rope points near the prediction", **bgm)

    # 3. Clusters: single linkage with a radius of a few beam spacings at the block's range (the
    # LiDAR's angular grid makes the point spacing grow with range), then the block-sized cluster
    # nearest to the prior.
    with times.stage("hook.cluster"):
        eps = float(np.clip(cfg.cluster_eps_steps * step_m, cfg.cluster_eps_min_m, cfg.cluster_eps_max_m))
        lab = _clusters(p, eps, cfg.cluster_method, cfg.cluster_auto_points)
        order = np.argsort(lab, kind="stable")
        bounds = np.flatnonzero(np.diff(lab[order])) + 1
        groups = [g for g in np.split(order, bounds) if len(g) >= cfg.min_cluster_points and lab[g[0]] >= 0]
        # A few clusters: loop over clusters, not points.
        dist = np.array([float(np.sqrt(np.min(np.einsum("ij,ij->i", p[g] - prior, p[g] - prior)))) for g in groups])
        ext = np.array([_cluster_extent(p[g]) for g in groups])
    if not groups:
        why = f"only stray points near the prediction (clusters < {cfg.min_cluster_points} points)"
        return _fail(n_all, why, **bgm)
    fits = (ext >= cfg.min_extent_m) & (ext <= cfg.max_extent_m)
    nearest = int(np.argmin(dist))
    if not fits.any():
        why = "too large: probably cargo" if ext[nearest] > cfg.max_extent_m else "too small"
        return _fail(n_all, f"nearest cluster {why} (extent {ext[nearest]:.1f} m)", extent=float(ext[nearest]), **bgm)
    k = int(np.flatnonzero(fits)[np.argmin(dist[fits])])
    idx = groups[k]
    pc = p[idx]

    # 4. Model fit -> reference point (ICP on the cluster). Then re-associate: the block's points
    # are all remaining gated points within mask_distance_m of the posed FULL mesh (this brings
    # back fragments that single linkage split off, and side walls seen at a slant, which the
    # visible-surface model lacks), one fine ICP pass on the model inliers among them, and for a
    # sparse block the ray-consistency refinement.
    with times.stage("hook.fit"):
        model = block_model(cfg.block_height_m, cfg.model_points)
        precise = pick_prior is not None and math.sqrt(float(np.linalg.eigvalsh(pick_prior[1])[-1])) <= cfg.prior_start_sigma_m
        fit = _fit_block(pc, cfg, rng, pick_prior[0] if precise else None)
        frac_in = float(np.count_nonzero(fit.inliers)) / len(pc)
        near = np.flatnonzero(np.linalg.norm(p - fit.t, axis=1) < cfg.block_height_m + 0.5)
        pn = p[near]
        sc = _score(pn, fit.t, fit.yaw, model, cfg)
        t, yaw = fit.t, fit.yaw
        if np.count_nonzero(sc.inliers) >= cfg.min_fit_points:
            pi = pn[sc.inliers]
            if len(pi) > cfg.fit_max_points:
                pi = pi[rng.choice(len(pi), cfg.fit_max_points, replace=False)]
            t, yaw = _icp_4dof(pi, t, yaw, model, cfg, coarse_iterations=0)
            sc = _score(pn, t, yaw, model, cfg)
        sigma_across = float("nan")
        n_model = int(np.count_nonzero(sc.inliers))
        if cfg.ray_refine and n_model >= cfg.min_fit_points:
            s = np.zeros(3) if sensor_position_m is None else np.asarray(sensor_position_m, dtype=np.float64)
            blk = np.zeros(n_all, dtype=bool)
            blk[gate[near[model.mesh_distance((pn - t) @ sc.R) < cfg.mask_distance_m]]] = True
            half1 = float(np.clip(cfg.ray_window_steps * step_m, cfg.ray_window_min_m, cfg.ray_window_max_m))
            reach = max(half1, float(np.abs(np.asarray(AMBIGUOUS_SHIFTS_M)).max()))  # window or a shift
            rays = _ray_evidence(pts, blk, t, yaw, s, reach, model, cfg, rng)
            t1, yaw1 = _ray_pick(rays, t, yaw, model, cfg, pick_prior)
            if t1 is not t:  # the rays chose a shifted copy: polish it with the ICP
                t, yaw = _icp_4dof(pn[sc.inliers], t1, yaw1, model, cfg, 0)
                sc = _score(pn, t, yaw, model, cfg)
            if n_model <= cfg.ray_refine_max_points:
                t, yaw, sigma_across = _ray_refine(rays, t, yaw, half1, model, cfg, pick_prior)
            sc = _score(pn, t, yaw, model, cfg)
        fit = sc
        on_block = model.mesh_distance((pn - fit.t) @ fit.R) < cfg.mask_distance_m
    mask = np.zeros(n_all, dtype=bool)
    mask[gate[near[on_block]]] = True
    n_in = int(np.count_nonzero(fit.inliers))
    tol = max(cfg.length_tolerance_m, cfg.length_tolerance_fraction * hoist_length_m)
    status = "ok"
    if n_in < cfg.min_fit_points:
        status = f"too few block points ({n_in})"
    elif fit.rms > cfg.max_fit_rms_m or frac_in < cfg.min_inlier_fraction:
        status = f"cluster does not fit the block model (rms {fit.rms:.2f} m, {100 * frac_in:.0f} % explained)"
    elif abs(float(np.linalg.norm(fit.t)) - hoist_length_m) > tol:
        status = f"reference point at {np.linalg.norm(fit.t):.1f} m from the tip, hoist length {hoist_length_m:.1f} m"
    if status != "ok":
        failed = _fail(n_all, status, float(ext[k]), fit.rms, n_in, **bgm)
        if n_in < cfg.min_fit_points and fit.rms <= cfg.max_fit_rms_m and frac_in >= cfg.min_inlier_fraction:
            # Too few points to fix the reference point, but the cluster did fit the block: its
            # points are still the block's (segmentation), only the position is withheld.
            failed.points_mask = mask
            failed.n_points = int(np.count_nonzero(mask))
        return failed
    return HookDetection(fit.t, mask, int(np.count_nonzero(mask)), fit.rms, status, float(ext[k]),
                         float(fit.yaw % math.pi), fit.R, sigma_across, **bgm)


def segmentation_scores(
    points_mask: np.ndarray, labels: np.ndarray, hook_label: int = int(Label.HOOK)
) -> tuple[float, float]:
    """(precision, recall) of a hook mask against per-point labels of the same frame.

    precision = |mask & hook| / |mask|, recall = |mask & hook| / |hook|, counting only the points
    of this frame; NaN when the denominator is zero.
    """
    m = np.asarray(points_mask, dtype=bool)
    h = np.asarray(labels) == hook_label
    tp = int(np.count_nonzero(m & h))
    n_m, n_h = int(np.count_nonzero(m)), int(np.count_nonzero(h))
    return (tp / n_m if n_m else float("nan"), tp / n_h if n_h else float("nan"))
