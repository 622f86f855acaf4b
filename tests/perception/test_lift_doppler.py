"""The clearance's rate from a radar scan: on a rigid deck and a swinging load whose every
velocity is known, the rates must be the height's own derivative, slope and spins included."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from boomtip.perception.lift import LoadClearance
from boomtip.perception.lift_doppler import LiftRadarConfig, load_spin, measure_clearance_rate

ORIGIN = np.array([1.5, -0.6, -0.8])  # the radar, levelled frame at the tip
HOOK = np.array([0.3, -0.2, -50.0])
HOOK_V = np.array([0.12, -0.05, -0.4])  # relative to the tip: swinging and lowered
HOOK_V_COV = np.diag([0.02, 0.02, 0.01]) ** 2  # the hook tracker's
DECK_PLANE = np.array([-62.0, 0.02, -0.03])  # z = a + b x + c y: rolled and pitched
DECK_U = np.array([0.35, -0.2, 0.6])  # the deck's velocity relative to the radar at the radar's origin
DECK_SPIN = np.array([0.015, -0.01, 0.002])
TOP_Z = -57.0  # the load's top face (level here)


def _deck_z(xy):
    return DECK_PLANE[0] + xy @ DECK_PLANE[1:]


def _scene(rng, n_deck=600, n_load=40):
    ang = rng.uniform(0, 2 * np.pi, n_deck)
    rad = rng.uniform(5.0, 13.0, n_deck)
    xy = np.column_stack([rad * np.cos(ang), rad * np.sin(ang)]) + HOOK[:2]
    deck = np.column_stack([xy, _deck_z(xy)])
    load_xy = rng.uniform([-3.0, -1.2], [3.0, 1.2], (n_load, 2)) + HOOK[:2] * (TOP_Z / HOOK[2])
    load = np.column_stack([load_xy, np.full(n_load, TOP_Z)])
    spin = load_spin(HOOK, HOOK_V)
    v_deck = DECK_U + np.cross(DECK_SPIN, deck - ORIGIN)
    v_load = HOOK_V + np.cross(spin, load - HOOK)
    pts, v = np.vstack([deck, load]), np.vstack([v_deck, v_load])
    b = (pts - ORIGIN) / np.linalg.norm(pts - ORIGIN, axis=1, keepdims=True)
    return pts, np.einsum("ij,ij->i", b, v)


def _fix(lowest, centre):
    return LoadClearance("ok", float(lowest[2] - _deck_z(lowest[:2])), 0.01, lowest, centre, 0.01,
                         float(_deck_z(lowest[:2])), float(_deck_z(centre[:2])), 0.01, 40, 600, DECK_PLANE)


def _height_rate(point):
    """d/dt of the point's height above the deck straight below it, the point riding on the load
    and the deck moving rigidly: by a central difference of the moved geometry."""
    dt = 1e-4
    spin = load_spin(HOOK, HOOK_V)
    v_point = HOOK_V + np.cross(spin, point - HOOK)
    n = np.array([-DECK_PLANE[1], -DECK_PLANE[2], 1.0])
    p0 = np.array([0.0, 0.0, DECK_PLANE[0]])  # a point of the deck plane

    def height(s):
        theta = DECK_SPIN * s
        angle = np.linalg.norm(theta)
        k = theta / angle
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
        n_s = R @ n
        p_s = ORIGIN + R @ (p0 - ORIGIN) + DECK_U * s  # u: the deck's velocity at the radar's origin
        q = point + v_point * s
        return float(((q - p_s) @ n_s) / n_s[2])

    return (height(dt) - height(-dt)) / (2 * dt)


def test_the_rates_are_the_heights_derivatives_slope_and_spins_included():
    rng = np.random.default_rng(3)
    pts, rate = _scene(rng)
    centre = np.append(HOOK[:2] * (TOP_Z / HOOK[2]), TOP_Z - 2.6)
    lowest = centre + np.array([3.0, 1.2, 0.0])
    out = measure_clearance_rate(pts, ORIGIN, rate, _fix(lowest, centre), 3.3, 2.6, HOOK, HOOK_V, HOOK_V_COV, DECK_SPIN, 1.0,
                                 LiftRadarConfig(), 0.01, rng)
    assert out.ok, out.status
    assert out.clearance_rate_mps == pytest.approx(_height_rate(lowest), abs=2e-4)
    assert out.centre_rate_mps == pytest.approx(_height_rate(centre), abs=2e-4)
    # the slope's term is not small: without it the rate would be off by several millimetres a second
    assert abs(_height_rate(centre) - (HOOK_V[2] - (DECK_U + np.cross(DECK_SPIN, centre - ORIGIN))[2])) > 0.005
    assert out.n_load == 40 and out.n_deck == 600
    assert out.load_mask.sum() == 40 and out.deck_mask.sum() == 600


def test_noisy_rates_give_a_sigma_that_covers_the_error():
    errors, sigmas = [], []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        pts, rate = _scene(rng, n_load=25)
        rate = rate + 0.049 * rng.standard_normal(len(rate))
        centre = np.append(HOOK[:2] * (TOP_Z / HOOK[2]), TOP_Z - 2.6)
        out = measure_clearance_rate(pts, ORIGIN, rate, _fix(centre, centre), 3.3, 2.6, HOOK, HOOK_V, HOOK_V_COV, DECK_SPIN, 1.0,
                                     LiftRadarConfig(), 0.049, rng)
        errors.append(out.centre_rate_mps - _height_rate(centre))
        sigmas.append(out.centre_sigma_mps)
    z = np.array(errors) / np.array(sigmas)
    assert 0.6 < np.sqrt(np.mean(z**2)) < 1.5  # honest: the scatter is the stated sigma's
    assert np.median(sigmas) < 0.015  # 25 load detections at 4.9 cm/s each


def test_too_few_detections_or_no_fix_say_why():
    rng = np.random.default_rng(0)
    pts, rate = _scene(rng, n_load=3)
    centre = np.append(HOOK[:2] * (TOP_Z / HOOK[2]), TOP_Z - 2.6)
    out = measure_clearance_rate(pts, ORIGIN, rate, _fix(centre, centre), 3.3, 2.6, HOOK, HOOK_V, HOOK_V_COV, None, 1.0,
                                 LiftRadarConfig(), 0.049, rng)
    assert not out.ok and out.status == "too few detections: 3 on the load, 600 on the deck"
    out = measure_clearance_rate(pts, ORIGIN, rate, LoadClearance("too few load points"), 3.3, 2.6, HOOK, HOOK_V, HOOK_V_COV, None,
                                 1.0, LiftRadarConfig(), 0.049, rng)
    assert not out.ok and out.status == "no LiDAR fix of the load and deck" and math.isnan(out.clearance_rate_mps)
    empty = measure_clearance_rate(np.zeros((0, 3)), ORIGIN, np.zeros(0), _fix(centre, centre), 3.3, 2.6, HOOK, HOOK_V,
                                   HOOK_V_COV, None, 1.0, LiftRadarConfig(), 0.049, rng)
    assert empty.status == "too few detections: 0 in the scan"


def test_nan_detections_are_left_out():
    rng = np.random.default_rng(1)
    pts, rate = _scene(rng)
    pts[:5] = np.nan
    rate[5:10] = np.nan
    centre = np.append(HOOK[:2] * (TOP_Z / HOOK[2]), TOP_Z - 2.6)
    out = measure_clearance_rate(pts, ORIGIN, rate, _fix(centre, centre), 3.3, 2.6, HOOK, HOOK_V, HOOK_V_COV, DECK_SPIN, 1.0,
                                 LiftRadarConfig(), 0.01, rng)
    assert out.ok and out.n_deck == 590 and np.isfinite(out.centre_rate_mps)


def _corners(centre):
    return centre + np.array([[sx * 3.0, sy * 1.2, 0.0] for sx in (-1, 1) for sy in (-1, 1)])


def _rate(pts, rate, fix):
    return measure_clearance_rate(pts, ORIGIN, rate, fix, 3.3, 2.6, HOOK, HOOK_V, HOOK_V_COV, DECK_SPIN, 1.0,
                                  LiftRadarConfig(), 0.01, np.random.default_rng(0))


def test_a_clearly_lowest_corner_gives_its_own_rate():
    pts, rate = _scene(np.random.default_rng(4))
    centre = np.append(HOOK[:2] * (TOP_Z / HOOK[2]), TOP_Z - 2.6)
    corners = _corners(centre)
    low = int(np.argmin(corners[:, 2] - _deck_z(corners[:, :2])))
    alone = _rate(pts, rate, dataclasses.replace(_fix(corners[low], centre), candidates_m=corners[[low]]))
    sure = _rate(pts, rate, dataclasses.replace(_fix(corners[low], centre), candidates_m=corners, candidate_sigmas_m=np.full(4, 1e-4)))
    assert sure.clearance_rate_mps == pytest.approx(alone.clearance_rate_mps, abs=1e-12)
    assert sure.clearance_rate_mps == pytest.approx(_height_rate(corners[low]), abs=2e-4)
    assert sure.sigma_mps == pytest.approx(alone.sigma_mps, rel=1e-9)


def test_two_corners_equally_low_give_the_mean_of_their_rates_widened_by_their_difference():
    pts, rate = _scene(np.random.default_rng(4))
    centre = np.append(HOOK[:2] * (TOP_Z / HOOK[2]), TOP_Z - 2.6)
    corners = _corners(centre)
    heights = corners[:, 2] - _deck_z(corners[:, :2])
    i, j = np.argsort(heights)[:2]
    corners[j, 2] -= heights[j] - heights[i]  # tied
    corners[[k for k in range(4) if k not in (i, j)], 2] += 1.0  # the others far above
    each = [_rate(pts, rate, dataclasses.replace(_fix(corners[k], centre), candidates_m=corners[[k]])) for k in (i, j)]
    tied = _rate(pts, rate, dataclasses.replace(_fix(corners[i], centre), candidates_m=corners, candidate_sigmas_m=np.full(4, 0.01)))
    r = [e.clearance_rate_mps for e in each]
    assert abs(r[0] - r[1]) > 0.01  # the tilting load's corners part by centimetres a second
    assert tied.clearance_rate_mps == pytest.approx(np.mean(r), abs=1e-12)
    assert tied.sigma_mps == pytest.approx(math.sqrt(np.mean([e.sigma_mps**2 for e in each]) + (r[0] - r[1]) ** 2 / 4), rel=1e-9)


def test_an_unknown_deck_spin_costs_its_sigma_through_the_whole_lever():
    rng = np.random.default_rng(5)
    pts, rate = _scene(rng)
    centre = np.append(HOOK[:2] * (TOP_Z / HOOK[2]), TOP_Z - 2.6)
    cfg = LiftRadarConfig()
    known = measure_clearance_rate(pts, ORIGIN, rate, _fix(centre, centre), 3.3, 2.6, HOOK, HOOK_V, HOOK_V_COV, DECK_SPIN,
                                   1.0, cfg, 0.01, np.random.default_rng(0))
    unknown = measure_clearance_rate(pts, ORIGIN, rate, _fix(centre, centre), 3.3, 2.6, HOOK, HOOK_V, HOOK_V_COV, None,
                                     1.0, cfg, 0.01, np.random.default_rng(0))
    # the spin left out is an error the sigma must cover, and it does: through the slope, 60 m of
    # lever turn a spin of a hundredth of a radian a second into millimetres to centimetres a second
    error = abs(unknown.centre_rate_mps - _height_rate(centre))
    assert error > 0.005 and error < 3 * unknown.centre_sigma_mps
    assert unknown.centre_sigma_mps > 10 * known.centre_sigma_mps


def test_without_a_load_model_the_load_is_whatever_hangs_above_the_deck():
    rng = np.random.default_rng(6)
    pts, rate = _scene(rng)
    centre = np.append(HOOK[:2] * (TOP_Z / HOOK[2]), TOP_Z)  # without a model: the lowest seen is the top
    out = measure_clearance_rate(pts, ORIGIN, rate, _fix(centre, centre), 8.0, math.inf, HOOK, HOOK_V, HOOK_V_COV,
                                 DECK_SPIN, 1.0, LiftRadarConfig(), 0.01, rng)
    assert out.ok and out.n_load == 40
    assert out.centre_rate_mps == pytest.approx(_height_rate(centre), abs=2e-4)
