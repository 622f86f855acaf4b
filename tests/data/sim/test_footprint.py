"""A diverging LiDAR beam: its footprint's returns merge into a mixed pixel when the sensor cannot
tell them apart, else the return mode picks; only rays at a depth edge have their footprint cast."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.data.sim.footprint import (CENTRE_WEIGHT, RING_RAYS, edge_rays, footprint_dirs, mixed_returns,
                                        sample_weights, thinned_returns)
from boomtip.data.sim.simulator import Simulation
from boomtip.tools.config.scenario import load_scenario

INF = np.inf


def test_the_samples_weigh_a_gaussian_beam_and_ring_the_ray_at_its_radius():
    assert sample_weights().sum() == pytest.approx(1.0)
    assert sample_weights()[0] == CENTRE_WEIGHT > sample_weights()[1]
    d = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.6, 0.0, -0.8]])
    sub = footprint_dirs(d, divergence_mrad=4.0)
    assert sub.shape == (3, 1 + RING_RAYS, 3)
    np.testing.assert_allclose(np.linalg.norm(sub, axis=2), 1.0, atol=1e-12)
    np.testing.assert_allclose(sub[:, 0], d)
    angle = np.arccos(np.clip(np.einsum("nj,nsj->ns", d, sub[:, 1:]), -1, 1))
    np.testing.assert_allclose(angle, 0.65 * 2e-3, rtol=1e-6)  # 0.65 of the 1/e^2 half-angle (2 mrad)
    np.testing.assert_allclose(sub[:, 1:].mean(axis=1) / np.linalg.norm(sub[:, 1:].mean(axis=1), axis=1, keepdims=True),
                               d, atol=1e-12)  # the ring is centred on the ray


def test_near_returns_merge_at_their_energy_weighted_range():
    r = np.array([[10.0, 10.3, INF]])
    e = np.array([[3.0, 1.0, 0.0]])
    (rng, j, energy), dual, _ = mixed_returns(r, e, separation_m=0.75, mode="strongest")
    assert rng[0] == pytest.approx((3 * 10.0 + 1 * 10.3) / 4)  # a mixed pixel, between the two surfaces
    assert j[0] == 0 and energy[0] == pytest.approx(4.0) and not dual.any()


@pytest.mark.parametrize("mode, expected, sample", [("strongest", 20.0, 2), ("first", 10.0, 0), ("last", 20.0, 2),
                                                    ("dual", 10.0, 0)])
def test_returns_farther_apart_than_the_pulse_are_picked_by_the_return_mode(mode, expected, sample):
    r = np.array([[10.0, INF, 20.0, 20.2]])
    e = np.array([[1.0, 0.0, 2.0, 2.0]])
    (rng, j, _), dual, (r2, j2, e2) = mixed_returns(r, e, separation_m=0.75, mode=mode)
    assert rng[0] == pytest.approx(expected, abs=0.11) and j[0] in (sample, sample + 1)
    assert dual[0] == (mode == "dual")
    if mode == "dual":
        assert r2[0] == pytest.approx(20.1) and e2[0] == pytest.approx(4.0)


def test_a_footprint_that_meets_nothing_has_no_return():
    (rng, _, energy), dual, _ = mixed_returns(np.full((2, 3), INF), np.zeros((2, 3)), 0.75, "strongest")
    assert np.isinf(rng).all() and not dual.any() and (energy == 0).all()


def test_edge_rays_are_those_beside_a_depth_step_or_a_miss_not_on_a_sloped_plane():
    az = np.deg2rad(np.arange(-30, 30.01, 0.5))[:, None]  # document 000's grid: 0.5 deg steps
    el = np.deg2rad(np.arange(-15, 15.01, 0.5))[None, :]
    plane = 20.0 / np.cos(az) / np.cos(el)  # a plane ahead, seen at up to 34 deg
    assert not edge_rays(plane, wrap_first_axis=False).any()
    step = plane.copy()
    step[60:] += 3.0  # a box's side: the far surface from the 61st azimuth on
    step[:, 0] = INF  # the lowest elevation meets nothing
    e = edge_rays(step, wrap_first_axis=False)
    assert e[59, 1:].all() and e[60, 1:].all() and not e[:58, 2:].any() and not e[62:, 2:].any()
    assert e[:, 0].all() and e[:, 1].all()  # the misses and the hits beside them
    # a spinning sensor's first and last azimuths are neighbours
    wrapped = plane.copy()
    wrapped[0] += 3.0
    assert edge_rays(wrapped, wrap_first_axis=True)[-1].all() and not edge_rays(wrapped, wrap_first_axis=False)[-1].any()


def hits(keys: list[str]):
    sim = Simulation(load_scenario("sts-loaded", ["duration_s=0.2", *keys]))
    h, _, _, second = sim._lidar_hits(0.1, sim._scene_poses, sim._sensor_fixed_hits("lidar"))
    return sim, h, second


def test_a_diverging_beam_mixes_only_the_edge_rays_and_dual_adds_the_far_surfaces():
    sim, line, none = hits([])
    _, beam, second = hits(["installation.lidar.beam_divergence_mrad=3"])
    assert none is None and len(second[0]) == 0
    a, b = line.range_m, beam.range_m
    fans = sim.lidar_pattern.fans
    edge = edge_rays(a.reshape(len(fans.az_rad), len(fans.el_rad)), False).ravel()
    same = (a == b) | (np.isinf(a) & np.isinf(b))
    assert same[~edge].all()  # a ray away from an edge: its line's range, to the bit
    moved = ~same & np.isfinite(a) & np.isfinite(b)
    assert 0.01 < moved.mean() < 0.3  # some edge rays see two surfaces
    assert (np.abs(b[moved] - a[moved]) > 0.05).any()  # ... metres apart in places: pixels between them
    _, dual_hits, (rays, r2, face2, cos2) = hits(["installation.lidar.beam_divergence_mrad=3",
                                                  "installation.lidar.returns=dual"])
    assert len(rays) > 20 and (r2 > dual_hits.range_m[rays] + 0.75).all()  # the far return, a pulse or more behind
    assert np.all(np.isin(rays, np.flatnonzero(edge)))
    assert (cos2 > 0).all()


def test_dual_frames_carry_both_returns_of_a_ray():
    base = Simulation(load_scenario("sts-loaded", ["duration_s=0.2", "installation.lidar.beam_divergence_mrad=3"]))
    dual = Simulation(load_scenario("sts-loaded", ["duration_s=0.2", "installation.lidar.beam_divergence_mrad=3",
                                                   "installation.lidar.returns=dual"]))
    _, _, _, (rays, *_) = dual._lidar_hits(0.1, dual._scene_poses, dual._sensor_fixed_hits("lidar"))
    assert len(dual.lidar_frame(1, 0.1)) - len(base.lidar_frame(1, 0.1)) == pytest.approx(len(rays), rel=0.1)


def test_second_returns_are_thinned_like_the_first_by_the_seas_clutter_and_dropouts():
    face_offset = np.array([0, 100, 300])  # bodies 0 (a ship), 1 (the sea), 2
    n = 20000
    rng = np.random.default_rng(5)
    faces = rng.integers(0, 400, n)
    second = (np.arange(n), np.full(n, 30.0), faces, np.full(n, 0.5))
    on_sea = (faces >= 100) & (faces < 300)
    rays, r2, f2, c2 = thinned_returns(second, face_offset, 1, 0.1, 0.0, np.random.default_rng(1))
    kept_sea = np.isin(rays, np.flatnonzero(on_sea))
    assert kept_sea.sum() == pytest.approx(0.1 * on_sea.sum(), rel=0.1)  # a tenth of the sea's
    assert (~kept_sea).sum() == (~on_sea).sum()  # all the rest
    rays, *_ = thinned_returns(second, face_offset, None, 0.0, 0.25, np.random.default_rng(1))
    assert len(rays) == pytest.approx(0.75 * n, rel=0.03)
    assert np.array_equal(thinned_returns(second, face_offset, None, 0.0, 0.0, np.random.default_rng(1))[0], second[0])
