"""Steps 2-3 of the hook stage (perception/hook_segment.py) on synthetic clouds: the large-plane
mask (removal only in the cells of large horizontal patches, so a block in a plane's shadow, or
level with a cargo top elsewhere, stays), the rope-line mask, single-linkage clustering and the
cluster extent; then the choice perception.hook makes from those labels and extents: the
block-sized cluster nearest the prior. Levelled frame, origin at the boom tip, z up, metres."""

from __future__ import annotations

import math

import numpy as np
import pytest

from boomtip.data.block_model import lower_block_mesh, visible_model_points
from boomtip.perception.hook import detect_hook
from boomtip.perception.hook_segment import cluster_extent, cluster_labels, large_plane_mask, rope_line_mask
from boomtip.perception.hook_types import HookConfig

CFG = HookConfig()
DECK_Z = -30.0
CELL_M = 0.5


def grid(x0, x1, y0, y1, z, step):
    xs, ys = np.meshgrid(np.arange(x0, x1 + 1e-9, step), np.arange(y0, y1 + 1e-9, step), indexing="ij")
    return np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)])


def without(p, cx, cy, hx, hy):
    """p less a rectangular footprint (a shadow: nothing behind an object reaches the plane)."""
    return p[~((np.abs(p[:, 0] - cx) < hx) & (np.abs(p[:, 1] - cy) < hy))]


def labelled(*parts):
    pts = np.vstack(parts)
    lab = np.concatenate([np.full(len(p), k) for k, p in enumerate(parts)])
    return pts + np.random.default_rng(3).normal(0.0, 0.01, pts.shape), lab


def removed_per_part(mask, lab):
    return [int(np.count_nonzero(mask[lab == k])) for k in range(lab.max() + 1)]


# ---------------------------------------------------------------------------------------
# Large planes


def _block(z_bottom):
    """A 2.4 x 1.2 m block: its bottom 0.1 m above z_bottom, its top 3 m up."""
    return (grid(-1.2, 1.2, -0.6, 0.6, z_bottom + 0.1, 0.2), grid(-1.2, 1.2, -0.6, 0.6, z_bottom + 3.0, 0.2))


def test_the_deck_goes_and_a_block_in_its_shadow_stays():
    deck = without(grid(-10, 10, -10, 10, DECK_Z, 0.25), 0, 0, 2.5, 2.0)  # the block's shadow
    below = without(grid(-8, 8, -8, 8, DECK_Z - 1.0, 1.0), 0, 0, 2.5, 2.0)  # returns under the deck
    low, top = _block(DECK_Z)
    under = grid(-1.0, 1.0, -0.5, 0.5, DECK_Z - 0.3, 0.25)  # block points even below the deck's height
    pts, lab = labelled(deck, below, low, top, under)
    mask = large_plane_mask(pts, CFG, CELL_M, np.random.default_rng(0))
    assert removed_per_part(mask, lab) == [len(deck), len(below), 0, 0, 0]


def test_without_the_shadow_the_band_would_take_the_blocks_low_points():
    """The same block over a deck with no hole: its bottom, 0.1 m above the deck (inside the
    0.25 m band), shares the deck's cells and goes; its top stays. The shadow is what keeps it."""
    deck = grid(-10, 10, -10, 10, DECK_Z, 0.25)
    low, top = _block(DECK_Z)
    pts, lab = labelled(deck, low, top)
    mask = large_plane_mask(pts, CFG, CELL_M, np.random.default_rng(0))
    assert removed_per_part(mask, lab) == [len(deck), len(low), 0]


