"""`boomtip bench lift`: the real-time factor of the lift chain as a user runs it (`boomtip
process` in a fresh process on a recording of the lift: start-up, reading, every output), with
the default workers, beside the hook chain alone on the same recording (what the load's
clearance, landing point and forecast add) and `--workers 1`.

The recording is simulated once into a scratch folder (not timed)."""

from __future__ import annotations

import json
import statistics
import tempfile
from pathlib import Path

from boomtip.tools.bench.process import open_recording, process_wall_s, simulate_recording

__all__ = ["bench_lift"]


def _accuracy(kpis: dict) -> dict:
    lift = kpis.get("lift") or {}
    got = {"clearance_rmse_m": (lift.get("clearance") or {}).get("rmse_m"),
           "clearance_rate_rmse_mps": (lift.get("clearance_rate") or {}).get("rmse_mps"),
           "landing_point_rmse_m": (lift.get("landing_point") or {}).get("rmse_m"),  # in the feeder's deck frame
           "landing_point_tip_rmse_m": (lift.get("landing_point") or {}).get("tip_rmse_m"),
           "forecast_rate_rmse_mps_at_2s": (lift.get("forecast") or {}).get("rmse_mps_at_2s")}
    return {k: v for k, v in got.items() if v is not None}


def bench_lift(scenario: str = "lift", duration_s: float | None = None, repeats: int = 3) -> dict:
    """Median wall time of `repeats` runs of each; ratio = the lift chain's real-time factor
    with the default workers."""
    with tempfile.TemporaryDirectory(prefix="boomtip-bench-lift-") as tmp:
        folder = Path(tmp)
        rec = simulate_recording(scenario, duration_s, folder)
        seconds = float(open_recording(rec, None).duration_s)
        runs: dict[str, list[float]] = {"lift": [], "hook_alone": [], "lift_workers_1": []}
        apt_ms, accuracy = [], {}
        for _ in range(repeats):  # interleaved: a machine's drift falls on all alike
            runs["lift"].append(process_wall_s(rec, folder / "out", None, []))
            kpis = json.loads((folder / "out" / "kpis.json").read_text())
            apt_ms.append(kpis["hook"]["segmentation"]["apt_ms"])
            accuracy = _accuracy(kpis)
            runs["hook_alone"].append(process_wall_s(rec, folder / "out", None, ["--set", "processing.chain=hook"]))
            runs["lift_workers_1"].append(process_wall_s(rec, folder / "out", 1, []))
    out: dict = {"recording": f"{scenario}, {seconds:g} s", "recording_s": seconds, "repeats": repeats}
    for name, walls in runs.items():
        wall = statistics.median(walls)
        out[name] = {"wall_s": round(wall, 3), "min_s": round(min(walls), 3), "max_s": round(max(walls), 3),
                     "realtime_factor": round(seconds / wall, 3)}
    out["frame_ms"] = round(statistics.median(apt_ms), 2)  # a LiDAR frame's stages, the lift's included
    out["lift_over_hook"] = round(out["lift"]["wall_s"] / out["hook_alone"]["wall_s"], 3)
    out["accuracy"] = accuracy
    out["ratio"] = out["lift"]["realtime_factor"]
    out["ratio_note"] = "the real-time factor of `boomtip process` with the lift chain, default workers, start-up and outputs included"
    return out
