"""Plane fitting for deck detection (document 000, section 4.1.1): least squares, RANSAC, D.

Frames and units
----------------
All points are numpy float64 arrays of shape (N, 3) in the SENSOR frame (boom-tip LiDAR or
radar), in metres; an Open3D point cloud is accepted wherever points go in. A plane is a numpy
array ``[a, b, c, d]`` with a unit normal ``n = (a, b, c)`` and ``n . x + d = 0``.

Orientation convention
----------------------
Planes returned by :func:`fit_plane_lsq`, :func:`ransac_plane` and
:func:`~boomtip.perception.multi_plane.multi_plane_deck` (the deck among several planes, Appendix F,
Algorithm 3) are oriented so that the sensor origin lies on the positive side: ``d > 0``, i.e. the normal
points from the plane towards the sensor. For the feeder deck seen from above, the normal
therefore points "up" (towards the boom tip) and ``n . up_sensor > 0``. Then the signed
distance ``n . x + d`` of a point is positive on the sensor side of the plane.
:func:`transform_plane` does NOT re-orient (see its docstring).

Distance along the wire
-----------------------
:func:`wire_plane_distance` implements document 000 eq. 4.8, ``D = -d / (n . n_w)``, where
``n_w`` is the unit wire (gravity) direction in the sensor frame, pointing DOWN from the tip.
With the orientation above and a deck below the sensor, ``n . n_w < 0`` and ``D > 0``.

Speed
-----
The RANSAC is vectorised: a batch of minimal samples gives a batch of candidate planes, all
scored on a random subsample of the cloud with a single matrix product; only the best
hypothesis is refined (least squares on its subsample inliers, then on its inliers among ALL
points). A few ms for 100k points, an order of magnitude less than Open3D's ``segment_plane``
with 1000 iterations. See ``ransac_plane``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.perception.cloud import as_points
from boomtip.perception.plane_moments import fit_plane_cols, moments_cols, plane_and_eig, select_inliers, eigh3

__all__ = [
    "RansacConfig",
    "PlaneFit",
    "fit_plane_lsq",
    "orient_plane_towards",
    "ransac_plane",
    "ransac_plane_cols",
    "plane_tilt_deg",
    "wire_plane_distance",
    "transform_plane",
]


# --------------------------------------------------------------------------------------
# Configuration and results
# --------------------------------------------------------------------------------------
class RansacConfig(BaseModel):
    """Vectorised RANSAC plane search (sensor frame, metres)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    distance_threshold_m: float = Field(0.05, gt=0, description="inlier band half-width, m")
    confidence: float = Field(0.999, gt=0, lt=1, description="stop when the chance of having missed a plane with the "
                              "best support so far is below 1 - confidence")
    max_iterations: int = Field(50_000, ge=1, description="cap on the number of hypotheses (the adaptive stop "
                                "ends the search before it down to a 5.5 % inlier share)")
    max_time_ms: float | None = Field(None, gt=0, description="live use: a time cap on the hypothesis search (the fit "
                                      "then depends on the machine's load; it says when the cap ended it)")
    subsample_size: int = Field(4000, ge=3, description="points used to score hypotheses")
    batch_size: int = Field(128, ge=1, description="hypotheses drawn and scored at once")
    min_inliers: int = Field(30, ge=3, description="fewer final inliers -> no plane")
    refit_iterations: int = Field(2, ge=0, description="least-squares refit / inlier re-selection rounds")
    refit_first_on_subsample: bool = Field(
        True,
        description="first refit round on the hypothesis' inliers within the score subsample (cheap); "
        "False: every round on all points (one more full pass and full fit, same result in practice)",
    )


