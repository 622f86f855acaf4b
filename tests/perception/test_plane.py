"""Tests for perception.plane (LSQ / RANSAC planes, wire distance) and perception.multi_plane
(multi-plane deck selection)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from boomtip.perception.multi_plane import MultiPlaneConfig, multi_plane_deck
from boomtip.perception.plane import (
    RansacConfig,
    fit_plane_lsq,
    orient_plane_towards,
    ransac_plane,
    ransac_plane_cols,
    transform_plane,
    wire_plane_distance,
)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    return math.degrees(math.acos(min(1.0, abs(float(a @ b)))))


def tilted_normal(tilt_deg: float, azimuth_deg: float) -> np.ndarray:
    axis = np.array([math.cos(math.radians(azimuth_deg)), math.sin(math.radians(azimuth_deg)), 0.0])
    return Rotation.from_rotvec(axis * math.radians(tilt_deg)).apply([0.0, 0.0, 1.0])


def plane_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e1 = np.cross(n, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


# --------------------------------------------------------------------------------------
# LSQ and RANSAC
# --------------------------------------------------------------------------------------

def test_fit_plane_lsq_exact_and_oriented():
    rng = np.random.default_rng(0)
    n = tilted_normal(7.0, 30.0)
    e1, e2 = plane_basis(n)
    c = np.array([1.0, -2.0, -40.0])
    st = rng.uniform(-10, 10, (500, 2))
    pts = c + st[:, :1] * e1 + st[:, 1:] * e2
    plane = fit_plane_lsq(pts)
    assert plane[3] > 0  # sensor origin on the positive side
    assert np.linalg.norm(plane[:3]) == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(pts @ plane[:3] + plane[3], 0.0, atol=1e-9)
    assert angle_deg(plane[:3], n) < 1e-7
    # the normal points towards the sensor (which is above this plane)
    assert plane[:3] @ n > 0
    # a plane ABOVE the sensor gets the normal pointing down (still d > 0)
    plane_up = fit_plane_lsq(pts * [1, 1, -1])
    assert plane_up[3] > 0 and plane_up[2] < 0
    with pytest.raises(ValueError):
        fit_plane_lsq(pts[:2])


def _plane_with_outliers(rng, n_pts=20000, outlier_frac=0.3, noise=0.01):
    n = tilted_normal(4.0, 110.0)
    e1, e2 = plane_basis(n)
    c = np.array([3.0, -5.0, -38.0])
    n_in = int(n_pts * (1 - outlier_frac))
    st = rng.uniform(-20, 20, (n_in, 2))
    inl = c + st[:, :1] * e1 + st[:, 1:] * e2 + rng.normal(0, noise, (n_in, 1)) * n
    out = rng.uniform(c - [20, 20, 6], c + [20, 20, 6], (n_pts - n_in, 3))
    pts = np.vstack([inl, out])
    perm = rng.permutation(n_pts)
    truth = orient_plane_towards(np.concatenate([n, [-n @ c]]))
    is_inlier = np.r_[np.ones(n_in, bool), np.zeros(n_pts - n_in, bool)][perm]
    return pts[perm], truth, is_inlier


def test_ransac_plane_with_30pct_outliers():
    rng = np.random.default_rng(1)
    pts, truth, is_inlier = _plane_with_outliers(rng)
    fit = ransac_plane(pts, RansacConfig(), rng)
    assert fit is not None
    assert fit.plane[3] > 0
    assert angle_deg(fit.plane[:3], truth[:3]) < 0.1
    assert abs(fit.plane[3] - truth[3]) < 0.002
    assert fit.plane[:3] @ truth[:3] > 0  # same orientation as the truth (towards the sensor)
    # inlier mask: nearly all true inliers, and the RMS is the 1 cm noise (truncated at 5 cm)
    assert np.count_nonzero(fit.inlier_mask & is_inlier) > 0.99 * np.count_nonzero(is_inlier)
    assert 0.008 < fit.rms_m < 0.012
    assert 0.69 < fit.inlier_ratio < 0.72
    # plain least squares on everything is badly off: the outliers matter
    lsq = fit_plane_lsq(pts)
    assert angle_deg(lsq[:3], truth[:3]) > 0.1 or abs(lsq[3] - truth[3]) > 0.002


def test_ransac_on_columns_is_ransac_and_carries_the_inliers_moments():
    rng = np.random.default_rng(11)
    pts, _, _ = _plane_with_outliers(rng)
    fit = ransac_plane(pts, RansacConfig(), np.random.default_rng(3))
    fit_cols = ransac_plane_cols(np.ascontiguousarray(pts.T), RansacConfig(), np.random.default_rng(3))
    assert np.array_equal(fit.plane, fit_cols.plane) and np.array_equal(fit.inlier_mask, fit_cols.inlier_mask)
    inl = pts[fit.inlier_mask]
    assert np.allclose(fit.centroid, inl.mean(axis=0), atol=1e-12)
    scatter = (inl - inl.mean(axis=0)).T @ (inl - inl.mean(axis=0))
    assert np.allclose(fit.scatter_evecs @ np.diag(fit.scatter_evals) @ fit.scatter_evecs.T, scatter, rtol=1e-9, atol=1e-9)
    # the plane is the scatter's smallest eigenvector through the centroid
    assert angle_deg(fit.plane[:3], fit.scatter_evecs[:, 0]) < 1e-6
    assert abs(fit.plane[:3] @ fit.centroid + fit.plane[3]) < 1e-12


def test_ransac_adaptive_stop_and_none_cases():
    rng = np.random.default_rng(2)
    pts, _, _ = _plane_with_outliers(rng, n_pts=5000, outlier_frac=0.1)
    fit = ransac_plane(pts, RansacConfig(batch_size=32), rng)
    # inlier ratio 0.9: 9 hypotheses are enough for 0.999, one batch of 32 is drawn
    assert fit is not None and fit.iterations == 32
    assert ransac_plane(np.zeros((2, 3)), RansacConfig(), rng) is None
    assert ransac_plane(np.zeros((0, 3)), RansacConfig(), rng) is None
    # pure noise in a big box: no plane has 30 % of the points within 1 mm
    noise = rng.uniform(-10, 10, (3000, 3))
    assert ransac_plane(noise, RansacConfig(distance_threshold_m=0.001, min_inliers=900), rng) is None


def test_ransac_axis_constraint():
    rng = np.random.default_rng(3)
    # a big vertical wall and a smaller horizontal floor
    wall = np.column_stack([rng.uniform(-10, 10, 6000), np.full(6000, 5.0), rng.uniform(-30, -10, 6000)])
    floor = np.column_stack([rng.uniform(-10, 10, 3000), rng.uniform(-10, 4, 3000), np.full(3000, -30.0)])
    pts = np.vstack([wall, floor])
    free = ransac_plane(pts, RansacConfig(), rng)
    assert abs(free.plane[1]) > 0.99  # the wall wins without a constraint
    horiz = ransac_plane(pts, RansacConfig(), rng, axis=np.array([0, 0, 1.0]), max_axis_angle_deg=15)
    assert horiz.plane[2] > 0.99 and horiz.plane[3] == pytest.approx(30.0, abs=1e-3)


# --------------------------------------------------------------------------------------
# Multi-plane deck scene
# --------------------------------------------------------------------------------------
def make_deck_scene(rng: np.random.Generator, n_deck: int = 40000, noise: float = 0.02, n_sea: int = 150):
    """Levelled frame (z up, sensor at the origin) -> returns points in a tilted SENSOR frame.

    Feeder deck 80 m x 24 m, 40 m below the sensor, tilted 3 deg; four cargo boxes with tops 3-8 m
    above the deck covering 40 % of it (plus their side walls); the crane vessel's own deck 8 m higher,
    to one side, with its hull side; ``n_sea`` sea points 5 m below the deck.
    Labels: 0 deck, 1 cargo top, 2 cargo side, 3 crane deck, 4 crane hull, 5 sea.
    """
    n = tilted_normal(3.0, 60.0)
    e1, e2 = plane_basis(n)
    c = np.array([0.0, 0.0, -40.0])
    st = np.column_stack([rng.uniform(-40, 40, n_deck), rng.uniform(-12, 12, n_deck)])
    # four boxes of 16 m x 12 m = 768 m^2 of 1920 m^2 = 40 %
    boxes = [((-36, -20), (-12, 0), 3.0), ((-10, 6), (0, 12), 5.0), ((12, 28), (-12, 0), 8.0), ((22, 38), (0, 12), 4.0)]
    h = np.zeros(n_deck)
    for (s0, s1), (t0, t1), hb in boxes:
        inside = (st[:, 0] >= s0) & (st[:, 0] < s1) & (st[:, 1] >= t0) & (st[:, 1] < t1)
        h[inside] = hb
    deck_like = c + st[:, :1] * e1 + st[:, 1:] * e2 + h[:, None] * n
    labels = [np.where(h > 0, 1, 0)]
    parts = [deck_like]
    # box side walls (two faces per box)
    for (s0, s1), (t0, t1), hb in boxes:
        m = 400
        s = rng.uniform(s0, s1, m)
        z = rng.uniform(0, hb, m)
        face = c + s[:, None] * e1 + t0 * e2 + z[:, None] * n
        m2 = 300
        t = rng.uniform(t0, t1, m2)
        z2 = rng.uniform(0, hb, m2)
        face2 = c + s0 * e1 + t[:, None] * e2 + z2[:, None] * n
        parts += [face, face2]
        labels += [np.full(m, 2), np.full(m2, 2)]
    # crane vessel deck (8 m higher, to the side) and its hull side wall
    crane = np.column_stack([rng.uniform(-40, 40, 8000), rng.uniform(16, 30, 8000), np.full(8000, -32.0)])
    hull = np.column_stack([rng.uniform(-40, 40, 2000), np.full(2000, 16.0), rng.uniform(-44, -32, 2000)])
    sea = np.column_stack([rng.uniform(-60, 60, n_sea), rng.uniform(-40, -16, n_sea), np.full(n_sea, -45.0)])
    parts += [crane, hull, sea]
    labels += [np.full(8000, 3), np.full(2000, 4), np.full(n_sea, 5)]
    pts_l = np.vstack(parts)
    pts_l += rng.normal(0, noise, pts_l.shape)
    lab = np.concatenate(labels)
    # sensor frame: the boom-tip sensor is pitched and rolled w.r.t. the levelled frame
    R_s_l = Rotation.from_euler("xyz", [5.0, -20.0, 30.0], degrees=True).as_matrix()
    T_s_l = np.eye(4)
    T_s_l[:3, :3] = R_s_l
    pts_s = pts_l @ R_s_l.T
    up_s = R_s_l @ np.array([0.0, 0.0, 1.0])
    deck_l = np.concatenate([n, [-n @ c]])
    deck_s = orient_plane_towards(transform_plane(deck_l, T_s_l))
    perm = rng.permutation(len(pts_s))
    return pts_s[perm], lab[perm], up_s, deck_s


def test_multi_plane_deck_picks_feeder_deck_not_cargo_or_crane_deck():
    rng = np.random.default_rng(4)
    pts, lab, up_s, deck_true = make_deck_scene(rng)
    res = multi_plane_deck(pts, up_s, MultiPlaneConfig(), rng)
    assert res is not None
    deck = res.deck
    assert angle_deg(deck.plane[:3], deck_true[:3]) < 0.1
    assert abs(deck.plane[3] - deck_true[3]) < 0.01
    d_true = wire_plane_distance(deck_true, -up_s)
    assert wire_plane_distance(deck.plane, -up_s) == pytest.approx(d_true, abs=0.01)
    assert d_true == pytest.approx(40.0, abs=1e-9)  # the deck plane passes through (0, 0, -40)
    # its inliers are deck points
    assert np.mean(lab[deck.inlier_mask] == 0) > 0.99
    # the candidates include cargo tops and the crane deck, all closer to the sensor
    cand_labels = [np.bincount(lab[c.inlier_mask], minlength=6).argmax() for c in res.candidates]
    assert 1 in cand_labels and 3 in cand_labels
    for j, lj in enumerate(cand_labels):
        if lj in (1, 3):
            assert res.distances_m[j] < res.distances_m[res.deck_index] - 2.0
    # all candidate masks are disjoint
    total = np.sum([c.inlier_mask for c in res.candidates], axis=0)
    assert total.max() == 1


def test_multi_plane_deck_rejects_sparse_sea_below_deck():
    rng = np.random.default_rng(5)
    # 1500 sea points (3.7 % of the cloud, 6 % of the deck's count): enough for RANSAC to find them
    pts, lab, up_s, deck_true = make_deck_scene(rng, n_sea=1500)
    cfg = MultiPlaneConfig(max_planes=10)
    res = multi_plane_deck(pts, up_s, cfg, rng)
    assert res is not None
    sea = [j for j, c in enumerate(res.candidates) if np.bincount(lab[c.inlier_mask], minlength=6).argmax() == 5]
    assert sea, "the sea points form a candidate plane"
    j = sea[0]
    # document 000's bare 'highest D' metric would take the sea; the area fraction rejects it
    assert res.distances_m[j] > res.distances_m[res.deck_index] + 4.0
    assert not res.eligible[j]
    assert angle_deg(res.deck.plane[:3], deck_true[:3]) < 0.1
    assert np.mean(lab[res.deck.inlier_mask] == 0) > 0.99
    # with no area fraction (document 000's metric), the sea wins: the test scene is discriminating
    bare = multi_plane_deck(pts, up_s, MultiPlaneConfig(max_planes=10, min_area_fraction=0.0), np.random.default_rng(5))
    assert np.bincount(lab[bare.deck.inlier_mask], minlength=6).argmax() == 5


def test_multi_plane_deck_without_horizontal_constraint_and_window():
    rng = np.random.default_rng(6)
    pts, lab, up_s, deck_true = make_deck_scene(rng)
    res = multi_plane_deck(pts, up_s, MultiPlaneConfig(horizontal_only=False, max_planes=10), rng)
    assert res is not None
    assert angle_deg(res.deck.plane[:3], deck_true[:3]) < 0.1
    assert max(res.tilts_deg) > 60  # walls were extracted as candidates, and rejected
    # a distance window that excludes the deck (e.g. a wrong filter prediction) -> a cargo top
    d_true = wire_plane_distance(deck_true, -up_s)
    res_w = multi_plane_deck(pts, up_s, MultiPlaneConfig(), rng, d_window_m=(d_true - 9, d_true - 2))
    assert res_w is not None and res_w.distances_m[res_w.deck_index] < d_true - 2
    assert multi_plane_deck(pts[:10], up_s, MultiPlaneConfig(), rng) is None


# --------------------------------------------------------------------------------------
# Wire distance and frame changes
# --------------------------------------------------------------------------------------
def test_wire_plane_distance_known_geometry():
    plane = np.array([0.0, 0.0, 1.0, 40.0])  # z = -40, normal up, d > 0
    down = np.array([0.0, 0.0, -1.0])
    assert wire_plane_distance(plane, down) == pytest.approx(40.0)
    # eq. 4.8 written out, and invariance to the plane's sign
    assert wire_plane_distance(-plane, down) == pytest.approx(40.0)
    # slanted wire: longer path
    w = np.array([math.sin(0.2), 0.0, -math.cos(0.2)])
    assert wire_plane_distance(plane, w) == pytest.approx(40.0 / math.cos(0.2))
    # origin 5 m lower
    assert wire_plane_distance(plane, down, origin=np.array([1.0, 2.0, -5.0])) == pytest.approx(35.0)
    # the intersection point lies on the plane
    n = tilted_normal(3.0, 10.0)
    pl = np.concatenate([n, [37.0]])
    D = wire_plane_distance(pl, down)
    assert n @ (D * down) + 37.0 == pytest.approx(0.0, abs=1e-12)
    # plane above the sensor: negative distance; wire parallel to plane: NaN
    assert wire_plane_distance(np.array([0.0, 0.0, -1.0, 10.0]), down) == pytest.approx(-10.0)
    assert math.isnan(wire_plane_distance(np.array([1.0, 0.0, 0.0, 3.0]), down))
    # unnormalised input
    assert wire_plane_distance(2 * plane, 3 * down) == pytest.approx(40.0)


def test_transform_plane_round_trip_and_points():
    rng = np.random.default_rng(7)
    R = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    t = rng.normal(size=3) * 10
    T_a_b = np.eye(4)
    T_a_b[:3, :3], T_a_b[:3, 3] = R, t
    n = tilted_normal(12.0, 45.0)
    plane_b = np.concatenate([n, [25.0]])
    e1, e2 = plane_basis(n)
    pts_b = -25.0 * n + rng.normal(size=(50, 1)) * e1 + rng.normal(size=(50, 1)) * e2
    plane_a = transform_plane(plane_b, T_a_b)
    pts_a = pts_b @ R.T + t
    assert np.allclose(pts_a @ plane_a[:3] + plane_a[3], 0.0, atol=1e-10)
    assert np.allclose(plane_a[:3], R @ n)  # orientation kept, not re-oriented
    back = transform_plane(plane_a, np.linalg.inv(T_a_b))
    assert np.allclose(back, plane_b, atol=1e-12)
    # a translation that puts the origin on the other side makes d negative: not re-oriented
    T = np.eye(4)
    T[:3, 3] = 60.0 * n
    moved = transform_plane(plane_b, T)
    assert moved[3] < 0 and np.allclose(moved[:3], n)
    assert orient_plane_towards(moved)[3] > 0


def test_ransac_refit_modes_agree():
    rng = np.random.default_rng(8)
    pts, truth, _ = _plane_with_outliers(rng, n_pts=30000)
    a = ransac_plane(pts, RansacConfig(), np.random.default_rng(0))
    b = ransac_plane(pts, RansacConfig(refit_first_on_subsample=False), np.random.default_rng(0))
    c = ransac_plane(pts, RansacConfig(refit_iterations=4), np.random.default_rng(0))
    for f in (a, b, c):
        assert angle_deg(f.plane[:3], truth[:3]) < 0.05 and abs(f.plane[3] - truth[3]) < 0.002
    assert np.mean(a.inlier_mask == b.inlier_mask) > 0.999
    # the returned mask is exactly the set the returned plane was fitted to
    assert np.allclose(fit_plane_lsq(pts[a.inlier_mask]), a.plane, atol=1e-12)
    assert np.allclose(fit_plane_lsq(pts[c.inlier_mask]), c.plane, atol=1e-12)
    # no refit: the raw 3-point hypothesis, mask = its inliers
    raw = ransac_plane(pts, RansacConfig(refit_iterations=0), np.random.default_rng(0))
    assert raw is not None and angle_deg(raw.plane[:3], truth[:3]) < 2.0


def test_select_deck_plane_rules():
    """The selection metric on hand-made candidates (levelled sensor frame, up = +z)."""
    from boomtip.perception.multi_plane import select_deck_plane
    from boomtip.perception.plane import PlaneFit

    rng = np.random.default_rng(9)
    up = np.array([0.0, 0.0, 1.0])
    groups, cands = [], []

    def add(normal, depth, count):
        n = np.asarray(normal, float) / np.linalg.norm(normal)
        e1, e2 = plane_basis(n)
        st = rng.uniform(-10, 10, (count, 2))
        c = np.array([0.0, 0.0, -depth])
        groups.append(c + st[:, :1] * e1 + st[:, 1:] * e2)
        plane = orient_plane_towards(np.concatenate([n, [-n @ c]]))
        cands.append(plane)

    add(tilted_normal(3.0, 0.0), 40.0, 1000)  # 0: feeder deck
    add(tilted_normal(30.0, 0.0), 45.0, 2000)  # 1: big slope, lower, too tilted
    add(tilted_normal(3.0, 0.0), 34.0, 600)  # 2: cargo top, higher
    add(tilted_normal(0.0, 0.0), 46.0, 60)  # 3: sea: lowest but sparse (< 15 % of 1000)
    add(tilted_normal(3.0, 0.0), 40.15, 300)  # 4: noise-tail fragment 15 cm under the deck
    add(-tilted_normal(0.0, 0.0), -20.0, 900)  # 5: horizontal surface 20 m ABOVE the sensor
    pts = np.vstack(groups)
    sizes = np.cumsum([0] + [len(g) for g in groups])
    fits = []
    for j, plane in enumerate(cands):
        mask = np.zeros(len(pts), bool)
        mask[sizes[j] : sizes[j + 1]] = True
        fits.append(PlaneFit(plane=plane, inlier_mask=mask, inlier_ratio=0.5, rms_m=0.01, iterations=1))
    res = select_deck_plane(pts, fits, up, MultiPlaneConfig())
    assert res.deck_index == 0
    assert res.fragment_of[4] == 0 and res.fragment_of[:4].tolist() == [-1, -1, -1, -1]
    assert res.eligible.tolist() == [True, False, True, False, False, False]
    assert res.tilts_deg[1] == pytest.approx(30.0) and res.tilts_deg[5] == pytest.approx(180.0)
    assert res.distances_m[5] == pytest.approx(-20.0)
    # each rule matters: without it, another candidate wins
    assert select_deck_plane(pts, fits, up, MultiPlaneConfig(max_tilt_deg=40)).deck_index == 1
    assert select_deck_plane(pts, fits, up, MultiPlaneConfig(min_area_fraction=0.0)).deck_index == 3
    assert select_deck_plane(pts, fits, up, MultiPlaneConfig(merge_distance_m=0.0)).deck_index == 4
    assert select_deck_plane(pts, fits, up, MultiPlaneConfig(), d_window_m=(30, 38)).deck_index == 2
    assert select_deck_plane(pts, fits[5:], up, MultiPlaneConfig()) is None  # nothing below the sensor
    assert select_deck_plane(pts, [], up, MultiPlaneConfig()) is None


def test_ransac_budget_follows_a_small_inlier_share_and_a_cap_is_reported():
    """5 % of the points on the plane: about 55,000 hypotheses for a 1e-3 chance of missing it
    (a fixed 1,000 would find it in 12 % of the searches); a smaller cap says it stopped short."""
    from boomtip.perception.plane import needed_iterations

    rng = np.random.default_rng(5)
    plane_pts = np.column_stack([rng.uniform(-10, 10, (500, 2)), np.zeros(500)])
    pts = np.vstack([plane_pts, rng.uniform(-10, 10, (9500, 3))])
    assert 5.4e4 < needed_iterations(0.05, 0.999) < 5.6e4
    fit = ransac_plane(pts, RansacConfig(distance_threshold_m=0.02), rng)
    assert fit is not None and not fit.capped and abs(fit.plane[2]) > 0.9999 and abs(fit.plane[3]) < 0.005
    assert fit.iterations >= 0.9 * fit.needed
    capped = ransac_plane(pts, RansacConfig(distance_threshold_m=0.02, max_iterations=1000), rng)
    assert capped is None or (capped.capped and capped.iterations == 1000)
    timed = ransac_plane(pts, RansacConfig(distance_threshold_m=0.02, max_time_ms=0.001), rng)
    assert timed is None or (timed.capped and timed.iterations == 128)  # one batch, then the clock


def test_biweight_refinement_converges_to_one_plane_from_any_start():
    """A cambered surface (z = -0.002 x^2, 5 cm of sag over 10 m) has many near-equal consensus
    planes; the biweight reaches the same one from starts 3 cm and 0.3 deg apart."""
    from boomtip.perception.plane_refine import refine_plane_biweight

    rng = np.random.default_rng(8)
    xy = rng.uniform(-5, 5, (20000, 2))
    z = -10.0 - 0.002 * xy[:, 0] ** 2 + 0.005 * rng.standard_normal(20000)
    pts = np.vstack([np.column_stack([xy, z]), rng.uniform(-5, 5, (5000, 3))])
    results = []
    for dz, tilt in [(0.0, 0.0), (0.03, 0.0), (-0.03, 0.3), (0.0, -0.3)]:
        n = tilted_normal(tilt, 0.0)
        start = np.concatenate([n, [10.0 + dz]])
        results.append(refine_plane_biweight(pts, start, 0.16))
    D = np.array([p[3] / p[2] for p in results])
    assert np.ptp(D) < 1e-3 and all(angle_deg(p[:3], results[0][:3]) < 0.01 for p in results)
    # and on a flat plane with outliers it is the plane
    flat = np.vstack([np.column_stack([xy, np.full(20000, -10.0)]), rng.uniform(-5, 5, (5000, 3))])
    p = refine_plane_biweight(flat, np.array([0.0, 0.0, 1.0, 10.02]), 0.16)
    assert abs(p[3] / p[2] - 10.0) < 1e-6 and angle_deg(p[:3], np.array([0, 0, 1.0])) < 1e-4


def test_the_search_below_a_plane_starts_beyond_its_own_noise():
    """A radar three times noisier than its data sheet: the margin follows the points' own
    spread (3 robust sigma), so the lower tail of the deck's returns is not a plane below it;
    a quiet sensor keeps the configured floor."""
    from boomtip.perception.deck import BELOW_SIGMAS, below_margin

    rng = np.random.default_rng(2)
    noisy = rng.normal(0.0, 0.43, 5000)
    # its inliers' spread (truncated at the band) puts the search beyond about 2 sigma of the noise
    assert 0.8 < below_margin(noisy, 0.45, 0.3) < BELOW_SIGMAS * 0.43
    # a deck 0.6 m below, as many points: its returns are not the plane's noise, and stay searchable
    quiet = rng.normal(0.0, 0.05, 2000)
    assert below_margin(np.r_[quiet, rng.normal(-0.6, 0.05, 2000)], 0.45, 0.3) < 0.6
    assert below_margin(rng.normal(0.0, 0.02, 5000), 0.08, 0.3) == 0.3
    assert below_margin(np.zeros(3), 0.45, 0.3) == 0.3  # too few points to say: the floor