def test_block_points_level_with_a_large_cargo_top_are_their_own_small_patch():
    """An 8 x 3 m cargo top 3 m above the deck is a large plane; the block's bottom, 6 m away
    at the same height, is an inlier of that plane but a patch of its own (2.4 m < 6 m): it stays."""
    deck = without(without(grid(-10, 10, -10, 10, DECK_Z, 0.25), 5.5, 0, 4.2, 1.7), -5.0, 0, 2.5, 2.0)
    cargo = grid(1.5, 9.5, -1.5, 1.5, DECK_Z + 3.0, 0.25)
    low = grid(-6.2, -3.8, -0.6, 0.6, DECK_Z + 3.0, 0.2)
    top = grid(-6.2, -3.8, -0.6, 0.6, DECK_Z + 5.0, 0.2)
    pts, lab = labelled(deck, cargo, low, top)
    for seed in range(5):  # whatever the RANSAC draws
        mask = large_plane_mask(pts, CFG, CELL_M, np.random.default_rng(seed))
        assert removed_per_part(mask, lab) == [len(deck), len(cargo), 0, 0], seed


def test_no_plane_larger_than_the_block_removes_nothing():
    top = grid(0, 2.4, 0, 1.2, DECK_Z, 0.1)  # a 2.4 x 1.2 m horizontal face, 325 points
    assert not large_plane_mask(top, CFG, CELL_M, np.random.default_rng(0)).any()
    few = grid(-10, 10, -10, 10, DECK_Z, 10.0)  # a large deck with fewer points than plane_min_inliers
    assert len(few) == 9 < CFG.plane_min_inliers
    assert not large_plane_mask(few, CFG, CELL_M, np.random.default_rng(0)).any()
    off = HookConfig(max_planes=0)
    deck = grid(-10, 10, -10, 10, DECK_Z, 0.25)
    assert not large_plane_mask(deck, off, CELL_M, np.random.default_rng(0)).any()


# ---------------------------------------------------------------------------------------
# The rope


U = np.array([0.05, -0.03, -1.0]) / math.sqrt(0.05**2 + 0.03**2 + 1.0)  # a swaying rope
E1 = np.cross(U, [1.0, 0.0, 0.0])
E1 /= np.linalg.norm(E1)
E2 = np.cross(U, E1)


def on_line(t, r, angle):
    """The point t along the line from the tip and r from it."""
    return t * U + r * (math.cos(angle) * E1 + math.sin(angle) * E2)


T_ROPE = np.arange(1.0, 20.0, 0.1)
ROPE = np.array([on_line(t, 0.05, 0.7 * k) for k, t in enumerate(T_ROPE)])
# the block below: a crown under the line (within the rope radius) and its body around it, at
# 20.0 m along the line and below
CROWN = np.array([on_line(20.0 + 0.05 * (k % 4), 0.1, 1.3 * k) for k in range(12)])
BODY = np.array([on_line(20.0 + 0.1 * (k % 5), 0.3 + 0.1 * (k % 12), 0.5 * k) for k in range(60)])


def test_rope_points_end_a_margin_above_the_block_top():
    pts = np.vstack([ROPE, CROWN, BODY])
    mask = rope_line_mask(pts, U, CFG)
    t_top = 20.0  # the highest block points near the line (2nd highest: the same here)
    expected = np.concatenate([T_ROPE < t_top - CFG.rope_top_margin_m, np.zeros(len(CROWN) + len(BODY), bool)])
    assert np.array_equal(mask, expected)
    assert 0 < np.count_nonzero(~expected[: len(ROPE)])  # the last 0.9 m of rope stays for the block fit


def test_one_stray_point_beside_the_line_does_not_cut_the_rope():
    stray = on_line(8.0, 1.0, 0.2)  # 1 m beside the line (within the 1.6 m 'near' radius), high up
    pts = np.vstack([ROPE, CROWN, BODY, stray])
    mask = rope_line_mask(pts, U, CFG)
    assert np.array_equal(mask[: len(ROPE)], T_ROPE < 20.0 - CFG.rope_top_margin_m)
    assert not mask[len(ROPE):].any()


def test_without_a_block_beside_the_line_everything_on_it_is_rope():
    pts = np.vstack([ROPE, CROWN, on_line(8.0, 1.0, 0.2)])  # one point near the line is not a block
    mask = rope_line_mask(pts, U, CFG)
    assert mask[: len(ROPE) + len(CROWN)].all() and not mask[-1]


