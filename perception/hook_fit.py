"""Step 4a-b of the hook stage (perception.hook): the known block model fitted to a cluster by a
4-DOF ICP (yaw about the rope + translation, the block hanging along the line from the tip),
from a few starting poses. Levelled frame, origin at the boom tip, metres."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from boomtip.data.block_model import SHEAVE_CROWN_Z_M
from boomtip.perception.hook_block import BlockModel, block_model, hanging_pose, rot_z, rotation_hanging, rotations_z
from boomtip.perception.hook_types import HookConfig

__all__ = ["BlockFit", "icp_4dof", "icp_4dof_starts", "score_pose", "score_poses", "fit_block"]


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


def _hanging_rotations(T: np.ndarray) -> np.ndarray:
    """(S, 3, 3): :func:`rotation_hanging` of each row of T (S, 3), the same formula on arrays."""
    nb = T / np.sqrt(np.einsum("ij,ij->i", T, T))[:, None]  # -b
    b = -nb
    k = 1.0 + b[:, 2]
    R = np.empty((len(T), 3, 3))
    R[:, :2, :2] = (b[:, :2, None] * nb[:, None, :2]) / k[:, None, None]  # (b_i * -b_j) / k
    R[:, 0, 0] += 1.0
    R[:, 1, 1] += 1.0
    R[:, :2, 2] = b[:, :2]
    R[:, 2, :2] = nb[:, :2]
    R[:, 2, 2] = 1.0 + (R[:, 2, 0] * b[:, 0] + R[:, 2, 1] * b[:, 1]) / k
    return R


def icp_4dof_starts(p: np.ndarray, T0: np.ndarray, yaw0: np.ndarray, model: BlockModel, cfg: HookConfig,
                    coarse_iterations: int, max_iterations: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`icp_4dof` from S starts at once (T0 (S, 3), yaw0 (S,)), each start iterating and
    stopping as it would alone; returns (T (S, 3), yaw (S,)). A far block gives the ICP a handful
    of points, so the cost of one ICP is numpy's per-call overhead: one call per step for all
    starts instead of one per start. The per-start sums run over all points with the rejected
    correspondences weighted zero (numpy sums them in the same order as the kept ones alone)."""
    T, yaw = np.array(T0, float).reshape(-1, 3), np.array(yaw0, float).reshape(-1)
    pts = model.points
    active = np.arange(len(T))
    Rz_active = rotations_z(yaw)  # the active starts' yaw rotations (each iteration's new yaws' are the next one's)
    for it in range(cfg.icp_iterations if max_iterations is None else max_iterations):
        if not len(active):
            break
        coarse = it < coarse_iterations
        thr = cfg.icp_max_correspondence_m if coarse else cfg.icp_final_correspondence_m
        t = T[active]
        Ru = _hanging_rotations(t)
        Rz = Rz_active
        # model frame: Rz^T Ru^T (p - t), as in icp_4dof
        q = p @ (Ru @ Rz) - ((t[:, None, :] @ Ru) @ Rz)
        d, idx = model.nearest_grid(q.reshape(-1, 3))
        ok = (d < thr).reshape(len(active), -1)
        n_ok = np.count_nonzero(ok, axis=1)
        live = n_ok >= 3  # fewer correspondences: that start stops where it is
        if not live.all():
            active, t, Ru, ok, n_ok = active[live], t[live], Ru[live], ok[live], n_ok[live]
            idx = idx.reshape(len(live), -1)[live].ravel()
            if not len(active):
                break
        w = ok[:, :, None]
        m = np.where(w, pts[idx].reshape(len(active), -1, 3), 0.0)
        x = np.where(w, p @ Ru, 0.0)  # the points in each start's rope frame
        mc, xc = m.sum(axis=1) / n_ok[:, None], x.sum(axis=1) / n_ok[:, None]
        # 2-D Procrustes per start: the cross-covariance of the centred xy coordinates
        H = np.einsum("sni,snj->sij", np.where(w[:, :, :2], m[:, :, :2] - mc[:, None, :2], 0.0), x[:, :, :2] - xc[:, None, :2])
        yaw_new = np.arctan2(H[:, 0, 1] - H[:, 1, 0], H[:, 0, 0] + H[:, 1, 1])
        Rz_active = rotations_z(yaw_new)
        t_new = np.einsum("sij,sj->si", Ru, xc - np.einsum("sij,sj->si", Rz_active, mc))
        dt = t_new - t
        T[active], yaw[active] = t_new, yaw_new
        if not coarse:
            going = np.sqrt(np.einsum("ij,ij->i", dt, dt)) >= cfg.icp_tolerance_m
            active, Rz_active = active[going], Rz_active[going]
    return T, yaw


