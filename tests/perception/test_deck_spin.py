"""The deck plane and its spin from the returns' times: the fit against a known moving plane,
its covariance against Monte Carlo, the crane's rotation removed, the times found for the
deck stage's inliers, and the plane alone when the frame has no times."""

from __future__ import annotations

import math

import numpy as np
import pytest
from boomtip.perception.deck_spin import deck_point_times, level_at_own_time, spin_plane_in_level
from boomtip.perception.geometry import rpy_matrix

ABC = np.array([0.012, -0.02, -45.0])
RATES = np.array([0.015, -0.008, 0.6])  # 0.86 and 0.46 deg/s, 0.6 m/s


def _sweep(rng, n=3000, noise_m=0.0):
    """Deck points under a grid's columns: time runs with x over 0.1 s, as the LiDAR's do."""
    x = rng.uniform(-60.0, 60.0, n)
    y = rng.uniform(-14.0, 14.0, n) + 25.0  # the deck off to one side of the tip
    t = (x + 60.0) / 120.0 * 0.1 + rng.normal(0.0, 2e-4, n)
    z = (ABC[0] + t * RATES[0]) * x + (ABC[1] + t * RATES[1]) * y + ABC[2] + t * RATES[2] + rng.normal(0.0, 1.0, n) * noise_m
    return np.column_stack([x, y, z]), t


def test_a_moving_plane_is_recovered_at_the_frames_time():
    pts, t = _sweep(np.random.default_rng(0))
    s = spin_plane_in_level(pts, t, 1.0)
    assert np.allclose(s.abc, ABC, atol=1e-9) and np.allclose(s.rates, RATES, atol=1e-8)
    assert s.n_points == 3000 and s.span_s == pytest.approx(0.1, abs=2e-3)


def test_the_joint_covariance_is_honest():
    """Monte Carlo over 300 fits: the six errors' chi-square mean is 6 with no inflation, and
    the height at the returns' mean time is known far better than at the frame's (the
    correlation the covariance must keep)."""
    rng = np.random.default_rng(1)
    d2 = []
    for _ in range(300):
        pts, t = _sweep(rng, 800, noise_m=0.02)
        s = spin_plane_in_level(pts, t, 1.0)
        e = np.r_[s.abc - ABC, s.rates - RATES]
        d2.append(e @ np.linalg.solve(s.cov, e))
    assert np.mean(d2) == pytest.approx(6.0, rel=0.1)
    g = np.array([0.0, 0.0, 1.0, 0.0, 0.0, float(t.mean())])  # c + t_mean c'
    assert g @ s.cov @ g < 0.01 * s.cov[2, 2]
    assert np.allclose(spin_plane_in_level(pts, t, 20.0).cov, 20.0 * s.cov, rtol=1e-12)


def test_points_levelled_at_their_own_time_match_the_exact_rotation():
    """A crane turning at 2 deg/s about a tilted axis: to first order in t the points are where
    the attitude at their time puts them, within half a millimetre at 45 m over 0.1 s (the
    second-order term, against the returns' 2 cm noise)."""
    rng = np.random.default_rng(2)
    q = rng.uniform([-40, -10, -46], [40, 40, -44], (500, 3))
    w = np.radians([1.5, -1.2, 0.6])
    t = rng.uniform(0.0, 0.1, 500)
    out = level_at_own_time(q, t, w)
    axis, rate = w / np.linalg.norm(w), np.linalg.norm(w)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    exact = np.array([(np.eye(3) + math.sin(rate * ti) * K + (1 - math.cos(rate * ti)) * K @ K) @ qi for qi, ti in zip(q, t)])
    assert np.max(np.abs(out - exact)) < 5e-4
    assert np.max(np.abs(q - exact)) > 0.05  # the correction is not nothing: 0.2 deg at 45 m


def test_the_crane_rotation_removed_leaves_the_feeders_own_spin():
    """A still deck seen from a crane rolling at 1 deg/s: levelled at the frame's attitude only,
    its slope seems to turn at 1 deg/s; levelled at each point's time, not."""
    rng = np.random.default_rng(3)
    pts, t = _sweep(rng)
    pts[:, 2] = ABC[0] * pts[:, 0] + ABC[1] * pts[:, 1] + ABC[2]
    w = np.radians([1.0, 0.0, 0.0])
    # what the sensor, turning with the crane, reports levelled at the frame's attitude: R(t)^T q
    seen = np.array([rpy_matrix(-w * ti) @ p for p, ti in zip(pts, t)])
    fooled = spin_plane_in_level(seen, t, 1.0)
    assert abs(fooled.rates[1]) == pytest.approx(math.radians(1.0), rel=0.05)
    right = spin_plane_in_level(level_at_own_time(seen, t, w), t, 1.0)
    assert np.max(np.abs(right.rates[:2])) < 2e-5 and abs(right.rates[2]) < 1e-3  # 0.1 % of it: second order


