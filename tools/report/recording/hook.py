"""The hook chain's recording: the LiDAR cloud levelled at the boom tip, the segmented block and
the block model fitted to it, the rope's points and axis, the estimated hook with its 3-sigma
ellipsoid and trail, the true hook's ghost, and the per-axis errors inside their 3-sigma bands."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from boomtip.data.frames import FrameSource
from boomtip.perception.hook_block import block_model
from boomtip.tools.report.classes import by_name, rgb
from boomtip.tools.report.recording.convention import BAND_SIGMAS, Recording
from boomtip.tools.report.recording.world import log_world

__all__ = ["AXIS_COLOURS", "BLOCK_MODEL_POINTS", "HookRerunLogger"]

AXIS_COLOURS = ([230, 60, 60], [60, 200, 60], [60, 120, 255])
BLOCK_MODEL_POINTS = 120  # of the block model drawn at the fitted pose (every frame: a 700 s run has 14,000)
PANELS = {"error": "hook position error [cm] (estimate - truth) and its 3 sigma", "points": "block points per frame"}


class HookRerunLogger:
    """A 700 s run has 14,000 frames of ~17k points: the full cloud is logged at most
    `full_cloud_hz` (default 2 Hz), the points around the hook (the detector's gate) every frame,
    which keeps a recording of a whole transfer to a few hundred MB."""

    def __init__(self, path: Path, source: FrameSource, gate_radius_m: float = 6.0, full_cloud_hz: float = 2.0,
                 trail_s: float = 10.0) -> None:
        self.source = source
        self.gate_radius_m = gate_radius_m
        self.full_cloud_dt = 1.0 / full_cloud_hz
        self.trail_s = trail_s
        self._last_full = -np.inf
        self._block_points = block_model(source.meta.installation.crane.block_height_m).points
        self._block_points = self._block_points[:: max(1, len(self._block_points) // BLOCK_MODEL_POINTS)]
        self._n_points: list[tuple[float, int]] = []
        self.recording = Recording(path, "boomtip-hook", "boom tip (levelled, z up; x along the boom)")

    def log_frame(self, res) -> None:
        """One LiDAR frame (tools.chains.hook's frame result): points in the levelled tip frame,
        the detection (perception.hook) and the rope's fitted points and axis (perception.rope),
        drawn to the hoist length."""
        if res is None or res.detection is None:
            return
        t_s, points_level, det, prior, rope, hoist_m = (res.row["t"], res.points_level, res.detection, res.prior,
                                                        res.rope, res.hoist_m)
        recording = self.recording
        recording.time(t_s)
        if t_s - self._last_full >= self.full_cloud_dt - 1e-9:
            self._last_full = t_s
            recording.points("sensors/lidar", points_level, "cloud", 0.05)
        if rope is not None and rope.ok and hoist_m is not None:
            recording.points("detections/rope/points", points_level[rope.mask], "rope", 0.04)
            recording.line("detections/rope/axis", np.array([np.zeros(3), hoist_m * rope.direction]), "rope", 0.03)
        else:
            recording.clear("detections/rope")
        near = np.einsum("ij,ij->i", points_level - prior, points_level - prior) < self.gate_radius_m**2
        block = det.points_mask
        other = near & ~block
        if det.rope_mask is not None:
            other &= ~det.rope_mask
            recording.points("detections/hook/rope_points", points_level[det.rope_mask], "rope", 0.05)
        recording.points("detections/hook/near", points_level[other], "hook_near", 0.08)
        recording.points("detections/hook/segment", points_level[block], "hook_segment", 0.12)
        self._n_points.append((t_s, int(np.count_nonzero(block))))
        if det.ok and np.all(np.isfinite(det.R_level_block)):
            model = self._block_points @ det.R_level_block.T + det.position_m
            recording.points("detections/hook/block", model, "hook_block", 0.05)
            recording.points("detections/hook/fix", det.position_m[None], "hook_block", 0.25, labels=["detected"])
        else:
            recording.clear("detections/hook/block")
            recording.clear("detections/hook/fix")

    def log_hook_tracks(self, t_s: np.ndarray, p_est_rel: np.ndarray, p_true_rel: np.ndarray | None, name: str,
                        cov_m2: np.ndarray | None = None) -> None:
        """Estimated (and true) hook relative to the tip at the LiDAR frame times: points, trails,
        the rope line from the tip to the estimate, its 3-sigma ellipsoid (`cov_m2` (T,3,3), axes
        aligned: the diagonal), and the error per axis with its band."""
        recording = self.recording
        est, true = f"estimates/{name}/hook", "truth/hook"
        k_trail = max(1, int(round(self.trail_s / max(float(np.median(np.diff(t_s))), 1e-3)))) if len(t_s) > 1 else 1
        for k, t in enumerate(t_s.tolist()):
            p = p_est_rel[k]
            if not np.all(np.isfinite(p)):
                continue
            recording.time(t)
            lo = max(0, k - k_trail)
            recording.line(f"{est}/rope", np.array([np.zeros(3), p]), "estimate", 0.04)
            recording.points(f"{est}/position", p[None], "estimate", 0.3, labels=[name])
            recording.line(f"{est}/trail", p_est_rel[lo : k + 1], "estimate", 0.03)
            if p_true_rel is not None:
                recording.points(f"{true}/position", p_true_rel[k][None], "truth", 0.3, labels=["truth"])
                recording.line(f"{true}/trail", p_true_rel[lo : k + 1], "truth", 0.03)
        sd = None
        if cov_m2 is not None:
            sd = np.sqrt(np.maximum(np.diagonal(cov_m2, axis1=1, axis2=2), 0.0))
            recording.ellipsoids(f"{est}/sigma3", t_s, p_est_rel, BAND_SIGMAS * sd, "estimate")
        if p_true_rel is not None:
            err_cm = (p_est_rel - p_true_rel) * 100.0
            for i, axis in enumerate("xyz"):
                recording.series(PANELS["error"], f"truth/error_cm/{axis}", t_s, err_cm[:, i], f"{name} {axis}",
                                 AXIS_COLOURS[i], None if sd is None else sd[:, i] * 100.0)
        if self._n_points:
            t, n = np.array(self._n_points, float).T
            recording.series(PANELS["points"], "detections/hook/n_points", t, n, "block points",
                             rgb(by_name("hook_segment").colour))

    def log_world(self) -> None:
        log_world(self.recording, self.source)

    def close(self) -> None:
        self.recording.close()
