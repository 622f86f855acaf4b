"""A frozen earlier implementation of the hook stage's block fit (perception.hook_fit) and
ray-consistency steps (perception.hook_rays), docstrings left out: the baseline that `boomtip
bench hook` times the stage against in the same run, with the same algorithms (one ICP per start,
one ray cast per pose grid). No run uses it."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d

from boomtip.data.block_model import AMBIGUOUS_SHIFTS_M, BODY_XY_M
from boomtip.perception.hook_block import BlockModel, block_model, hanging_pose, rot_z, rotation_hanging
from boomtip.perception.hook_fit import BlockFit, initial_guesses
from boomtip.perception.hook_rays import RayEvidence, prior_nats, ray_sigma
from boomtip.perception.hook import BlockSteps
from boomtip.perception.hook_types import HookConfig

__all__ = ["REFERENCE_STEPS", "fit_block", "ray_pick", "ray_refine"]


def icp_4dof(p: np.ndarray, t0: np.ndarray, yaw0: float, model: BlockModel, cfg: HookConfig,
             coarse_iterations: int, max_iterations: int | None = None) -> tuple[np.ndarray, float]:
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
    R = hanging_pose(t, yaw)
    d, _ = model.nearest((p - t) @ R)
    inl = d < cfg.icp_final_correspondence_m
    rms = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    return BlockFit(t, yaw, R, rms, inl)


def fit_block(p: np.ndarray, cfg: HookConfig, rng: np.random.Generator, prior_t: np.ndarray | None = None) -> BlockFit:
    model = block_model(cfg.block_height_m, cfg.model_points)
    ps = p if len(p) <= cfg.fit_max_points else p[rng.choice(len(p), cfg.fit_max_points, replace=False)]

    def better(a: BlockFit | None, b: BlockFit) -> bool:
        return a is None or (b.inliers.sum(), -b.rms) > (a.inliers.sum(), -a.rms)

    best: BlockFit | None = None
    starts = initial_guesses(ps, cfg)
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


def _ray_costs(model: BlockModel, t_c: np.ndarray, yaw_c: float, offs: np.ndarray, dyaw: np.ndarray,
               s: np.ndarray, d: np.ndarray, r: np.ndarray, blk: np.ndarray, cfg: HookConfig):
    Ru = rotation_hanging(t_c)
    T = t_c[None] + offs @ Ru[:, :2].T  # (P, 3)
    yaws = yaw_c + dyaw
    Rys = np.stack([Ru @ rot_z(y) for y in yaws])  # (Y, 3, 3)
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


def ray_pick(rays: RayEvidence, t: np.ndarray, yaw: float, model: BlockModel, cfg: HookConfig,
             prior: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, float]:
    R = hanging_pose(t, yaw)
    cands = [t] + [t + R @ np.asarray(sh) for sh in AMBIGUOUS_SHIFTS_M]
    costs = [_ray_costs(model, c, yaw, np.zeros((1, 2)), np.zeros(1), rays.s, rays.d, rays.r, rays.blk, cfg)
             for c in cands]
    refs = np.array([c[1][0] for c in costs])
    nats = np.array([c[0][0] for c in costs]) / (2 * ray_sigma(cfg, t) ** 2) + prior_nats(refs, prior)
    k = int(np.argmin(nats))
    return (t, yaw) if k == 0 else (refs[k], yaw)


def ray_refine(rays: RayEvidence, t0: np.ndarray, yaw0: float, half1: float, model: BlockModel,
               cfg: HookConfig, prior: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, float, float]:
    inv2s2 = 1.0 / (2 * ray_sigma(cfg, t0) ** 2)

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
    for k in np.argsort(cost * inv2s2 + prior_nats(refs, prior))[: cfg.ray_starts]:
        c2, r2, y2 = grid(refs[k], float(yaws[k]), step1, n2, ystep1, ny2)
        j = int(np.argmin(c2))
        score = float(c2[j]) * inv2s2 + float(prior_nats(r2[j:j + 1], prior)[0])
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


# the reference block fit and ray steps, for perception.hook.detect_hook's `steps`
REFERENCE_STEPS = BlockSteps(fit_block, ray_pick, ray_refine)
