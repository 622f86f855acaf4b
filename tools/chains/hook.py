"""The hook chain (document 002's, on real clouds): per LiDAR frame, the tracking filter's
prediction, the frame levelled with its attitude, the rope's direction and the lower block's fix
(perception.hook_pipeline) corrected into the tracker; at the end, the multi-rate EKF/UKF
estimators over every measurement, the encoders and the MRU.

Built from the installation (LiDAR spec and mount, crane geometry and nominal dynamics, rope
radius, block model) and the processing settings: never from the simulated world. How it holds
its memory and uses the cores (tables on disk, frames and estimators in child processes) is the
run's RunResources, not this module's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from boomtip.data.frames import Frame, FrameSource, Truth, sample_after
from boomtip.data.hook_streams import HookMeasurements
from boomtip.data.installation import Installation
from boomtip.fusion.consistency import consistency_block, flagged_notes
from boomtip.fusion.hook_config import nominal_crane_params
from boomtip.fusion.hook_run import HookFilterRun, run_hook_filter
from boomtip.fusion.hook_tracker import HookTracker
from boomtip.perception.hook import HookDetection
from boomtip.perception.hook_pipeline import HookPipeline, sigma_across
from boomtip.perception.rope import RopeFix
from boomtip.perception.timing import StageTimes
from boomtip.tools.chains.chain import ChainError, NullVisualiser
from boomtip.tools.chains.pictures import FramePictures
from boomtip.tools.report.hook_rows import FrameRows, fill_block, fill_prediction, fill_rope, fill_scores, frame_row
from boomtip.tools.report.hook_store import COV_P, P_REL, EstimateStore
from boomtip.tools.chains.resources import RunResources
from boomtip.tools.config.processing import Processing
from boomtip.tools.report import hook as outputs

# each estimator's CPU time relative to the others (as `boomtip bench hook` reports them): to
# split them evenly between two cores
ESTIMATOR_COST = {"ukf_flexible": 5.3, "ukf_rigid": 2.9, "ekf_flexible": 0.95, "ekf_rigid": 0.85}


@dataclass
class HookFrameResult:
    """One LiDAR frame's work, for the outputs and the visualiser."""

    row: dict
    points_level: np.ndarray | None = None
    detection: HookDetection | None = None
    prior: np.ndarray | None = None
    rope: RopeFix | None = None
    hoist_m: float | None = None
    cov: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    times: StageTimes | None = None  # the frame's stage times (ms), for benchmarks

    @property
    def t_s(self) -> float:
        return float(self.row["t"])


@dataclass
class HookResult:
    rows: FrameRows
    read_measurements: Callable[[], HookMeasurements]  # the run's measurements, read from disk when asked
    runs: dict[str, HookFilterRun]  # statistics; the samples are in ``stores``
    stores: dict[str, EstimateStore] = field(default_factory=dict)

    @property
    def measurements(self) -> HookMeasurements:
        """Every measurement of the run as arrays (made on each access: not held by the result)."""
        return self.read_measurements()


