"""Step 4a-b of the hook stage (perception.hook): the known block model fitted to a cluster by a
4-DOF ICP (yaw about the rope + translation, the block hanging along the line from the tip),
from a few starting poses. Levelled frame, origin at the boom tip, metres."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from boomtip.data.block_model import SHEAVE_CROWN_Z_M
from boomtip.perception.hook_block import BlockModel, block_model, hanging_pose, rot_z, rotation_hanging
from boomtip.perception.hook_types import HookConfig

__all__ = ["BlockFit", "icp_4dof", "score_pose", "fit_block"]


@dataclass
class BlockFit:
    """One posed model scored against a set of points."""

    t: np.ndarray  # reference point, levelled frame
    yaw: float
    R: np.ndarray  # block orientation, levelled <- block
    rms: float  # RMS of the inliers' distances to the model
    inliers: np.ndarray  # bool over the points scored


def icp_4dof(p: np.ndarray, t0: np.ndarray, yaw0: float, model: BlockModel, cfg: HookConfig,
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
    pts = model.points
    for it in range(cfg.icp_iterations if max_iterations is None else max_iterations):
        coarse = it < coarse_iterations
        thr = cfg.icp_max_correspondence_m if coarse else cfg.icp_final_correspondence_m
        Ru = rotation_hanging(t)
        Rz = rot_z(yaw)
        # model frame: Rz^T Ru^T (p - t), one 3 x 3 product for all points
        q = p @ (Ru @ Rz) - (t @ Ru) @ Rz
        d, idx = model.nearest_grid(q)
        ok = d < thr
        n_ok = int(np.count_nonzero(ok))
        if n_ok < 3:
            break
        if n_ok == len(ok):
            m, x = pts[idx], p @ Ru  # the points in the rope frame (absolute)
        else:
            m, x = pts[idx[ok]], p[ok] @ Ru
        mc, xc = m.mean(axis=0), x.mean(axis=0)
        # 2-D Procrustes: the cross-covariance of the centred xy coordinates
        H = (m[:, :2] - mc[:2]).T @ (x[:, :2] - xc[:2])
        yaw_new = math.atan2(float(H[0, 1] - H[1, 0]), float(H[0, 0] + H[1, 1]))
        t_new = Ru @ (xc - rot_z(yaw_new) @ mc)
        dt = t_new - t
        step = math.sqrt(float(dt @ dt))
        t, yaw = t_new, yaw_new
        if step < cfg.icp_tolerance_m and not coarse:
            break
    return t, yaw


def score_pose(p: np.ndarray, t: np.ndarray, yaw: float, model: BlockModel, cfg: HookConfig) -> BlockFit:
    """Exact residuals of p against the posed model; inliers within the final correspondence cut."""
    R = hanging_pose(t, yaw)
    d, _ = model.nearest((p - t) @ R)
    inl = d < cfg.icp_final_correspondence_m
    rms = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    return BlockFit(t, yaw, R, rms, inl)


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


def fit_block(p: np.ndarray, cfg: HookConfig, rng: np.random.Generator, prior_t: np.ndarray | None = None) -> BlockFit:
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

    def better(a: BlockFit | None, b: BlockFit) -> bool:
        return a is None or (b.inliers.sum(), -b.rms) > (a.inliers.sum(), -a.rms)

    best: BlockFit | None = None
    starts = _initial_guesses(ps, cfg)
    if prior_t is not None:
        starts += [(np.asarray(prior_t, float), starts[0][1] + dy) for dy in (0.0, math.pi / 2)]
    for t0, y0 in starts:
        t, yaw = icp_4dof(ps, t0, y0, model, cfg, cfg.icp_coarse_iterations)
        cand = score_pose(p, t, yaw, model, cfg)
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
            t, yaw = icp_4dof(ps, t_top + sh * ax, y, model, cfg, cfg.icp_coarse_iterations,
                              max_iterations=cfg.icp_coarse_iterations)
            coarse.append(score_pose(ps, t, yaw, model, cfg))
    coarse.sort(key=lambda f: (-f.inliers.sum(), f.rms))
    for c in coarse[:2]:
        t, yaw = icp_4dof(ps, c.t, c.yaw, model, cfg, 0)
        cand = score_pose(p, t, yaw, model, cfg)
        if better(best, cand):
            best = cand
    return best

