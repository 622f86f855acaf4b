"""Covariance matching: a stream noisier than stated gets its variance widened to what its
innovations show, never narrowed below the statement, and one outlier moves it little."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.fusion.heave_filter import HeaveFilter, HeaveFilterConfig, Measurement
from boomtip.fusion.noise_matching import MAX_SCALE, NoiseMatch, matched_ratio


def _run(noise_scale: float, memory_s: float, seed: int = 1, n: int = 2000, stated: float = 0.01, jerk_psd: float = 0.2):
    """A still D of 20 m measured at 20 Hz with noise noise_scale x the stated sigma (q: the
    working-limit default; with a far smaller q the filter remembers the noisy start for long)."""
    rng = np.random.default_rng(seed)
    f = HeaveFilter(HeaveFilterConfig(jerk_psd=jerk_psd, noise_memory_s=memory_s))
    t = np.arange(n) / 20.0
    for tk, e in zip(t, rng.normal(0.0, noise_scale * stated, n)):
        f.add(Measurement(tk, tk, "D", 20.0 + e, stated, "deck_radar"))
    scale = dict(f._newest().noise).get("deck_radar", NoiseMatch()).scale
    return f, scale


def test_matched_ratio_is_the_real_over_the_stated_noise_on_average():
    rng = np.random.default_rng(2)
    R, HPHt = np.diag([1.0, 4.0]), np.diag([0.5, 0.5])
    ys = rng.multivariate_normal(np.zeros(2), HPHt + 9.0 * R, 20000)
    got = np.array([matched_ratio(y, R, HPHt, np.inf) for y in ys])
    assert np.mean(got) == pytest.approx(9.0, rel=0.03)
    # beyond the gate: as one on the gate; within it once the scale has widened the gate
    assert matched_ratio(np.array([10.0]), np.eye(1), np.zeros((1, 1)), 16.0) == pytest.approx(16.0)
    assert matched_ratio(np.array([10.0]), np.eye(1), np.zeros((1, 1)), 16.0, scale=9.0) == pytest.approx(100.0)
    # one the prediction's uncertainty dominates claims at most the gate times the scale
    assert matched_ratio(np.array([30.0]), np.eye(1), np.eye(1) * 99.0, 16.0) == pytest.approx(16.0)
    assert np.isnan(matched_ratio(np.array([np.nan]), np.eye(1), np.zeros((1, 1)), 16.0))


def test_a_stream_five_times_noisier_than_stated_is_widened_about_25_times():
    _, scale = _run(5.0, 5.0)
    assert scale == pytest.approx(25.0, rel=0.35)


def test_a_stream_as_noisy_as_stated_or_quieter_keeps_its_statement():
    assert _run(1.0, 5.0)[1] < 1.4
    assert _run(0.3, 5.0)[1] == 1.0
    assert _run(5.0, 0.0)[1] == 1.0  # off


def test_the_widened_sigma_is_honest_where_the_stated_one_is_not():
    for memory_s, honest in ((5.0, True), (0.0, False)):
        errs = []
        for seed in range(20):
            f, _ = _run(5.0, memory_s, seed=seed, n=600)
            x, P = f.estimate(f.last_time_s)
            errs.append((x[0] - 20.0) / np.sqrt(P[0, 0]))
        within = np.mean(np.abs(errs) < 3.0)
        assert (within >= 0.9) == honest, (memory_s, within)


def test_one_outlier_moves_the_scale_by_little():
    m = NoiseMatch()
    for k in range(100):
        m = m.after(k * 0.05, 1.0, 5.0)
    hit = m.after(5.0, matched_ratio(np.array([1e3]), np.eye(1), np.zeros((1, 1)), 15.1), 5.0)
    assert hit.scale < 1.3 and m.scale == pytest.approx(1.0)

