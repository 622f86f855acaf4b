"""The feeder's deck frame in a lift: a feeder (deck, bulwarks, cargo) moving under a hanging
load, the own vessel's deck beside it across the gap, sampled afresh with centimetre noise each
frame; the landing point in the deck frame stays where it is on the feeder."""

from __future__ import annotations

import math

import numpy as np
import pytest

from boomtip.data.poses import inverse, pose_matrix, transform
from boomtip.perception.feeder_registration import pose_information
from boomtip.perception.lift_deck_frame import (DeckFrameConfig, DeckFrameTracker, feeder_deck_cells, height_sigma_m, plane_in,
                                                pose_covariance, point_sigma_m)

DECK_Z_M = -79.0
NOISE_M = 0.01
LOAD_XY, LOAD_RADIUS_M = np.array([1.0, -2.0]), 4.0
# (centre x, y; size x, y, z) on the feeder's deck: cargo, a coaming, the bulwarks along both sides
BOXES = [(-20.0, 3.0, 6.1, 2.4, 2.6), (-12.0, -5.0, 12.2, 2.4, 5.2), (15.0, 2.0, 6.1, 7.3, 2.6), (25.0, -6.0, 3.0, 3.0, 1.5),
         (0.0, 9.5, 60.0, 0.3, 1.2), (0.0, -9.5, 60.0, 0.3, 1.2)]


def _box_points(rng, cx, cy, sx, sy, sz, spacing=0.3):
    """Points on a box's top and four sides, standing on the deck (feeder body frame)."""
    out = []
    for face in range(5):
        u = rng.uniform(-0.5, 0.5, (int(max(sx, sy) * max(sy, sz) / spacing**2) + 20, 2))
        if face == 0:
            p = np.column_stack([u[:, 0] * sx, u[:, 1] * sy, np.full(len(u), sz)])
        elif face < 3:
            p = np.column_stack([np.full(len(u), (face - 1.5) * sx), u[:, 0] * sy, (u[:, 1] + 0.5) * sz])
        else:
            p = np.column_stack([u[:, 0] * sx, np.full(len(u), (face - 3.5) * sy), (u[:, 1] + 0.5) * sz])
        out.append(p + (cx, cy, 0.0))
    return np.vstack(out)


def feeder_cloud(rng):
    """The feeder's returns in its body frame (deck at z 0, the load's shadow left out) and the own vessel's deck."""
    deck = np.column_stack([rng.uniform(-30, 30, 12000), rng.uniform(-10, 10, 12000), np.zeros(12000)])
    deck = deck[np.hypot(deck[:, 0] - LOAD_XY[0], deck[:, 1] - LOAD_XY[1]) > 2.0]
    feeder = np.vstack([deck] + [_box_points(rng, *b) for b in BOXES])
    own = np.column_stack([rng.uniform(-40, 40, 6000), rng.uniform(15, 40, 6000), np.full(6000, 6.0)])
    return feeder, own


def feeder_pose(t_s: float) -> np.ndarray:
    """The feeder in the levelled frame: deck at DECK_Z_M, swaying, surging, yawing, rolling and pitching."""
    return pose_matrix(0.4 * math.sin(0.7 * t_s), 0.6 * math.sin(0.7 * t_s + 1.0), DECK_Z_M + 1.0 * math.sin(0.7 * t_s + 2.0),
                       math.radians(1.0) * math.sin(0.7 * t_s + 0.5), math.radians(1.5) * math.sin(0.7 * t_s),
                       math.radians(0.5) * math.sin(0.7 * t_s + 0.3))


def frame(rng, feeder, own, t_s):
    T = feeder_pose(t_s)
    keep = rng.random(len(feeder)) < 0.7  # another sample each frame: a scan's beams fall elsewhere
    pts = np.vstack([transform(T, feeder[keep]), own + (0.0, 0.0, DECK_Z_M)])
    return pts + NOISE_M * rng.standard_normal(pts.shape), T


def deck_plane_about(T: np.ndarray) -> np.ndarray:
    """z = a + b x + c y of the feeder's deck (level frame), as the lift's deck ring gives it."""
    n, p = T[:3, 2], T[:3, 3]
    return np.array([p[2] + (n[0] * p[0] + n[1] * p[1]) / n[2], -n[0] / n[2], -n[1] / n[2]])


