"""Doppler ambiguity: wrapped range rates back on the branch a prior predicts, and the prior
from the last scan's velocity and the last decks' distances."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.perception.doppler import doppler_velocity
from boomtip.perception.doppler_alias import alias_prior_level, deck_rate, unwrap_range_rates


def _scan(u_true, v, rng, n=300):
    az, el = rng.uniform(-0.5, 0.5, n), rng.uniform(-0.1, 0.1, n)
    b = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    b = b[:, [1, 2, 0]] * np.array([1.0, 1.0, -1.0])  # looking down -z
    points = b * rng.uniform(30, 50, n)[:, None]
    true = b @ u_true + rng.normal(0, 0.02, n)
    return points, true, np.mod(true + v, 2 * v) - v


def test_unwrapping_with_a_prior_within_v_restores_every_rate_and_the_velocity():
    rng = np.random.default_rng(4)
    u_true = np.array([0.3, -0.2, 1.9])  # the deck coming up fast: beyond 1.25 m/s along the beams
    points, true, wrapped = _scan(u_true, 1.25, rng)
    assert np.max(np.abs(true - wrapped)) > 2.0  # really wrapped
    for prior in (u_true + [0.4, -0.3, 0.9], u_true - [0.0, 0.0, 1.0]):  # off by up to 1 m/s
        back = unwrap_range_rates(points, wrapped, 1.25, prior)
        np.testing.assert_allclose(back, true, atol=1e-9)
    fit = doppler_velocity(points, unwrap_range_rates(points, wrapped, 1.25, u_true), None, np.random.default_rng(0))
    assert fit.velocity_sensor == pytest.approx(u_true, abs=0.01)
    assert unwrap_range_rates(points, wrapped, 0.0, u_true) is wrapped  # a radar that never wraps: as reported


def test_the_prior_takes_the_scan_velocity_and_the_freshest_decks_rate():
    last = (10.0, np.array([0.2, 0.1, -0.5]))
    lidar = [(9.9, 40.00), (10.0, 39.85)]  # D falling 1.5 m/s: the deck comes up, u_z = +1.5
    radar = [(9.95, 40.0), (10.0, 40.2)]
    assert deck_rate(10.05, lidar) == pytest.approx(-1.5)
    assert alias_prior_level(10.05, last, [lidar, radar]) == pytest.approx([0.2, 0.1, 1.5])
    assert alias_prior_level(10.05, last, [[], radar]) == pytest.approx([0.2, 0.1, -4.0])
    assert alias_prior_level(10.05, None, [lidar, radar]) == pytest.approx([0.0, 0.0, 1.5])
    assert alias_prior_level(10.05, last, [[], []]) == pytest.approx(last[1])
    assert alias_prior_level(11.0, last, [lidar, radar]) is None  # all too old: the alias is not known
    assert deck_rate(10.05, [(9.0, 40.0), (10.0, 39.0)]) is None  # the decks a second apart: no rate
    # with a branch width: the scan's velocity stands unless the distances say its branch is wrong
    near = (10.0, np.array([0.2, 0.1, 1.4]))
    assert alias_prior_level(10.05, near, [lidar], 1.25) == pytest.approx([0.2, 0.1, 1.4])
    assert alias_prior_level(10.05, last, [lidar], 1.25) == pytest.approx([0.2, 0.1, 1.5])
