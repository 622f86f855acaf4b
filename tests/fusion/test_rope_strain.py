"""The rope's strain beyond its nominal, learnt causally from the block fixes."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.fusion.hook_run import along_rope_sigma, with_length_sigma
from boomtip.fusion.rope_strain import rope_strain


def _fixes(strain: float, n: int = 600, length: float = 115.0, sigma: float = 0.15, seed: int = 1):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 10.0
    u = np.array([0.02, -0.01, -1.0]) / np.linalg.norm([0.02, -0.01, -1.0])
    p = (length * (1 + strain) + rng.normal(0, sigma, n))[:, None] * u
    return t, p, np.full(n, sigma), np.arange(0, 60, 0.01), np.full(6000, length)


def test_a_softer_reeving_s_extra_strain_is_learnt_within_its_sigma():
    t, p, s, te, hoist = _fixes(8e-4)  # 9 cm at 115 m
    est = rope_strain(t, p, s, te, hoist, 2e-3, 5e-5)
    assert est.strain[-1] == pytest.approx(8e-4, abs=3 * est.sigma[-1]) and est.sigma[-1] < 2e-4
    e, sig = est.at(np.array([-1.0, 30.0, 1e3]))
    assert e[0] == 0.0 and sig[0] == 2e-3  # before the first fix: the prior
    assert sig[1] > est.sigma[-1] and e[2] == est.strain[-1]  # causal: only the fixes so far


def test_a_wild_fix_is_gated_and_nan_fixes_are_skipped():
    t, p, s, te, hoist = _fixes(0.0, n=200)
    p[100] *= 1.05  # 5.7 m off
    p[50] = np.nan
    est = rope_strain(t, p, s, te, hoist, 2e-3, 5e-5)
    assert est.strain[100] == est.strain[99] and est.strain[50] == est.strain[49]  # gated, skipped: no change
    assert abs(est.strain[101]) < 3 * est.sigma[101] and np.all(np.isfinite(est.strain))


def test_the_length_sigma_lies_along_the_rope():
    p = np.array([[0.0, 0.0, -100.0], [60.0, 0.0, -80.0]])
    cov = with_length_sigma(p, np.zeros((2, 3, 3)), np.array([1e-3, 1e-3]))
    assert cov[0, 2, 2] == pytest.approx(0.01) and cov[0, 0, 0] == 0.0
    assert cov[1] == pytest.approx(0.01 * np.outer([0.6, 0, -0.8], [0.6, 0, -0.8]))
    c = np.diag([1.0, 1.0, 4.0])[None].repeat(2, 0)
    assert along_rope_sigma(p, np.array([0.5, np.nan]), c, 0.02) == pytest.approx([2.0, np.sqrt(0.36 + 0.64 * 4)])
    assert along_rope_sigma(p, np.array([0.5, np.nan]), None, 0.02) == pytest.approx([0.5, 0.02])
