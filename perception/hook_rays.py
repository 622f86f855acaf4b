"""Step 4c of the hook stage (perception.hook): ray consistency. The beams, not just the points,
tell block poses apart: which beams hit the block, which passed it to the deck and at what range.
Used to pick between a fit and its copies one sheave pitch off, and to refine a sparse block's
pose on grids. Levelled frame, origin at the boom tip, metres."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from boomtip.data.block_model import AMBIGUOUS_SHIFTS_M, BODY_TOP_Z_M, BODY_XY_M, SHEAVE_CROWN_Z_M
from boomtip.perception.hook_block import BlockModel, hanging_pose, rot_z, rotation_hanging, rotations_z
from boomtip.perception.hook_types import HookConfig

__all__ = ["RayEvidence", "ray_evidence", "ray_sigma", "ray_pick", "ray_refine"]


def _ray_costs(model: BlockModel, t_c: np.ndarray, yaw_c: np.ndarray, offs: np.ndarray, dyaw: np.ndarray,
               s: np.ndarray, d: np.ndarray, r: np.ndarray, blk: np.ndarray, cfg: HookConfig):
    """Ray-consistency cost of C x Y x P poses: around each of C centres (t_c (C, 3), yaw_c (C,)),
    offsets (P, 2) across the rope and yaw offsets (Y,). Rays: origin s, unit directions d (K, 3),
    measured ranges r (K,), blk (K,) True for the block's points. One Open3D cast for all poses
    and rays (the centres of one search step together: their cost is numpy's per-call overhead
    more than the cast).

    Per pose the offset along the rays (~ along the rope) is solved in closed form (mean range
    residual of the block rays that hit). Cost per ray, clipped at c = ray_clip_m:
      block ray, model hit: min(e^2, c^2), e = measured - model range; block ray, model miss: c^2
      other ray, model hit: min(e^2, c^2) unless the point is well in front (occlusion: 0), so a
      ray that went PAST where the model puts the block (a deck point beside it) is a contradiction
      other ray, model miss: 0.
    Returns cost (C*Y*P,), reference points (C*Y*P, 3), yaws (C*Y*P,), centre by centre.
    """
    t_c, yaw_c = np.asarray(t_c, float).reshape(-1, 3), np.asarray(yaw_c, float).reshape(-1)
    C, Y, P, K = len(t_c), len(dyaw), len(offs), len(d)
    rays = np.empty((C, Y, P, K, 6), dtype=np.float32)
    Ts, yaws = [], []
    for c in range(C):  # a few centres: each one's poses as the single-centre search had them
        Ru = rotation_hanging(t_c[c])
        T = t_c[c][None] + offs @ Ru[:, :2].T  # (P, 3)
        yc = yaw_c[c] + dyaw
        Rys = Ru @ rotations_z(yc)  # (Y, 3, 3)
        rays[c, ..., :3] = ((s[None] - T) @ Rys)[:, :, None, :]  # ray origins, block frame
        rays[c, ..., 3:] = (d @ Rys)[:, None, :, :]  # ray directions, block frame
        Ts.append(T)
        yaws.append(yc)
    th = model.scene.cast_rays(o3d.core.Tensor.from_numpy(rays.reshape(-1, 6)))["t_hit"].numpy().reshape(C * Y * P, K)
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
    refs = np.concatenate([np.tile(T, (Y, 1)) for T in Ts]) + dz[:, None] * dm[None]
    return cost, refs, np.concatenate([np.repeat(yc, P) for yc in yaws])


@dataclass
class RayEvidence:
    s: np.ndarray  # (3,) sensor origin
    d: np.ndarray  # (K, 3) unit directions
    r: np.ndarray  # (K,) measured ranges
    blk: np.ndarray  # (K,) True for the block's points


def ray_evidence(pts: np.ndarray, blk_mask: np.ndarray, t0: np.ndarray, yaw0: float, s: np.ndarray,
                 reach_m: float, model: BlockModel, cfg: HookConfig, rng: np.random.Generator) -> RayEvidence:
    """The rays that can tell poses near (t0, yaw0) apart: every input point whose ray (from the
    sensor) passes within the model's reach of t0 and that is not far in front of it (occluders and
    rope carry nothing). Non-block rays only if they pass (at mid-height of the visible top, block
    frame of the given pose) within reach_m of the block's footprint: only those can be hit by a
    pose in the search. Subsampled to ray_max_block + ray_max_other."""
    a = t0 - s
    ra = float(np.linalg.norm(a))
    cos_lim = math.cos((model.radius_m + cfg.ray_cone_margin_m) / ra)
    # A ray in the cone with r > ra - 1 reaches along the cone's axis beyond cos_lim (ra - 1): a
    # cheap first cut (10 cm of slack for rounding) keeps the tests below to the few points near
    # the block's line of sight instead of the whole frame; they are the same tests on the same values.
    reach_along = cos_lim * max(ra - 1.0, 0.0) - 0.1 if cos_lim > 0 else -np.inf  # (a cone wider than 180 deg: no cut)
    near = np.flatnonzero(pts @ (a / ra) > float(s @ (a / ra)) + reach_along)
    v = pts[near] - s
    r = np.sqrt(np.einsum("ij,ij->i", v, v))
    ev = (v @ (a / ra) > cos_lim * r) & (r > ra - 1.0)
    ib = np.flatnonzero(ev & blk_mask[near])
    io = np.flatnonzero(ev & ~blk_mask[near])
    R0 = hanging_pose(t0, yaw0)
    ob = R0.T @ (s - t0)
    db = (v[io] / r[io, None]) @ R0
    lam = (0.5 * (SHEAVE_CROWN_Z_M + BODY_TOP_Z_M) - ob[2]) / np.minimum(db[:, 2], -1e-6)
    xy = ob[None, :2] + lam[:, None] * db[:, :2]
    out = np.maximum(np.abs(xy) - 0.5 * np.asarray(BODY_XY_M), 0.0)
    io = io[np.hypot(out[:, 0], out[:, 1]) < reach_m + 0.15]
    ib, io = near[ib], near[io]  # indices into the frame, as the subsampling draws them
    if len(ib) > cfg.ray_max_block:
        ib = rng.choice(ib, cfg.ray_max_block, replace=False)
    if len(io) > cfg.ray_max_other:
        io = rng.choice(io, cfg.ray_max_other, replace=False)
    idx = np.searchsorted(near, np.concatenate([ib, io]))  # back to rows of v and r
    blk = np.zeros(len(idx), dtype=bool)
    blk[: len(ib)] = True
    return RayEvidence(s, v[idx] / r[idx, None], r[idx], blk)


def ray_sigma(cfg: HookConfig, t: np.ndarray) -> float:
    """Range noise of the block's returns at the block's range (see ``ray_sigma_per_m``)."""
    r = float(np.linalg.norm(t))
    return max(cfg.ray_sigma_m, min(cfg.ray_sigma_per_m * r, cfg.ray_sigma_max_m))


def prior_nats(refs: np.ndarray, prior: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """-log N(ref; prior) up to a constant for each row of refs (0 without a prior)."""
    if prior is None:
        return np.zeros(len(refs))
    d = refs - prior[0]
    return 0.5 * np.einsum("ij,ij->i", d, np.linalg.solve(prior[1], d.T).T)


def ray_pick(rays: RayEvidence, t: np.ndarray, yaw: float, model: BlockModel, cfg: HookConfig,
             prior: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, float]:
    """Of the fitted pose and its near-symmetric copies (AMBIGUOUS_SHIFTS_M, one sheave pitch along
    the axle: a partly hidden block can be fitted one pitch off, with the same point-to-model RMS),
    the one the rays agree with best: the wrong copy puts the block on rays that went past it.
    With a sparse block the rays often cannot tell; a filter prediction ``prior`` = (mean,
    covariance) then joins the choice: the copy with
    the least ray cost / (2 ray_sigma^2) + Mahalanobis^2 / 2. The prior only picks the copy; the
    fix itself comes from the rays and points (no double counting in the filter)."""
    R = hanging_pose(t, yaw)
    cands = np.array([t] + [t + R @ np.asarray(sh) for sh in AMBIGUOUS_SHIFTS_M])
    cost, refs, _ = _ray_costs(model, cands, np.full(len(cands), yaw), np.zeros((1, 2)), np.zeros(1), rays.s, rays.d,
                               rays.r, rays.blk, cfg)
    nats = cost / (2 * ray_sigma(cfg, t) ** 2) + prior_nats(refs, prior)
    k = int(np.argmin(nats))
    return (t, yaw) if k == 0 else (refs[k], yaw)


def ray_refine(rays: RayEvidence, t0: np.ndarray, yaw0: float, half1: float, model: BlockModel,
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
         Mahalanobis distance, as in :func:`ray_pick`: the coarse grid spans a sheave pitch);
      3. a fine grid around it: the estimate is its posterior mean, weights exp(-cost / 2 sigma^2),
         the centre of the poses the rays cannot tell apart rather than an arbitrary one of them.
    """
    inv2s2 = 1.0 / (2 * ray_sigma(cfg, t0) ** 2)

    def grid(t_c, yaw_c, half, n, yaw_half, n_yaw):
        """The poses on a grid about each centre (t_c (C, 3) or (3,), yaw_c (C,) or scalar)."""
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
    ks = np.argsort(cost * inv2s2 + prior_nats(refs, prior))[: cfg.ray_starts]
    c2, r2, y2 = grid(refs[ks], yaws[ks], step1, n2, ystep1, ny2)  # the local grids together
    per = len(c2) // len(ks)
    for a in range(0, len(c2), per):  # each local grid's best, in the coarse order
        j = a + int(np.argmin(c2[a:a + per]))
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