def deck_ring(pts: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """The deck's returns about the load (x, y), as the lift's deck ring finds them."""
    ring = np.abs(pts[:, 2] - plane[0] - plane[1] * pts[:, 0] - plane[2] * pts[:, 1]) < 0.05
    ring &= np.hypot(pts[:, 0] - LOAD_XY[0], pts[:, 1] - LOAD_XY[1]) < 8.0
    return pts[ring, :2]


def test_the_feeder_deck_is_the_cells_connected_to_those_under_the_load_not_the_own_vessel_across_the_gap():
    rng = np.random.default_rng(0)
    flat = np.column_stack([rng.uniform(-30, 30, 5000), rng.uniform(-10, 10, 5000), np.full(5000, DECK_Z_M)])
    own = np.column_stack([rng.uniform(-30, 30, 3000), rng.uniform(14, 30, 3000), np.full(3000, DECK_Z_M + 0.1)])
    pts = np.vstack([flat, own])
    deck = feeder_deck_cells(pts, np.array([DECK_Z_M, 0.0, 0.0]), flat[:50, :2], 0.8, 1.0)
    assert len(deck) == len(flat) and deck[:, 1].max() < 10.0  # the same height, but not connected
    assert len(feeder_deck_cells(pts, np.array([DECK_Z_M + 5.0, 0.0, 0.0]), flat[:50, :2], 0.8, 1.0)) == 0


def test_a_points_sigmas_are_those_of_the_registrations_pose_moving_it():
    # the pose's parametrisation is the registration's (pose_information): a point moves by dt + dw x (p - o)
    rng = np.random.default_rng(5)
    pts, normals = rng.normal(size=(400, 3)) * (20.0, 8.0, 2.0), rng.normal(size=(400, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    origin, point = np.array([1.0, -2.0, 80.0]), np.array([4.0, 3.0, 0.5])
    cov = np.linalg.inv(pose_information(pts, normals, origin, 0.05))
    d = rng.multivariate_normal(np.zeros(6), cov, 200_000)
    moved = d[:, :3] + np.cross(d[:, 3:], point - origin)
    assert point_sigma_m(cov, point, origin) == pytest.approx(math.sqrt(0.5 * (moved[:, 0].var() + moved[:, 1].var())), rel=0.01)
    assert height_sigma_m(cov, point, origin) == pytest.approx(moved[:, 2].std(), rel=0.01)


def test_a_direction_the_structure_leaves_free_keeps_the_priors_variance():
    rng = np.random.default_rng(2)
    deck = np.column_stack([rng.uniform(-30, 30, 2000), rng.uniform(-10, 10, 2000), np.full(2000, -79.0)])
    info = pose_information(deck, np.tile([0.0, 0.0, 1.0], (2000, 1)), np.zeros(3), 0.03)  # a bare deck: x, y, yaw free
    prior = np.diag([0.1**2] * 3 + [0.01**2] * 3)
    cov = pose_covariance(info, prior)
    assert cov[0, 0] == pytest.approx(0.01, rel=1e-6) and cov[5, 5] == pytest.approx(1e-4, rel=1e-6)
    assert cov[2, 2] < 1e-3 * prior[2, 2] and cov[3, 3] < 1e-3 * prior[3, 3]  # z and the tilts pinned by the deck


def test_a_point_sigma_is_the_translation_and_the_rotation_times_its_lever_arm():
    cov = np.diag([1e-4, 1e-4, 1e-4, 0.0, 0.0, 0.0])
    assert point_sigma_m(cov, np.array([5.0, 3.0, -80.0]), np.zeros(3)) == pytest.approx(0.01)
    cov = np.diag([0.0, 0.0, 0.0, 0.0, 0.0, 1e-6])  # yaw 1 mrad about the origin, the point 10 m off along x
    assert point_sigma_m(cov, np.array([10.0, 0.0, -80.0]), np.zeros(3)) == pytest.approx(0.01 / math.sqrt(2.0))


@pytest.mark.parametrize("seed", range(3))
def test_the_landing_point_stays_still_in_the_deck_frame_while_the_feeder_moves(seed):
    rng = np.random.default_rng(seed)
    feeder, own = feeder_cloud(rng)
    tracker = DeckFrameTracker(DeckFrameConfig())
    landing_body = np.array([LOAD_XY[0], LOAD_XY[1], 0.0])  # a spot on the feeder's deck
    T_key = None
    errors, sigmas, moved = [], [], []
    for t in np.arange(0.0, 12.0, 0.05):  # a 20 Hz LiDAR
        pts, T = frame(rng, feeder, own, t)
        if tracker.due(t):
            plane = deck_plane_about(T)
            tracker.update(t, pts, plane, deck_ring(pts, plane), LOAD_XY, LOAD_RADIUS_M)
        T_key = T if T_key is None else T_key
        landing_level = transform(T, landing_body[None])[0]
        placed = tracker.landing_in_deck(t, landing_level, 0.0)
        assert placed is not None
        p_deck, sigma = placed
        truth = transform(T_key, landing_body[None])[0]  # the deck frame: the level frame at the keyframe
        errors.append(np.abs(p_deck[:2] - truth[:2]))
        sigmas.append(sigma)
        moved.append(np.linalg.norm(landing_level[:2] - truth[:2]))
    errors, sigmas = np.array(errors), np.array(sigmas)
    assert max(moved) > 0.5  # the spot moves under the tip by decimetres
    assert tracker.statuses == {"keyframe": 1, "ok": 60}  # the frame after the keyframe, then every 0.2 s
    assert np.sqrt(np.mean(errors**2)) < 0.006 and errors.max() < 0.025  # it stays within millimetres on the deck
    assert np.mean(errors.max(axis=1) <= 3.0 * sigmas) > 0.95 and np.median(sigmas) < 3.0 * np.sqrt(np.mean(errors**2))


def test_a_plane_moved_to_another_frame_holds_the_same_points():
    T = pose_matrix(0.3, -1.2, 5.0, 0.02, -0.03, 0.4)
    plane = np.array([-79.0, 0.01, -0.02])
    xy = np.array([[3.0, -4.0], [-20.0, 7.0], [0.0, 0.0]])
    on = np.column_stack([xy, plane[0] + xy @ plane[1:]])
    moved, plane_moved = transform(T, on), plane_in(T, plane)
    assert np.allclose(moved[:, 2], plane_moved[0] + moved[:, :2] @ plane_moved[1:], atol=1e-9)
    assert np.allclose(plane_in(inverse(T), plane_moved), plane, atol=1e-12)


def test_the_deck_last_seen_is_carried_with_the_feeder_to_where_the_load_hides_it():
    rng = np.random.default_rng(3)
    feeder, own = feeder_cloud(rng)
    tracker = DeckFrameTracker(DeckFrameConfig())
    assert tracker.deck_plane_at(0.0, LOAD_XY) is None  # nothing seen yet
    errors, sigmas = [], []
    for t in np.arange(0.0, 10.0, 0.05):
        pts, T = frame(rng, feeder, own, t)
        plane = deck_plane_about(T)
        if tracker.due(t) or t >= 2.0:  # the deck hidden: every frame registered (as the lift chain does)
            tracker.update(t, pts, plane, deck_ring(pts, plane), LOAD_XY, LOAD_RADIUS_M)
        if t < 2.0:  # the deck seen about the load (exactly: the sigma is the pose's alone), then hidden by it
            tracker.remember_deck(t, plane, 0.0)
        elif (predicted := tracker.deck_plane_at(t, LOAD_XY)) is not None:
            z_true = plane[0] + plane[1:] @ LOAD_XY
            errors.append(predicted[0][0] + predicted[0][1:] @ LOAD_XY - z_true)
            sigmas.append(predicted[1])
    errors, sigmas = np.array(errors), np.array(sigmas)
    assert len(errors) == 160  # every frame from 2 s
    rms = np.sqrt(np.mean(errors**2))
    assert rms < 0.004 and np.mean(np.abs(errors) <= 3.0 * sigmas) > 0.95  # the feeder heaves 2 m
    # the registration's sigma is its information's, thinned for residuals a real scan shares: on these
    # independent samples of perfect boxes it errs wide, by about 3.5 times
    assert np.median(sigmas) < 5.0 * rms


def test_the_deck_frame_waits_for_the_tip_to_settle_and_keeps_its_error_in_the_landing_points_sigma():
    rng = np.random.default_rng(11)
    feeder, own = feeder_cloud(rng)
    tracker = DeckFrameTracker(DeckFrameConfig(keyframe_max_tip_sigma_m=0.03))
    pts, T = frame(rng, feeder, own, 0.0)
    plane = deck_plane_about(T)
    assert tracker.update(0.0, pts, plane, deck_ring(pts, plane), LOAD_XY, LOAD_RADIUS_M, 0.2) == "the boom tip's place not yet settled"
    assert tracker.model is None and tracker.pose_at(0.0) is None
    assert tracker.update(0.05, pts, plane, deck_ring(pts, plane), LOAD_XY, LOAD_RADIUS_M, 0.02) == "keyframe"
    p_level = transform(T, np.array([[LOAD_XY[0], LOAD_XY[1], 0.0]]))[0]
    _, sigma = tracker.landing_in_deck(0.05, p_level, 0.0)
    assert sigma == pytest.approx(0.02)  # at the keyframe the frame's own error alone


def test_the_deck_frame_is_taken_afresh_after_registrations_fail_and_never_extrapolated_far():
    rng = np.random.default_rng(7)
    feeder, own = feeder_cloud(rng)
    cfg = DeckFrameConfig(rekey_after_failures=3)
    tracker = DeckFrameTracker(cfg)
    pts, T = frame(rng, feeder, own, 0.0)
    plane = deck_plane_about(T)
    assert tracker.update(0.0, pts, plane, deck_ring(pts, plane), LOAD_XY, LOAD_RADIUS_M) == "keyframe"
    for t in (0.2, 0.4, 0.6):  # the feeder gone from view (only the own vessel): nothing to register
        assert tracker.update(t, own + (0.0, 0.0, DECK_Z_M), plane, LOAD_XY[None], LOAD_XY, LOAD_RADIUS_M) != "ok"
    assert tracker.pose_at(0.0 + cfg.max_extrapolation_s + 0.1) is None
    pts, T = frame(rng, feeder, own, 0.8)
    plane = deck_plane_about(T)
    assert tracker.update(0.8, pts, plane, deck_ring(pts, plane), LOAD_XY, LOAD_RADIUS_M) == "keyframe"
    assert tracker.key_t_s == 0.8
    assert np.allclose(inverse(tracker.pose_at(0.8).T_deck_level), np.eye(4))
