"""The load's clearance in one levelled frame: a container's top face hanging on the rope's line
over a rolling deck, sampled as a LiDAR at the tip would (a grid of points, centimetre noise)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import ndtr

from boomtip.perception.lift import LiftConfig, chance_lowest, height_plane, measure_clearance, plane_height_at, rope_line_xy

SIZE = (6.058, 2.438, 2.591)
HOOK = np.array([0.5, -0.3, -60.0])
BLOCK_M, SLING_M = 4.0, 3.0
NOISE_M = 0.01


def _rot(yaw, tilt_y, tilt_x=0.0):
    cy, sy, ct, st, cx, sx = math.cos(yaw), math.sin(yaw), math.cos(tilt_y), math.sin(tilt_y), math.cos(tilt_x), math.sin(tilt_x)
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    Ry = np.array([[ct, 0, st], [0, 1, 0], [-st, 0, ct]])
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return Ry @ Rx @ Rz


def _deck_z(xy, deck):
    return deck[0] + xy[..., 0] * deck[1] + xy[..., 1] * deck[2]


def scene(deck=(-80.0, 0.02, -0.012), yaw=0.5, tilt=(0.03, 0.01), seed=0, spacing=0.4):
    """(points, true clearance, true underside centre): the load's top face and slings, the deck
    around it (not under it: the load hides that), centimetre noise."""
    rng = np.random.default_rng(seed)
    R = _rot(yaw, *tilt)
    below = BLOCK_M + SLING_M + SIZE[2]
    z_centre = HOOK[2] - below
    centre = np.append(rope_line_xy(HOOK, z_centre), z_centre)
    L, W, H = SIZE
    gx, gy = np.meshgrid(np.arange(-L / 2 + 0.1, L / 2, spacing), np.arange(-W / 2 + 0.1, W / 2, spacing))
    top = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, H)]) @ R.T + centre
    slings = np.array([[0.0, 0.0, H + SLING_M * f] for f in (0.3, 0.6, 0.9)]) @ R.T + centre
    g = np.arange(-14, 14, spacing)
    dx, dy = np.meshgrid(g, g)
    xy = np.column_stack([dx.ravel(), dy.ravel()]) + centre[:2]
    d = np.linalg.norm(xy - centre[:2], axis=1)
    xy = xy[(d > 0.5 * math.hypot(L, W)) & (d < 12.0)]
    deck_pts = np.column_stack([xy, _deck_z(xy, deck)])
    corners = np.array([[sx * L / 2, sy * W / 2, 0.0] for sx in (-1, 1) for sy in (-1, 1)]) @ R.T + centre
    C_true = float(np.min(corners[:, 2] - _deck_z(corners[:, :2], deck)))
    pts = np.vstack([top, slings, deck_pts])
    return pts + NOISE_M * rng.standard_normal(pts.shape), C_true, centre


@pytest.mark.parametrize("seed", range(5))
def test_the_clearance_and_the_landing_point_are_found_within_their_sigmas(seed):
    pts, C_true, centre = scene(seed=seed, yaw=0.3 * seed)
    obs = measure_clearance(pts, HOOK, BLOCK_M, SIZE, LiftConfig(), range_noise_m=NOISE_M, angular_step_rad=0.4 / 70)
    assert obs.ok, obs.status
    assert abs(obs.clearance_m - C_true) <= max(3 * obs.sigma_m, 0.005)
    assert obs.sigma_m < 0.02
    assert np.linalg.norm(obs.underside_centre_m[:2] - centre[:2]) <= 3 * obs.centre_sigma_m


def test_a_deck_hidden_about_the_load_is_taken_from_the_fallback_with_its_sigma_and_said_so():
    deck = np.array([-80.0, 0.02, -0.012])
    pts, C_true, centre = scene(deck=tuple(deck))
    pts = pts[np.abs(pts[:, 2] - _deck_z(pts[:, :2], deck)) > 0.1]  # the deck's returns gone (the load and more hide it)
    cfg, noise = LiftConfig(), dict(range_noise_m=NOISE_M, angular_step_rad=0.4 / 70)
    assert measure_clearance(pts, HOOK, BLOCK_M, SIZE, cfg, **noise).status == "too few deck points about the load"
    obs = measure_clearance(pts, HOOK, BLOCK_M, SIZE, cfg, **noise, deck_fallback=(deck, 0.01))
    assert obs.ok and obs.deck_hidden == "too few deck points about the load" and obs.n_deck == 0 and obs.deck_sigma_m == 0.01
    assert abs(obs.clearance_m - C_true) <= 3 * obs.sigma_m and 0.01 < obs.sigma_m < 0.02  # the fallback's sigma in C's
    low = measure_clearance(pts, HOOK, BLOCK_M, SIZE, cfg, **noise, deck_fallback=(deck - (0.05, 0.0, 0.0), 0.01))
    assert low.clearance_m - obs.clearance_m == pytest.approx(0.05, abs=1e-6)  # C is measured against it
    seen = measure_clearance(scene(deck=tuple(deck))[0], HOOK, BLOCK_M, SIZE, cfg, **noise, deck_fallback=(deck - (0.05, 0.0, 0.0), 0.01))
    assert seen.deck_hidden is None and abs(seen.clearance_m - C_true) <= 3 * seen.sigma_m  # a deck seen is the frame's own


def test_the_lowest_point_is_the_corner_nearest_the_deck_below_not_the_lowest_in_height():
    # The load tilts down towards -x (its +x end 18 cm higher); the deck rises towards +x four
    # times faster, so the corner nearest the deck is at +x though the lowest in height is at -x.
    deck = (-80.0, 0.12, 0.0)
    pts, C_true, centre = scene(deck=deck, yaw=0.0, tilt=(-0.03, 0.0))
    obs = measure_clearance(pts, HOOK, BLOCK_M, SIZE, LiftConfig(), range_noise_m=NOISE_M, angular_step_rad=0.4 / 70)
    assert obs.ok and abs(obs.clearance_m - C_true) <= 3 * obs.sigma_m
    assert obs.lowest_point_m[0] > centre[0] + 2.0  # the +x end


def test_a_level_loads_corners_give_c_as_their_heights_weighted_by_their_chance_to_be_lowest():
    # level load, level deck: the four corners' heights differ by their noise alone, so the least
    # of them reads low; C weighs each by its chance to be the lowest
    pts, C_true, _ = scene(deck=(-80.0, 0.0, 0.0), yaw=0.3, tilt=(0.0, 0.0), seed=3, spacing=0.6)
    obs = measure_clearance(pts, HOOK, BLOCK_M, SIZE, LiftConfig(), range_noise_m=NOISE_M, angular_step_rad=0.6 / 70)
    h = obs.candidates_m[:, 2] - plane_height_at(obs.deck_plane, obs.candidates_m[:, :2])
    w = chance_lowest(h, obs.candidate_sigmas_m)
    assert w.max() < 0.9  # no corner is surely the lowest
    assert obs.clearance_m == pytest.approx(float(w @ h), abs=1e-12) and h.min() < obs.clearance_m < h.mean()
    tilted, _, _ = scene(tilt=(0.03, 0.01), seed=3)  # a tilted load: its lowest corner is sure, C is its height
    obs = measure_clearance(tilted, HOOK, BLOCK_M, SIZE, LiftConfig(), range_noise_m=NOISE_M, angular_step_rad=0.4 / 70)
    assert obs.clearance_m == pytest.approx(obs.lowest_point_m[2] - obs.deck_z_m, abs=1e-9)


def test_without_a_model_the_clearance_is_to_the_lowest_point_seen():
    deck = (-80.0, 0.02, -0.012)
    pts, C_true, _ = scene(deck=deck, tilt=(0.0, 0.0))
    obs = measure_clearance(pts, HOOK, BLOCK_M, None, LiftConfig(unknown_load_radius_m=3.5), range_noise_m=NOISE_M)
    assert obs.ok
    # from above only the top is seen: the lowest point seen is on the top, a load's height over the truth
    top = pts[obs.load_mask]
    above = top[:, 2] - _deck_z(top[:, :2], deck)
    assert above.min() - 0.03 <= obs.clearance_m <= np.percentile(above, 50)
    assert obs.clearance_m > C_true + SIZE[2] - 0.1


def test_nan_points_change_nothing_and_their_masks_index_the_frame():
    pts, _, _ = scene()
    with_nan = np.vstack([pts[:100], np.full((5, 3), np.nan), pts[100:]])
    a = measure_clearance(pts, HOOK, BLOCK_M, SIZE, LiftConfig())
    b = measure_clearance(with_nan, HOOK, BLOCK_M, SIZE, LiftConfig())
    assert b.clearance_m == a.clearance_m
    assert len(b.load_mask) == len(with_nan) and not b.load_mask[100:105].any()
    assert np.array_equal(with_nan[b.load_mask], pts[a.load_mask])


def test_the_corners_lowest_in_height_lie_at_the_other_end_in_that_scene():
    # the scene above, checked: without the deck's slope the lowest corner is the -x one
    pts, _, centre = scene(deck=(-80.0, 0.0, 0.0), yaw=0.0, tilt=(-0.03, 0.0))
    obs = measure_clearance(pts, HOOK, BLOCK_M, SIZE, LiftConfig(), range_noise_m=NOISE_M)
    assert obs.ok and obs.lowest_point_m[0] < centre[0] - 2.0


@pytest.mark.parametrize("pts, status", [
    (np.zeros((0, 3)), "no points"),
    (np.array([[0.0, 0.0, -70.0]] * 10), "too few deck points"),
])
def test_a_frame_without_a_load_or_a_deck_says_why(pts, status):
    obs = measure_clearance(pts, HOOK, BLOCK_M, SIZE, LiftConfig())
    assert not obs.ok and status in obs.status and math.isnan(obs.clearance_m)


def test_a_deck_too_far_from_the_last_one_is_searched_afresh():
    pts, C_true, _ = scene()
    obs = measure_clearance(pts, HOOK, BLOCK_M, SIZE, LiftConfig(), deck_prior_z_m=-70.0, range_noise_m=NOISE_M)
    assert obs.ok and abs(obs.clearance_m - C_true) < 0.02


def test_height_plane_leaves_the_outliers_out():
    rng = np.random.default_rng(3)
    xy = rng.uniform(-5, 5, (200, 2))
    z = 1.0 + 0.1 * xy[:, 0] - 0.05 * xy[:, 1] + 0.005 * rng.standard_normal(200)
    z[:10] += 2.0
    coef, keep = height_plane(np.column_stack([xy, z]), 3.0)
    assert np.allclose(coef, [1.0, 0.1, -0.05], atol=3e-3)
    assert not keep[:10].any() and keep[10:].mean() > 0.97


def test_without_a_model_cargo_within_the_search_radius_is_not_taken_for_the_load():
    deck = (-80.0, 0.02, -0.012)
    pts, C_true, centre = scene(deck=deck, tilt=(0.0, 0.0))
    # a crate 2 m high on the deck, 5 m from the load's axis: inside the 8 m a model-less search covers
    g = np.arange(-1.0, 1.0, 0.4)
    cx, cy = np.meshgrid(g, g)
    xy = np.column_stack([cx.ravel(), cy.ravel()]) + centre[:2] + [5.0, 0.0]
    crate = np.column_stack([xy, _deck_z(xy, deck) + 2.0])
    obs = measure_clearance(np.vstack([pts, crate]), HOOK, BLOCK_M, None, LiftConfig(), range_noise_m=NOISE_M)
    assert obs.ok and obs.clearance_m > C_true + SIZE[2] - 0.1  # the load's top, not the crate's 2 m
    assert not obs.load_mask[len(pts):].any()


def test_the_chance_to_be_lowest_is_the_normal_law_of_the_difference_for_two_and_sums_to_one():
    c = chance_lowest(np.array([0.10, 0.12]), np.array([0.01, 0.02]))
    assert c[0] == pytest.approx(ndtr(0.02 / math.hypot(0.01, 0.02)), rel=1e-12) and c.sum() == pytest.approx(1.0)
    four = chance_lowest(np.array([0.10, 0.10, 0.10, 0.10]), np.full(4, 0.01))
    assert four == pytest.approx(np.full(4, 0.25))
    far = chance_lowest(np.array([0.5, 0.1, 0.9, 0.3]), np.full(4, 0.01))
    assert far[1] == pytest.approx(1.0, abs=1e-12) and far.sum() == pytest.approx(1.0)
    assert np.all(np.diff(chance_lowest(np.array([0.10, 0.11, 0.12]), np.full(3, 0.01))) < 0)  # lower, likelier
