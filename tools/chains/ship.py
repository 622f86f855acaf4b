"""Ship-to-ship transfer: the heave chain and, when the installation has a LiDAR, the feeder's
6-DOF chain beside it, on the same frames (the feeder chain reuses the heave chain's deck and
Doppler stages). Outputs, kpis and report are the heave chain's plus the feeder's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from boomtip.data.frames import Frame, FrameSource, Truth
from boomtip.tools.config.processing import Processing
from boomtip.perception.pipeline import FrameResult
from boomtip.tools.chains.feeder import FeederChain, FeederResult
from boomtip.tools.chains.heave import HeaveChain, HeaveResult


@dataclass
class ShipResult:
    heave: HeaveResult
    feeder: FeederResult


class ShipChain:
    name = "heave"

    def __init__(self, source: FrameSource, processing: Processing) -> None:
        self.heave = HeaveChain(source, processing)
        self.feeder = FeederChain(source, processing)
        self.feeder.gap.pipeline = self.heave.pipeline  # its stages run on frames in an MRU gap (feeder_mru_gap)
        self.source = source
        self.p_tip_crane_m = source.meta.installation.T_crane_boomtip()[:3, 3]

    def process(self, frame: Frame) -> FrameResult:
        res = self.heave.process(frame)
        self.feeder.process(frame, res)
        return res

    def finish(self, duration_s: float, t_start_s: float = 0.0) -> ShipResult:
        return ShipResult(self.heave.finish(duration_s, t_start_s), self.feeder.finish())

    def write(self, out: Path, result: ShipResult) -> list[str]:
        from boomtip.tools.report.feeder import write_feeder_estimates, write_feeder_online

        written = self.heave.write(out, result.heave)
        write_feeder_estimates(out / "feeder_estimates.csv", result.feeder)
        return written + ["feeder_estimates.csv"] + write_feeder_online(out, result.feeder)

    def kpis(self, result: ShipResult, truth: Truth | None, windows=()) -> dict:
        from boomtip.tools.report.feeder import feeder_kpis

        kpis = self.heave.kpis(result.heave, truth, windows)
        fused = result.heave.estimates.get("fused")
        heave_D = (fused.t_s, fused.x[:, 0]) if fused is not None else None
        from boomtip.tools.chains.runner import outage_windows

        kpis["feeder"] = feeder_kpis(result.feeder, truth, self.p_tip_crane_m, windows, heave_D,
                                     outage_windows(self.source, ("mru",)))
        return kpis

    def report(self, out: Path, kpis: dict, result: ShipResult, truth: Truth | None) -> list[str]:
        from boomtip.tools.report.feeder import report_section, write_feeder_plot
        from boomtip.tools.chains.runner import outage_windows

        written = self.heave.report(out, kpis, result.heave, truth)
        report = out / "report.md"
        if report.exists():
            with open(report, "a", encoding="utf-8") as fh:
                fh.write(report_section(kpis, outage_windows(self.source)))
        plot = write_feeder_plot(out, result.feeder, truth, self.p_tip_crane_m)
        return written + ([] if plot is None or "plots" in written else ["plots"])

    def visualiser(self, path: Path, source: FrameSource):
        return self.heave.visualiser(path, source)

    def visualise_result(self, viz, result: ShipResult, truth: Truth | None) -> None:
        from boomtip.tools.report.feeder import log_feeder, truth_of

        self.heave.visualise_result(viz, result.heave, truth)
        res = result.feeder
        truth_pose = truth_of(res, truth, self.p_tip_crane_m)[0] if truth is not None and "feeder_x" in truth.columns and len(res.t_s) else None
        mru = self.source.mru

        def yaw(t: float) -> float:
            att = mru.attitude(t)
            return float(att[0][2]) if att is not None else 0.0

        log_feeder(viz, res, res.model_points_map, res.T_map_feeder, truth_pose, yaw, mesh_feeder=self._feeder_mesh(truth, res))

    def _feeder_mesh(self, truth: Truth | None, res) -> tuple[np.ndarray, np.ndarray] | None:
        """The simulated feeder's mesh in the feeder frame as the truth defines it (its body axes,
        origin below the tip at the first frame), for the recording only; None for a recording
        of a real run or one without the feeder's truth."""
        from boomtip.tools.report.feeder_truth import feeder_origin_body

        bodies = getattr(getattr(self.source, "world", None), "bodies", None) or []
        feeder = next((b for b in bodies if b.name == "feeder"), None)
        if feeder is None or truth is None or "feeder_x" not in truth.columns or not np.isfinite(res.t_definition_s):
            return None
        origin = feeder_origin_body(truth, res.t_definition_s, self.p_tip_crane_m)
        return feeder.vertices - origin, feeder.triangles
