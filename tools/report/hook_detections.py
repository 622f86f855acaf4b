"""plots/detections.png of a hook run: what the hook pipeline found in the pictured LiDAR frames (a
representative one and the worst: tools/chains/pictures.py), from above and from the side in the
levelled boom-tip frame about the hook, in the recording's class colours; and the status of the
block fit and the rope fit per frame."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from boomtip.perception.hook_block import block_model
from boomtip.tools.report.classes import by_name
from boomtip.tools.report.detections import DETECTIONS_PLOT, frames_figure
from boomtip.tools.report.plots import legend, plot_path, save

__all__ = ["FrameStatus", "hook_detections_figure", "hook_frame_title", "write_hook_detections"]

VIEW_HALF_M = 8.0  # the drawn neighbourhood of the hook (the detector's gate is 6 m)
MAX_CLOUD_POINTS = 20_000
BLOCK_MODEL_POINTS = 600


@dataclass(frozen=True)
class FrameStatus:
    """One stage's status at a frame, as the status timeline reads it."""

    t_s: float
    method: str
    status: str

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def statuses(t_s: np.ndarray, block_status: np.ndarray, rope_status: np.ndarray) -> list[FrameStatus]:
    return ([FrameStatus(float(t), "hook block", str(s)) for t, s in zip(t_s, block_status)]
            + [FrameStatus(float(t), "rope", str(s)) for t, s in zip(t_s, rope_status) if s])


def hook_frame_title(res) -> str:
    if res is None:
        return "No LiDAR frame in this run: nothing to draw"
    det = res.detection
    if det is None or res.points_level is None:
        return f"LiDAR frame at t = {res.t_s:.2f} s: no hook detection ran ({res.row.get('status', '')})"
    what = "the block found" if det.ok else f"no block fit ({det.status})"
    return f"LiDAR frame at t = {res.t_s:.2f} s, {det.n_points} block points: {what}"


def write_hook_detections(out: Path, frames: list, rows: list[FrameStatus], block_height_m: float) -> Path:
    return save(hook_detections_figure(frames, rows, block_height_m), plot_path(out, DETECTIONS_PLOT))


def hook_detections_figure(frames: list, rows: list[FrameStatus], block_height_m: float):
    """`frames`: (the hook chain's frame result with its cloud, why it is pictured)."""
    return frames_figure(frames, rows, lambda above, side, res: _draw(above, side, res, block_height_m), hook_frame_title,
                         "What the hook pipeline detected (levelled boom-tip frame)")


def _draw(above, side, res, block_height_m: float) -> None:
    if res is None or res.detection is None or res.points_level is None:
        return
    det, pts = res.detection, res.points_level
    centre = det.position_m if np.all(np.isfinite(det.position_m)) else res.prior
    near = np.all(np.abs(pts - centre) < VIEW_HALF_M, axis=1)
    block = det.points_mask & near
    rope = (det.rope_mask if det.rope_mask is not None else np.zeros(len(pts), bool)) & near & ~block
    other = near & ~block & ~rope
    layers = {"hook_near": pts[other][:: max(1, int(other.sum()) // MAX_CLOUD_POINTS)], "rope": pts[rope],
              "hook_segment": pts[block]}
    if det.ok and np.all(np.isfinite(det.R_level_block)):
        model = block_model(block_height_m).points
        layers["hook_block"] = model[:: max(1, len(model) // BLOCK_MODEL_POINTS)] @ det.R_level_block.T + det.position_m
    styles = {"hook_near": {"s": 2, "alpha": 0.3}, "rope": {"s": 6}, "hook_segment": {"s": 14}, "hook_block": {"s": 1, "alpha": 0.5}}
    for name, q in layers.items():
        if len(q) == 0:
            continue
        c = by_name(name)
        above.scatter(q[:, 0], q[:, 1], color=c.colour, label=c.label, **styles[name])
        side.scatter(q[:, 0], q[:, 2], color=c.colour, label=c.label, **styles[name])
    for ax, (i, j) in ((above, (0, 1)), (side, (0, 2))):
        ax.scatter([res.prior[i]], [res.prior[j]], marker="+", s=80, color=by_name("estimate").colour,
                   label="predicted (the tracker's prior)")
        ax.set_xlabel("x from the boom tip [m] (levelled)")
    above.set_ylabel("y from the boom tip [m]")
    side.set_ylabel("z from the boom tip [m]")
    above.set_aspect("equal", adjustable="datalim")
    legend(side, fontsize=8)
