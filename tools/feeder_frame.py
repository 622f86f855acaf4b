"""The filter's states as the estimates are written: the feeder frame (origin and centre line
as the whole run found them) in the heading frame at the tip, levelled with the run's final
calibration, with the levelling's own uncertainty added to the variances."""

from __future__ import annotations

import numpy as np
from boomtip.fusion.level_calibration import Tilt
from boomtip.perception.feeder_registration import pose_matrix, pose_vector


def estimates_in_feeder_frame(out, tips: list[np.ndarray], pivots: list[np.ndarray], tilt: Tilt | None, C_final: np.ndarray,
                              T_map_feeder: np.ndarray, sigma_level: float, mru_bias_sigma_rad: float,
                              line_sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T, 6) poses, (T, 6) rates and (T, 12) variances of the filter's recorded states `out`
    (FeederEstimates); tips and pivots: the tip's velocity and the LiDAR's position at each."""
    # The levelling's own uncertainty: the calibration's sigma once it has one, else the
    # survey's. Corrected about the LiDAR, a tilt moves the deck below it sideways by its
    # lever. The MRU's bias tilts the same sensor-to-level rotation as a mount error and is
    # calibrated with it; what it moves besides is the tip about the vessel's origin, which the
    # estimate (relative to the tip) sees only in z, by the horizontal offset.
    s_lvl = tilt.sigma_rad if tilt is not None else sigma_level
    # about the vertical: the own hull's calibration, else the survey's mount accuracy
    s_rz = tilt.rz_sigma_rad if tilt is not None and tilt.rz_sigma_rad is not None else sigma_level
    pose, rates, var = [], [], []
    for x, P, tip, pivot in zip(out.x, out.P, tips, pivots):
        x = relative_to_tip(x, tip)
        y, J = _feeder_pose_jacobian(x[:6], C_final, pivot, T_map_feeder)
        lever = float(np.linalg.norm(y[:3] - pivot))
        extra = np.array([(lever * s_lvl) ** 2] * 2 + [(float(np.hypot(y[0], y[1])) * mru_bias_sigma_rad) ** 2,
                                                      s_lvl ** 2, s_lvl ** 2, line_sigma ** 2 + s_rz ** 2])
        pose.append(y)
        rates.append(J @ x[6:12])
        var.append(np.concatenate([np.diag(J @ P[:6, :6] @ J.T) + extra, np.diag(J @ P[6:12, 6:12] @ J.T)]))
    return np.array(pose), np.array(rates), np.array(var)


def relative_to_tip(x: np.ndarray, tip_velocity: np.ndarray) -> np.ndarray:
    """Pose and rates relative to the tip: the state's rates are relative to the vessel."""
    out = np.array(x[:12], dtype=float)
    out[6:9] -= tip_velocity
    return out


def _feeder_pose_jacobian(pose_map_level: np.ndarray, C: np.ndarray, pivot: np.ndarray,
                          T_map_feeder: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The feeder frame's pose and its Jacobian (6x6, central differences) w.r.t. the map's."""
    y = _feeder_pose(pose_map_level, C, pivot, T_map_feeder)
    J = np.zeros((6, 6))
    for j in range(6):
        e = np.zeros(6)
        e[j] = 1e-6
        d = _feeder_pose(pose_map_level + e, C, pivot, T_map_feeder) - _feeder_pose(pose_map_level - e, C, pivot, T_map_feeder)
        d[3:] = (d[3:] + np.pi) % (2 * np.pi) - np.pi
        J[:, j] = d / 2e-6
    return y, J


def _feeder_pose(pose_map_level: np.ndarray, C: np.ndarray, pivot: np.ndarray, T_map_feeder: np.ndarray) -> np.ndarray:
    """The feeder frame's pose in the corrected heading frame: the map's pose in the level
    frame, turned by the levelling correction about the LiDAR, composed with the feeder
    frame's place in the map."""
    T = pose_matrix(*pose_map_level) @ T_map_feeder
    Tc = np.eye(4)
    Tc[:3, :3] = C
    Tc[:3, 3] = pivot - C @ pivot
    return pose_vector(Tc @ T)