def test_the_rope_radius_decides_what_is_on_the_line():
    # one point beside the line (0.26 m) is no block top: the points on the line are all rope
    pts = np.array([on_line(5.0, r, 0.4) for r in (0.0, 0.1, 0.24, 0.26)])
    assert rope_line_mask(pts, U, CFG).tolist() == [True, True, True, False]


# ---------------------------------------------------------------------------------------
# Clusters


def _same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    pairs = {(int(x), int(y)) for x, y in zip(a, b)}
    return len(pairs) == len(set(a.tolist())) == len(set(b.tolist()))


@pytest.mark.parametrize("method", ["kdtree", "dbscan", "auto"])
def test_single_linkage_chains_and_splits_at_eps(method):
    chain = np.column_stack([0.27 * np.arange(20), np.zeros(20), np.zeros(20)])  # 0.27 apart: one cluster
    gap = chain[-1] + [0.33, 0.0, 0.0]  # 0.33 beyond its end: a cluster of its own
    far = np.array([[50.0, 50.0, 50.0]])
    lab = cluster_labels(np.vstack([chain, gap, far]), 0.3, method)
    assert lab.dtype == np.int64 and (lab >= 0).all()
    assert len(set(lab[:20].tolist())) == 1
    assert len({lab[0], lab[20], lab[21]}) == 3


def test_the_kdtree_and_dbscan_routes_give_the_same_partition():
    rng = np.random.default_rng(2)
    centres = rng.uniform(-10, 10, (12, 3))
    pts = np.vstack([c + rng.normal(0, 0.3, (40, 3)) for c in centres] + [rng.uniform(-12, 12, (60, 3))])
    for eps in (0.2, 0.4, 0.8):
        a, b = cluster_labels(pts, eps, "kdtree"), cluster_labels(pts, eps, "dbscan")
        assert _same_partition(a, b), eps
        assert (b >= 0).all()  # min_points=1: DBSCAN leaves no noise
    assert _same_partition(cluster_labels(pts, 0.4, "auto", auto_points=len(pts) + 1), cluster_labels(pts, 0.4, "dbscan"))
    assert _same_partition(cluster_labels(pts, 0.4, "auto", auto_points=len(pts)), cluster_labels(pts, 0.4, "kdtree"))


def test_the_routes_agree_on_a_pair_exactly_eps_apart():
    pts = np.array([[0.0, 0.0, 0.0], [0.25, 0.0, 0.0]])  # 0.25 is exact in binary
    assert _same_partition(cluster_labels(pts, 0.25, "kdtree"), cluster_labels(pts, 0.25, "dbscan"))


def test_no_points_no_labels():
    for method in ("kdtree", "dbscan", "auto"):
        lab = cluster_labels(np.zeros((0, 3)), 0.3, method)
        assert lab.shape == (0,) and lab.dtype == np.int64


@pytest.mark.parametrize("yaw_deg", [0.0, 30.0, 90.0, 137.0])
def test_cluster_extent_is_the_box_diagonal_whatever_the_yaw(yaw_deg):
    # the corners and a regular grid of a 2.5 x 1.2 x 1.0 m box: the principal axes are its sides
    xs, ys, zs = np.meshgrid(np.linspace(-1.25, 1.25, 11), np.linspace(-0.6, 0.6, 7), np.linspace(-20, -19, 5))
    box = np.column_stack([xs.ravel(), ys.ravel(), zs.ravel()])
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    box = box @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + [3.0, -2.0, 0.0]
    assert cluster_extent(box) == pytest.approx(math.sqrt(2.5**2 + 1.2**2 + 1.0**2), rel=1e-12)


def test_cluster_extent_of_fewer_than_two_points_is_zero():
    assert cluster_extent(np.zeros((0, 3))) == 0.0 and cluster_extent(np.ones((1, 3))) == 0.0
    assert cluster_extent(np.array([[0, 0, 0], [0, 0, -2.0]])) == pytest.approx(2.0)


# ---------------------------------------------------------------------------------------
# The block-sized cluster nearest the prior (the choice perception.hook makes)

