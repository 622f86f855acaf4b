"""Tests for perception.plane_moments (a plane's least-squares fit from its points' moments)."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.perception.plane_moments import fit_plane_cols, select_inliers, eigh3


def test_eigh3_is_numpys_eigh_bit_for_bit_and_fails_as_it_does():
    rng = np.random.default_rng(7)
    for _ in range(300):  # scatters of patches from millimetres to kilometres across
        a = rng.normal(size=(3, 40)) * 10.0 ** rng.uniform(-3, 3, size=(3, 1))
        s = a @ a.T
        w_ref, v_ref = np.linalg.eigh(s)
        w, v = eigh3(s)
        assert np.array_equal(w, w_ref) and np.array_equal(v, v_ref)
    w, v = eigh3(np.diag([3.0, 1.0, 2.0]))
    assert np.array_equal(w, [1.0, 2.0, 3.0]) and np.array_equal(np.abs(v), [[0, 0, 1], [1, 0, 0], [0, 1, 0]])
    with pytest.raises(np.linalg.LinAlgError):
        eigh3(np.full((3, 3), np.nan))


def test_fit_and_inliers_on_columns():
    rng = np.random.default_rng(8)
    pts = np.column_stack([rng.uniform(-5, 5, 400), rng.uniform(-5, 5, 400), np.full(400, -20.0)])
    pts[:, 2] += rng.normal(0, 0.01, 400)
    pts[:40, 2] += 3.0  # off the plane
    cols = np.ascontiguousarray(pts.T)
    plane = fit_plane_cols(cols[:, 40:])
    assert plane[3] > 0 and abs(abs(plane[2]) - 1.0) < 1e-5 and abs(plane[3] - 20.0) < 0.01
    idx = select_inliers(cols, plane, 0.05)
    assert idx.dtype == np.intp and np.array_equal(idx, np.arange(40, 400))