def score_poses(p: np.ndarray, T: np.ndarray, yaws: np.ndarray, model: BlockModel, cfg: HookConfig) -> list[BlockFit]:
    """:func:`score_pose` of S poses (T (S, 3), yaws (S,)) with one KD-tree query."""
    R = _hanging_rotations(T) @ rotations_z(yaws)
    d, _ = model.nearest(((p[None] - T[:, None, :]) @ R).reshape(-1, 3))
    d = d.reshape(len(T), -1)
    out = []
    for k in range(len(T)):  # a few poses: the loop is over poses, not points
        inl = d[k] < cfg.icp_final_correspondence_m
        rms = float(np.sqrt(np.mean(d[k][inl] ** 2))) if inl.any() else float("inf")
        out.append(BlockFit(T[k], float(yaws[k]), R[k], rms, inl))
    return out


def initial_guesses(p: np.ndarray, cfg: HookConfig) -> list[tuple[np.ndarray, float]]:
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
    point, adds starts there (the cluster's yaw and the perpendicular one): a far block's few
    points can start the ICP in a wrong basin that still explains most of them.

    If none fits well (RMS above icp_good_rms_m + icp_good_rms_per_m * range), e.g. a partly
    occluded block, whose visible part is nearly square (poor principal axis) and whose top
    centroid is off-centre, retry from yaws every icp_retry_yaw_step_deg combined with shifts of
    +-icp_retry_shift_m along the block's long axis: each start runs the coarse ICP stage only, the
    two best then run to convergence. The starts of each round run together
    (:func:`icp_4dof_starts`, :func:`score_poses`).
    """
    model = block_model(cfg.block_height_m, cfg.model_points)
    ps = p if len(p) <= cfg.fit_max_points else p[rng.choice(len(p), cfg.fit_max_points, replace=False)]

    def better(a: BlockFit | None, b: BlockFit) -> bool:
        return a is None or (b.inliers.sum(), -b.rms) > (a.inliers.sum(), -a.rms)

    def best_of(fits: list[BlockFit], best: BlockFit | None) -> BlockFit | None:
        for cand in fits:  # in the starts' order: the first of equals wins
            if better(best, cand):
                best = cand
        return best

    starts = initial_guesses(ps, cfg)
    if prior_t is not None:
        starts += [(np.asarray(prior_t, float), starts[0][1] + dy) for dy in (0.0, math.pi / 2)]
    T, Y = icp_4dof_starts(ps, np.array([s[0] for s in starts]), np.array([s[1] for s in starts]), model, cfg,
                           cfg.icp_coarse_iterations)
    best = best_of(score_poses(p, T, Y, model, cfg), None)
    assert best is not None
    t_top = starts[0][0]
    if best.rms <= cfg.icp_good_rms_m + cfg.icp_good_rms_per_m * float(np.linalg.norm(t_top)):
        return best
    step = math.radians(cfg.icp_retry_yaw_step_deg)
    Ru = rotation_hanging(t_top)
    retry_t, retry_yaw = [], []
    for k in range(int(round(math.pi / step))):
        y = starts[0][1] + k * step
        ax = Ru @ np.array([math.cos(y), math.sin(y), 0.0])  # the block's long axis
        for sh in (0.0, -cfg.icp_retry_shift_m, cfg.icp_retry_shift_m):
            retry_t.append(t_top + sh * ax)
            retry_yaw.append(y)
    T, Y = icp_4dof_starts(ps, np.array(retry_t), np.array(retry_yaw), model, cfg, cfg.icp_coarse_iterations,
                           max_iterations=cfg.icp_coarse_iterations)
    coarse = score_poses(ps, T, Y, model, cfg)
    coarse.sort(key=lambda f: (-f.inliers.sum(), f.rms))
    top = coarse[:2]
    T, Y = icp_4dof_starts(ps, np.array([c.t for c in top]), np.array([c.yaw for c in top]), model, cfg, 0)
    return best_of(score_poses(p, T, Y, model, cfg), best)
