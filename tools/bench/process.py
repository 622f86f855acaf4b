"""`boomtip bench process`: the real-time factor of `boomtip process` as a user runs it (a fresh
process: start-up, reading, every output), with the default workers and with one, beside
kiss-icp's own odometry pipeline registering the same LiDAR frames in one process.

The default recording is simulated once into a scratch folder (not timed): sts-loaded with a
128 x 1024 spinning LiDAR at 20 Hz and the radar. `recording` benches one of the user's own
instead (with its installation file where the format carries none)."""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["bench_process", "DEFAULT_LIDAR"]

DEFAULT_LIDAR = ("lidar.pattern=spinning", "lidar.channels=128", "lidar.columns=1024", "lidar.rate_hz=20")
CLI = [sys.executable, "-c", "from boomtip.tools.cli import main; main()"]


def simulate_recording(scenario: str, duration_s: float | None, folder: Path, sets: tuple[str, ...] = ()) -> Path:
    """`boomtip simulate` into folder/recording (the scenario's duration when None), with `--set`s."""
    rec = folder / "recording"
    args = ["simulate", "-s", scenario, "-o", str(rec)] + (["--duration", str(duration_s)] if duration_s else [])
    for key in sets:
        args += ["--set", key]
    subprocess.run(CLI + args, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    return rec


def process_wall_s(recording: Path, out: Path, workers: int | None, extra: list[str]) -> float:
    args = ["process", str(recording), "-o", str(out), "--force", *extra]
    if workers is not None:
        args += ["--workers", str(workers)]
    t0 = time.perf_counter()
    done = subprocess.run(CLI + args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"boomtip {' '.join(args)} failed: {done.stderr.strip()[-400:]}")
    return wall


def open_recording(recording: Path, installation: Path | None):
    from boomtip.data.io.installation_file import load_installation
    from boomtip.data.io.loaders import open_source

    return open_source(recording, None, load_installation(installation) if installation else None, None, None, 1)


def _kiss_icp_wall_s(recording: Path, installation: Path | None) -> tuple[float, int]:
    """kiss-icp's own pipeline over the recording's LiDAR frames, reading included."""
    from boomtip.tools.bench.feeder import plain_kiss_icp

    t0 = time.perf_counter()
    source, kiss, frames = open_recording(recording, installation), plain_kiss_icp(), 0
    for frame in source:
        if frame.sensor != "lidar" or frame.error is not None or len(frame) == 0:
            continue
        pts = frame.points_sensor[np.all(np.isfinite(frame.points_sensor), axis=1)]
        kiss.register_frame(pts, np.zeros(len(pts)))
        frames += 1
    return time.perf_counter() - t0, frames


def _accuracy(kpis: dict) -> dict:
    """What the default run measured, where the recording has truth (the same in every repeat)."""
    fused = ((kpis.get("solutions") or {}).get("fused") or {})
    feeder = kpis.get("feeder") or {}
    got = {"fused_mae_D_m": fused.get("mae_D_m"), "fused_mae_D_dot_mps": fused.get("mae_D_dot_mps"),
           "feeder_rmse_pos_m": feeder.get("rmse_pos_m"), "feeder_rmse_rpy_deg": feeder.get("rmse_rpy_deg")}
    return {k: v for k, v in got.items() if v is not None}


def bench_process(scenario: str = "sts-loaded", duration_s: float = 20.0, repeats: int = 3,
                  recording: Path | None = None, installation: Path | None = None) -> dict:
    """Median wall time of `repeats` runs of `boomtip process` with the default workers and with
    `--workers 1`, and of kiss-icp's pipeline on the same frames; ratio = the default's real-time factor."""
    extra = ["--installation", str(installation)] if installation else []
    with tempfile.TemporaryDirectory(prefix="boomtip-bench-process-") as tmp:
        folder = Path(tmp)
        rec = recording if recording is not None else simulate_recording(scenario, duration_s, folder, DEFAULT_LIDAR)
        seconds = float(open_recording(rec, installation).duration_s)
        runs: dict[str, list[float]] = {"default": [], "workers_1": [], "kiss_icp": []}
        lidar_frames, apt_ms, accuracy = 0, [], {}
        for _ in range(repeats):  # interleaved: a machine's drift falls on all three alike
            runs["default"].append(process_wall_s(rec, folder / "out", None, extra))
            kpis = json.loads((folder / "out" / "kpis.json").read_text())
            apt = (kpis.get("feeder") or {}).get("apt_ms")
            apt_ms.append(float("nan") if apt is None else apt)
            accuracy = _accuracy(kpis)
            runs["workers_1"].append(process_wall_s(rec, folder / "out", 1, extra))
            wall, lidar_frames = _kiss_icp_wall_s(rec, installation)
            runs["kiss_icp"].append(wall)
    out: dict = {"recording": str(recording) if recording else f"{scenario}, {duration_s:g} s, " + ", ".join(DEFAULT_LIDAR),
                 "recording_s": seconds, "lidar_frames": lidar_frames, "repeats": repeats}
    for name, walls in runs.items():
        wall = statistics.median(walls)
        out[name] = {"wall_s": round(wall, 3), "min_s": round(min(walls), 3), "max_s": round(max(walls), 3),
                     "realtime_factor": round(seconds / wall, 3)}
    out["kiss_icp"]["ms_per_lidar_frame"] = round(1e3 * out["kiss_icp"]["wall_s"] / max(lidar_frames, 1), 2)
    out["feeder_apt_ms"] = round(statistics.median(apt_ms), 2)  # the feeder chain per LiDAR frame, its worker's share included
    out["accuracy"] = accuracy
    out["speedup_workers"] = round(out["workers_1"]["wall_s"] / out["default"]["wall_s"], 3)
    out["ratio"] = out["default"]["realtime_factor"]
    out["ratio_note"] = "the real-time factor of `boomtip process` with the default workers, start-up and outputs included"
    return out