@dataclass
class PlaneFit:
    """One fitted plane.

    plane: [a, b, c, d], unit normal, oriented so that d >= 0 (sensor on the positive side).
    inlier_mask: bool (N,) over the points passed in (for multi_plane_deck: over the ORIGINAL cloud).
    inlier_ratio: inliers / N (N = points passed to the RANSAC call that produced this fit).
    rms_m: RMS of the inliers' point-to-plane distances, metres.
    iterations: number of RANSAC hypotheses drawn.
    needed: hypotheses the adaptive stop asked for, given the best support found.
    capped: the search stopped at max_iterations or max_time_ms before `needed`.
    """

    plane: np.ndarray
    inlier_mask: np.ndarray
    inlier_ratio: float
    rms_m: float
    iterations: int
    needed: float = 0.0
    capped: bool = False
    # The inliers' centroid and the eigen-decomposition (eigenvalues ascending, eigenvectors as
    # columns) of their scatter about it, from the least-squares fit: a caller judging their
    # extent needs no second pass over the points. None when a fit did not supply them.
    centroid: np.ndarray | None = None
    scatter_evals: np.ndarray | None = None
    scatter_evecs: np.ndarray | None = None

    @property
    def n_inliers(self) -> int:
        return int(np.count_nonzero(self.inlier_mask))


# --------------------------------------------------------------------------------------
# Basic geometry
# --------------------------------------------------------------------------------------
def orient_plane_towards(plane: np.ndarray, point: np.ndarray | None = None) -> np.ndarray:
    """Flip the sign of ``plane`` so that ``point`` (default: the sensor origin) is on its positive side.

    For the origin this means d >= 0. A plane passing exactly through the point is returned unchanged.
    """
    plane = np.asarray(plane, dtype=np.float64)
    p = np.zeros(3) if point is None else np.asarray(point, dtype=np.float64)
    s = plane[:3] @ p + plane[3]
    return -plane if s < 0 else plane.copy()


def fit_plane_lsq(points: np.ndarray) -> np.ndarray:
    """Least-squares (total least squares) plane through ``points`` (N >= 3, sensor frame, metres).

    Minimises the sum of squared orthogonal distances: the normal is the right singular vector of
    the centred points with the smallest singular value. Returns [a, b, c, d], unit normal,
    oriented so that the sensor origin is on the positive side (d >= 0).
    Raises ValueError for fewer than 3 points or a non-finite one.
    """
    pts = as_points(points)
    if len(pts) < 3:
        raise ValueError("fit_plane_lsq needs at least 3 points")
    if not np.isfinite(pts).all():
        raise ValueError("fit_plane_lsq needs finite points (preprocess drops the others)")
    return fit_plane_cols(np.ascontiguousarray(pts.T))


def plane_tilt_deg(plane: np.ndarray, up: np.ndarray) -> float:
    """Angle in degrees between the plane normal (as oriented) and the unit vector ``up``; 0..180."""
    n = np.asarray(plane, dtype=np.float64)[:3]
    u = np.asarray(up, dtype=np.float64)
    c = float(n @ u) / (np.linalg.norm(n) * np.linalg.norm(u))
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def wire_plane_distance(
    plane: np.ndarray, wire_dir: np.ndarray, origin: np.ndarray | None = None
) -> float:
    """Distance from ``origin`` along the unit ``wire_dir`` to ``plane`` (document 000 eq. 4.8).

    Solves ``n . (origin + D wire_dir) + d = 0``:  ``D = -(n . origin + d) / (n . wire_dir)``.
    With origin = 0 this is eq. 4.8, ``D = -d / (n_p . n_w)``. All in the plane's frame, metres.
    ``wire_dir`` points DOWN from the boom tip (gravity direction in the sensor frame); it is
    normalised here. D is positive when the plane is ahead along ``wire_dir`` (deck below the tip)
    and independent of the plane's sign convention. Returns NaN when |n . wire_dir| < 1e-6
    (wire parallel to the plane).
    """
    from boomtip.perception.geometry import heave_distance  # the one implementation of eq. 4.8

    plane = np.asarray(plane, dtype=np.float64)
    w = np.asarray(wire_dir, dtype=np.float64)
    o = np.zeros(3) if origin is None else np.asarray(origin, dtype=np.float64)
    return float(heave_distance(plane / np.linalg.norm(plane[:3]), w / np.linalg.norm(w), o))