REF = np.array([0.0, 0.0, -20.0])


@pytest.fixture(scope="module")
def scene():
    """A block (300 points of its model's visible top, extent 2.9 m) hanging at REF; a stray
    blob (extent 0.2 m) 2.6 m away; a 7 x 4 m vertical wall (extent 8.1 m, not a horizontal
    plane, so the plane step keeps it) 5 m away; a 1.2 x 0.8 m flat decoy (extent 1.4 m) 4 m
    the other way. Only the block and the decoy are block-sized (0.5 to 6 m)."""
    rng = np.random.default_rng(5)
    block = visible_model_points(lower_block_mesh(4.0), 300) + REF
    stray = REF + np.array([2.5, 0.6, -0.3]) + rng.normal(0, 0.05, (10, 3))
    ys, zs = np.meshgrid(np.arange(-3.5, 3.51, 0.2), np.arange(-23.0, -18.99, 0.2), indexing="ij")
    wall = np.column_stack([np.full(ys.size, 5.0), ys.ravel(), zs.ravel()])
    decoy = grid(-4.6, -3.4, -0.4, 0.4, -20.5, 0.1)
    parts = {"block": block, "stray": stray, "wall": wall, "decoy": decoy}
    extents = {k: cluster_extent(v) for k, v in parts.items()}
    assert extents["stray"] < CFG.min_extent_m < extents["decoy"] < extents["block"] < CFG.max_extent_m < extents["wall"]
    return parts, extents


def _detect(parts, names, prior):
    pts = np.vstack([parts[n] for n in names])
    det = detect_hook(pts, prior, 20.0, CFG, np.random.default_rng(0))
    bounds = np.cumsum([0] + [len(parts[n]) for n in names])
    return det, {n: int(np.count_nonzero(det.points_mask[a:b])) for n, a, b in zip(names, bounds[:-1], bounds[1:])}


def _nearest(parts, prior):
    return sorted(parts, key=lambda n: float(np.min(np.linalg.norm(parts[n] - prior, axis=1))))


def test_the_block_sized_cluster_is_chosen_over_nearer_ones(scene):
    parts, extents = scene
    prior = REF + np.array([3.2, 0.0, -0.3])
    assert _nearest(parts, prior)[:3] == ["stray", "wall", "block"]  # the block is the third nearest
    det, kept = _detect(parts, list(parts), prior)
    assert det.status == "ok"
    assert det.cluster_extent_m == pytest.approx(extents["block"], rel=1e-12)
    assert kept == {"block": len(parts["block"]), "stray": 0, "wall": 0, "decoy": 0}
    assert np.linalg.norm(det.position_m - REF) < 0.02


def test_of_two_block_sized_clusters_the_nearer_is_chosen(scene):
    parts, extents = scene
    prior = np.array([-3.0, 0.0, -20.3])
    assert _nearest(parts, prior)[0] == "decoy"
    det, kept = _detect(parts, list(parts), prior)
    # the fit runs on the decoy (and, flat as it is, accepts it: 117 points at 7 cm RMS, within
    # max_fit_rms_m); the real block, farther from the prior, is not tried
    assert det.cluster_extent_m == pytest.approx(extents["decoy"], rel=1e-12)
    assert kept == {"block": 0, "stray": 0, "wall": 0, "decoy": len(parts["decoy"])}


def test_with_no_block_sized_cluster_the_nearest_says_why(scene):
    parts, extents = scene
    prior = REF + np.array([2.5, 0.0, -0.3])
    det, _ = _detect(parts, ["stray", "wall"], prior)
    assert det.status == f"nearest cluster too small (extent {extents['stray']:.1f} m)"
    assert det.cluster_extent_m == pytest.approx(extents["stray"], rel=1e-12)
    det, _ = _detect(parts, ["stray", "wall"], np.array([4.5, 0.0, -21.0]))
    assert det.status == f"nearest cluster too large: probably cargo (extent {extents['wall']:.1f} m)"
    assert det.cluster_extent_m == pytest.approx(extents["wall"], rel=1e-12)
