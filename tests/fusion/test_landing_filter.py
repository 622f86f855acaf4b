"""The landing point's offset from the rope's line: a random walk per axis."""

from __future__ import annotations

import math

import numpy as np

from boomtip.fusion.landing_filter import LandingOffsetFilter


def test_noisy_offsets_are_averaged_to_their_stated_sigma():
    rng = np.random.default_rng(1)
    f = LandingOffsetFilter(rate_sigma_mps=0.01)
    true = np.array([0.3, -0.2])
    for k in range(400):
        assert f.update(0.05 * k, true + 0.07 * rng.standard_normal(2), 0.07)
    sigma = math.sqrt(f.predicted_var(20.0))
    assert sigma < 0.02
    assert np.all(np.abs(f.x - true) < 3 * sigma)


def test_errors_shared_by_neighbouring_frames_keep_the_sigma_honest():
    """Centre errors correlated over 0.5 s (an AR(1) at 20 Hz): taken as independent, the filter's
    sigma shrinks below its error; with their correlation time it covers it."""
    rng = np.random.default_rng(2)
    dt, tau, n = 0.05, 0.5, 4000
    phi = math.exp(-dt / tau)
    e = np.zeros((n, 2))
    for k in range(1, n):  # a recursion over time steps, a few thousand
        e[k] = phi * e[k - 1] + 0.07 * math.sqrt(1 - phi**2) * rng.standard_normal(2)
    true = np.array([0.3, -0.2])
    cover = {}
    for corr in (0.0, tau):
        f = LandingOffsetFilter(rate_sigma_mps=0.01, error_correlation_s=corr)
        inside = []
        for k in range(n):
            f.update(dt * k, true + e[k], 0.07)
            if k >= 200:
                inside.append(np.all(np.abs(f.x - true) <= 3 * math.sqrt(f.predicted_var(dt * k))))
        cover[corr] = np.mean(inside)
    assert cover[0.0] < 0.9 and cover[tau] > 0.97


def test_an_offset_far_outside_the_prediction_is_gated_and_nan_is_ignored():
    f = LandingOffsetFilter(rate_sigma_mps=0.01)
    for k in range(50):
        f.update(0.05 * k, np.array([0.0, 0.0]), 0.05)
    x = f.x.copy()
    assert not f.update(2.6, np.array([3.0, 0.0]), 0.05)
    assert not f.update(2.65, np.array([np.nan, 0.0]), 0.05)
    assert np.array_equal(f.x, x)


def test_its_variance_grows_while_no_frame_comes():
    f = LandingOffsetFilter(rate_sigma_mps=0.05)
    f.update(0.0, np.zeros(2), 0.05)
    assert f.predicted_var(10.0) > f.predicted_var(1.0) > f.predicted_var(0.0)
    assert math.isinf(LandingOffsetFilter(0.05).predicted_var(0.0))
