"""Ship-to-ship transfer: the relative heave (the heave chain) and, when the installation has a
LiDAR, the feeder's 6-DOF motion beside it on the same frames. The feeder pipeline reuses the
heave pipeline's deck and Doppler stages; its estimator fuses what it measures.

Outputs, kpis and report are the heave chain's plus the feeder's:
OUT/feeder_estimates.csv          the feeder frame in the heading frame at the tip, offline definition
OUT/feeder_estimates_online.csv   the same rows as a live controller had them
OUT/feeder_calibration.csv        the feeder frame's definition over the run
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from boomtip.data.frames import Frame, FrameSource, LevellingAttitude, Truth
from boomtip.data.poses import inverse, pose_vector
from boomtip.fusion.feeder_estimator import DeckMeasurement, FeederEstimator
from boomtip.fusion.radar_offset import RadarOffsetConfig
from boomtip.perception.feeder import FeederPerception, LidarObservation, RadarObservation
from boomtip.perception.feeder_pipeline import FeederPipeline
from boomtip.perception.pipeline import FrameResult
from boomtip.perception.timing import StageTimes
from boomtip.tools.chains.heave import HeaveChain, HeaveResult
from boomtip.tools.chains.pictures import FramePictures
from boomtip.tools.chains.provenance import outage_windows
from boomtip.tools.chains.resources import RunResources
from boomtip.tools.chains.workers import ForkExecutor
from boomtip.tools.config.processing import Processing
from boomtip.tools.report import feeder as feeder_outputs
from boomtip.tools.report.feeder import FeederResult
from boomtip.tools.report.plots import link_in_report, plot_link


@dataclass
class ShipFrame:
    """What `ShipChain.perceive` made of a frame, for `fuse`."""

    heave: FrameResult
    t_s: float
    sensor: str
    skipped: str | None  # why the feeder has nothing of it (an unreadable or empty frame, no attitude)
    attitude: LevellingAttitude | None = None
    observations: list[LidarObservation | RadarObservation] = field(default_factory=list)  # ready to fuse, in time order
    missing: list[tuple[float, str, str]] = field(default_factory=list)  # what the feeder's stages could not measure


def frame_result(output: ShipFrame | FrameResult) -> FrameResult:
    """The heave pipeline's result of a frame: a perceived frame's, or `fuse`'s output itself."""
    return output.heave if isinstance(output, ShipFrame) else output


@dataclass
class ShipResult:
    heave: HeaveResult
    feeder: FeederResult


# the report's parts' relative times (heave report and plots, the feeder's plot, the pictured
# frames' detections: 2.3, 1.0 and 1.5 s on a 20 s sts-loaded run), to split them between two processes
REPORT_COSTS = {"heave": 2.3, "feeder": 1.0, "detections": 1.5}


def deck_measurement(obs: LidarObservation | RadarObservation) -> DeckMeasurement | None:
    """A frame's deck plane as the estimator takes it: with its spin when the returns' times gave one."""
    spin, plane = (obs.spin if isinstance(obs, LidarObservation) else None), obs.plane
    if plane is None:
        return None
    if spin is not None:  # the spin's plane: at the frame's time, not at its returns' mean time
        return DeckMeasurement(spin.abc, spin.cov, plane.normal, spin.rates)
    return DeckMeasurement(plane.abc, plane.cov, plane.normal)


