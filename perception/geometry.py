"""Relative-heave geometry shared by the stages: wire direction, tip, D and D-dot.

Frames: `sensor` is the LiDAR or radar frame; `level` is a frame with world (gravity-
aligned) axes whose origin moves with the sensor: vectors rotate from sensor to level
axes with R_level_sensor = R_world_crane(MRU) R_crane_boomtip R_boomtip_sensor.
"""

from __future__ import annotations

import numpy as np

E_Z = np.array([0.0, 0.0, 1.0])


def rpy_matrix(rpy_rad: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) for one attitude. Written out because building a scipy
    Rotation costs ~50x more than the nine products, once per frame."""
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy_rad), np.sin(rpy_rad)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def rotation_level_sensor(rpy_crane_rad: np.ndarray, T_crane_boomtip: np.ndarray, T_boomtip_sensor: np.ndarray) -> np.ndarray:
    """Sensor axes -> gravity-aligned axes, from the MRU attitude and the mount (eq. 4.3)."""
    return rpy_matrix(rpy_crane_rad) @ (T_crane_boomtip[:3, :3] @ T_boomtip_sensor[:3, :3])


def wire_dir_sensor(R_level_sensor: np.ndarray) -> np.ndarray:
    """Gravity's direction (the wire, straight down) in sensor axes: n_w^s."""
    return R_level_sensor.T @ -E_Z


def tip_in_sensor(T_boomtip_sensor: np.ndarray) -> np.ndarray:
    """The boom tip (origin of the boom-tip frame) in sensor coordinates."""
    R, t = T_boomtip_sensor[:3, :3], T_boomtip_sensor[:3, 3]
    return -R.T @ t


def heave_distance(plane_sensor: np.ndarray, wire_dir: np.ndarray, p_tip_sensor: np.ndarray) -> float:
    """D: distance from the tip along the wire to the plane n.x + d = 0 (eq. 4.8, from the tip)."""
    n, d = plane_sensor[:3], plane_sensor[3]
    denom = float(n @ wire_dir)
    if abs(denom) < 1e-6:
        return float("nan")
    return -(float(n @ p_tip_sensor) + d) / denom


def heave_rate_document(u_level: np.ndarray) -> float:
    """Document 000's D-dot (eq. 4.29): the deck's velocity relative to the sensor projected
    on the wire direction, D-dot = u . n_w with n_w = -e_z. Ignores the deck's rotation."""
    return float(-u_level[2])


def heave_rate_exact(
    u_level: np.ndarray,
    normal_level: np.ndarray,
    omega_feeder_level: np.ndarray,
    omega_crane_level: np.ndarray,
    r_tip_from_sensor_level: np.ndarray,
    D_m: float,
) -> float:
    """Exact D-dot from one radar scan's velocity u plus the deck's normal and spin.

    u = v_f(p_s) - v_s is the feeder's velocity field at the sensor relative to the sensor
    (what the range rates observe; level axes). With p_d = p_t - D e_z the deck point
    below the tip and r = p_t - p_s:
        p_t_dot   = v_s + w_c x r
        v_f(p_d)  = v_f(p_s) + w_f x (r - D e_z)
        D_dot     = n.(p_t_dot - v_f(p_d)) / (n.e_z)
                  = n.(-u + w_c x r - w_f x (r - D e_z)) / (n.e_z)
    Only w_f's components perpendicular to n matter (n.(w x a) = a.(n x w)).
    """
    n = normal_level / np.linalg.norm(normal_level)
    if n[2] < 0:
        n = -n
    rel = -u_level + np.cross(omega_crane_level, r_tip_from_sensor_level) - np.cross(
        omega_feeder_level, r_tip_from_sensor_level - D_m * E_Z
    )
    return float(n @ rel / n[2])


class NormalRate:
    """The deck's angular velocity (perpendicular to its normal) from the normal over time.

    n_dot = w x n gives w_perp = n x n_dot. n_dot is the slope of a local quadratic fit
    over the recent window, evaluated at the newest sample: causal, and far less noisy than
    a two-frame difference (noise on n_dot falls as window^-1.5).
    """

    def __init__(self, window_s: float = 1.0, min_samples: int = 4) -> None:
        self.window_s = window_s
        self.min_samples = min_samples
        self.t: list[float] = []
        self.n: list[np.ndarray] = []

    def add(self, t_s: float, normal_level: np.ndarray) -> None:
        n = normal_level / np.linalg.norm(normal_level)
        self.t.append(t_s)
        self.n.append(n if n[2] > 0 else -n)
        while self.t and self.t[0] < t_s - self.window_s:
            self.t.pop(0)
            self.n.pop(0)

    def omega(self, t_s: float) -> np.ndarray | None:
        """w_perp at time t (extrapolated from the fit), or None with too few samples."""
        if len(self.t) < self.min_samples:
            return None
        tt = np.asarray(self.t) - t_s
        N = np.asarray(self.n)
        deg = 2 if len(tt) >= 6 else 1
        V = np.vander(tt, deg + 1, increasing=True)  # columns 1, t, t^2
        coef = np.linalg.lstsq(V, N, rcond=None)[0]  # (deg+1, 3)
        n0 = coef[0] / np.linalg.norm(coef[0])
        return np.cross(n0, coef[1])

    def normal(self, t_s: float) -> np.ndarray | None:
        if not self.n:
            return None
        return self.n[-1]


def plane_sigma_at(points_on_plane: np.ndarray, plane: np.ndarray, query: np.ndarray) -> float:
    """1-sigma error of a least-squares plane's offset at `query` (m).

    Regression prediction variance: s^2 (1/N + q^T (X^T X)^-1 q), with X the inliers'
    in-plane coordinates about their centroid, q the query's, s the residual RMS.
    """
    n = plane[:3]
    N = len(points_on_plane)
    if N < 4:
        return float("nan")
    resid = points_on_plane @ n + plane[3]
    s2 = float(resid @ resid) / (N - 3)
    u = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    c = points_on_plane.mean(axis=0)
    X = (points_on_plane - c) @ np.stack([u, v], axis=1)
    q = (query - c) @ np.stack([u, v], axis=1)
    try:
        var = s2 * (1.0 / N + q @ np.linalg.solve(X.T @ X, q))
    except np.linalg.LinAlgError:
        return float("nan")
    return float(np.sqrt(max(var, 0.0)))
