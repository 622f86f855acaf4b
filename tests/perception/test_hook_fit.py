"""The block fit's starts run together (perception.hook_fit.icp_4dof_starts, score_poses) and the
ray costs of several pose grids cast together (perception.hook_rays._ray_costs): the same poses
(to 1e-12 m: sums in another order) and the same costs as one start or one grid at a time."""

from __future__ import annotations

import math

import numpy as np

from boomtip.perception.hook_block import block_model, hanging_pose
from boomtip.perception.hook_fit import icp_4dof, icp_4dof_starts, score_pose, score_poses
from boomtip.perception.hook_rays import _ray_costs
from boomtip.perception.hook_types import HookConfig

CFG = HookConfig()


def _block_points(t: np.ndarray, yaw: float, n: int, seed: int) -> np.ndarray:
    """n model points posed at (t, yaw), with 1 cm noise and a stray point."""
    model = block_model(CFG.block_height_m, CFG.model_points)
    rng = np.random.default_rng(seed)
    q = model.points[rng.choice(len(model.points), n, replace=False)]
    p = q @ hanging_pose(t, yaw).T + t + rng.normal(0, 0.01, (n, 3))
    return np.vstack([p, t + [2.0, 0.0, 0.5]])


def test_starts_together_converge_as_each_alone():
    model = block_model(CFG.block_height_m, CFG.model_points)
    t_true, yaw_true = np.array([3.0, -2.0, -60.0]), 0.4
    rng = np.random.default_rng(1)
    for n in (6, 40, 300):  # a far block's few points and a near block's many
        p = _block_points(t_true, yaw_true, n, seed=n)
        T0 = t_true + rng.normal(0, 0.3, (7, 3))
        Y0 = yaw_true + rng.normal(0, 0.5, 7)
        T0[6] += [30.0, 0.0, 0.0]  # too far: fewer than 3 correspondences, stops where it is
        for coarse, max_it in ((CFG.icp_coarse_iterations, None), (CFG.icp_coarse_iterations, CFG.icp_coarse_iterations),
                               (0, None)):
            T, Y = icp_4dof_starts(p, T0, Y0, model, CFG, coarse, max_it)
            for k in range(len(T0)):
                t, y = icp_4dof(p, T0[k], float(Y0[k]), model, CFG, coarse, max_it)
                np.testing.assert_allclose(T[k], t, rtol=0, atol=1e-12)
                assert abs(Y[k] - y) < 1e-12
        np.testing.assert_array_equal(T[6], T0[6])
        fits = score_poses(p, T, Y, model, CFG)
        for k, f in enumerate(fits):
            g = score_pose(p, T[k], float(Y[k]), model, CFG)
            np.testing.assert_array_equal(f.inliers, g.inliers)
            assert f.rms == g.rms or abs(f.rms - g.rms) <= 1e-12 * g.rms  # batched rotations: the last bit
            np.testing.assert_allclose(f.R, g.R, rtol=0, atol=1e-14)
        best = max(fits, key=lambda f: (f.inliers.sum(), -f.rms))
        assert n < 10 or np.abs(best.t - t_true).max() < 0.05


def test_pose_grids_cast_together_cost_as_one_at_a_time():
    model = block_model(CFG.block_height_m, CFG.model_points)
    t, yaw = np.array([1.0, 2.0, -40.0]), 0.3
    p = _block_points(t, yaw, 60, seed=2)
    s = np.array([0.8, 0.1, 0.3])
    d = (p - s) / np.linalg.norm(p - s, axis=1, keepdims=True)
    r = np.linalg.norm(p - s, axis=1)
    blk = np.arange(len(p)) < 60
    g = np.linspace(-0.1, 0.1, 3)
    offs = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    dyaw = np.radians([-2.0, 0.0, 2.0])
    centres = t + np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, -0.2, 0.1]])
    yaws = yaw + np.array([0.0, 0.05, -math.pi / 2])
    cost, refs, ys = _ray_costs(model, centres, yaws, offs, dyaw, s, d, r, blk, CFG)
    assert cost.shape == (3 * 3 * 9,) and refs.shape == (81, 3)
    per = 27
    for c in range(3):
        c1, r1, y1 = _ray_costs(model, centres[c], yaws[c], offs, dyaw, s, d, r, blk, CFG)
        np.testing.assert_array_equal(cost[c * per:(c + 1) * per], c1)
        np.testing.assert_array_equal(refs[c * per:(c + 1) * per], r1)
        np.testing.assert_array_equal(ys[c * per:(c + 1) * per], y1)
    assert cost[per // 2] == cost[:per].min()  # the true pose is the first grid's best


def test_the_voxel_grid_built_in_slabs_answers_as_the_tree_does():
    """Each cell holds the model point nearest to its centre (the grid is built slab by slab)."""
    model = block_model(CFG.block_height_m, CFG.model_points)
    rng = np.random.default_rng(3)
    cells = np.column_stack([rng.integers(0, n, 3000) for n in model.shape])
    centres = model.lo + (cells + 0.5) * model.cell
    d, idx = model.tree.query(centres, distance_upper_bound=0.55 + model.cell)
    want = np.where(np.isfinite(d), idx, -1)
    assert np.array_equal(model.grid[tuple(cells.T)], want)
    assert np.count_nonzero(want >= 0) > 300 and np.count_nonzero(want < 0) > 300  # both kinds of cell tried


def test_the_ray_evidence_keeps_the_rays_a_test_on_every_point_keeps():
    """ray_evidence's first cut (along the line of sight) drops no ray the full tests keep."""
    from boomtip.perception.hook_rays import ray_evidence

    model = block_model(CFG.block_height_m, CFG.model_points)
    t, yaw, s = np.array([1.5, -1.0, -40.0]), 0.3, np.array([0.6, 0.4, -0.2])
    rng = np.random.default_rng(5)
    block = _block_points(t, yaw, 120, 1)
    deck = np.column_stack([rng.uniform(-15, 15, 4000), rng.uniform(-15, 15, 4000), np.full(4000, -46.0)])
    far = rng.normal(0, 20, (4000, 3)) + [0, 0, -20]  # everywhere, in front of and behind the block
    pts = np.vstack([block, deck, far])
    blk = np.zeros(len(pts), dtype=bool)
    blk[: len(block) - 1] = True
    cfg = CFG.model_copy(update={"ray_max_block": 10_000, "ray_max_other": 10_000})  # no subsample
    ev = ray_evidence(pts, blk, t, yaw, s, 0.5, model, cfg, np.random.default_rng(0))
    # the same tests on every point of the frame
    a = t - s
    ra = float(np.linalg.norm(a))
    v = pts - s
    r = np.sqrt(np.einsum("ij,ij->i", v, v))
    cos_lim = math.cos((model.radius_m + cfg.ray_cone_margin_m) / ra)
    ev_all = (v @ (a / ra) > cos_lim * r) & (r > ra - 1.0)
    got_block = {tuple(x) for x in (s + ev.d[ev.blk] * ev.r[ev.blk, None]).round(9)}
    assert got_block == {tuple(x) for x in pts[ev_all & blk].round(9)} and len(got_block) > 50
    assert 0 < np.count_nonzero(~ev.blk) < np.count_nonzero(ev_all & ~blk)  # the footprint test drops some