def transform_plane(plane: np.ndarray, T_a_b: np.ndarray) -> np.ndarray:
    """Express a plane given in frame b in frame a, with ``p_a = R p_b + t`` (``T_a_b`` 4x4).

    ``n_a = R n_b`` and ``d_a = d_b - n_a . t``. The normal keeps its ORIGINAL physical
    direction: the result is NOT re-oriented towards the origin of frame a, so ``d_a`` may be
    negative. The caller decides (e.g. with :func:`orient_plane_towards`). The round trip with
    ``inv(T_a_b)`` returns the input exactly (up to rounding).
    """
    plane = np.asarray(plane, dtype=np.float64)
    T = np.asarray(T_a_b, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    n_a = R @ plane[:3]
    return np.concatenate([n_a, [plane[3] - n_a @ t]])


# --------------------------------------------------------------------------------------
# RANSAC
# --------------------------------------------------------------------------------------
def needed_iterations(inlier_ratio: float, confidence: float, sample_size: int = 3) -> float:
    """Hypotheses needed to draw one all-inlier minimal sample with probability ``confidence``."""
    if inlier_ratio <= 0.0:
        return math.inf
    p_good = inlier_ratio**sample_size
    if p_good >= 1.0:
        return 1.0
    return math.log(1.0 - confidence) / math.log1p(-p_good)


def ransac_plane(points: np.ndarray, cfg: RansacConfig | None = None, rng: np.random.Generator | None = None, *,
                 axis: np.ndarray | None = None, max_axis_angle_deg: float | None = None,
                 min_support: float = 0.0) -> PlaneFit | None:
    """Vectorised RANSAC plane fit (sensor frame, metres).

    1. Score set: a random subsample of ``cfg.subsample_size`` points (all points if fewer; drawn
       with replacement), centred on its mean, float32, homogeneous (4, S).
    2. Repeatedly draw ``cfg.batch_size`` triplets from the score set, build all candidate planes
       at once (cross products), and count every candidate's inliers with ONE matrix product
       ``[n, d] (B, 4) @ points (4, S)`` (float32: rounding ~1e-5 m, far below any threshold).
       Keep the best.
    3. Adaptive stop: after each batch, stop when the hypotheses drawn reach
       ``log(1 - confidence) / log(1 - w^3)`` with w the best subsample inlier ratio: the chance
       that a plane with that support was never sampled is then below 1 - confidence. A ground
       that is 6 % of a real scan needs about 32,000 hypotheses (a fixed 1,000 often misses
       it). ``cfg.max_iterations`` caps the search (deterministic: the same cloud
       and seed give the same plane on any machine); ``cfg.max_time_ms``, off by default, adds a
       time cap for live use. The fit says when a cap ended it (``capped``).
    4. Refinement, ``cfg.refit_iterations`` least-squares rounds (float64). With
       ``cfg.refit_first_on_subsample`` (default) round 1 refits the best hypothesis on its inliers
       within the score set (cheap, and already far better than a plane through 3 points); every
       other round scores the current plane on ALL points, takes those inliers and refits on them.
       The returned plane is the last fit and ``inlier_mask`` is exactly the set of points it was
       fitted to (the all-point inliers of the previous plane). With the default 2 rounds this costs
       one pass over the cloud plus one gather + fit instead of three passes and two full fits.

    ``min_support``: the smallest inlier share the caller would accept. The budget is then the
    one that finds a plane of at least that share, not the (much larger) one that makes sure
    no smaller plane was missed: searching on would only find planes the caller rejects.

    Optional constraint: with ``axis`` (unit vector) and ``max_axis_angle_deg``, hypotheses whose
    normal is more than that angle from +-axis are discarded before scoring (used by
    :func:`~boomtip.perception.multi_plane.multi_plane_deck` to look only for near-horizontal planes).

    ``rng`` draws the subsample and the triplets (default: seeded, the same plane every call).
    Returns None with fewer than 3 points or when the final inlier count is below
    ``cfg.min_inliers``; points must be finite (non-finite ones spoil the fit: None, or run
    :func:`~boomtip.perception.preprocess.preprocess` first). The plane is oriented with d >= 0
    (sensor on the positive side).
    """
    cols = np.ascontiguousarray(as_points(points).T)
    return ransac_plane_cols(cols, cfg, rng, axis=axis, max_axis_angle_deg=max_axis_angle_deg, min_support=min_support)


def ransac_plane_cols(cols: np.ndarray, cfg: RansacConfig | None = None, rng: np.random.Generator | None = None, *,
                      axis: np.ndarray | None = None, max_axis_angle_deg: float | None = None,
                      min_support: float = 0.0) -> PlaneFit | None:
    """:func:`ransac_plane` on points stored column-wise, (3, N) C-contiguous float64 (sensor
    frame, metres): a caller that runs several searches on one cloud lays it out once.
    The fit also carries its inliers' centroid and scatter eigen-decomposition."""
    cfg = cfg or RansacConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    n_pts = cols.shape[1]
    if n_pts < 3:
        return None
    thr = float(cfg.distance_threshold_m)

    # --- score set: subsample, centred, float32, homogeneous (4, S) -----------------------------
    s = min(n_pts, cfg.subsample_size)
    sub = cols.take(rng.integers(0, n_pts, size=s), axis=1) if s < n_pts else cols
    centre = np.add.reduce(sub, axis=1) / s  # ndarray.mean's arithmetic, without its wrapper
    sub_c = sub - centre[:, None]  # (3, S) float64, used for hypotheses and the first refit
    sub_h = np.empty((4, s), dtype=np.float32)
    sub_h[:3] = sub_c
    sub_h[3] = 1.0
    thr32 = np.float32(thr)
    # OpenBLAS runs a GEMM single-threaded when m*n*k < 65536 * 4; bigger ones wake helper threads,
    # and on a busy machine a (128 x 4) @ (4 x 4000) product can then wait tens of ms for them
    # instead of taking a fraction of one. Scoring in row chunks below that size is as fast and never waits.
    chunk = max(1, 262143 // (4 * s))
    dist_buf = np.empty((min(chunk, cfg.batch_size), s), dtype=np.float32)
    # inlier counts accumulate in 16 bits while they fit: summing uint8 into int32 costs twice as much
    count_dtype = np.uint16 if s < 65536 else np.int32

    cos_max = None
    if axis is not None and max_axis_angle_deg is not None:
        ax = np.asarray(axis, dtype=np.float64)
        ax = ax / np.sqrt(ax.dot(ax))  # np.linalg.norm's arithmetic, without its wrapper
        cos_max = math.cos(math.radians(max_axis_angle_deg))

    best_count, best_n, best_d, drawn = -1, None, 0.0, 0
    needed = min(float(cfg.max_iterations), needed_iterations(min_support, cfg.confidence))
    deadline = time.perf_counter() + 1e-3 * cfg.max_time_ms if cfg.max_time_ms is not None else math.inf
    timed_out = False
    while drawn < min(needed, cfg.max_iterations):
        if drawn and deadline < math.inf and time.perf_counter() > deadline:
            timed_out = True
            break
        b = min(cfg.batch_size, cfg.max_iterations - drawn)
        tri = rng.integers(0, s, size=(b, 3))
        drawn += b
        # The triplets by columns, (3, B) rows: the cross and dot products written out on contiguous
        # rows cost a fraction of np.cross / einsum on (B, 3) rows (same products, same order).
        p0, e1, e2 = (sub_c.take(tri[:, j], axis=1) for j in range(3))
        e1 -= p0
        e2 -= p0
        (x1, y1, z1), (x2, y2, z2) = e1, e2
        nrm = np.empty((3, b))
        np.subtract(y1 * z2, z1 * y2, out=nrm[0])
        np.subtract(z1 * x2, x1 * z2, out=nrm[1])
        np.subtract(x1 * y2, y1 * x2, out=nrm[2])
        norms = np.sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2])
        # degenerate (repeated or collinear) triplets: normal undefined
        scale = np.maximum(x1 * x1 + y1 * y1 + z1 * z1, x2 * x2 + y2 * y2 + z2 * z2)
        ok = norms > 1e-9 * np.maximum(scale, 1e-12)
        if not np.count_nonzero(ok):  # ndarray.any() goes through Python wrappers, ~10x the cost
            continue
        keep = ok.nonzero()[0]
        nrm = nrm.take(keep, axis=1)
        nrm /= norms[keep]
        p0 = p0.take(keep, axis=1)
        if cos_max is not None:
            tilt_ok = np.abs(ax[0] * nrm[0] + ax[1] * nrm[1] + ax[2] * nrm[2]) >= cos_max
            if not np.count_nonzero(tilt_ok):
                continue
            keep = tilt_ok.nonzero()[0]
            nrm, p0 = nrm.take(keep, axis=1), p0.take(keep, axis=1)
        d = -(nrm[0] * p0[0] + nrm[1] * p0[1] + nrm[2] * p0[2])
        # (B, S) signed distances with ONE GEMM, then |.| < thr counted per hypothesis
        # (uint8 row sums are cheaper than count_nonzero(axis=...))
        hyp = np.empty((len(d), 4), dtype=np.float32)
        hyp[:, :3] = nrm.T
        hyp[:, 3] = d
        counts = np.empty(len(d), dtype=count_dtype)
        for c0 in range(0, len(d), chunk):  # a few GEMM calls, see `chunk` above
            # each chunk scored while its distances are still in cache (a whole batch's are
            # larger than the L2 cache)
            rows = hyp[c0 : c0 + chunk]
            dist = dist_buf[: len(rows)]
            np.matmul(rows, sub_h, out=dist)
            np.abs(dist, out=dist)
            (dist < thr32).view(np.uint8).sum(axis=1, dtype=count_dtype, out=counts[c0 : c0 + len(rows)])
        k = int(counts.argmax())
        if counts[k] > best_count:
            best_count = int(counts[k])
            best_n = nrm[:, k].copy()
            best_d = float(d[k])
            needed = needed_iterations(max(best_count / s, min_support), cfg.confidence)

    if best_n is None:
        return None

    # --- refinement (float64) ------------------------------------------------------------------
    plane_c = np.concatenate([best_n, [best_d]])  # in the centred frame of the score set
    full_rounds = cfg.refit_iterations
    if cfg.refit_first_on_subsample and full_rounds >= 1:
        full_rounds -= 1
        idx_s = select_inliers(sub_c, plane_c, thr)
        if len(idx_s) >= 3:
            plane_c = fit_plane_cols(sub_c.take(idx_s, axis=1))
    plane = np.concatenate([plane_c[:3], [plane_c[3] - plane_c[:3] @ centre]])  # sensor frame
    idx = select_inliers(cols, plane, thr)
    x_in = None  # the columns of idx, once gathered
    moments = None  # (centroid, evals, evecs) of x_in, once fitted
    for r in range(full_rounds):
        if r > 0:  # re-select with the previous round's fit
            idx = select_inliers(cols, plane, thr)
            x_in = None
        if len(idx) < 3:
            break
        x_in = cols.take(idx, axis=1)
        centroid, scatter = moments_cols(x_in)
        plane, evals, evecs = plane_and_eig(centroid, scatter)
        moments = (centroid, evals, evecs)
    n_in = len(idx)
    if n_in < max(cfg.min_inliers, 3):
        return None
    plane = orient_plane_towards(plane)
    mask = np.zeros(n_pts, dtype=bool)
    mask[idx] = True
    if x_in is not None and moments is not None:
        # The plane was fitted to these inliers: it passes through their centroid along the
        # scatter's least eigenvector, so their squared distances sum to that eigenvalue (to
        # rounding), with no further pass over them.
        rms = math.sqrt(max(float(moments[1][0]), 0.0) / n_in)
    else:  # no full round ran (refit_iterations <= 1): the plane was fitted to others
        x_in = cols.take(idx, axis=1)
        centroid, scatter = moments_cols(x_in)
        moments = (centroid, *eigh3(scatter))
        r_in = plane[:3] @ x_in + plane[3]
        rms = float(np.sqrt(np.einsum("i,i->", r_in, r_in) / n_in))
    return PlaneFit(plane=plane, inlier_mask=mask, inlier_ratio=n_in / n_pts, rms_m=rms, iterations=drawn,
                    needed=needed, capped=timed_out or drawn < needed, centroid=moments[0],
                    scatter_evals=moments[1], scatter_evecs=moments[2])
