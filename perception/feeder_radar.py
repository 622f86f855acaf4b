"""The feeder's x, y and yaw from the radar's detections against the LiDAR's feeder model.

When the LiDAR is out, the radar's Doppler gives the feeder's velocity, and a velocity
integrated over tens of seconds drifts (across the ship most: the radar's 12 deg of elevation
span little of it). The radar's detections are points too: a third or so of them fall on the
feeder's structure that the LiDAR's merged model holds, each with 13-19 cm of noise (range
0.14 m, azimuth 0.29 deg, elevation 0.43 deg at 25-30 m). Registered to the model, with z,
roll and pitch held where the filter has them (the deck's planes fix those), they give x, y
and yaw to centimetres and a tenth of a degree a frame, without drift.

The registration here is a Gauss-Newton of the point-to-plane residuals in the filter's own
coordinates (x, y, yaw of the feeder frame in the level frame), each residual weighted by the
detection's noise along the model's normal and a Tukey kernel at `tukey_sigmas` of it.
Open3D's ICP (and `point_to_plane.icp_point_to_plane`) weigh every point alike and move all
six degrees of freedom: with the radar's anisotropic noise, ten times the LiDAR's, that would
weigh a grazing wall detection like a good one and let the detections' noise move z, roll and
pitch, which the deck planes already fix far better.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from boomtip.perception.geometry import rpy_matrix
from boomtip.perception.point_to_plane import Surface
from pydantic import BaseModel, ConfigDict, Field


class RadarRegistrationConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(True, description="register the radar's detections to the feeder model while the LiDAR has none")
    after_s: float = Field(0.5, gt=0, description="used once the LiDAR has had no registration this long")
    min_model_frames: int = Field(50, ge=1, description="the model must be merged from this many LiDAR frames")
    deck_band_m: float = Field(0.25, ge=0, description="detections within this of the deck's plane are not searched "
                               "(the deck's normal is vertical: no x, y or yaw in them)")
    max_correspondence_m: float = Field(0.6, gt=0, description="a detection farther than this from the model is not on it")
    tukey_sigmas: float = Field(3.0, gt=0, description="Tukey's kernel at this many of a residual's own sigmas")
    model_sigma_m: float = Field(0.02, ge=0, description="the model's own spread along its normals (LiDAR noise, voxels)")
    min_matches: int = Field(30, ge=3, description="fewer detections on the model give no registration")
    max_iterations: int = Field(4, ge=1)
    converged_m: float = Field(0.005, gt=0, description="the iteration stops when no step moves x or y by more than this (a frame is good to 5 cm)")
    info_inflation: float = Field(8.0, ge=1, description="the information divided by this: a frame's errors repeat in the "
                                  "next ones (the radar sees the same structure from about the same place for seconds), "
                                  "and a filter that took them as independent would claim far too much")
    learn_every: int = Field(4, ge=1, description="while the LiDAR registers, the offset is learnt from every this-many-th radar frame")
    max_sigma_m: float = Field(0.3, gt=0, description="directions of a frame's registration known worse than this are not updated")
    offset_frames: int = Field(400, ge=1, description="the radar-minus-LiDAR offset is a running mean over at most this "
                                "many frames (a mount error of 0.05 deg is 2 cm at 25 m)")
    min_offset_frames: int = Field(40, ge=1, description="no update before the offset has this many frames")


@dataclass
class RadarRegistration:
    x_y_yaw: np.ndarray  # the feeder frame's x, y (m), yaw (rad) in the level frame
    info: np.ndarray  # 3x3 information of (x, y, yaw)
    matched: int  # detections on the model
    status: str  # "ok" or why there is none


def detection_covariance(points_sensor: np.ndarray, range_sigma_m: float, azimuth_sigma_rad: float,
                         elevation_sigma_rad: float) -> np.ndarray:
    """(N, 3, 3) covariance of each detection in the sensor frame from its range, azimuth
    (about z, from x) and elevation (towards z) noise."""
    r = np.linalg.norm(points_sensor, axis=1)
    u = points_sensor / np.where(r > 0, r, 1.0)[:, None]
    horizontal = np.hypot(u[:, 0], u[:, 1])
    ca, sa = np.where(horizontal > 0, u[:, 0] / np.where(horizontal > 0, horizontal, 1.0), 1.0), \
        np.where(horizontal > 0, u[:, 1] / np.where(horizontal > 0, horizontal, 1.0), 0.0)
    se = u[:, 2]
    e_az = np.column_stack([-sa, ca, np.zeros_like(ca)])
    e_el = np.column_stack([-se * ca, -se * sa, horizontal])
    s = np.column_stack([np.full_like(r, range_sigma_m), r * horizontal * azimuth_sigma_rad, r * elevation_sigma_rad])
    axes = np.stack([u, e_az, e_el], axis=1) * s[:, :, None]  # (N, 3 axes, 3)
    return np.einsum("nki,nkj->nij", axes, axes)


def _to_map(pose: np.ndarray, points_level: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Level-frame points in the feeder (map) frame at pose (x, y, z, roll, pitch, yaw of the
    map frame in the level frame): R^T (p - t) with R = Rz R_tilt. Also Rz^T (p - t), R_tilt, R."""
    Rz = rpy_matrix((0.0, 0.0, pose[5]))
    R_tilt = rpy_matrix((pose[3], pose[4], 0.0))
    a = (points_level - pose[:3]) @ Rz  # Rz^T (p - t)
    return a @ R_tilt, a, R_tilt, Rz @ R_tilt


