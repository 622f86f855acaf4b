"""Rigid poses: the angles of rotation matrices undo rpy_matrices."""

from __future__ import annotations

import numpy as np

from boomtip.data.poses import matrices_rpy, pose_vector, rpy_matrices


def test_the_angles_of_rotations_are_those_they_were_made_from():
    rng = np.random.default_rng(0)
    rpy = rng.uniform(-1.5, 1.5, (200, 3)) * (1.0, 1.0, 2.0)  # pitch within +-90 deg, yaw about
    R = rpy_matrices(rpy)
    assert np.allclose(matrices_rpy(R), rpy, atol=1e-12)
    T = np.eye(4)
    T[:3, :3] = R[7]
    assert np.allclose(pose_vector(T)[3:], matrices_rpy(R[7:8])[0], atol=1e-15)  # the single pose's the same
