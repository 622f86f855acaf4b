"""The hook chain (document 002's, on real clouds): per LiDAR frame, level the cloud with the
tracking filter's attitude, fit the rope's direction, segment and fit the lower block with the
tracker's prediction as prior; at the end, the multi-rate EKF/UKF estimators over every
measurement, the encoders and the MRU.

Built from the installation (LiDAR spec and mount, crane geometry and nominal dynamics, rope
radius, block model) and the processing settings: never from the simulated world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from boomtip.data.crane_model import CraneParams
from boomtip.data.frames import Frame, FrameSource, Truth, sample_after
from boomtip.data.installation import CraneSpec, Installation, LidarSpec
from boomtip.data.meshes import Label
from boomtip.tools.config.processing import Processing
from boomtip.data.sim.simulator import Simulation
from boomtip.fusion.hook_run import HookFilterRun, HookMeasurements, run_hook_filter
from boomtip.fusion.hook_tracker import HookTracker
from boomtip.perception.geometry import rpy_matrix
from boomtip.perception.hook import HookDetection, detect_hook, segmentation_scores
from boomtip.perception.rope import RopeFix, fit_rope
from boomtip.perception.timing import StageTimes
from boomtip.tools.report import hook as outputs
from boomtip.tools.chains import workers as workers
from boomtip.tools.chains.hook_rows import DiskTable, FrameRows
from boomtip.tools.chains.hook_store import P_REL, EstimateStore
from boomtip.tools.chains.runner import ChainError, NullVisualiser

ROW_DEFAULTS = {"x": np.nan, "y": np.nan, "z": np.nan, "sigma_x_m": np.nan, "sigma_y_m": np.nan, "sigma_z_m": np.nan,
                "n_points": 0, "fit_rms_m": np.nan, "precision": np.nan, "recall": np.nan, "hook_points_true": 0,
                "tracker_accepted": False, "pred_x": np.nan, "pred_y": np.nan, "pred_z": np.nan,
                "pred_sigma_across_m": np.nan, "rope_status": "", "rope_points": 0, "rope_ux": np.nan,
                "rope_uy": np.nan, "rope_uz": np.nan, "rope_sigma_across_m": np.nan, "rope_accepted": False,
                "rope_precision": np.nan, "rope_radius_m": np.nan}
TRIM_EVERY_FRAMES = 200  # the heap's free pages returned every this many frames (10 s at 20 Hz)
# each estimator's CPU time relative to the others (bench hook, 20 s of hook-2): to split them
# evenly between two cores
ESTIMATOR_COST = {"ukf_flexible": 5.3, "ukf_rigid": 2.9, "ekf_flexible": 0.95, "ekf_rigid": 0.85}


def nominal_crane_params(crane: CraneSpec, flexible: bool = True) -> CraneParams:
    """The filter's crane: the installation's nominal geometry and dynamics (Table 4.1)."""
    return CraneParams(m=crane.dynamics.hook_mass_kg, m_b=crane.dynamics.boom_mass_kg, L=crane.geometry.boom_length_m, b=crane.geometry.boom_foot_offset_m,
                       h=crane.geometry.boom_foot_height_m, c=crane.geometry.crane_base_m, k_f=crane.dynamics.boom_stiffness_nm_per_rad,
                       c_f=crane.dynamics.boom_damping, flexible=flexible)


def detection_sigma_m(position_m: np.ndarray, lidar: LidarSpec) -> float:
    """1-sigma per axis of a block fix. Across the beams, the block's position is fixed by its
    two edges, and each edge is only known to within one beam spacing s = r * dtheta (uniform:
    s / sqrt(12)); the points inside the outline do not sharpen the edges, so the two edges give
    s / sqrt(24) whatever the point count. Never better than the specified range noise."""
    r = float(np.linalg.norm(position_m))
    return float(max(lidar.range_noise_m, 0.005, r * lidar.angular_step_rad / math.sqrt(24.0)))


def sigma_across(cov_m2: np.ndarray) -> float:
    """Largest horizontal 1-sigma of a hook position covariance (m): across the rope."""
    return float(np.sqrt(max(np.linalg.eigvalsh(cov_m2[:2, :2])[-1], 0.0)))


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

    def __init__(self, source: FrameSource, processing: Processing) -> None:
        inst: Installation = source.meta.installation
        enc, m = source.encoders, source.mru  # once: a source may read them from disk on each access
        if enc is None:
            raise ChainError(f"{source.meta.name}: the hook chain needs the crane's encoder stream (slew, luff, hoist)")
        if not inst.lidar.enabled:
            raise ChainError("installation.lidar.enabled is false: the hook chain needs a LiDAR")
        self.lidar = inst.lidar
        self.cfg = processing.hook.detector
        self.rope_cfg = processing.hook.rope
        if "radius_m" not in self.rope_cfg.model_fields_set:  # the rope as installed
            self.rope_cfg = self.rope_cfg.model_copy(update={"radius_m": inst.crane.rope_radius_m})
        if "block_height_m" not in self.cfg.model_fields_set:
            self.cfg = self.cfg.model_copy(update={"block_height_m": inst.crane.block_height_m})
        self.estimators = processing.hook.estimators
        self.filter_cfg = processing.hook.filter
        if "levelling_bias_sigma_rad" not in self.filter_cfg.model_fields_set:  # the kit's stated accuracy
            self.filter_cfg = self.filter_cfg.model_copy(update={"levelling_bias_sigma_rad": inst.levelling_bias_sigma_rad("lidar")})
        self.seed = processing.seed
        self.params = nominal_crane_params(inst.crane)
        # The hoist encoder reads the rope paid out; the pendulum is that stretched by the
        # hook's weight, with the rope's nominal EA (rigid when the installation gives none).
        stretch = 1.0 + (self.params.m * self.params.g / inst.crane.rope_ea_n if inst.crane.rope_ea_n else 0.0)
        # The encoder and MRU tables on disk (what a 700 s run held in memory, 6.2 MB, for the
        # whole run): the tracker reads a frame's samples at a time, the estimators the whole
        # tables in their own processes. Only the times stay here, to find the rows.
        self.enc_t = np.asarray(enc["t"], float)
        self.enc_table = DiskTable(np.column_stack([enc["slew"], enc["luff"], np.asarray(enc["hoist"]) * stretch]))
        self.mru_table = DiskTable(np.column_stack([m.rpy_rad[:, 0], m.rpy_rad[:, 1], m.rpy_rate_radps[:, 0], m.rpy_rate_radps[:, 1]]))
        # Of the MRU log, only its times and gaps (whether a frame has an attitude): the estimators
        # take the values from mru_table, and the source's log is not held for the whole run.
        self.mru_t_s, self.mru_max_gap_s = m.t_s, m.max_gap_s
        del enc, m
        self.tracker: HookTracker | None = HookTracker(self.enc_t, self.enc_table, self.mru_t_s, self.mru_table, params=self.params)
        self._times: tuple[DiskTable, DiskTable] | None = None  # the times, once the frames are done
        self.T_ts = inst.lidar.mount.matrix()
        self.rows = FrameRows()
        self.warnings: list[str] = []
        self.last: tuple[float, np.ndarray] | None = None

    def process(self, frame: Frame) -> HookFrameResult | None:
        if frame.sensor != "lidar":
            return None
        times = StageTimes()
        t = frame.t_s
        res = HookFrameResult({"t": t, **ROW_DEFAULTS})
        if frame.error is not None:
            res.row["status"] = f"unreadable frame: {frame.error}"
        elif sample_after(self.mru_t_s, self.mru_max_gap_s, t) is None or not (self.enc_t[0] <= t <= self.enc_t[-1]):
            res.row["status"] = f"no MRU attitude or encoder reading at t={t:.3f} s"
        else:
            self._perceive(frame, res, times)
        res.row["time_ms"] = times.total()
        res.times = times
        # What finish() needs, without the frame's cloud and masks (a 700 s run has 14,000 frames)
        ok = res.rope is not None and res.rope.ok
        self.rows.append(res.row, res.cov, res.rope.direction if ok else None, res.rope.cov if ok else None)
        if len(self.rows) % TRIM_EVERY_FRAMES == 0:
            workers.release_free_memory()
        return res

    def frames(self, source: FrameSource):
        """The source's frames: a simulation's made on the second core while this one perceives
        (the simulator's ray casting costs about as much as the perception)."""
        if workers.parallel_enabled() and isinstance(source, Simulation):
            return workers.frames_in_child(source)
        return iter(source)

    def _perceive(self, frame: Frame, res: HookFrameResult, times: StageTimes) -> None:
        row, t = res.row, frame.t_s
        with times.stage("hook.track"):
            p_pred, cov_pred = self.tracker.predict(t)
        with times.stage("hook.level"):
            # The tracker's attitude (MRU and encoders filtered, boom deflection included), not
            # one raw MRU sample: its 0.02 deg noise alone moves a 200 m hook by 7 cm.
            roll, pitch, heading = self.tracker.tip_attitude()
            hoist = self._hoist_at(t)
            R_tip = rpy_matrix(np.array([roll, pitch, 0.0])) @ rpy_matrix(np.array([0.0, 0.0, heading]))
            pts = frame.points_sensor @ (R_tip @ self.T_ts[:3, :3]).T + R_tip @ self.T_ts[:3, 3]
        row["pred_x"], row["pred_y"], row["pred_z"] = p_pred
        row["pred_sigma_across_m"] = sigma_across(cov_pred)
        if self.rope_cfg.enabled:
            res.rope = self._rope(pts, p_pred, row["pred_sigma_across_m"], hoist, frame.index, times, row)
            if res.rope.ok:
                p_pred, cov_pred = self.tracker.estimate()
        # Prior: the tracker's estimate when it is certain enough to associate a sparse block;
        # else the last detection when recent (the hook moves < 1 m in 0.5 s), else straight
        # below the tip at the hoist length.
        tracked = bool(np.all(np.isfinite(p_pred)) and sigma_across(cov_pred) <= self.cfg.sparse_max_prior_sigma_m)
        if tracked:
            prior = p_pred
        elif self.last is not None and t - self.last[0] <= 0.5:
            prior = self.last[1]
        else:
            prior = np.array([0.0, 0.0, -hoist])
        rng = np.random.default_rng([self.seed, 7, frame.index])
        det = detect_hook(pts, prior, hoist, self.cfg, rng, times, sensor_position_m=R_tip @ self.T_ts[:3, 3],
                          prior_cov_m2=cov_pred if tracked else None)
        res.points_level, res.detection, res.prior, res.hoist_m = pts, det, prior, hoist
        row["status"], row["n_points"], row["fit_rms_m"] = det.status, det.n_points, det.fit_rms_m
        if det.has_fix:
            res.cov = det.cov_m2 if det.cov_m2 is not None else np.eye(3) * detection_sigma_m(det.position_m, self.lidar) ** 2
            row["x"], row["y"], row["z"] = det.position_m
            row["sigma_x_m"], row["sigma_y_m"], row["sigma_z_m"] = np.sqrt(np.diag(res.cov))
            with times.stage("hook.track"):
                row["tracker_accepted"] = self.tracker.correct(det.position_m, res.cov)
            self.last = (t, det.position_m)
        labels = frame.fields.get("label")  # per-point truth, in simulated recordings only: scoring
        if labels is not None:
            row["precision"], row["recall"] = segmentation_scores(det.points_mask, labels)
            row["hook_points_true"] = int(np.count_nonzero(labels == Label.HOOK))
            if res.rope is not None and res.rope.ok:
                row["rope_precision"] = float(np.mean(labels[res.rope.mask] == Label.ROPE))

    def _hoist_at(self, t: float) -> float:
        """The hoist encoder (stretched) interpolated at t, from the two rows about t: np.interp's
        value depends on those alone, so the same number as over the whole log."""
        i0 = max(int(np.searchsorted(self.enc_t, t, "right")) - 1, 0)
        # at least one row: a time stamp repeated at t would otherwise leave an empty slice
        i1 = max(min(int(np.searchsorted(self.enc_t, t, "left")) + 1, len(self.enc_t)), i0 + 1)
        return float(np.interp(t, self.enc_t[i0:i1], self.enc_table[i0:i1][:, 2]))

    def _times_to_disk(self) -> None:
        """After the frames: the encoder and MRU times on disk too, and the tracker let go (the
        outputs' peak then holds nothing the run's length makes larger)."""
        if self._times is None:
            self._times = DiskTable(self.enc_t), DiskTable(self.mru_t_s)
            self.enc_t = self.mru_t_s = self.tracker = None

    def measurements(self) -> HookMeasurements:
        """Every measurement of the run as arrays (the estimators' input), read from disk: made
        where an estimator runs (a child process), not held by the chain."""
        self._times_to_disk()
        rows = self.rows
        t_enc, t_mru = (np.asarray(t) for t in self._times)
        if not len(rows):
            return HookMeasurements(np.zeros(0), np.zeros((0, 3)), t_enc, np.asarray(self.enc_table), t_mru,
                                    np.asarray(self.mru_table), lidar_cov_m2=np.zeros((0, 3, 3)))
        return HookMeasurements(
            t_lidar=rows["t"], lidar_p_rel_tip_world=rows.xyz(),
            t_encoders=t_enc, encoders=np.asarray(self.enc_table), t_mru=t_mru, mru=np.asarray(self.mru_table),
            lidar_cov_m2=rows.cov_m2, rope_direction=rows.rope_direction, rope_cov=rows.rope_cov,
        )

    def _rope(self, pts, p_pred, sigma_across_m, hoist_m, index, times, row) -> RopeFix:
        """Fit the rope about the tracker's predicted direction and correct the tracker with it."""
        range_m = float(np.linalg.norm(p_pred))
        rng = np.random.default_rng([self.seed, 8, index])
        rope = fit_rope(pts, p_pred / range_m, sigma_across_m / range_m, hoist_m, self.rope_cfg, rng, times)
        row["rope_status"], row["rope_points"] = rope.status, rope.n_points
        if rope.ok:
            row["rope_ux"], row["rope_uy"], row["rope_uz"] = rope.direction
            row["rope_radius_m"] = rope.radius_m
            row["rope_sigma_across_m"] = hoist_m * math.sqrt(float(np.linalg.eigvalsh(rope.cov)[-1]))
            with times.stage("hook.track"):
                row["rope_accepted"] = self.tracker.correct_rope(rope.direction, rope.cov)
        return rope

    def finish(self, duration_s: float, t_start_s: float = 0.0) -> HookResult:
        self._times_to_disk()
        workers.release_free_memory()  # before the estimators' processes fork, and the outputs
        rows = self.rows
        if not len(rows):  # no LiDAR frame at all: the encoders alone do not make a hook estimate
            self.warnings.append("no LiDAR frame in this run: no hook estimate")
            return HookResult(rows, self.measurements, {})
        meas: list[HookMeasurements] = []  # made once per process that runs estimators
        # each run's samples go to disk as they come: a run's memory stays flat in its length
        stores = {name: EstimateStore(self.params) for name in self.estimators}

        def estimate(name: str):
            kind, model = name.split("_")
            if not meas:
                meas.append(self.measurements())
            run = run_hook_filter(meas[0], kind, model, self.params.model_copy(update={"flexible": model == "flexible"}),
                                  self.filter_cfg, sink=stores[name])
            return run, stores[name].state()

        # the estimators are independent: shared between two forked children
        done = workers.run_split(self.estimators, ESTIMATOR_COST, estimate)
        runs = {}
        for name, (run, state) in done.items():
            stores[name].adopt(state)
            runs[name] = run
        meas.clear()  # (a serial run made them here)
        return HookResult(rows, self.measurements, runs, stores)

    # -- outputs -------------------------------------------------------------------------
    def write(self, out: Path, result: HookResult) -> list[str]:
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
        hook["segmentation"] = seg
        hook["rope"] = outputs.rope_kpis(rows, truth)
        return {"hook": hook, **({"warnings": list(self.warnings)} if self.warnings else {})}

    def report(self, out: Path, kpis: dict, result: HookResult, truth: Truth | None) -> list[str]:
        if not result.runs or truth is None:  # the CSVs and kpis.json say what was estimated
            return []
        workers.release_free_memory()  # what the outputs freed, before the plots' peak
        outputs.write_hook_report(out, kpis, kpis.get("program"), result.runs, result.stores, truth, result.rows)
        return ["hook_report.md", "plots"]

    def visualiser(self, path: Path, source: FrameSource):
        from boomtip.tools.report.rerun import HookRerunLogger

        return HookRerunLogger(path, source, gate_radius_m=self.cfg.prior_radius_m)

    def visualise_result(self, viz, result: HookResult, truth: Truth | None) -> None:
        # without a recording nothing is logged: the estimates are not read back (a 700 s run's
        # whole estimate, read at the run's peak, raised it by about 9 MB)
        if not result.runs or isinstance(viz, NullVisualiser):
            return
        name = "ekf_flexible" if "ekf_flexible" in result.runs else next(iter(result.runs))
        t_run, p_rel = result.stores[name].columns(P_REL)
        t_l = result.rows["t"]
        t_l = t_l[(t_l >= t_run[0]) & (t_l <= t_run[-1])]
        p_est = np.column_stack([np.interp(t_l, t_run, p_rel[:, k]) for k in range(3)])
        p_true = np.column_stack([truth.at(f"hook_rel_{a}", t_l) for a in "xyz"]) if truth is not None else None
        viz.log_hook_tracks(t_l, p_est, p_true, name)
