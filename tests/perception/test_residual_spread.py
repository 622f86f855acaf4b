"""A fit's residual spread pooled over frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from boomtip.perception.residual_spread import ResidualSpread

SIGMA_M, POINTS = 0.03, 12


def _frames(n: int, seed: int = 4) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, SIGMA_M, (n, POINTS))


def test_without_memory_a_frame_has_its_own_spread():
    r = _frames(1)[0]
    spread = ResidualSpread().pooled(0.0, float(r @ r), POINTS - 1, 0.0).pooled(0.05, 4.0 * float(r @ r), POINTS - 1, 0.0)
    assert spread.sigma_m == pytest.approx(2.0 * math.sqrt(float(r @ r) / (POINTS - 1)))


def test_an_earlier_frame_weighs_less_with_its_age_and_none_before_any():
    assert math.isnan(ResidualSpread().sigma_m)
    spread = ResidualSpread().pooled(0.0, 1.0, 1.0, 1.0).pooled(2.0, 4.0, 1.0, 1.0)
    w = math.exp(-2.0)
    assert spread.sigma_m == pytest.approx(math.sqrt((w * 1.0 + 4.0) / (w + 1.0)))
    # a frame that comes before the last one starts afresh rather than weighing the pool up
    assert ResidualSpread().pooled(5.0, 1.0, 1.0, 1.0).pooled(4.0, 4.0, 1.0, 1.0).sigma_m == pytest.approx(2.0)


def test_a_frame_without_a_finite_spread_leaves_the_pool_as_it_was():
    pool = ResidualSpread().pooled(0.0, 1.0, 4.0, 1.0)
    assert pool.pooled(0.05, math.nan, 4.0, 1.0) == pool and pool.pooled(0.05, 1.0, 0.0, 1.0) == pool


def test_a_pooled_spread_is_the_sensors_and_an_error_in_its_sigmas_is_one():
    # each frame: a mean of POINTS noisy heights, its sigma from the frame's own spread or the pool's
    frames = _frames(4000)
    err = frames.mean(axis=1)
    ss = np.sum((frames - err[:, None]) ** 2, axis=1)
    own = np.sqrt(ss / (POINTS - 1) / POINTS)
    pool, pooled = ResidualSpread(), np.empty(len(frames))
    for k, s in enumerate(ss):  # 20 frames a second, a second's memory
        pool = pool.pooled(0.05 * k, float(s), POINTS - 1, 1.0)
        pooled[k] = pool.sigma_m / math.sqrt(POINTS)
    assert np.std(pooled[100:]) / SIGMA_M * math.sqrt(POINTS) < 0.06  # the frames' own scatter by ~0.2
    assert np.sqrt(np.mean((err / own) ** 2)) > 1.08  # a noisy sigma makes the errors look too large
    assert np.sqrt(np.mean((err[100:] / pooled[100:]) ** 2)) == pytest.approx(1.0, abs=0.03)
