"""Benchmarks of real recordings: how fast the loaders read (`bench io`) and how the deck stage
holds on real LiDAR scans with the ground as the deck (`bench ground`).

Both default to the real Ouster captures shipped in tests/data/real/ouster (BSD, see its
README): an OS1-128 (3 scans, ground 28 %), an OS2-128 (ground 9 %) and an OS1-32.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from boomtip.data.frames import Frame
from boomtip.data.installation import Installation

REAL = Path(__file__).resolve().parents[2] / "tests" / "data" / "real" / "ouster"
PCAPS = ("OS-1-128_v2.3.0_1024x10_lb_n3.pcap", "OS-2-128-U1_v2.3.0_1024x10.pcap", "OS-1-32-G_v2.1.1_1024x10.pcap")


def level_installation() -> Installation:
    """The ground as the deck: a level, identity-mounted spinning LiDAR at the boom tip, no
    radar, no markers."""
    return Installation.model_validate({
        "attitude": "level", "radar": {"enabled": False}, "markers": {"enabled": False},
        "lidar": {"pattern": "spinning", "rate_hz": 10, "mount": {"xyz_m": [0, 0, 0], "rpy_deg": [0, 0, 0]}},
        "crane": {"geometry": {"boom_tip_m": [0, 0, 0]}}})


def _pcap(path: Path | None) -> Path:
    path = path or REAL / PCAPS[0]
    if not path.is_file():
        from boomtip.data.io.recording import RecordingError

        raise RecordingError(f"{path}: no such pcap (the default lives in the source tree's tests/data/real/ouster)")
    return path


def bench_io(pcap: Path | None = None, frames: int = 60, rate_hz: float = 20.0, mcap_s: float = 5.0) -> dict:
    """Ouster pcap and MCAP read rates, as recording seconds per wall second. The pcap is read
    over and over until `frames` frames have come out; `rate_hz` is the frame rate the ratio
    assumes (a 20 Hz OS1-128: 131k returns per frame at twice this capture's 10 Hz). The
    baseline is ouster-sdk's own loop on the same frames (open, iterate, XYZLut, drop zero
    ranges): what the loader adds on top of it is the second ratio."""
    from ouster.sdk import core, open_source

    from boomtip.data.io.ouster import OusterPcapSource

    pcap = _pcap(pcap)
    src = OusterPcapSource(pcap, level_installation())
    n_file = len(src)
    passes = max(1, -(-frames // n_file))

    def ours() -> tuple[int, int]:
        n = pts = 0
        for _ in range(passes):
            for f in src:
                n += 1
                pts += len(f)
        return n, pts

    lut = core.XYZLut(src.info)

    def raw() -> int:
        n = 0
        for _ in range(passes):
            s = open_source(str(pcap), meta=[str(src.meta_json)], sensor_idx=0)
            for fs in s:
                for scan in fs.valid_frames():
                    rng = scan.field(core.ChanField.RANGE)
                    lut(rng).reshape(-1, 3)[(rng > 0).ravel()]
                    n += 1
            s.close()
        return n

    ours(), raw()  # warm the caches and imports
    t0 = time.perf_counter()
    n, pts = ours()
    wall = time.perf_counter() - t0
    t0 = time.perf_counter()
    raw()
    wall_raw = time.perf_counter() - t0
    out = {"pcap": pcap.name, "frames": n, "points_per_frame": pts / n, "assumed_rate_hz": rate_hz,
           "pcap_ms_per_frame": 1e3 * wall / n, "ouster_sdk_ms_per_frame": 1e3 * wall_raw / n,
           "ratio": (n / rate_hz) / wall, "overhead_vs_ouster_sdk": wall / wall_raw}
    if mcap_s > 0:
        out.update(_bench_mcap(mcap_s))
    return out


def _bench_mcap(duration_s: float) -> dict:
    from boomtip.data.io.rosbag import RosBagSource
    from boomtip.data.io.ros_writer import write_bag
    from boomtip.tools.config.scenario import load_scenario
    from boomtip.data.sim.sources import simulation_for

    s = load_scenario("sts-loaded", [f"duration_s={duration_s}"])
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bench"
        write_bag(simulation_for(s), out, "mcap")
        t0 = time.perf_counter()
        src = RosBagSource(out / "bench.mcap", None)
        n = sum(1 for _ in src)
        wall = time.perf_counter() - t0
    return {"mcap_duration_s": duration_s, "mcap_frames": n, "mcap_wall_s": wall, "mcap_ratio": duration_s / wall}


def _frames(pcap: Path) -> list[Frame]:
    from boomtip.data.io.ouster import OusterPcapSource

    return [f for f in OusterPcapSource(pcap, level_installation())]


def open3d_ground(points: np.ndarray, threshold_m: float, iterations: int, probability: float, seed: int,
                  max_planes: int = 6) -> tuple[np.ndarray, int]:
    """Open3D's segment_plane, plane after plane, until one within 10 deg of level: the ground
    as Open3D finds it, and its inlier count."""
    import open3d as o3d

    rest = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    for _ in range(max_planes):
        o3d.utility.random.seed(seed)
        plane, inliers = rest.segment_plane(threshold_m, 3, iterations, probability=probability)
        if abs(plane[2]) > np.cos(np.radians(10.0)):
            return np.asarray(plane), len(inliers)
        rest = rest.select_by_index(inliers, invert=True)
    return np.full(4, np.nan), 0


def bench_ground(pcaps: list[Path] | None = None, seeds: int = 20, tolerance_m: float = 0.01,
                 reference_iterations: int = 20000) -> dict:
    """Deck D (the ground below the sensor) against Open3D's segment_plane on the same points,
    over `seeds` seeds of the pipeline. The reference is an exhaustive segment_plane (no early
    stop, `reference_iterations` hypotheses: millimetres from seed to seed); Open3D's usual
    call (1000 hypotheses with its early stop) is run over the same seeds for its own spread."""
    from boomtip.data.frames import MruLog
    from boomtip.perception.pipeline import HeavePipeline, PipelineConfig

    inst = level_installation()
    cfg = PipelineConfig(methods=("deck_lidar",))
    thr = cfg.deck_lidar.multi_plane.ransac.distance_threshold_m
    rmin = cfg.deck_lidar.preprocess.min_range_m
    scans = []
    for pcap in pcaps or [REAL / p for p in PCAPS]:
        for frame in _frames(pcap):
            pts = frame.points_sensor
            pts = pts[np.linalg.norm(pts, axis=1) >= rmin]  # the deck stage's own range window
            ref, n_ref = open3d_ground(pts, thr, reference_iterations, 1.0, 0)
            D_ref = float(ref[3] / ref[2])  # level, identity mount: D is the plane's height below the sensor
            mru = MruLog.level(frame.t_s, frame.t_s)
            ours, ms, capped = [], [], 0
            for seed in range(seeds):
                row = HeavePipeline(inst, mru, cfg, seed=seed).process(frame).measurements[0]
                ours.append(row.value if row.ok else np.nan)
                ms.append(row.time_ms)
                capped += row.ok and row.status != "ok"
            o3d_D, o3d_ms = [], []
            for seed in range(seeds):
                t0 = time.perf_counter()
                p, _ = open3d_ground(pts, thr, 1000, 0.99999999, seed)
                o3d_ms.append(1e3 * (time.perf_counter() - t0))
                o3d_D.append(float(p[3] / p[2]))
            err = np.abs(np.array(ours) - D_ref)
            o3d_err = np.abs(np.array(o3d_D) - D_ref)
            scans.append({
                "scan": f"{pcap.stem}#{frame.index}", "points": int(len(pts)), "ground_fraction": n_ref / len(pts),
                "D_reference_m": D_ref, "within_tolerance": int(np.sum(err <= tolerance_m)),
                "max_error_m": float(np.nanmax(err)) if np.isfinite(err).any() else float("nan"),
                "median_error_m": float(np.nanmedian(err)), "missing": int(np.sum(~np.isfinite(err))), "capped": capped,
                "deck_ms": float(np.median(ms)),
                "open3d_default_within_tolerance": int(np.sum(o3d_err <= tolerance_m)),
                "open3d_default_max_error_m": float(np.max(o3d_err)), "open3d_default_ms": float(np.median(o3d_ms)),
            })
    worst = min(s["within_tolerance"] for s in scans)
    return {"seeds": seeds, "tolerance_m": tolerance_m, "threshold_m": thr, "reference_iterations": reference_iterations,
            "scans": scans, "worst_within_tolerance": worst,
            "ratio": float(np.median([s["open3d_default_ms"] / s["deck_ms"] for s in scans]))}
