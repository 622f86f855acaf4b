"""Hook (lower block) segmentation and reference point from a boom-tip LiDAR frame (document 002).

Frames and units
----------------
Input points are (N, 3) float, metres, in a GRAVITY-LEVELLED frame with its origin at the boom
tip (the rope's suspension point), z up: the caller rotates the sensor points with the MRU
attitude and the mount and adds the sensor's offset from the tip. The prior ``p_prior`` and the
output ``position_m`` are in the same frame. The block model (``data.block_model``) lives in the
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

Modules: this one runs the chain (and the sparse fix for a far block); steps 2-3 live in
perception.hook_segment, 4a-b in perception.hook_fit, 4c in perception.hook_rays, the block model
in perception.hook_block, the configuration and result in perception.hook_types.

Accuracy (simulated OS1-128, 1024 columns, 1.5 cm noise growing for weak returns, sensor 0.85 m
from the rope): see the report of tests/perception/test_hook_segmentation.py. A near block costs
the ICP alone; a sparse far block adds the ray refinement, the dearer step.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import numpy as np

from boomtip.data.block_model import AMBIGUOUS_SHIFTS_M
from boomtip.data.meshes import Label
from boomtip.perception.cloud import as_points
from boomtip.perception.hook_block import block_footprint, block_model, rotation_hanging
from boomtip.perception.hook_fit import fit_block, icp_4dof, score_pose
from boomtip.perception.hook_rays import ray_evidence, ray_pick, ray_refine, ray_sigma
from boomtip.perception.hook_segment import cluster_extent, cluster_labels, large_plane_mask, rope_line_mask
from boomtip.perception.hook_types import HookConfig, HookDetection
from boomtip.perception.timing import StageTimes

# block_footprint, block_model and rotation_hanging: the block model as the stage uses it, for
# the callers that pose or check it (tests, tools).
__all__ = [
    "BLOCK_STEPS",
    "BlockSteps",
    "HookConfig",
    "HookDetection",
    "detect_hook",
    "segmentation_scores",
    "sparse_block_fix",
    "block_footprint",
    "block_model",
    "rotation_hanging",
]


class BlockSteps(NamedTuple):
    """The block fit (4a-b) and the ray-consistency steps (4c) that detect_hook composes."""

    fit: Callable
    pick: Callable
    refine: Callable


BLOCK_STEPS = BlockSteps(fit_block, ray_pick, ray_refine)


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
    steps: BlockSteps | None = None,
) -> HookDetection:
    """Segment the lower block in one LiDAR frame and estimate its reference point.

    points_level: (N, 3) levelled frame, origin at the boom tip, z up (metres); an Open3D point
        cloud also does.
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
    rng: draws the ICP subsamples and ray subsets (default: seeded, the same result every call).
    steps: the block fit and the ray steps (default BLOCK_STEPS; a benchmark passes its baseline's).
    Returns a :class:`HookDetection`; on failure position_m is NaN and status gives the reason.
    """
    pts = as_points(points_level)
    cfg = cfg or HookConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    times = times if times is not None else StageTimes()
    # The prediction resolves the block's near-symmetric copies (a sheave pitch apart); its
    # covariance is widened by the fix's own scatter within one copy.
    prior = None
    if prior_cov_m2 is not None:
        prior = (np.asarray(p_prior, float), np.asarray(prior_cov_m2, float) + cfg.prior_pick_sigma_m**2 * np.eye(3))
    det = _detect_by_model_fit(pts, p_prior, hoist_length_m, cfg, rng, times, sensor_position_m, prior, steps)
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
    mean is off by a quarter of the block (~0.3 m). Such frames keep their
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
    noise2 = ray_sigma(cfg, p_prior) ** 2
    var_across = min(12.0 * fp.var_long_m2, step_m**2) / 12.0 + noise2
    var_along = fp.var_vertical_m2 + noise2  # not / n: the hits of one scan line share a surface
    cov = R @ np.diag([var_across, var_across, var_along]) @ R.T
    return HookDetection(position, mask, n, float("nan"), "sparse", extent, cov_m2=cov)


def _detect_by_model_fit(pts: np.ndarray, p_prior: np.ndarray, hoist_length_m: float, cfg: HookConfig,
                         rng: np.random.Generator, times: StageTimes,
                         sensor_position_m: np.ndarray | None,
                         pick_prior: tuple[np.ndarray, np.ndarray] | None = None,
                         steps: "BlockSteps | None" = None) -> HookDetection:
    steps = steps or BLOCK_STEPS
    """Steps 1-4 of the module docstring (gate, background, clusters, model fit)."""
    n_all = len(pts)
    prior = np.asarray(p_prior, dtype=np.float64).reshape(3)
    range_m = max(float(np.linalg.norm(prior)), 1.0)
    step_m = cfg.lidar_angular_step_rad * range_m  # beam spacing at the block

    # 1. Gate: a sphere around the prior (3 sigma of the prediction + the block's size), and below
    # the tip (nothing of the block can be above it; removes the boom and the sensor's own mount).
    with times.stage("hook.gate"):
        diff = pts - prior
        d2 = np.einsum("ij,ij->i", diff, diff)
        gate = np.flatnonzero((d2 < cfg.prior_radius_m**2) & (pts[:, 2] < -cfg.below_tip_m))
        p = pts[gate]
    if len(p) < cfg.min_gate_points:
        return _fail(n_all, "no points near the prediction")

    # 2. Background: large horizontal planes (deck, big cargo tops), then the rope.
    with times.stage("hook.planes"):
        cell = max(cfg.plane_cell_min_m, cfg.plane_cell_steps * step_m)
        planes = large_plane_mask(p, cfg, cell, rng) if cfg.max_planes > 0 else np.zeros(len(p), dtype=bool)
        rope = rope_line_mask(p, prior / range_m, cfg) & ~planes
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
        lab = cluster_labels(p, eps, cfg.cluster_method, cfg.cluster_auto_points)
        order = np.argsort(lab, kind="stable")
        bounds = np.flatnonzero(np.diff(lab[order])) + 1
        groups = [g for g in np.split(order, bounds) if len(g) >= cfg.min_cluster_points and lab[g[0]] >= 0]
        # A few clusters: loop over clusters, not points.
        dist = np.array([float(np.sqrt(np.min(np.einsum("ij,ij->i", p[g] - prior, p[g] - prior)))) for g in groups])
        ext = np.array([cluster_extent(p[g]) for g in groups])
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
        fit = steps.fit(pc, cfg, rng, pick_prior[0] if precise else None)
        frac_in = float(np.count_nonzero(fit.inliers)) / len(pc)
        near = np.flatnonzero(np.linalg.norm(p - fit.t, axis=1) < cfg.block_height_m + 0.5)
        pn = p[near]
        sc = score_pose(pn, fit.t, fit.yaw, model, cfg)
        t, yaw = fit.t, fit.yaw
        if np.count_nonzero(sc.inliers) >= cfg.min_fit_points:
            pi = pn[sc.inliers]
            if len(pi) > cfg.fit_max_points:
                pi = pi[rng.choice(len(pi), cfg.fit_max_points, replace=False)]
            t, yaw = icp_4dof(pi, t, yaw, model, cfg, coarse_iterations=0)
            sc = score_pose(pn, t, yaw, model, cfg)
        sigma_across = float("nan")
        n_model = int(np.count_nonzero(sc.inliers))
        mesh_d = None  # (the pose scored, its points' distances to the full mesh), when computed
        if cfg.ray_refine and n_model >= cfg.min_fit_points:
            s = np.zeros(3) if sensor_position_m is None else np.asarray(sensor_position_m, dtype=np.float64)
            blk = np.zeros(n_all, dtype=bool)
            mesh_d = (sc, model.mesh_distance((pn - t) @ sc.R))
            blk[gate[near[mesh_d[1] < cfg.mask_distance_m]]] = True
            half1 = float(np.clip(cfg.ray_window_steps * step_m, cfg.ray_window_min_m, cfg.ray_window_max_m))
            reach = max(half1, float(np.abs(np.asarray(AMBIGUOUS_SHIFTS_M)).max()))  # window or a shift
            rays = ray_evidence(pts, blk, t, yaw, s, reach, model, cfg, rng)
            t1, yaw1 = steps.pick(rays, t, yaw, model, cfg, pick_prior)
            if t1 is not t:  # the rays chose a shifted copy: polish it with the ICP
                t, yaw = icp_4dof(pn[sc.inliers], t1, yaw1, model, cfg, 0)
                sc = score_pose(pn, t, yaw, model, cfg)
            if n_model <= cfg.ray_refine_max_points:
                t, yaw, sigma_across = steps.refine(rays, t, yaw, half1, model, cfg, pick_prior)
            if t is not sc.t or yaw != sc.yaw:  # (a pose the rays kept is scored already)
                sc = score_pose(pn, t, yaw, model, cfg)
        fit = sc
        if mesh_d is not None and mesh_d[0] is fit:
            on_block = mesh_d[1] < cfg.mask_distance_m
        else:
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
