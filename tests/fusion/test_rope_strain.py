"""The rope's length beyond the hoist's reading, learnt causally from the block fixes: an
offset and a strain, parted as the hoist changes."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.fusion.hook_run import along_rope_sigma, with_length_sigma
from boomtip.fusion.rope_strain import rope_length

ARGS = (0.2, 2e-3, 1e-3, 5e-5)  # prior offset and strain sigmas, their walks


def _fixes(offset: float, strain: float, hoist_fn, n: int = 600, sigma: float = 0.15, seed: int = 1):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 10.0
    te = np.arange(0, n / 10.0, 0.01)
    hoist = hoist_fn(te)
    u = np.array([0.02, -0.01, -1.0]) / np.linalg.norm([0.02, -0.01, -1.0])
    true = hoist_fn(t) * (1 + strain) + offset
    p = (true + rng.normal(0, sigma, n))[:, None] * u
    return t, p, np.full(n, sigma), te, hoist


def test_a_softer_reeving_s_stretch_and_an_offset_part_as_the_hoist_changes():
    """Hoisting from 40 to 115 m: a 9 cm stretch at 115 m (strain 8e-4) and a 0.1 m offset of
    the fitted block point are told apart, and the correction at 115 m is within its sigma."""
    hoist = lambda t: 40.0 + 75.0 * np.clip(t / 60.0, 0.0, 1.0)
    t, p, s, te, h = _fixes(0.1, 8e-4, hoist)
    est = rope_length(t, p, s, te, h, *ARGS)
    delta, sigma = est.correction(np.array([60.5]), np.array([115.0]))
    assert delta[0] == pytest.approx(0.1 + 8e-4 * 115.0, abs=3 * sigma[0]) and sigma[0] < 0.03
    assert est.state[-1, 1] == pytest.approx(8e-4, abs=4e-4)


def test_before_any_fix_the_prior_and_a_fix_applies_only_after_it():
    t, p, s, te, h = _fixes(0.0, 8e-4, lambda t: np.full_like(t, 115.0), n=50)
    est = rope_length(t, p, s, te, h, *ARGS)
    d, sig = est.correction(np.array([-1.0, t[5], t[5] + 0.002]), np.full(3, 115.0))
    assert d[0] == 0.0 and sig[0] == pytest.approx(np.hypot(0.2, 2e-3 * 115.0))
    assert d[1] == est.correction(np.array([t[4] + 0.002]), np.array([115.0]))[0][0]  # stamped with fix 5: before it
    assert d[2] != d[1]


def test_a_wild_fix_is_gated_and_nan_fixes_are_skipped():
    t, p, s, te, h = _fixes(0.0, 0.0, lambda t: np.full_like(t, 115.0), n=200)
    p[100] *= 1.05  # 5.7 m off
    p[50] = np.nan
    est = rope_length(t, p, s, te, h, *ARGS)
    assert np.array_equal(est.state[100], est.state[99]) and np.array_equal(est.state[50], est.state[49])
    assert np.all(np.isfinite(est.state))


def test_the_length_sigma_lies_along_the_rope():
    p = np.array([[0.0, 0.0, -100.0], [60.0, 0.0, -80.0]])
    cov = with_length_sigma(p, np.zeros((2, 3, 3)), np.array([0.1, 0.1]))
    assert cov[0, 2, 2] == pytest.approx(0.01) and cov[0, 0, 0] == 0.0
    assert cov[1] == pytest.approx(0.01 * np.outer([0.6, 0, -0.8], [0.6, 0, -0.8]))
    c = np.diag([1.0, 1.0, 4.0])[None].repeat(2, 0)
    assert along_rope_sigma(p, np.array([0.5, np.nan]), c, 0.02) == pytest.approx([2.0, np.sqrt(0.36 + 0.64 * 4)])
    assert along_rope_sigma(p, np.array([0.5, np.nan]), None, 0.02) == pytest.approx([0.5, 0.02])