class ShipChain:
    name = "heave"  # kpis.json's chain: the heave chain's figures, with the feeder's beside them

    def __init__(self, source: FrameSource, processing: Processing, resources: RunResources | None = None) -> None:
        self.heave = HeaveChain(source, processing, resources)
        inst, cfg = source.meta.installation, processing.feeder
        rr = cfg.radar_registration
        self.estimator = FeederEstimator(source.mru, inst, cfg, RadarOffsetConfig(rr.enabled, rr.after_s, rr.learn_every,
                                         rr.offset_frames, rr.min_offset_frames, rr.max_sigma_m), source.feeder_mru,
                                         self.heave.resources.block_store("boomtip-feeder-states-"))
        stages = FeederPerception(inst, cfg.perception, self.estimator.rates_averaged_over, self.estimator.noise.angle_rad)
        # a lagged merge of the feeder's model in a process of its own when the run has two
        merges = ForkExecutor("boomtip-merge") if self.heave.resources.parallel else None
        self.pipeline = FeederPipeline(inst, cfg, stages, processing.seed, heave=self.heave.pipeline, merge_executor=merges)
        self.source = source
        self.p_tip_crane_m = inst.T_crane_boomtip()[:3, 3]
        self.missing: list[tuple[float, str, str]] = []  # frames the feeder could not use: (t, sensor, why)
        self.frame_ms: list[float] = []
        self.stage_ms: dict[str, float] = {}  # the LiDAR frames' time by stage, summed over the run

    def frames(self, source: FrameSource):
        return iter(source)

    # -- per frame -------------------------------------------------------------------------
    def process(self, frame: Frame) -> FrameResult:
        return self.fuse(self.perceive(frame))

    def perceive(self, frame: Frame) -> ShipFrame:
        """The heave and feeder pipelines' per-frame stages; reads the MRU log, not the estimator's state."""
        heave = self.heave.perceive(frame)
        if frame.error is not None or len(frame) == 0:
            return ShipFrame(heave, frame.t_s, frame.sensor, frame.error or "empty frame")
        att = self.estimator.levelling(frame.t_s)
        if att is None:
            return ShipFrame(heave, frame.t_s, frame.sensor, "no MRU attitude")
        known = len(self.pipeline.missing)
        observations = self.pipeline.observe(frame, heave, att)
        missing, self.pipeline.missing[known:] = self.pipeline.missing[known:], []  # to fuse, in order with its own
        return ShipFrame(heave, frame.t_s, frame.sensor, None, att, observations, missing)

    def without_clouds(self, p: ShipFrame) -> ShipFrame:
        """What `fuse` needs: the heave stages' cloud and detections dropped, the feeder's observations kept."""
        return replace(p, heave=self.heave.without_clouds(p.heave))

    def frame_score(self, output: ShipFrame | FrameResult, truth: Truth | None) -> tuple[float, str] | None:
        return self.heave.frame_score(frame_result(output), truth)

    def fuse(self, p: ShipFrame) -> FrameResult:
        """A perceived frame into the estimators, in time order."""
        heave = self.heave.fuse(p.heave)
        if p.skipped is not None:
            self.missing.append((p.t_s, p.sensor, p.skipped))
            return heave
        self.estimator.adopt(p.attitude, p.t_s, p.sensor)
        self.pipeline.missing.extend(p.missing)
        for obs in p.observations:
            self._fuse(obs)
        return heave

    def _fuse(self, obs: LidarObservation | RadarObservation) -> None:
        if isinstance(obs, LidarObservation):
            self.frame_ms.append(timed_fusion(self._lidar, obs, self.stage_ms))
        elif self.estimator.started:
            self._radar(obs)

    def _lidar(self, obs: LidarObservation, times: StageTimes) -> None:
        est, pipe = self.estimator, self.pipeline
        pipe.next_lidar_frame(times)
        deck = est.lidar_deck(obs.t_s, obs.tip_level, obs.tip_velocity, obs.t_level_sensor, obs.noise, deck_measurement(obs))
        # without a deck its structure has nothing to stand on; not to register (the pipeline's cadence): its deck alone
        if not (deck and obs.to_register):
            if est.started:
                est.record(obs.t_s, "lidar", obs.tip_velocity, obs.t_level_sensor, pipe.edges_known)
            return
        T_map_level = est.map_pose()
        structure = pipe.structure(obs, T_map_level, est.deck_plane(), times)
        reg = pipe.register(obs, structure, T_map_level, est.registration_sigma_m(), times)
        if reg is not None:
            est.update_registration(obs.t_s, pose_vector(inverse(reg.T_map_level)), reg.info6, pipe.young_model, obs.noise)
        pipe.keep(obs, structure, reg, est.map_pose(), est.position_sigma_x_m(), times)
        est.record(obs.t_s, "lidar", obs.tip_velocity, obs.t_level_sensor, pipe.edges_known)

    def _radar(self, obs: RadarObservation) -> None:
        est = self.estimator
        if obs.velocity_level is None and obs.plane is None:
            self.missing.append((obs.t_s, "radar", obs.status))  # its detections may still register below
        est.predict(obs.t_s, obs.tip_level, obs.tip_velocity, obs.noise)
        est.update_radar(obs.t_s, obs.velocity_level, obs.velocity_cov, obs.xi_level, deck_measurement(obs), obs.noise)
        wanted = est.radar_registration_wanted(obs.t_s)
        reg = self.pipeline.register_radar(obs, est.filter.x[:6], count_failure=wanted == "update") if wanted else None
        if reg is not None:
            est.radar_registration(wanted, reg.x_y_yaw, reg.info)
        est.record(obs.t_s, "radar", obs.tip_velocity, obs.lidar_level, self.pipeline.edges_known)

    # -- at the end ------------------------------------------------------------------------
    def close(self) -> None:
        """A run that stops early: a merge running beside the frames is stopped."""
        self.pipeline.merges.close()

    def finish_perception(self) -> list[LidarObservation | RadarObservation]:
        """After the last frame: the observations the feeder's pipeline still holds back (a run
        shorter than its warm-up), with what the static test has; for `finish_fusion`."""
        return self.pipeline.ready()

    def finish_fusion(self, held: list[LidarObservation | RadarObservation]) -> None:
        for obs in held:
            self._fuse(obs)

    def finish(self) -> ShipResult:
        self.finish_fusion(self.finish_perception())  # empty when a worker's perception handed them over
        model_points = self.pipeline.finish()
        est = self.estimator.finish(self.pipeline.lines, self.pipeline.hull_yaws)
        started = np.isfinite(est.t_definition_s)
        feeder = FeederResult(**vars(est), frame_ms=self.frame_ms, stage_ms=self.stage_ms, missing=self.missing + self.pipeline.missing,
                              model_points_map=model_points if started else None, merges=self.pipeline.merges.records)
        return ShipResult(self.heave.finish(), feeder)

    def outputs(self, out: Path, result: ShipResult) -> list[str]:
        heave, feeder = result.heave, result.feeder
        written = self.heave.outputs(out, heave)
        feeder_outputs.write_feeder_estimates(out / "feeder_estimates.csv", feeder)
        return written + ["feeder_estimates.csv"] + feeder_outputs.write_feeder_online(out, feeder)

    def kpis(self, result: ShipResult, truth: Truth | None, windows=()) -> dict:
        heave, feeder = result.heave, result.feeder
        kpis = self.heave.kpis(heave, truth, windows)
        fused = heave.estimates.get("fused")
        heave_D = (fused.t_s, fused.x[:, 0]) if fused is not None else None
        kpis["feeder"] = feeder_outputs.feeder_kpis(feeder, truth, self.p_tip_crane_m, windows, heave_D,
                                                    outage_windows(self.source, ("mru",)))
        if feeder.consistency:
            kpis.setdefault("consistency", {})["feeder"] = feeder.consistency
        return kpis

    def report(self, out: Path, kpis: dict, result: ShipResult, truth: Truth | None,
               pictures: FramePictures | None = None) -> list[str]:
        # the heave report, the feeder's plot and the pictured frames drawn side by side when the
        # run has two processes; the report's sections appended here, in their order
        parts = {"heave": lambda: self.heave.report_text(out, kpis, result.heave, truth),
                 "feeder": lambda: feeder_outputs.write_feeder_plot(out, result.feeder, truth, self.p_tip_crane_m)}
        if pictures is not None:
            parts["detections"] = lambda: self.heave.detections_plot(out, pictures, result.heave, frame_result)
        drawn = self.heave.resources.map_split(list(parts), REPORT_COSTS, lambda name: parts[name]())
        written, plot = drawn["heave"], drawn["feeder"]
        report = out / "report.md"
        if report.exists():
            with open(report, "a", encoding="utf-8") as fh:
                fh.write(feeder_outputs.report_section(kpis, outage_windows(self.source))
                         + (f"\n{plot_link(plot)}\n" if plot is not None else ""))
        if "detections" in drawn:
            link_in_report(out, "Detections", drawn["detections"])
        plotted = plot is not None or "detections" in drawn
        return written + ([] if not plotted or "plots" in written else ["plots"])

    def visualiser(self, path: Path, source: FrameSource):
        return self.heave.visualiser(path, source)

    def visualise_result(self, viz, result: ShipResult, truth: Truth | None) -> None:
        heave, res = result.heave, result.feeder
        self.heave.visualise_result(viz, heave, truth)
        truth_pose = (feeder_outputs.truth_of(res, truth, self.p_tip_crane_m)[0]
                      if truth is not None and "feeder_x" in truth.columns and len(res.t_s) else None)
        mru = self.source.mru

        def yaw(t: float) -> float:
            att = mru.attitude(t)
            return float(att[0][2]) if att is not None else 0.0

        from boomtip.tools.report.recording.feeder import log_feeder

        log_feeder(viz, res, truth_pose, yaw, mesh_feeder=self._visualised_feeder_mesh(truth, res))

    def _visualised_feeder_mesh(self, truth: Truth | None, res: FeederResult) -> tuple[np.ndarray, np.ndarray] | None:
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


def timed_fusion(fuse: Callable[[LidarObservation, StageTimes], None], obs: LidarObservation,
                 totals: dict[str, float]) -> float:
    """`fuse(obs, times)` timed: what its stages do not claim is the estimator's ("feeder.filter").
    The frame's stages (its perception's too) are summed into `totals`; returns the frame's ms."""
    times, t0 = StageTimes(), time.perf_counter()
    fuse(obs, times)
    times.ms["feeder.filter"] = (time.perf_counter() - t0) * 1e3 - times.total()
    for name, ms in (*obs.stage_ms.items(), *times.ms.items()):
        totals[name] = totals.get(name, 0.0) + ms
    return obs.ms + times.total()
