"""The known lower block as processing sees it (block frame: origin = the reference point, the
rope attachment at the top centre; z up along the rope, x along the long axis, y along the
sheave axle): its visible-surface model with fast nearest-point lookups, where beams from above
land on it, and how it hangs from the tip."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from boomtip.data.block_model import lower_block_mesh, visible_model_points

__all__ = ["BlockModel", "block_model", "BlockFootprint", "block_footprint", "rotation_hanging", "rot_z",
           "rotations_z", "hanging_pose"]


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
        self.grid = np.empty(tuple(self.shape), np.int32)
        # in slabs along x: all 600,000 cell centres and their answers at once would be about 40 MB
        for a in range(0, self.shape[0], 16):
            centres = np.stack(np.meshgrid(axes[0][a:a + 16], axes[1], axes[2], indexing="ij"), axis=-1).reshape(-1, 3)
            d, idx = self.tree.query(centres, distance_upper_bound=margin_m + grid_cell_m, workers=-1)
            self.grid[a:a + 16] = np.where(np.isfinite(d), idx, -1).reshape(-1, *self.shape[1:])
        self._grid_flat = self.grid.ravel()
        self._strides = np.array([self.shape[1] * self.shape[2], self.shape[2], 1], np.int64)
        self._shape_u = self.shape.astype(np.uint64)

    def mesh_distance(self, q: np.ndarray) -> np.ndarray:
        """Distance of each row of q (block frame) to the FULL mesh (any face, seen or not)."""
        return self.scene.compute_distance(o3d.core.Tensor(q.astype(np.float32))).numpy().astype(np.float64)

    def nearest(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact: (distance, index) of the nearest model point for each row of q (block frame)."""
        return self.tree.query(q)

    def nearest_grid(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Grid lookup: (distance, index); distance inf and index -1 outside the grid's reach."""
        c = np.floor((q - self.lo) / self.cell).astype(np.int64)
        # one unsigned test for 0 <= c < shape (a negative index wraps to a huge one)
        in_range = c.view(np.uint64) < self._shape_u
        if in_range.all():  # the usual case in the ICP: no masks (one reduction, not one per row)
            idx = self._grid_flat[c @ self._strides]
        else:
            inside = in_range.all(axis=1)
            idx = np.full(len(q), -1, dtype=np.int32)
            idx[inside] = self._grid_flat[c[inside] @ self._strides]
        if idx.min(initial=0) >= 0:
            diff = q - self.points[idx]
            return np.sqrt(np.einsum("ij,ij->i", diff, diff)), idx
        ok = idx >= 0
        d = np.full(len(q), np.inf)
        diff = q[ok] - self.points[idx[ok]]
        d[ok] = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        return d, idx


_MODELS: dict[tuple[float, int], BlockModel] = {}


def block_model(height_m: float = 4.0, n: int = 6000) -> BlockModel:
    """The known block's visible-surface model and indices (cached: ~0.5 s to build once).
    Keyed on the values (an lru_cache keys ``f(4.0)`` and ``f(4.0, 6000)`` apart: the same
    model built twice)."""
    key = (float(height_m), int(n))
    if key not in _MODELS:
        _MODELS[key] = BlockModel(*key)
    return _MODELS[key]


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
    Rodrigues' formula I + [v]x + [v]x^2 / (1 + c) written out on floats (called tens of times
    per frame in the ICP, where the 3 x 3 numpy products cost more than the arithmetic).
    """
    ux, uy, uz = (float(c) for c in u)
    r = math.sqrt(ux * ux + uy * uy + uz * uz)
    bx, by, bz = -ux / r, -uy / r, -uz / r
    # a = (0, 0, 1): v = a x b = (-b_y, b_x, 0), c = a . b = b_z
    k = 1.0 + bz
    xy = (bx * -by) / k
    return np.array([[1.0 + (bx * -bx) / k, xy, bx],
                     [xy, 1.0 + (by * -by) / k, by],
                     [-bx, -by, 1.0 + ((-bx * bx) + (-by * by)) / k]])


def rot_z(psi: float) -> np.ndarray:
    """Rotation by psi about z (the block's yaw about the rope)."""
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotations_z(psi: np.ndarray) -> np.ndarray:
    """(S, 3, 3): :func:`rot_z` of each angle in psi (S,)."""
    c, s = np.cos(psi), np.sin(psi)
    R = np.zeros((len(psi), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


def hanging_pose(t: np.ndarray, yaw: float) -> np.ndarray:
    """Block orientation (levelled <- block) with its reference point at t, hanging from the tip."""
    return rotation_hanging(t) @ rot_z(yaw)

