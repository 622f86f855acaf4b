"""plots/detections.png: what the heave pipeline found in the pictured LiDAR frames (a
representative one, and the worst: tools/chains/pictures.py), drawn over each frame's cloud from
above and from the side (in the deck plane's axes: a picture that reads the same
whatever the sensor's mount), and each method's status over the run. A look at the detections
without a viewer; a run without a LiDAR frame, or a frame without a deck, says so in the title."""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path

import numpy as np

from boomtip.perception.pipeline import FrameResult, Measurement
from boomtip.tools.report.classes import by_name
from boomtip.tools.report.plots import legend, plot_path, save

__all__ = ["DETECTIONS_PLOT", "deck_axes", "detections_figure", "detections_title", "frames_figure", "write_detections",
           "status_timeline"]

DETECTIONS_PLOT = "detections"
MAX_CLOUD_POINTS = 40_000  # the faded cloud is drawn from at most this many returns (evenly picked)
STATUS_OK = "#2ca02c"
STATUS_COLOURS = ("#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf", "#ff7f0e")


def deck_axes(plane_sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows u, v, n (n the plane's normal towards the sensor) and the plane's point nearest the
    sensor: coordinates from above are (u, v), from the side (u, height above the deck)."""
    n = np.asarray(plane_sensor[:3], float)
    n = n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(helper, n)
    u /= np.linalg.norm(u)
    R = np.vstack([u, np.cross(n, u), n])
    return R, -float(plane_sensor[3]) * n


def _in_deck(points: np.ndarray, R: np.ndarray, origin: np.ndarray) -> np.ndarray:
    return (np.asarray(points, float).reshape(-1, 3) - origin) @ R.T


def status_timeline(ax, rows: Collection[Measurement]) -> None:
    """A row per method, each frame a mark coloured by its status: ok, or each reason apart."""
    methods = sorted({r.method for r in rows})
    reasons = sorted({r.status for r in rows if not r.ok})
    colour = {"ok": STATUS_OK, **{s: STATUS_COLOURS[i % len(STATUS_COLOURS)] for i, s in enumerate(reasons)}}
    labelled: set[str] = set()
    for y, m in enumerate(methods):
        by_status: dict[str, list[float]] = {}
        for r in rows:
            if r.method == m:
                by_status.setdefault("ok" if r.ok else r.status, []).append(r.t_s)
        for status, t in by_status.items():
            label = None if status in labelled else (status if len(status) <= 60 else status[:57] + "...")
            labelled.add(status)
            ax.plot(t, np.full(len(t), y), "|", ms=9, color=colour[status], label=label)
    ax.set_yticks(range(len(methods)), methods)
    ax.set_ylim(-0.7, max(len(methods), 1) - 0.3)
    ax.set_xlabel("t [s] from the recording's start")
    ax.set_title("Each method's status per frame" if methods else "Each method's status per frame: no measurement in this run")
    legend(ax, fontsize=8)


def write_detections(out: Path, frames: list[tuple[FrameResult, str]], rows: Collection[Measurement], p_tip_sensor: np.ndarray) -> Path:
    """OUT/plots/detections.png: each of `frames` (a LiDAR frame's result with its cloud and
    detections, and why it is pictured; none: the run had no LiDAR frame) from above and from the
    side, and the status of every method."""
    return save(detections_figure(frames, rows, p_tip_sensor), plot_path(out, DETECTIONS_PLOT))


def detections_title(frame: FrameResult | None) -> str:
    deck = frame.deck_lidar if frame is not None else None
    if frame is None:
        return "No LiDAR frame in this run: nothing to draw"
    if deck is None or deck.plane_sensor is None:
        why = deck.status if deck is not None else "no deck stage ran"
        return f"LiDAR frame {frame.frame.index} (t = {frame.frame.t_s:.2f} s): no deck found ({why})"
    return f"LiDAR frame {frame.frame.index} (t = {frame.frame.t_s:.2f} s) and its detections, in the deck plane's axes"


def detections_figure(frames: list[tuple[FrameResult, str]], rows: Collection[Measurement], p_tip_sensor: np.ndarray):
    """The picture as a matplotlib figure: each frame from above and from the side, then the status timeline."""
    return frames_figure(frames, rows, lambda above, side, frame: _draw_frame(above, side, frame, p_tip_sensor),
                         detections_title, "What the heave pipeline detected")


def frames_figure(frames: list[tuple[object, str]], rows: list, draw, title_of, suptitle: str):
    """Each pictured frame (a chain's output, why it is pictured) in a row, from above and from the
    side (`draw(above, side, output)`), titled `title_of(output)`; then every stage's status per
    frame (`rows`: .t_s, .method, .status, .ok). Without a frame, `title_of(None)` says why."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = max(len(frames), 1)
    fig = plt.figure(figsize=(13, 4.5 + 4.5 * n), layout="constrained")
    grid = fig.add_gridspec(n + 1, 2, height_ratios=[1.6] * n + [1])
    for k, (output, why) in enumerate(frames or [(None, "")]):
        above, side = fig.add_subplot(grid[k, 0]), fig.add_subplot(grid[k, 1])
        draw(above, side, output)
        above.set_title(f"{title_of(output)}\n{why}: from above" if why else title_of(output), loc="left", fontsize=9)
        side.set_title("from the side", fontsize=9)
    status_timeline(fig.add_subplot(grid[n, :]), rows)
    fig.suptitle(suptitle if frames else title_of(None))
    return fig


def _draw_frame(above, side, frame: FrameResult | None, p_tip_sensor: np.ndarray) -> None:
    deck = frame.deck_lidar if frame is not None else None
    if deck is None or deck.plane_sensor is None:
        return  # the title says why
    R, origin = deck_axes(deck.plane_sensor)
    pts = frame.frame.points_sensor
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    layers = {"cloud": pts[:: max(1, len(pts) // MAX_CLOUD_POINTS)]}
    if deck.fit is not None:
        layers["deck"] = deck.points_used[deck.fit.inlier_mask]
    ref = frame.reflectors
    if ref is not None:
        layers["bright"], layers["markers"] = ref.bright_points, ref.marker_centroids
    layers["tip"] = p_tip_sensor
    for name, points in layers.items():
        q = _in_deck(points, R, origin)
        if len(q) == 0:
            continue
        colour, label = by_name(name).colour, by_name(name).label  # the recording's class colours
        style = ({"s": 2, "alpha": 0.3} if name == "cloud" else {"s": 4} if name in ("deck", "bright")
                 else {"s": 40, "marker": "x" if name == "markers" else "^"})
        above.scatter(q[:, 0], q[:, 1], color=colour, label=label, linewidths=1.5, **style)
        side.scatter(q[:, 0], q[:, 2], color=colour, label=label, linewidths=1.5, **style)
    above.set_aspect("equal", adjustable="datalim")
    above.set_xlabel("u along the deck [m]")
    above.set_ylabel("v along the deck [m]")
    side.set_xlabel("u along the deck [m]")
    side.set_ylabel("height above the deck [m]")
    legend(side, fontsize=8)