class HookChain:
    name = "hook"

    def __init__(self, source: FrameSource, processing: Processing, resources: RunResources | None = None,
                 load_mass_kg: float = 0.0) -> None:
        """load_mass_kg: a load's known mass on the hook, beyond the installation's hook mass (the lift)."""
        inst: Installation = source.meta.installation
        enc, m = source.encoders, source.mru  # once: a source may read them from disk on each access
        if enc is None:
            raise ChainError(f"{source.meta.name}: the hook chain needs the crane's encoder stream (slew, luff, hoist)")
        if not inst.lidar.enabled:
            raise ChainError("installation.lidar.enabled is false: the hook chain needs a LiDAR")
        self.resources = resources or RunResources()
        self.pipeline = HookPipeline(inst, processing.hook.detector, processing.hook.rope, processing.seed)
        self.estimators = processing.hook.estimators
        self.filter_cfg = processing.hook.filter
        if "levelling_bias_sigma_rad" not in self.filter_cfg.model_fields_set:  # the kit's stated accuracy
            self.filter_cfg = self.filter_cfg.model_copy(update={"levelling_bias_sigma_rad": inst.levelling_bias_sigma_rad("lidar")})
        self.params = nominal_crane_params(inst.crane)
        if load_mass_kg:
            self.params = self.params.model_copy(update={"m": self.params.m + load_mass_kg})
        # The hoist encoder reads the rope paid out; the pendulum is that stretched by the
        # hook's weight, with the rope's nominal EA (rigid when the installation gives none).
        stretch = 1.0 + (self.params.m * self.params.g / inst.crane.rope_ea_n if inst.crane.rope_ea_n else 0.0)
        # The encoder and MRU tables: the tracker reads a frame's samples at a time, the
        # estimators the whole tables (in their own processes on a lean run). Only the times
        # stay here, to find the rows.
        self.enc_t = np.asarray(enc["t"], float)
        self.enc_table = self.resources.table(np.column_stack([enc["slew"], enc["luff"], np.asarray(enc["hoist"]) * stretch]))
        self.mru_table = self.resources.table(np.column_stack([m.rpy_rad[:, 0], m.rpy_rad[:, 1], m.rpy_rate_radps[:, 0],
                                                               m.rpy_rate_radps[:, 1]]))
        # Of the MRU log, only its times and gaps (whether a frame has an attitude): the estimators
        # take the values from mru_table, and the source's log is not held for the whole run.
        self.mru_t_s, self.mru_max_gap_s = m.t_s, m.max_gap_s
        del enc, m
        self.tracker: HookTracker | None = HookTracker(self.enc_t, self.enc_table, self.mru_t_s, self.mru_table, params=self.params)
        self._times: tuple | None = None  # the times, once the frames are done
        self.rows = FrameRows()
        self.warnings: list[str] = []
        self.source_notes = source.meta.notes  # the loader's (dropped samples, ...): it may add to it while frames are read

    def frames(self, source: FrameSource):
        return self.resources.frames(source)

    def process(self, frame: Frame) -> HookFrameResult | None:
        if frame.sensor != "lidar":
            return None
        times = StageTimes()
        res = HookFrameResult(frame_row(frame.t_s), times=times)
        if frame.error is not None:
            res.row["status"] = f"unreadable frame: {frame.error}"
        elif sample_after(self.mru_t_s, self.mru_max_gap_s, frame.t_s) is None or not (self.enc_t[0] <= frame.t_s <= self.enc_t[-1]):
            res.row["status"] = f"no MRU attitude or encoder reading at t={frame.t_s:.3f} s"
        else:
            self._perceive(frame, res, times)
        res.row["time_ms"] = times.total()
        # What finish() needs, without the frame's cloud and masks (a 700 s run has 14,000 frames)
        ok = res.rope is not None and res.rope.ok
        self.rows.append(res.row, res.cov, res.rope.direction if ok else None, res.rope.cov if ok else None)
        return res

    def _perceive(self, frame: Frame, res: HookFrameResult, times: StageTimes) -> None:
        row, t, tracker, pipeline = res.row, frame.t_s, self.tracker, self.pipeline
        with times.stage("hook.track"):
            p_pred, cov_pred = tracker.predict(t)
        with times.stage("hook.level"):
            # The tracker's attitude (MRU and encoders filtered, boom deflection included), not
            # one raw MRU sample: its 0.02 deg noise alone moves a 200 m hook by 7 cm.
            levelled = pipeline.level(frame.points_sensor, *tracker.tip_attitude())
            res.hoist_m = tracker.hoist_at(t)
        fill_prediction(row, p_pred, sigma_across(cov_pred))
        if pipeline.rope_cfg.enabled:
            res.rope = rope = pipeline.rope(levelled, p_pred, row["pred_sigma_across_m"], res.hoist_m, frame.index, times)
            fill_rope(row, rope, res.hoist_m)
            if rope.ok:
                with times.stage("hook.track"):
                    row["rope_accepted"] = tracker.correct_rope(rope.direction, rope.cov)
                p_pred, cov_pred = tracker.estimate()
        res.detection, res.cov, res.prior = pipeline.block(levelled, t, p_pred, cov_pred, res.hoist_m, frame.index, times)
        res.points_level = levelled.points_level
        fill_block(row, res.detection, res.cov)
        if res.detection.has_fix:
            with times.stage("hook.track"):
                row["tracker_accepted"] = tracker.correct(res.detection.position_m, res.cov)
        fill_scores(row, res.detection, res.rope, frame.fields.get("label"))

    def _finish_frames(self) -> None:
        """After the frames: the encoder and MRU times in the run's tables too, and the tracker
        let go (the outputs' peak then holds nothing the run's length makes larger)."""
        if self._times is None:
            self._times = self.resources.table(self.enc_t), self.resources.table(self.mru_t_s)
            self.enc_t = self.mru_t_s = self.tracker = None

    def finish_measurements(self) -> HookMeasurements:
        """Every measurement of the run as arrays (the estimators' input), read from disk: made
        where an estimator runs (a child process), not held by the chain."""
        self._finish_frames()
        rows = self.rows
        t_enc, t_mru = (np.asarray(t) for t in self._times)
        if not len(rows):
            return HookMeasurements(np.zeros(0), np.zeros((0, 3)), t_enc, np.asarray(self.enc_table), t_mru,
                                    np.asarray(self.mru_table), lidar_cov_m2=np.zeros((0, 3, 3)))
        return HookMeasurements(
            t_lidar=rows["t"], lidar_p_rel_tip_world=rows.xyz(),
            t_encoders=t_enc, encoders=np.asarray(self.enc_table), t_mru=t_mru, mru=np.asarray(self.mru_table),
            lidar_cov_m2=rows.cov_m2, rope_direction=rows.rope_direction, rope_cov=rows.rope_cov,
            lidar_model_fit=np.asarray(rows["status"]) == "ok",
        )

    def finish(self) -> HookResult:
        return self.finish_until(None)

    def finish_until(self, until_s: float | None) -> HookResult:
        """The estimators over the run's measurements, up to `until_s` when given (where their
        model stops holding: a lift's load landed, the rope slack)."""
        self._finish_frames()
        self.resources.release()  # before the estimators' processes fork, and the outputs
        rows = self.rows
        read = self.finish_measurements if until_s is None else (lambda: self.finish_measurements().until(until_s))
        if not len(rows):  # no LiDAR frame at all: the encoders alone do not make a hook estimate
            self.warnings.append("no LiDAR frame in this run: no hook estimate")
            return HookResult(rows, read, {})
        firsts = [np.min(np.asarray(t), initial=math.inf) for t in (rows["t"], *self._times)]
        if until_s is not None and max(firsts) > until_s:  # an estimate needs a sample of each stream
            self.warnings.append(f"no LiDAR frame, encoder reading or MRU sample up to {until_s:.2f} s: no hook estimate")
            return HookResult(rows, read, {})
        meas: list[HookMeasurements] = []  # made once per process that runs estimators
        # each run's samples go to disk as they come: a run's memory stays flat in its length
        stores = {name: EstimateStore(self.params) for name in self.estimators}

        def estimate(name: str):
            kind, model = name.split("_")
            if not meas:
                meas.append(read())
            run = run_hook_filter(meas[0], kind, model, self.params.model_copy(update={"flexible": model == "flexible"}),
                                  self.filter_cfg, sink=stores[name])
            return run, stores[name].state()

        # the estimators are independent: shared between two forked children
        done = self.resources.map_split(self.estimators, ESTIMATOR_COST, estimate)
        runs = {}
        for name, (run, state) in done.items():
            stores[name].adopt(state)
            runs[name] = run
        meas.clear()  # (a serial run made them here)
        return HookResult(rows, read, runs, stores)

    # -- outputs -------------------------------------------------------------------------
    def outputs(self, out: Path, result: HookResult) -> list[str]:
        outputs.write_rows(out / "hook_measurements.csv", result.rows)
        outputs.write_estimates(out / "hook_estimates.csv", result.stores)
        return ["hook_measurements.csv", "hook_estimates.csv"]

    def kpis(self, result: HookResult, truth: Truth | None, windows: list[tuple[float, float]] = ()) -> dict:
        rows = result.rows
        status = rows["status"]
        n = len(rows)
        seg = {"found_fraction": int(np.count_nonzero(status == "ok")) / max(n, 1),
               "sparse_fraction": int(np.count_nonzero(status == "sparse")) / max(n, 1),
               "frames": n, "apt_ms": float(np.mean(rows["time_ms"])) if n else float("nan")}
        hook: dict = {"estimators_note": f"errors in the world frame, first {outputs.WARMUP_S:g} s excluded"}
        if truth is not None:
            for name, run in result.runs.items():
                hook[name] = outputs.estimator_kpis(run, result.stores[name], truth)
            seg.update(outputs.segmentation_kpis(rows, truth))
        else:  # what each estimator made of the hook's path, nothing to score it against
            hook["estimated"] = {name: outputs.estimated_path(result.stores[name]) for name in result.runs}
        hook["segmentation"] = seg
        hook["rope"] = outputs.rope_kpis(rows, truth)
        warnings = list(self.source_notes) + list(self.warnings)
        consistency = {f"hook_{name}": consistency_block(run.innovations) for name, run in result.runs.items()}
        for name, block in consistency.items():
            warnings += flagged_notes(block, name)
        return {"hook": hook, "consistency": consistency, **({"warnings": warnings} if warnings else {})}

    def report(self, out: Path, kpis: dict, result: HookResult, truth: Truth | None,
               pictures: FramePictures | None = None) -> list[str]:
        written = self.report_text(out, kpis, result, truth)
        if pictures is not None:
            written += [w for w in self.picture(out, pictures, result) if w not in written]
        return written

    def report_text(self, out: Path, kpis: dict, result: HookResult, truth: Truth | None) -> list[str]:
        """report.md and its plots, without the pictured frames."""
        if not result.runs:  # the CSVs and kpis.json say what was measured
            return []
        if truth is None:
            outputs.write_hook_estimates_report(out, kpis)
            return ["report.md"]
        self.resources.release()  # what the outputs freed, before the plots' peak
        outputs.write_hook_report(out, kpis, kpis.get("program"), result.runs, result.stores, truth, result.rows)
        return ["report.md", "plots"]

    def frame_score(self, res: HookFrameResult, truth: Truth | None) -> tuple[float, str] | None:
        """How bad a frame's hook fix is, for the pictures' worst frame (None: not a candidate):
        with truth, its largest error along an axis in that axis's stated sigmas; without, a
        failed fit (the first of them wins) or else its largest stated sigma."""
        row = res.row
        if res.detection is None:
            return None
        p = np.array([row["x"], row["y"], row["z"]], float)
        sigma = np.array([row["sigma_x_m"], row["sigma_y_m"], row["sigma_z_m"]], float)
        if truth is None:
            if not res.detection.has_fix:
                return math.inf, f"the first frame without a hook fix ({row['status']}); no truth here"
            return float(np.max(sigma)), f"the least certain hook fix (sigma {100 * np.max(sigma):.1f} cm); no truth here"
        error_m = p - np.array([truth.at(f"hook_rel_{a}", np.array([res.t_s]))[0] for a in "xyz"])
        if not (np.all(np.isfinite(error_m)) and np.all(sigma > 0)):
            return None
        z = float(np.max(np.abs(error_m) / sigma))
        return z, f"the worst hook fix: error {100 * np.linalg.norm(error_m):.1f} cm, {z:.1f} of its sigmas along an axis"

    def picture(self, out: Path, pictures: FramePictures, result: HookResult) -> list[str]:
        """plots/detections.png (the pictured frames' detections, the block and rope fits' status), linked from report.md."""
        from boomtip.tools.report.hook_detections import statuses, write_hook_detections
        from boomtip.tools.report.plots import PLOTS_DIR, link_in_report

        rows = result.rows
        frames = [(p.output, p.why) for p in pictures.frames()]
        path = write_hook_detections(out, frames, statuses(rows["t"], rows["status"], rows["rope_status"]),
                                     self.pipeline.cfg.block_height_m)
        link_in_report(out, "Detections", path)
        return [PLOTS_DIR]

    def visualiser(self, path: Path, source: FrameSource):
        from boomtip.tools.report.recording.hook import HookRerunLogger

        return HookRerunLogger(path, source, gate_radius_m=self.pipeline.cfg.prior_radius_m)

    def visualise_result(self, viz, result: HookResult, truth: Truth | None) -> None:
        # without a recording nothing is logged: the estimates are not read back (a 700 s run's
        # whole estimate, read at the run's peak, would raise it by megabytes)
        if not result.runs or isinstance(viz, NullVisualiser):
            return
        name = "ekf_flexible" if "ekf_flexible" in result.runs else next(iter(result.runs))
        t_run, rel_to_cov = result.stores[name].columns(slice(P_REL.start, COV_P.stop))  # one pass over the store
        p_rel, cov = rel_to_cov[:, : P_REL.stop - P_REL.start], rel_to_cov[:, COV_P.start - P_REL.start :]
        t_l = result.rows["t"]
        t_l = t_l[(t_l >= t_run[0]) & (t_l <= t_run[-1])]
        p_est = np.column_stack([np.interp(t_l, t_run, p_rel[:, k]) for k in range(3)])
        cov_l = np.column_stack([np.interp(t_l, t_run, cov[:, k]) for k in range(9)]).reshape(-1, 3, 3)
        p_true = np.column_stack([truth.at(f"hook_rel_{a}", t_l) for a in "xyz"]) if truth is not None else None
        viz.log_hook_tracks(t_l, p_est, p_true, name, cov_l)
        viz.log_world()
