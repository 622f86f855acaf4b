"""rerun-sdk recordings (.rrd, no viewer needed): clouds, detections and time series.

Everything 3-D is logged in the boom tip's gravity-levelled frame (origin at the tip, z up),
so the deck appears below at z = -D whatever the crane vessel's attitude.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from boomtip.data.frames import FrameSource, Truth
from boomtip.fusion.solutions import Estimates
from boomtip.perception.geometry import tip_in_sensor
from boomtip.perception.pipeline import FrameResult
from boomtip.tools.report.heave import COLORS

TIMELINE = "sensor_time"


def _colormap(values: np.ndarray, lo: float, hi: float, name: str) -> np.ndarray:
    import matplotlib

    cmap = matplotlib.colormaps[name]
    x = np.clip((values - lo) / max(hi - lo, 1e-9), 0, 1)
    return (cmap(x)[:, :3] * 255).astype(np.uint8)


def _hex(c: str) -> list[int]:
    return [int(c[i : i + 2], 16) for i in (1, 3, 5)]


def _stream(application_id: str):
    """A recording stream that batches rows into large chunks: rerun's default flushes every few
    milliseconds, and an offline run logs a frame's small entities (plane, wire, markers) each
    into a chunk of its own whose schema outweighs its data (a sixth of a recording's size)."""
    import rerun as rr

    return rr.RecordingStream(application_id, batcher_config=rr.ChunkBatcherConfig(
        flush_tick=5.0, flush_num_bytes=8 * 1024 * 1024, flush_num_rows=100_000))


def _start(rec, path: Path, blueprint, tip_radius_m: float) -> None:
    """Save to `path` (before anything is logged) and set up the levelled boom-tip frame."""
    import rerun as rr

    rec.save(str(path), default_blueprint=blueprint)
    rec.log("tip", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log("tip/boom_tip", rr.Points3D([[0, 0, 0]], radii=tip_radius_m, colors=[[255, 255, 255]], labels=["boom tip"]), static=True)


class RerunLogger:
    """A heave run in rerun. The full LiDAR cloud is logged `full_cloud_hz` times a second and
    the points around the wire (where the deck is measured) every frame; radar frames (a few
    hundred detections) and the series are kept whole: 60 s stay a few tens of MB."""

    def __init__(self, path: Path, source: FrameSource, full_cloud_hz: float = 1.0, near_wire_m: float = 8.0) -> None:
        import rerun as rr
        import rerun.blueprint as rrb

        self.rr = rr
        self.meta = source.meta
        self.full_cloud_dt = 1.0 / full_cloud_hz
        self.near_wire_m = near_wire_m
        self._last_full = -np.inf
        self.rec = _stream("boomtip")
        blueprint = rrb.Blueprint(
            rrb.Horizontal(
                rrb.Spatial3DView(origin="tip", name="boom tip (levelled, z up)"),
                rrb.Vertical(
                    rrb.TimeSeriesView(origin="heave/D", name="D [m]"),
                    rrb.TimeSeriesView(origin="heave/D_dot", name="D-dot [m/s]"),
                    rrb.TimeSeriesView(origin="heave/error_D_mm", name="D error [mm]"),
                ),
                column_shares=[3, 2],
            ),
            collapse_panels=True,
        )
        _start(self.rec, path, blueprint, tip_radius_m=0.4)

    def _to_tip(self, res: FrameResult, p_sensor: np.ndarray) -> np.ndarray:
        R = res.extras["R_level_sensor"]
        p_tip = tip_in_sensor(self.meta.T_boomtip_sensor[res.frame.sensor])
        return (p_sensor - p_tip) @ R.T

    def log_frame(self, res: FrameResult) -> None:
        rr, rec, f = self.rr, self.rec, res.frame
        rec.set_time(TIMELINE, duration=f.t_s)
        if "R_level_sensor" not in res.extras or len(f) == 0:
            return
        pts = self._to_tip(res, f.points_sensor)
        if f.sensor == "lidar":
            inten = np.log10(np.maximum(f.fields.get("intensity", np.ones(len(f))), 1e-3))
            keep = slice(None)
            if f.t_s - self._last_full >= self.full_cloud_dt - 1e-9:
                self._last_full = f.t_s
            else:  # between full clouds, only the points around the wire
                keep = np.einsum("ij,ij->i", pts[:, :2], pts[:, :2]) < self.near_wire_m**2
            rec.log("tip/lidar", rr.Points3D(pts[keep], colors=_colormap(inten[keep], -1.5, 1.5, "viridis"), radii=0.06))
            deck = res.deck_lidar
            if deck is not None and deck.ok:
                self._log_plane("tip/deck_plane", res, deck.plane_sensor, deck.D_m, [80, 160, 255, 90])
            ref = res.reflectors
            if ref is not None and len(ref.marker_centroids):
                rec.log("tip/reflectors", rr.Points3D(self._to_tip(res, ref.marker_centroids), radii=0.5, colors=[[255, 60, 200]]))
        else:
            rr_mps = f.fields.get("range_rate", np.zeros(len(f)))
            rec.log("tip/radar", rr.Points3D(pts, colors=_colormap(rr_mps, -1.5, 1.5, "coolwarm"), radii=0.25))

    def _log_plane(self, path: str, res: FrameResult, plane_sensor: np.ndarray, D: float, rgba: list[int]) -> None:
        rr = self.rr
        R = res.extras["R_level_sensor"]
        n = R @ plane_sensor[:3]
        n = n / np.linalg.norm(n)
        p_d = np.array([0.0, 0.0, -D])
        u = np.cross(n, [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        half_u, half_v = 45.0, 12.0
        quad = np.array([p_d + a * half_u * u + b * half_v * v for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        self.rec.log(path, rr.Mesh3D(vertex_positions=quad, triangle_indices=[[0, 1, 2], [0, 2, 3]], vertex_colors=[rgba] * 4))
        self.rec.log("tip/wire", rr.LineStrips3D([[[0, 0, 0], p_d]], colors=[[255, 200, 0]], radii=0.08))
        self.rec.log("tip/p_d", rr.Points3D([p_d], radii=0.35, colors=[[255, 200, 0]], labels=[f"D = {D:.3f} m"]))

    def log_estimates(self, estimates: dict[str, Estimates], truth: Truth | None) -> None:
        rr, rec = self.rr, self.rec
        series = []
        if truth is not None:
            series.append(("truth", truth.t_s, truth.columns["D"], truth.columns["D_dot"], None, [0, 0, 0]))
        for name, e in estimates.items():
            ok = np.isfinite(e.x[:, 0])
            err = (e.x[ok, 0] - truth.at("D", e.t_s[ok])) * 1e3 if truth is not None else None
            series.append((name, e.t_s[ok], e.x[ok, 0], e.x[ok, 1], err, _hex(COLORS.get(name, "#777777"))))
        for name, t, D, V, err, color in series:
            for q, values in (("D", D), ("D_dot", V), ("error_D_mm", err)):
                if values is None or (q == "error_D_mm" and name == "doppler_radar"):
                    continue
                path = f"heave/{q}/{name}"
                rec.log(path, rr.SeriesLines(colors=[color], names=name, widths=2.5 if name == "truth" else 1.2), static=True)
                rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t)], columns=rr.Scalars.columns(scalars=values))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()


class HookRerunLogger:
    """A hook run in rerun: the LiDAR cloud levelled at the boom tip, the segmented block, the
    rope line, the estimated and the true hook with their trails, and the per-axis errors.

    A 700 s run has 14,000 frames of ~17k points: the full cloud is logged at most
    `full_cloud_hz` (default 2 Hz), the points around the hook (the detector's gate) every frame,
    which keeps a recording of a whole transfer to a few hundred MB.
    """

    def __init__(self, path: Path, source: FrameSource, gate_radius_m: float = 6.0, full_cloud_hz: float = 2.0,
                 trail_s: float = 10.0) -> None:
        import rerun as rr
        import rerun.blueprint as rrb

        self.rr = rr
        self.gate_radius_m = gate_radius_m
        self.full_cloud_dt = 1.0 / full_cloud_hz
        self.trail_s = trail_s
        self._last_full = -np.inf
        self.rec = _stream("boomtip-hook")
        blueprint = rrb.Blueprint(
            rrb.Horizontal(
                rrb.Spatial3DView(origin="tip", name="boom tip (levelled, z up; x along the boom)"),
                rrb.Vertical(
                    rrb.TimeSeriesView(origin="hook/error_cm", name="hook position error [cm] (estimate - truth)"),
                    rrb.TimeSeriesView(origin="hook/points", name="block points per frame"),
                ),
                column_shares=[3, 2],
            ),
            collapse_panels=True,
        )
        _start(self.rec, path, blueprint, tip_radius_m=0.3)

    def log_frame(self, res) -> None:
        """One LiDAR frame (tools.hook_chain.HookFrameResult): points in the levelled tip frame,
        the detection (perception.hook) and the rope's fitted points and axis (perception.rope),
        drawn to the hoist length."""
        if res is None or res.detection is None:
            return
        t_s, points_level, det, prior, rope, hoist_m = (res.row["t"], res.points_level, res.detection, res.prior,
                                                        res.rope, res.hoist_m)
        gate_radius_m = self.gate_radius_m
        rr, rec = self.rr, self.rec
        rec.set_time(TIMELINE, duration=t_s)
        if t_s - self._last_full >= self.full_cloud_dt - 1e-9:
            self._last_full = t_s
            rec.log("tip/cloud", rr.Points3D(points_level, colors=[[150, 150, 150]], radii=0.05))
        if rope is not None and rope.ok and hoist_m is not None:
            rec.log("tip/rope_fit/points", rr.Points3D(points_level[rope.mask], colors=[[255, 140, 0]], radii=0.04))
            rec.log("tip/rope_fit/axis", rr.LineStrips3D([[[0.0, 0.0, 0.0], (hoist_m * rope.direction).tolist()]],
                                                         colors=[[255, 140, 0]], radii=0.03))
        else:
            rec.log("tip/rope_fit", rr.Clear(recursive=True))
        near = np.einsum("ij,ij->i", points_level - prior, points_level - prior) < gate_radius_m**2
        block = det.points_mask
        other = near & ~block
        if det.rope_mask is not None:
            other &= ~det.rope_mask
            rec.log("tip/rope_points", rr.Points3D(points_level[det.rope_mask], colors=[[255, 200, 0]], radii=0.05))
        rec.log("tip/near_hook", rr.Points3D(points_level[other], colors=[[90, 140, 255]], radii=0.08))
        rec.log("tip/hook_points", rr.Points3D(points_level[block], colors=[[255, 40, 40]], radii=0.12))
        rec.log("hook/points/block", rr.Scalars(float(np.count_nonzero(block))))
        if det.ok:
            rec.log("tip/detection", rr.Points3D([det.position_m], radii=0.25, colors=[[255, 40, 40]], labels=["detected"]))
        else:
            rec.log("tip/detection", rr.Clear(recursive=False))

    def log_hook_tracks(self, t_s: np.ndarray, p_est_rel: np.ndarray, p_true_rel: np.ndarray | None, name: str) -> None:
        """Estimated (and true) hook relative to the tip at the LiDAR frame times: points, trails,
        the rope line from the tip to the estimate, and the error per axis."""
        rr, rec = self.rr, self.rec
        k_trail = max(1, int(round(self.trail_s / max(float(np.median(np.diff(t_s))), 1e-3)))) if len(t_s) > 1 else 1
        for k, t in enumerate(t_s.tolist()):
            rec.set_time(TIMELINE, duration=t)
            lo = max(0, k - k_trail)
            p = p_est_rel[k]
            if not np.all(np.isfinite(p)):
                continue
            rec.log("tip/rope", rr.LineStrips3D([[[0.0, 0.0, 0.0], p]], colors=[[255, 200, 0]], radii=0.04))
            rec.log("tip/hook_estimate", rr.Points3D([p], radii=0.3, colors=[[40, 220, 80]], labels=[name]))
            rec.log("tip/hook_estimate_trail", rr.LineStrips3D([p_est_rel[lo : k + 1]], colors=[[40, 220, 80]], radii=0.03))
            if p_true_rel is not None:
                rec.log("tip/hook_truth", rr.Points3D([p_true_rel[k]], radii=0.3, colors=[[255, 255, 255]], labels=["truth"]))
                rec.log("tip/hook_truth_trail", rr.LineStrips3D([p_true_rel[lo : k + 1]], colors=[[255, 255, 255]], radii=0.03))
        if p_true_rel is not None:
            err_cm = (p_est_rel - p_true_rel) * 100.0
            for i, (axis, color) in enumerate(zip("xyz", ([230, 60, 60], [60, 200, 60], [60, 120, 255]))):
                path = f"hook/error_cm/{axis}"
                rec.log(path, rr.SeriesLines(colors=[color], names=f"{name} {axis}"), static=True)
                ok = np.isfinite(err_cm[:, i])
                rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t_s[ok])], columns=rr.Scalars.columns(scalars=err_cm[ok, i]))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()
