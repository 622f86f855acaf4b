"""Rigid poses shared by the simulator, perception and fusion: R = Rz(yaw) Ry(pitch) Rx(roll),
4x4 transforms, their inverse and their action on points. Pure functions."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["rpy_matrix", "rpy_matrices", "pose_matrix", "pose_vector", "inverse", "transform"]


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


def rpy_matrices(rpy: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) for (T,3) angles: (T,3,3)."""
    if len(rpy) == 1:  # one instant (a frame's pose): Python floats, not 20 calls on 1-element arrays
        roll, pitch, yaw = rpy[0].tolist()
        cr, cp, cy, sr, sp, sy = math.cos(roll), math.cos(pitch), math.cos(yaw), math.sin(roll), math.sin(pitch), math.sin(yaw)
        return np.array([[[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                          [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                          [-sp, cp * sr, cp * cr]]])
    # Each angle's cosine and sine contiguous, the nine entries built in a (9, T) array and
    # turned to (T, 3, 3) in one copy: a sweep's columns, T = 1024, twice a frame.
    c, s = np.cos(rpy.T), np.sin(rpy.T)
    cr, cp, cy, sr, sp, sy = c[0], c[1], c[2], s[0], s[1], s[2]
    cysp, sysp = cy * sp, sy * sp
    R = np.empty((9, len(rpy)))
    np.multiply(cy, cp, out=R[0])
    np.multiply(cysp, sr, out=R[1])
    R[1] -= sy * cr
    np.multiply(cysp, cr, out=R[2])
    R[2] += sy * sr
    np.multiply(sy, cp, out=R[3])
    np.multiply(sysp, sr, out=R[4])
    R[4] += cy * cr
    np.multiply(sysp, cr, out=R[5])
    R[5] -= cy * sr
    np.negative(sp, out=R[6])
    np.multiply(cp, sr, out=R[7])
    np.multiply(cp, cr, out=R[8])
    return np.ascontiguousarray(R.T).reshape(-1, 3, 3)


def matrices_rpy(R: np.ndarray) -> np.ndarray:
    """(T,3) angles (roll, pitch, yaw) of (T,3,3) rotations R = Rz(yaw) Ry(pitch) Rx(roll): rpy_matrices' inverse."""
    return np.column_stack([np.arctan2(R[:, 2, 1], R[:, 2, 2]), -np.arcsin(np.clip(R[:, 2, 0], -1.0, 1.0)),
                            np.arctan2(R[:, 1, 0], R[:, 0, 0])])


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
