"""The heave (and ship) chain's recording: the clouds, the deck planes, reflectors and the wire
per frame; D and D-dot of every solution, the fused one with its 3-sigma band and the deck point's
3-sigma ellipsoid; the truth and the errors against it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from boomtip.data.frames import FrameSource, Truth
from boomtip.fusion.solutions import Estimates
from boomtip.perception.geometry import tip_in_sensor
from boomtip.perception.pipeline import FrameResult
from boomtip.tools.report.classes import by_name, rgb
from boomtip.tools.report.heave import COLORS
from boomtip.tools.report.recording.convention import BAND_SIGMAS, Recording, colormap
from boomtip.tools.report.recording.world import log_world

__all__ = ["DECK_HALF_SIZE_M", "ELLIPSOID_RATE_HZ", "MAX_INLIERS_DRAWN", "RerunLogger"]

DECK_HALF_SIZE_M = (45.0, 12.0)  # the drawn deck plane's half extent along and across
# a deck stage's inliers drawn per frame, evenly picked: the plane is drawn whole, and the
# recording stays within 30 MB a minute
MAX_INLIERS_DRAWN = {"deck_lidar": 600, "deck_radar": 100}
ELLIPSOID_RATE_HZ = 10.0  # the deck point's 3-sigma ellipsoid, per solution
DECK_POINT_HALF_WIDTH_M = 0.5  # the deck point's ellipsoid across the wire: D has no horizontal sigma
BANDED = ("fused",)  # the solutions drawn with their 3-sigma bands and ellipsoid (the others' would hide them)
PANELS = {"D": "D [m] and its 3 sigma", "D_dot": "D-dot [m/s] and its 3 sigma", "error_D_mm": "D error [mm] (estimate - truth)"}


class RerunLogger:
    """A heave run in rerun. The full LiDAR cloud is logged `full_cloud_hz` times a second and
    the points around the wire (where the deck is measured) every frame; radar frames (a few
    hundred detections) and the series are kept whole: 60 s stay a few tens of MB."""

    def __init__(self, path: Path, source: FrameSource, full_cloud_hz: float = 1.0, near_wire_m: float = 4.0) -> None:
        self.source = source
        self.meta = source.meta
        self.full_cloud_dt = 1.0 / full_cloud_hz
        self.near_wire_m = near_wire_m
        self._last_full = -np.inf
        self.recording = Recording(path, "boomtip", "boom tip (levelled, z up)")
        self.rr = self.recording.rr

    def _to_tip(self, res: FrameResult, p_sensor: np.ndarray) -> np.ndarray:
        R = res.extras["R_level_sensor"]
        p_tip = tip_in_sensor(self.meta.T_boomtip_sensor[res.frame.sensor])
        return (p_sensor - p_tip) @ R.T

    def log_frame(self, res: FrameResult) -> None:
        rr, recording, f = self.rr, self.recording, res.frame
        recording.time(f.t_s)
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
            recording.log("sensors/lidar", rr.Points3D(pts[keep], colors=colormap(inten[keep], -1.5, 1.5, "viridis"), radii=0.06))
            self._log_deck("deck_lidar", res, res.deck_lidar, "deck")
            ref = res.reflectors
            if ref is not None and len(ref.marker_centroids):
                recording.points("detections/reflectors_lidar/markers", self._to_tip(res, ref.marker_centroids), "markers", 0.5)
            else:
                recording.clear("detections/reflectors_lidar")
        else:
            rr_mps = f.fields.get("range_rate", np.zeros(len(f)))
            recording.log("sensors/radar", rr.Points3D(pts, colors=colormap(rr_mps, -1.5, 1.5, "coolwarm"), radii=0.25))
            self._log_deck("deck_radar", res, res.deck_radar, "deck_radar")

    def _log_deck(self, stage: str, res: FrameResult, deck, cls: str) -> None:
        """A deck stage's inliers, its plane (a quad about the wire's foot) and the wire to the
        deck labelled with D; cleared when the stage found none in this frame."""
        path = f"detections/{stage}"
        if deck is None or not deck.ok or deck.plane_sensor is None:
            self.recording.clear(path)
            return
        rr, recording = self.rr, self.recording
        if deck.fit is not None:
            inliers = deck.points_used[deck.fit.inlier_mask]
            inliers = inliers[:: max(1, -(-len(inliers) // MAX_INLIERS_DRAWN[stage]))]
            recording.points(f"{path}/inliers", self._to_tip(res, inliers), cls, 0.08)
        n = res.extras["R_level_sensor"] @ deck.plane_sensor[:3]
        n = n / np.linalg.norm(n)
        p_d = np.array([0.0, 0.0, -deck.D_m])
        u = np.cross(n, [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        (hu, hv), colour = DECK_HALF_SIZE_M, rgb(by_name(cls).colour)
        quad = np.array([p_d + a * hu * u + b * hv * v for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        recording.log(f"{path}/plane", rr.Mesh3D(vertex_positions=quad, triangle_indices=[[0, 1, 2], [0, 2, 3]],
                                                 albedo_factor=[*colour, 90], class_ids=[by_name(cls).id]))
        recording.line(f"{path}/wire", np.array([np.zeros(3), p_d]), "wire", 0.08)
        recording.points(f"{path}/p_d", p_d[None], "wire", 0.35, labels=[f"D = {deck.D_m:.3f} m"])

    def log_estimates(self, estimates: dict[str, Estimates], truth: Truth | None) -> None:
        recording = self.recording
        if truth is not None:
            white = rgb(by_name("truth").colour)
            recording.series(PANELS["D"], "truth/D", truth.t_s, truth.columns["D"], "truth", white, width=2.5)
            recording.series(PANELS["D_dot"], "truth/D_dot", truth.t_s, truth.columns["D_dot"], "truth", white, width=2.5)
        for name, e in estimates.items():
            colour = rgb(COLORS.get(name, "#777777"))
            D, V = e.x[:, 0].copy(), e.x[:, 1].copy()
            if e.lost is not None:  # a lost estimate is not drawn, as estimates.csv leaves it empty
                D[e.lost.D], V[e.lost.D_dot] = np.nan, np.nan
            sd_D, sd_V = np.sqrt(np.maximum(e.var[:, :2], 0.0)).T if name in BANDED else (None, None)
            recording.series(PANELS["D_dot"], f"estimates/{name}/D_dot", e.t_s, V, name, colour, sd_V)
            if name == "doppler_radar":  # its D is an integral of D-dot: drifts by design
                continue
            recording.series(PANELS["D"], f"estimates/{name}/D", e.t_s, D, name, colour, sd_D)
            if sd_D is not None:
                self._log_deck_point(name, e.t_s, D, sd_D)
            if truth is not None:
                err_mm = (D - truth.at("D", e.t_s)) * 1e3
                recording.series(PANELS["error_D_mm"], f"truth/error_D_mm/{name}", e.t_s, err_mm, name, colour,
                                 None if sd_D is None else sd_D * 1e3)

    def _log_deck_point(self, name: str, t_s: np.ndarray, D: np.ndarray, sd_D: np.ndarray) -> None:
        """The deck point below the tip, (0, 0, -D), with its 3-sigma ellipsoid in D."""
        if len(t_s) == 0:
            return
        keep = np.r_[True, np.diff(np.floor(t_s * ELLIPSOID_RATE_HZ)) > 0]
        D, sd = D[keep], sd_D[keep]
        centers = np.column_stack([np.zeros_like(D), np.zeros_like(D), -D])
        half = np.column_stack([np.full_like(D, DECK_POINT_HALF_WIDTH_M), np.full_like(D, DECK_POINT_HALF_WIDTH_M), BAND_SIGMAS * sd])
        self.recording.ellipsoids(f"estimates/{name}/deck_point", t_s[keep], centers, half, "estimate")

    def log_world(self) -> None:
        log_world(self.recording, self.source)

    def close(self) -> None:
        self.recording.close()
