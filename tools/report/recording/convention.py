"""One convention for every chain's rerun recording (.rrd, no viewer needed).

Everything 3-D is in the boom tip's gravity-levelled frame (origin at the tip, z up, the MRU's
heading), so the deck appears below at z = -D whatever the crane vessel's attitude. Entity roots:

- `world/`: the boom tip; in a simulated run the bodies' meshes moved by their poses;
- `sensors/lidar`, `sensors/radar`: the clouds (radar detections coloured by range rate);
- `detections/<stage>`: what each perception stage found, coloured by its class;
- `estimates/<solution>`: positions with their 3-sigma ellipsoids, series with 3-sigma bands;
- `truth/`: ghosts and series of the simulated truth, and the errors against it.

Classes (ids, labels, colours) come from one AnnotationContext at the root
(tools.report.classes). The blueprint, sent when the recording closes, opens with the 3-D view
on the left and a panel per series on the right.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from boomtip.tools.report.classes import CLASSES, by_name, rgb

__all__ = ["BAND_ALPHA", "BAND_SIGMAS", "ROOTS", "TIMELINE", "Recording", "colormap"]

TIMELINE = "sensor_time"
ROOTS = ("world", "sensors", "detections", "estimates", "truth")
BAND_ALPHA = 90  # the 3-sigma band's lines: the series' colour, faded
BAND_SIGMAS = 3.0  # the bands' and the ellipsoids' half width, in sigmas


def colormap(values: np.ndarray, lo: float, hi: float, name: str) -> np.ndarray:
    import matplotlib

    cmap = matplotlib.colormaps[name]
    x = np.clip((values - lo) / max(hi - lo, 1e-9), 0, 1)
    return (cmap(x)[:, :3] * 255).astype(np.uint8)


class Recording:
    """A recording stream saved to `path`, set up in the convention above; `series` and the
    entities logged through it make the blueprint's panels."""

    def __init__(self, path: Path, application_id: str, view_name: str) -> None:
        import rerun as rr

        self.rr = rr
        self.view_name = view_name
        self.panels: dict[str, list[str]] = {}  # panel title -> the entity paths it shows
        self.t_range_s = [np.inf, -np.inf]
        # rows batched into large chunks: rerun's default flushes every few milliseconds, and an
        # offline run logs a frame's small entities each into a chunk of its own whose schema
        # outweighs its data
        self.rec = rr.RecordingStream(application_id, batcher_config=rr.ChunkBatcherConfig(
            flush_tick=5.0, flush_num_bytes=8 * 1024 * 1024, flush_num_rows=100_000))
        self.rec.save(str(path))
        self.rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.rec.log("/", rr.AnnotationContext([rr.AnnotationInfo(c.id, c.label, rgb(c.colour)) for c in CLASSES]),
                     static=True)
        self.rec.log("world/boom_tip", rr.Points3D([[0, 0, 0]], radii=0.3, class_ids=[by_name("tip").id],
                                                   show_labels=True), static=True)

    def time(self, t_s: float) -> None:
        self.rec.set_time(TIMELINE, duration=t_s)
        self.t_range_s = [min(self.t_range_s[0], t_s), max(self.t_range_s[1], t_s)]

    def log(self, path: str, entity, static: bool = False) -> None:
        self.rec.log(path, entity, static=static)

    def clear(self, path: str) -> None:
        self.rec.log(path, self.rr.Clear(recursive=True))

    def points(self, path: str, points: np.ndarray, cls: str, radius_m: float, labels: list[str] | None = None) -> None:
        """Points of a class; the class's name is in the legend, not written beside each point."""
        self.rec.log(path, self.rr.Points3D(points, radii=radius_m, class_ids=by_name(cls).id, labels=labels,
                                            show_labels=labels is not None))

    def line(self, path: str, vertices: np.ndarray, cls: str, radius_m: float) -> None:
        """A polyline through `vertices` (N,3)."""
        self.rec.log(path, self.rr.LineStrips3D([vertices], radii=radius_m, class_ids=[by_name(cls).id], show_labels=False))

    def series(self, panel: str, path: str, t_s: np.ndarray, values: np.ndarray, name: str, colour: list[int],
               sigma: np.ndarray | None = None, width: float = 1.2) -> None:
        """A time series at `path` (its NaN rows dropped), and with `sigma` its +-3 sigma band as
        two faded lines below it; shown in the blueprint's panel `panel`."""
        rr, rec = self.rr, self.rec
        ok = np.isfinite(values)
        lines = [(path, values, colour, name, width)]
        if sigma is not None:
            ok &= np.isfinite(sigma)
            band = [*colour[:3], BAND_ALPHA]
            lines += [(f"{path}/sigma3_high", values + BAND_SIGMAS * sigma, band, f"{name} +3 sigma", 0.8),
                      (f"{path}/sigma3_low", values - BAND_SIGMAS * sigma, band, f"{name} -3 sigma", 0.8)]
        if not ok.any():
            return
        for p, v, c, n, w in lines:
            rec.log(p, rr.SeriesLines(colors=[c], names=n, widths=w), static=True)
            rec.send_columns(p, indexes=[rr.TimeColumn(TIMELINE, duration=t_s[ok])],
                             columns=rr.Scalars.columns(scalars=v[ok]))
        self.panels.setdefault(panel, []).append(f"+ /{path}/**" if sigma is not None else f"+ /{path}")

    def ellipsoids(self, path: str, t_s: np.ndarray, centers: np.ndarray, half_sizes: np.ndarray, cls: str,
                   quaternions_xyzw: np.ndarray | None = None) -> None:
        """One ellipsoid per time: a position's 3-sigma, its axes the tip frame's or rotated by
        `quaternions_xyzw` (T,4)."""
        rr = self.rr
        ok = np.all(np.isfinite(centers), axis=1) & np.all(np.isfinite(half_sizes), axis=1)
        if not ok.any():
            return
        self.rec.log(path, rr.Ellipsoids3D(half_sizes=[[0.0, 0.0, 0.0]], class_ids=[by_name(cls).id], show_labels=False,
                                           fill_mode=rr.components.FillMode.MajorWireframe), static=True)
        extra = {} if quaternions_xyzw is None else {"quaternions": quaternions_xyzw[ok]}
        self.rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t_s[ok])],
                              columns=rr.Ellipsoids3D.columns(centers=centers[ok], half_sizes=half_sizes[ok], **extra))

    def mesh(self, path: str, vertices: np.ndarray, triangles: np.ndarray, cls: str, alpha: int = 255) -> None:
        self.rec.log(path, self.rr.Mesh3D(vertex_positions=vertices.astype(np.float32), triangle_indices=triangles,
                                          albedo_factor=[*rgb(by_name(cls).colour), alpha]), static=True)

    def poses(self, path: str, t_s: np.ndarray, R: np.ndarray, p: np.ndarray, scale: np.ndarray | None = None) -> None:
        """The transform of `path` (and everything under it) over time: rotations (T,3,3), positions (T,3)."""
        rr = self.rr
        ok = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(R.reshape(len(R), -1)), axis=1)
        if not ok.any():
            return
        extra = {} if scale is None else {"scale": scale[ok]}
        self.rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t_s[ok])],
                              columns=rr.Transform3D.columns(translation=p[ok], mat3x3=R[ok], **extra))

    def blueprint(self):
        import rerun.blueprint as rrb

        spatial = rrb.Spatial3DView(origin="/", name=self.view_name,
                                    contents=[f"+ /{root}/**" for root in ROOTS])
        if not self.panels:
            return rrb.Blueprint(spatial, collapse_panels=True)
        series = [rrb.TimeSeriesView(origin="/", name=title, contents=paths) for title, paths in self.panels.items()]
        return rrb.Blueprint(rrb.Horizontal(spatial, rrb.Vertical(*series), column_shares=[3, 2]), collapse_panels=True)

    def close(self) -> None:
        self.rec.send_blueprint(self.blueprint())
        self.rec.flush()
        self.rec.disconnect()
