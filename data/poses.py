"""Rigid poses shared by the simulator, perception and fusion: R = Rz(yaw) Ry(pitch) Rx(roll),
4x4 transforms, their inverse and their action on points. Pure functions."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["rpy_matrix", "pose_matrix", "pose_vector", "inverse", "transform"]


def rpy_matrix(rpy_rad) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) for one attitude. Written out because building a scipy
    Rotation costs ~50x more than the nine products, once per frame."""
    r, p, y = rpy_rad.tolist() if isinstance(rpy_rad, np.ndarray) else (float(v) for v in rpy_rad)
    cr, cp, cy, sr, sp, sy = math.cos(r), math.cos(p), math.cos(y), math.sin(r), math.sin(p), math.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def pose_matrix(x: float, y: float, z: float, roll: float, pitch: float, yaw: float) -> np.ndarray:
    """4x4 from a position and R = Rz(yaw) Ry(pitch) Rx(roll)."""
    T = np.eye(4)
    T[:3, :3] = rpy_matrix((roll, pitch, yaw))
    T[:3, 3] = (x, y, z)
    return T


def pose_vector(T: np.ndarray) -> np.ndarray:
    """(x, y, z, roll, pitch, yaw) of a 4x4 with R = Rz(yaw) Ry(pitch) Rx(roll)."""
    R = T[:3, :3]
    return np.array([T[0, 3], T[1, 3], T[2, 3], np.arctan2(R[2, 1], R[2, 2]),
                     -np.arcsin(np.clip(R[2, 0], -1.0, 1.0)), np.arctan2(R[1, 0], R[0, 0])])


def inverse(T: np.ndarray) -> np.ndarray:
    """The inverse of a rigid 4x4 transform."""
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def transform(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) points moved by a 4x4 transform."""
    return points @ T[:3, :3].T + T[:3, 3]
