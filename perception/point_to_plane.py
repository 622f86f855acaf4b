"""Point-to-plane ICP with a Tukey kernel against a surface whose search index is built once.

Open3D's `registration_icp` does the same iteration but builds a k-d tree of the target on
every call: against the feeder's merged model (tens of thousands of points) that build is
most of a call's time, while the model changes only at a merge. Here the index
(Open3D's tensor nearest-neighbour search, built once per model) is kept, and each
iteration is one batched k-nearest query and a 6 x 6 solve.

The iteration is Open3D's (pipelines/registration/Registration.cpp, TransformationEstimation-
PointToPlane): correspondences are the nearest model point within `max_correspondence_m`;
the update solves the Gauss-Newton normal equations of the residuals n . (p - q), weighted by
Tukey's (1 - (r / k)^2)^2, for (rx, ry, rz, tx, ty, tz) applied as Rz Ry Rx; it stops when the
fitness and the inlier RMSE both change by less than `relative_change`. The poses agree with
Open3D's to 1e-14 on recorded feeder frames (tests/perception/test_point_to_plane.py).

The nearest-neighbour queries are most of an iteration's time, and after the first the pose
moves by millimetres: each source point's nearest and second-nearest surface points are kept,
and a point is queried again only when it has moved by half their distances' gap or more since
(below that the nearest cannot have changed: every other point is at least d2 - moved away,
the nearest at most d1 + moved). The correspondences are the full query's: from a good
prediction, few points need a second query.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class IcpResult:
    T: np.ndarray  # 4x4: source frame -> the surface's frame
    source_index: np.ndarray  # (K,) matched source points
    surface_index: np.ndarray  # (K,) their nearest surface points
    fitness: float  # matched / source points
    inlier_rmse_m: float
    iterations: int


class Surface:
    """Points with normals (one frame, e.g. a feeder model's map frame) and their search index."""

    def __init__(self, points: np.ndarray, normals: np.ndarray) -> None:
        import open3d.core as o3c

        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.normals = np.ascontiguousarray(normals, dtype=np.float64)
        if self.points.shape != self.normals.shape or self.points.ndim != 2 or self.points.shape[1] != 3:
            raise ValueError(f"a surface needs (N, 3) points and normals, got {self.points.shape} and {self.normals.shape}")
        self._o3c = o3c
        self._nns = o3c.nns.NearestNeighborSearch(o3c.Tensor(self.points))
        self._nns.knn_index()

    def __len__(self) -> int:
        return len(self.points)

    def nearest(self, query: np.ndarray, max_distance_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(query index, surface index, squared distance) of the queries with a surface point
        within max_distance_m."""
        rows = np.flatnonzero(np.isfinite(query).all(axis=1))  # Open3D's search fails on a non-finite row
        if len(rows) == 0:
            return rows, np.zeros(0, dtype=np.int64), np.zeros(0)
        q = query if len(rows) == len(query) else query[rows]
        idx, d2 = self._nns.knn_search(self._o3c.Tensor(np.ascontiguousarray(q, dtype=np.float64)), 1)
        idx, d2 = idx.numpy()[:, 0], d2.numpy()[:, 0]
        ok = np.flatnonzero(d2 <= max_distance_m * max_distance_m)
        return rows[ok], idx[ok].astype(np.int64), d2[ok]

    def nearest_two(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per query row (finite rows only): its nearest surface point, the distance to it, and
        the gap to the second nearest (inf on a one-point surface)."""
        k = 2 if len(self.points) >= 2 else 1
        idx, d2 = self._nns.knn_search(self._o3c.Tensor(np.ascontiguousarray(query, dtype=np.float64)), k)
        idx, d = idx.numpy(), np.sqrt(d2.numpy())
        gap = d[:, 1] - d[:, 0] if k == 2 else np.full(len(d), np.inf)
        return idx[:, 0].astype(np.int64), d[:, 0], gap


class Correspondences:
    """The nearest surface point of each source point as the pose changes, queried again only
    for the points that may have changed it: moved by half the gap between their nearest and
    second-nearest distances (with a margin for rounding) since they were last queried."""

    def __init__(self, surface: Surface, source: np.ndarray, max_distance_m: float) -> None:
        n = len(source)
        self.surface, self.max_d2 = surface, max_distance_m * max_distance_m
        self.queried_at = np.full((n, 3), np.nan)  # where each point was when last queried (NaN: never)
        self.index = np.zeros(n, dtype=np.int64)
        self.gap = np.zeros(n)
        # each point's nearest surface point and its normal, gathered when it is queried: every
        # call and iteration reads them, and a gather from the whole surface costs cache misses
        self.nearest_points = np.zeros((n, 3))
        self.nearest_normals = np.zeros((n, 3))
        # queries in spatial order (1 m cells of the source's own frame, x-major): neighbouring
        # queries walk the same branches of the index, a third faster than the voxel sampling's
        # hash order. Column by column (numpy's reductions along a short axis are slow); the
        # order within a cell changes no result, so the sort need not be stable.
        cell_key = np.zeros(n, dtype=np.int64)
        for axis in range(3):
            c = source[:, axis]
            c = np.where(np.isfinite(c), c, 0.0)
            cell_key <<= 21  # 21 bits an axis: 2 000 km of 1 m cells
            cell_key |= np.floor(c - c.min(initial=np.inf)).astype(np.int64)
        self.order = np.argsort(cell_key)

    def at(self, moved: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(source index, surface index, squared distance) of the points matched within the
        distance at these positions (non-finite rows match nothing)."""
        # row-wise sums of squares by einsum: numpy's sum over a length-3 axis is several times slower
        step = moved - self.queried_at
        moved_m = np.sqrt(np.einsum("ij,ij->i", step, step))
        stale = ~(2.0 * moved_m + 1e-9 < self.gap)  # NaN (never queried): stale
        rows = self.order[stale[self.order]]
        at = moved.take(rows, axis=0)  # take: a third of a fancy index's time for rows
        finite = np.isfinite(np.einsum("ij,ij->i", at, at))  # Open3D's search fails on a non-finite row
        if not finite.all():
            rows, at = rows[finite], at[finite]
        if len(rows):
            index, _, self.gap[rows] = self.surface.nearest_two(at)
            self.index[rows] = index
            self.queried_at[rows] = at
            self.nearest_points[rows] = self.surface.points.take(index, axis=0)
            self.nearest_normals[rows] = self.surface.normals.take(index, axis=0)
        dq = moved - self.nearest_points
        d2 = np.einsum("ij,ij->i", dq, dq)
        ok = np.flatnonzero(d2 <= self.max_d2)  # a non-finite row compares False
        return ok, self.index[ok], d2[ok]


def rotation_zyx(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rz(rz) Ry(ry) Rx(rx), Open3D's TransformVector6dToMatrix4d."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    return np.array([[cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
                     [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
                     [-sy, cy * sx, cy * cx]])


def cross_rows(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """Row-wise a x b into out, numpy's cross's own arithmetic without its per-call reshaping
    (as long again as the products on a few thousand rows)."""
    a0, a1, a2, b0, b1, b2 = a[:, 0], a[:, 1], a[:, 2], b[:, 0], b[:, 1], b[:, 2]
    np.multiply(a1, b2, out=out[:, 0])
    out[:, 0] -= a2 * b1
    np.multiply(a2, b0, out=out[:, 1])
    out[:, 1] -= a0 * b2
    np.multiply(a0, b1, out=out[:, 2])
    out[:, 2] -= a1 * b0


def _matches(matcher: Correspondences, source: np.ndarray, T: np.ndarray):
    moved = source @ T[:3, :3].T
    moved += T[:3, 3]
    src_i, srf_i, d2 = matcher.at(moved)
    fitness = len(src_i) / len(source) if len(source) else 0.0
    rmse = float(np.sqrt(d2.sum() / len(d2))) if len(d2) else 0.0
    return moved, src_i, srf_i, fitness, rmse


def icp_point_to_plane(surface: Surface, source: np.ndarray, T_guess: np.ndarray, max_correspondence_m: float,
                       tukey_m: float, relative_change: float, max_iterations: int,
                       matcher: Correspondences | None = None) -> IcpResult:
    """Register source points (their own frame) to the surface from T_guess (source -> surface).
    `matcher`: the correspondences of an ICP of the same source to the same surface within the
    same distance that ran before (a refinement from its pose re-queries only the points that
    may have changed their nearest)."""
    T = np.array(T_guess, dtype=np.float64)
    matcher = matcher if matcher is not None else Correspondences(surface, source, max_correspondence_m)
    moved, src_i, srf_i, fitness, rmse = _matches(matcher, source, T)
    it = 0
    while it < max_iterations and len(src_i) >= 6:
        p = moved.take(src_i, axis=0)
        q, n = matcher.nearest_points.take(src_i, axis=0), matcher.nearest_normals.take(src_i, axis=0)
        r = np.einsum("ij,ij->i", p - q, n)
        w = 1.0 - (r / tukey_m) ** 2
        w *= w
        w[np.abs(r) > tukey_m] = 0.0
        J = np.empty((len(r), 6))
        cross_rows(p, n, J[:, :3])
        J[:, 3:] = n
        Jw = J * w[:, None]
        JTJ, JTr = Jw.T @ J, Jw.T @ r
        try:
            x = -np.linalg.solve(JTJ, JTr)
        except np.linalg.LinAlgError:
            break  # exactly singular (every residual beyond the kernel): the pose stays
        update = np.eye(4)
        update[:3, :3] = rotation_zyx(*x[:3])
        update[:3, 3] = x[3:]
        T = update @ T
        it += 1
        previous = (fitness, rmse)
        moved, src_i, srf_i, fitness, rmse = _matches(matcher, source, T)
        if abs(previous[0] - fitness) < relative_change and abs(previous[1] - rmse) < relative_change:
            break
    return IcpResult(T, src_i, srf_i, fitness, rmse, it)