def test_the_inliers_times_are_found_through_a_range_crop_or_refused():
    rng = np.random.default_rng(4)
    frame = rng.normal(0.0, 20.0, (1000, 3))
    frame[::50] = 0.5  # within the crop's minimum range
    frame[7] = np.nan
    times = np.arange(1000, dtype=np.float32) * 1e-4
    r = np.linalg.norm(frame, axis=1)
    kept = np.flatnonzero(np.isfinite(r) & (r >= 2.0))
    used = frame[kept]
    mask = rng.random(len(used)) < 0.4
    assert np.array_equal(deck_point_times(frame, times, used, mask), times[kept[mask]])
    assert np.array_equal(deck_point_times(used, times[kept], used, mask), times[kept[mask]])  # nothing cropped
    thinned = used[::2]  # another preprocessing (a voxel grid, a random subsample): refused
    assert deck_point_times(frame, times, thinned, mask[::2]) is None
    moved = used + 1e-3  # points that are not the frame's: refused
    assert deck_point_times(frame, times, moved, mask) is None


def test_the_feeders_lidar_observation_has_a_spin_only_with_times_that_span_the_sweep():
    """The frame's deck (a still one, seen from a still crane: no rates) with column times over
    0.1 s: a spin, at the plane's place, with rates within their 3 sigma of 0; with every time 0
    (a sensor without per-point times, or a simulation without sweep motion), times that run
    in proportion to x (nothing separates a heave rate from the slope), or switched off: the
    plane alone."""
    from types import SimpleNamespace

    from boomtip.tools.config.scenario import load_scenario
    from boomtip.perception.feeder import FeederConfig, FeederPerception

    inst = load_scenario("sts-loaded").installation
    per = FeederPerception(inst)
    rpy, rate = np.zeros(3), np.zeros(3)
    R_ls, t_ls = per.sensor_in_level("lidar", rpy)
    rng = np.random.default_rng(5)
    deck_level = np.column_stack([rng.uniform(-50, 50, 4000), rng.uniform(10, 35, 4000), np.full(4000, -44.0)])
    deck_level[:, 2] += 0.01 * deck_level[:, 0] + rng.normal(0, 0.02, 4000)
    pts_sensor = (deck_level - t_ls) @ R_ls  # level -> sensor
    # a grid's columns: the time runs with the angle from the sensor, not with x
    times = ((np.arctan2(deck_level[:, 0], 44.0) + 1.0) / 2.0 * 0.1).astype(np.float32)
    mask = np.ones(4000, dtype=bool)
    deck = SimpleNamespace(ok=True, fit=SimpleNamespace(inlier_mask=mask), points_used=pts_sensor, status="ok")
    obs = per.lidar(0.0, pts_sensor, rpy, rate, deck, times)
    assert obs.spin is not None and obs.spin.n_points == 4000
    assert np.allclose(obs.spin.abc, obs.plane.abc, atol=[1e-3, 1e-3, 0.05])
    assert np.all(np.abs(obs.spin.rates) < 3 * np.sqrt(np.diag(obs.spin.cov)[3:]))
    assert per.lidar(0.0, pts_sensor, rpy, rate, deck, np.zeros(4000, np.float32)).spin is None
    in_step = ((deck_level[:, 0] + 50.0) / 100.0 * 0.1).astype(np.float32)  # time in proportion to x: no separating them
    assert per.lidar(0.0, pts_sensor, rpy, rate, deck, in_step).spin is None
    assert per.lidar(0.0, pts_sensor, rpy, rate, deck).spin is None
    off = FeederPerception(inst, FeederConfig(spin=False))
    assert off.lidar(0.0, pts_sensor, rpy, rate, deck, times).spin is None and off.lidar(0.0, pts_sensor, rpy, rate, deck, times).plane is not None


def test_too_few_points_for_six_coefficients_are_refused():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-5, 5, (6, 3))
    pts[:, 2] = 0.1 * pts[:, 0]
    t = np.linspace(0.0, 0.05, 6)
    assert spin_plane_in_level(pts, t, 20.0) is None  # exact fit: no residual to scale a covariance
    pts = rng.uniform(-5, 5, (200, 3))
    pts[:, 2] = 0.1 * pts[:, 0] + rng.normal(0, 0.01, 200)
    assert spin_plane_in_level(pts, rng.uniform(0, 0.05, 200), 20.0) is not None
