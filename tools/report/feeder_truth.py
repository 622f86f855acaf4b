"""The feeder frame's true pose and twist in the crane vessel's heading frame, from a truth
table (truth.csv's crane_* and feeder_* columns), with the estimator's definition applied
to the truth at the first frame: origin at the deck point straight below the boom tip,
z along the deck normal, x along the feeder's centre line. Scoring only: processing never
sees it.

Heading frame: origin at the boom tip, z up (gravity), x along the crane's heading; it moves
with the tip and turns with the crane's yaw, not with its roll and pitch.
"""

from __future__ import annotations

import numpy as np
from boomtip.data.frames import Truth
from scipy.spatial.transform import Rotation

POSE = ("x", "y", "z", "roll", "pitch", "yaw")


def body_pose_world(truth: Truth, body: str, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T,3,3) rotations and (T,3) positions of a body (crane, feeder) in the world at t; NaN
    outside the truth's span."""
    rpy = np.column_stack([truth.at(f"{body}_{a}", t_s) for a in ("roll", "pitch", "yaw")])
    p = np.column_stack([truth.at(f"{body}_{a}", t_s) for a in ("x", "y", "z")])
    R = np.full((len(t_s), 3, 3), np.nan)
    ok = np.all(np.isfinite(rpy), axis=1)
    if ok.any():
        R[ok] = Rotation.from_euler("ZYX", rpy[ok, ::-1]).as_matrix()
    return R, p


def feeder_origin_body(truth: Truth, t0_s: float, p_tip_crane_m: np.ndarray) -> np.ndarray:
    """The deck point straight below the boom tip at t0, in feeder body coordinates (the
    body's deck is its z = freeboard plane; truth.D is the vertical distance to it)."""
    t = np.array([t0_s])
    R_c, p_c = body_pose_world(truth, "crane", t)
    R_f, p_f = body_pose_world(truth, "feeder", t)
    p_tip = R_c[0] @ p_tip_crane_m + p_c[0]
    p_deck = p_tip - np.array([0.0, 0.0, float(truth.at("D", t)[0])])
    return R_f[0].T @ (p_deck - p_f[0])


def feeder_pose_truth(truth: Truth, t_s: np.ndarray, origin_body_m: np.ndarray, p_tip_crane_m: np.ndarray) -> np.ndarray:
    """(T, 6) x, y, z, roll, pitch, yaw of the feeder frame in the heading frame."""
    R_c, p_c = body_pose_world(truth, "crane", t_s)
    p_tip = np.einsum("tij,j->ti", R_c, p_tip_crane_m) + p_c
    R_f, p_f = body_pose_world(truth, "feeder", t_s)
    yaw_c = truth.at("crane_yaw", t_s)
    c, s_ = np.cos(yaw_c), np.sin(yaw_c)
    Rz_T = np.zeros((len(t_s), 3, 3))
    Rz_T[:, 0, 0], Rz_T[:, 0, 1], Rz_T[:, 1, 0], Rz_T[:, 1, 1], Rz_T[:, 2, 2] = c, s_, -s_, c, 1.0
    R_hf = Rz_T @ R_f
    p_hf = np.einsum("tij,tj->ti", Rz_T, p_f + np.einsum("tij,j->ti", R_f, origin_body_m) - p_tip)
    rpy = np.full((len(t_s), 3), np.nan)
    ok = np.all(np.isfinite(R_hf), axis=(1, 2))
    if ok.any():
        rpy[ok] = Rotation.from_matrix(R_hf[ok]).as_euler("ZYX")[:, ::-1]
    return np.column_stack([p_hf, rpy])


def feeder_twist_truth(truth: Truth, t_s: np.ndarray, origin_body_m: np.ndarray, p_tip_crane_m: np.ndarray,
                       dt_s: float = 1e-3) -> np.ndarray:
    """(T, 6) rates of the pose (m/s, rad/s of the Euler angles): central differences of the
    closed-form pose, whose error at 1 ms is far below any estimator's."""
    a = feeder_pose_truth(truth, t_s - dt_s, origin_body_m, p_tip_crane_m)
    b = feeder_pose_truth(truth, t_s + dt_s, origin_body_m, p_tip_crane_m)
    d = b - a
    d[:, 3:] = (d[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    return d / (2 * dt_s)
