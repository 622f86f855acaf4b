"""The feeder's part of a ship run's recording: its pose series with their 3-sigma bands beside
the truth, and in the 3-D view the feeder at the estimated pose (its mesh in a simulated run,
else the chain's own registered model) and a ghost at the true pose."""

from __future__ import annotations

import math

import numpy as np

from boomtip.data.poses import inverse, pose_matrix, transform
from boomtip.tools.report.classes import by_name, rgb
from boomtip.tools.report.recording.convention import BAND_SIGMAS
from boomtip.tools.report.feeder_truth import POSE

__all__ = ["FEEDER_SERIES_HZ", "log_feeder"]

FEEDER_SERIES_HZ = 10.0  # the pose series and the mesh's transforms: the file stays small
MODEL_RATE_HZ = 0.2  # the registered model's points, at the estimated pose
MODEL_POINTS = 800
PANELS = ("feeder position [m] (heading frame at the tip)", "feeder attitude [deg]")
POSE_COLOURS = ([230, 60, 60], [60, 200, 60], [60, 120, 255]) * 2


def log_feeder(viz, res, truth_pose: np.ndarray | None, rpy_yaw,
               mesh_feeder: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """`res` a FeederResult (tools.report.feeder); `truth_pose` (T,6) or None; `rpy_yaw(t)` the
    crane vessel's heading (the heading frame -> the tip view's axes); `mesh_feeder` the
    simulated feeder's mesh in the feeder frame (display only: processing never sees it)."""
    recording = vars(viz).get("recording")  # the null visualiser has none
    if recording is None or len(res.t_s) == 0:
        return
    keep = np.r_[True, np.diff(np.floor(res.t_s * FEEDER_SERIES_HZ)) > 0]
    t_s, pose = res.t_s[keep], res.pose[keep]
    sd = np.sqrt(np.maximum(res.var[keep, :6], 0.0))
    for i, name in enumerate(POSE):
        scale, panel = (1.0, PANELS[0]) if i < 3 else (180 / math.pi, PANELS[1])
        recording.series(panel, f"estimates/feeder/pose/{name}", t_s, pose[:, i] * scale, name, POSE_COLOURS[i], sd[:, i] * scale)
        if truth_pose is not None:
            recording.series(panel, f"truth/feeder/pose/{name}", t_s, truth_pose[keep, i] * scale, f"{name} truth",
                             rgb(by_name("truth").colour), width=2.0)
    yaw = np.array([rpy_yaw(float(t)) for t in t_s])
    Rz = np.array([[[math.cos(y), -math.sin(y), 0.0], [math.sin(y), math.cos(y), 0.0], [0.0, 0.0, 1.0]]
                   for y in yaw])  # heading frame -> the tip view's axes
    # the feeder frame's origin with its 3-sigma ellipsoid (axes: the heading frame's)
    q_yaw = np.column_stack([np.zeros((len(yaw), 2)), np.sin(yaw / 2), np.cos(yaw / 2)])
    recording.ellipsoids("estimates/feeder/origin", t_s, np.einsum("tij,tj->ti", Rz, pose[:, :3]), BAND_SIGMAS * sd[:, :3],
                         "estimate", q_yaw)
    if mesh_feeder is not None:
        vertices, triangles = mesh_feeder
        for root, poses, cls, alpha in (("estimates/feeder", pose, "feeder_vessel", 255),
                                        ("truth/feeder", None if truth_pose is None else truth_pose[keep], "truth", 70)):
            if poses is None:
                continue
            # the transform on the body alone: the series and the origin's ellipsoid beside it are in the tip view's axes
            recording.mesh(f"{root}/body/mesh", vertices, triangles, cls, alpha)
            T = np.array([pose_matrix(*p) if np.all(np.isfinite(p)) else np.full((4, 4), np.nan) for p in poses])
            recording.poses(f"{root}/body", t_s, Rz @ T[:, :3, :3], np.einsum("tij,tj->ti", Rz, T[:, :3, 3]))
    _log_model(recording, res, t_s, pose, Rz)


def _log_model(recording, res, t_s: np.ndarray, pose: np.ndarray, Rz: np.ndarray) -> None:
    """The chain's registered model (what the registration aligns each frame to) at the
    estimated pose, a few times a minute."""
    if res.model_points_map is None or res.T_map_feeder is None or len(res.model_points_map) == 0:
        return
    pts_feeder = transform(inverse(res.T_map_feeder), res.model_points_map)
    pts_feeder = pts_feeder[:: max(1, len(pts_feeder) // MODEL_POINTS)]
    last = -np.inf
    for k, t in enumerate(t_s):
        if t - last < 1.0 / MODEL_RATE_HZ or not np.all(np.isfinite(pose[k])):
            continue
        last = t
        recording.time(float(t))
        recording.points("detections/feeder/model", transform(pose_matrix(*pose[k]), pts_feeder) @ Rz[k].T, "feeder_model", 0.08)