def _map_points(pose: np.ndarray, points_level: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points in the map frame (see _to_map), their derivatives by x, y and yaw, (N, 3, 3),
    and R."""
    p_map, a, R_tilt, R = _to_map(pose, points_level)
    d = np.empty((len(points_level), 3, 3))
    d[:, :, 0], d[:, :, 1] = -R[0], -R[1]
    # by the yaw: R_tilt^T d(Rz^T)/dyaw (p - t) = -R_tilt^T (e_z x a)
    d[:, :, 2] = -np.column_stack([-a[:, 1], a[:, 0], np.zeros(len(a))]) @ R_tilt
    return p_map, d, R


def register_radar(surface: Surface, detections_sensor: np.ndarray, R_level_sensor: np.ndarray, t_level_sensor: np.ndarray,
                   detection_sigma: tuple[float, float, float], pose_guess: np.ndarray,
                   cfg: RadarRegistrationConfig) -> RadarRegistration:
    """x, y and yaw of the feeder frame (level frame) that put the radar's detections (sensor
    frame; their range, azimuth and elevation 1-sigma) on the model, z, roll and pitch held at
    the guess's."""
    pose = np.array(pose_guess, dtype=float)
    k2 = cfg.tukey_sigmas ** 2
    detections_sensor = detections_sensor[np.isfinite(detections_sensor).all(axis=1)]
    points_level = detections_sensor @ R_level_sensor.T + t_level_sensor
    # Only detections that can land on the structure are searched: off the deck's band (a
    # deck's vertical normal says nothing of x, y or yaw: two thirds of those on the model)
    # and inside the model's plan outline (not the sea, the own vessel, false alarms).
    xy = surface.points[:, :2]
    lo, hi = xy.min(axis=0) - 1.0, xy.max(axis=0) + 1.0  # microseconds for the model's points: no cache to keep in step
    p_map = _to_map(pose, points_level)[0]
    keep = ((np.abs(p_map[:, 2]) > cfg.deck_band_m) & (p_map[:, 0] > lo[0]) & (p_map[:, 0] < hi[0])
            & (p_map[:, 1] > lo[1]) & (p_map[:, 1] < hi[1]))
    points_level = points_level[keep]
    cov_level = R_level_sensor @ detection_covariance(detections_sensor[keep], *detection_sigma) @ R_level_sensor.T
    info, matched = np.zeros((3, 3)), 0
    for _ in range(cfg.max_iterations):
        p_map, d_map, R = _map_points(pose, points_level)
        src, srf, _ = surface.nearest(p_map, cfg.max_correspondence_m)
        matched = len(src)
        if matched < cfg.min_matches:
            return RadarRegistration(pose[[0, 1, 5]], np.zeros((3, 3)), matched, f"{matched} radar detections on the model "
                                     f"(< {cfg.min_matches})")
        n = surface.normals[srf]
        r = np.einsum("ij,ij->i", p_map[src] - surface.points[srf], n)
        n_level = n @ R.T  # the normal in the level frame, where the covariance is
        var = np.einsum("ni,nij,nj->n", n_level, cov_level[src], n_level) + cfg.model_sigma_m ** 2
        u = r * r / (var * k2)
        w = np.where(u < 1.0, (1.0 - u) ** 2, 0.0) / var
        J = np.einsum("ni,nij->nj", n, d_map[src])  # (M, 3): residual by x, y, yaw
        Jw = J * w[:, None]
        A = Jw.T @ J
        if np.linalg.cond(A) > 1e12:
            return RadarRegistration(pose[[0, 1, 5]], np.zeros((3, 3)), matched, "radar registration degenerate")
        step = -np.linalg.solve(A, Jw.T @ r)
        pose[[0, 1, 5]] += step
        inliers = u < 1.0
        info = (J[inliers] / var[inliers, None]).T @ J[inliers]
        if max(abs(step[0]), abs(step[1])) < cfg.converged_m:
            break
    if not np.all(np.isfinite(pose)):
        return RadarRegistration(np.asarray(pose_guess, dtype=float)[[0, 1, 5]], np.zeros((3, 3)), matched,
                                 "radar registration diverged")
    return RadarRegistration(pose[[0, 1, 5]], info / cfg.info_inflation, matched, "ok")


