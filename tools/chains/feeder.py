"""The feeder chain: the feeder's 6-DOF motion relative to the crane vessel, from the boom-tip
LiDAR and radar, beside the heave chain (whose deck and Doppler stages it reuses).

Per frame: LiDAR -> deck plane (z, roll, pitch) + registration of the structure to the
feeder's keyframe (x, y, yaw, only the directions the geometry constrains), radar -> the
feeder point's velocity and the radar's deck plane; each an update of one EKF, seeded frame
by frame with its prediction.

The first `static.warmup_s` of frames are held back: until then nothing says which returns
are static in the sensor frame. They are then processed in order, and frames from there on
as they come.

The feeder frame (the estimate's definition): origin at the deck point straight below the
boom tip at the first LiDAR frame, z along the deck normal, x along the feeder's centre
line (the median over frames of its longest straight hull edge). The filter runs in a map
frame; at the end (tools/feeder_frame) its states are written twice in the heading frame at the
tip: levelled and defined with what the whole run found (the best offline estimate of a
recording: a constant is best known from all of it), and each row with what was known at its
own time (what a live controller had; the calibration's history beside it).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from boomtip.data.frames import Frame, FrameSource
from boomtip.tools.config.processing import Processing
from boomtip.fusion.attitude_filter import averaged_rates, complementary_angle_sigma, complementary_attitude
from boomtip.fusion.feeder_filter import FeederFilter
from boomtip.fusion.level_calibration import Tilt
from boomtip.fusion.models.relative_motion import deck_plane
from boomtip.fusion.mru_bridge import MruBridge
from boomtip.perception.feeder import (
    FeederPerception,
    Footprint,
    LidarObservation,
    RadarObservation,
    centre_line_yaw,
)
from boomtip.perception.feeder_radar import RadarOffset, register_radar
from boomtip.perception.feeder_registration import (
    FeederModel,
    condition_on,
    inverse,
    pose_matrix,
    pose_vector,
    transform,
    yaw_only,
)
from boomtip.perception.pipeline import FrameResult
from boomtip.perception.static_returns import StaticReturns
from boomtip.perception.timing import StageTimes
from boomtip.fusion.feeder_frame import CausalEstimates, FrameData, causal_estimates, estimates_in_feeder_frame, frame_at, levelling_at
from boomtip.tools.chains.feeder_merge import BackgroundMerges, MergeRecord
from boomtip.tools.chains.feeder_mru_gap import MruGap, inflated_sigmas

DECK_STAGES = ("deck.preprocess", "deck.planes", "deck.refine", "deck.intersect")


@dataclass
class FeederResult:
    t_s: np.ndarray  # (T,)
    pose: np.ndarray  # (T, 6) x, y, z (m), roll, pitch, yaw (rad): the feeder frame in the heading frame
    rates: np.ndarray  # (T, 6)
    var: np.ndarray  # (T, 12) variances of pose and rates
    t_definition_s: float  # the first LiDAR frame: where the feeder frame is defined
    tilt: Tilt | None  # the final levelling calibration
    centre_line: tuple[float, int] | None  # yaw of the centre line in the map frame, frames it was found in
    counts: dict
    frame_ms: list[float]  # wall time per LiDAR frame on the chain's thread (feeder stages, the deck stage it reuses, waits for a merge)
    notes: list[str] = field(default_factory=list)
    missing: list[tuple[float, str, str]] = field(default_factory=list)  # (t, sensor, why)
    T_map_feeder: np.ndarray | None = None  # the feeder frame in the model's (map) frame
    model_points_map: np.ndarray | None = None  # the keyframe, for the display
    feeder_mru: dict | None = None  # the feeder MRU's offsets as estimated, when there is one
    merges: list[MergeRecord] = field(default_factory=list)  # the model's merges (inline, or beside the frames)
    online: CausalEstimates | None = None  # the same rows as a live controller had them (feeder_frame)


class FeederChain:
    name = "feeder"

    def __init__(self, source: FrameSource, processing: Processing) -> None:
        inst = source.meta.installation
        cfg = processing.feeder
        self.cfg = cfg
        # the levelling's attitude: the MRU's angles filtered with its rates (see attitude_filter)
        self.mru = complementary_attitude(source.mru, cfg.mru_tau_s) if cfg.mru_tau_s > 0 else source.mru
        self.mru, n_rates = averaged_rates(self.mru, cfg.mru_rate_half_window_s)
        g = cfg.mru_gap  # through a gap in the log: its forecast (tools/feeder_mru_gap)
        if g.enabled:
            self.mru = MruBridge(self.mru, g.history_s, g.rate_hz, g.order, math.radians(g.max_sigma_deg))
        self.gap = MruGap()  # its pipeline: ShipChain's
        angle_sigma = complementary_angle_sigma(math.radians(inst.mru.angle_noise_deg), math.radians(inst.mru.rate_noise_degps),
                                                cfg.mru_tau_s, 1.0 / inst.mru.rate_hz)
        self.perception = FeederPerception(inst, cfg.perception, rates_averaged_over=n_rates, angle_sigma_rad=angle_sigma)
        self.static = StaticReturns(cfg.perception.static)
        self.model = FeederModel(cfg.perception.registration)
        self.merges = BackgroundMerges(self.model)
        # frames the model must be merged from before a registration's x and y update the filter:
        # at most its last merge's (no merges at all: the first keyframe's one frame)
        self.xy_after_frames = min(cfg.register_xy_after_frames, max(cfg.perception.registration.model_merges, default=1))
        self.filter = FeederFilter(cfg.filter)
        # An MRU on the feeder, when the source has its stream (document 004's second MRU)
        fm = getattr(source, "feeder_mru", None)
        self.feeder_mru = fm if (fm is not None and cfg.use_feeder_mru) else None
        self.feeder_mru_sigma = (math.radians(inst.feeder_mru.angle_noise_deg), math.radians(inst.feeder_mru.rate_noise_degps))
        self.feeder_mru_gaps = 0
        self.rng = np.random.default_rng([processing.seed, 13])
        self.queue: list[LidarObservation | RadarObservation] = []
        self.normals: list[tuple[float, np.ndarray]] = []  # LiDAR deck normals (level frame) for the calibration
        self.t_definition: float | None = None
        self.T_level_map0: np.ndarray | None = None
        self.frame_ms: list[float] = []
        self.missing: list[tuple[float, str, str]] = []
        self.pivots: list[np.ndarray] = []  # the LiDAR's position (level, from the tip) at each recorded state
        self.tips: list[np.ndarray] = []  # the tip's velocity relative to the vessel at each recorded state
        self.lines: list[tuple[float, int]] = []  # the centre line's yaw in the map frame, every few frames
        self.hull_yaws: list[float] = []  # the own hull's edge in the level frame, every few frames
        self.known: list[tuple[float, int, int]] = []  # at each record: its time, how many lines and hull edges by then
        self.lidar_frames = 0
        self.failed_registrations = 0  # in a row: after rekey_after_failures a new keyframe is taken
        self.footprint: Footprint | None = None  # the deck's outline in the map frame, from the first deck
        self.radar_offset, self.radar_offset_n = np.zeros(3), 0  # radar deck - LiDAR deck: slopes, height
        # the radar's detections registered to the model: while the LiDAR registers too, their
        # offset is learnt from every `learn_every`-th radar frame; without the LiDAR, they update
        self.radar_reg = cfg.radar_registration
        self.radar_reg_offset = RadarOffset(self.radar_reg.offset_frames)
        self.detection_sigma = (inst.radar.range_noise_m, math.radians(inst.radar.azimuth_noise_deg),
                                math.radians(inst.radar.elevation_noise_deg))
        self.last_registration_t = -math.inf
        self.radar_frames = 0

    # -- per frame -------------------------------------------------------------------------
    def process(self, frame: Frame, heave: FrameResult | None) -> StageTimes:
        times = StageTimes()
        if frame.error is not None or len(frame) == 0:
            self.missing.append((frame.t_s, frame.sensor, frame.error or "empty frame"))
            return times
        # with a bridge through the MRU's gaps, the attitude's variance too (zero off the gaps)
        att = self.mru.attitude_var(frame.t_s) if isinstance(self.mru, MruBridge) else self.mru.attitude(frame.t_s)
        if att is None:
            self.missing.append((frame.t_s, frame.sensor, "no MRU attitude"))
            return times
        rpy, rpy_rate, *var = att
        var = var[0] if var else None
        if var is None or not var.any() or self.gap.pipeline is None:
            self.gap.mru_back(self.filter, frame.sensor)
            return self._observe(frame, heave, rpy, rpy_rate, times)
        heave, rows = self.gap.stages(frame, rpy, var), len(self.filter.out.P)
        with inflated_sigmas(self.perception, var):
            self._observe(frame, heave, rpy, rpy_rate, times)
        self.gap.in_gap_rows(self.filter.out, rows)
        return times

    def _observe(self, frame: Frame, heave: FrameResult | None, rpy: np.ndarray, rpy_rate: np.ndarray, times: StageTimes) -> StageTimes:
        t_obs = time.perf_counter()
        with times.stage("feeder.observe"):
            if frame.sensor == "lidar":
                obs = self.perception.lidar(frame.t_s, frame.points_sensor, rpy, rpy_rate,
                                            heave.deck_lidar if heave is not None else None, frame.fields.get("t"))
                obs.static_keys = self.static.add(frame.t_s, obs.sample_returns_sensor)
            else:
                obs = self.perception.radar(frame.t_s, rpy, rpy_rate, heave.doppler if heave is not None else None,
                                            heave.deck_radar if heave is not None else None, frame.points_sensor)
        if frame.sensor == "lidar":
            # the chain's time per LiDAR frame: this, the steps below, and the deck stage it reuses
            obs.ms = (time.perf_counter() - t_obs) * 1e3 + (heave.times.total(*DECK_STAGES) if heave is not None else 0.0)
        self.queue.append(obs)
        if self.static.ready:
            self._drain(times)
        return times

    def _drain(self, times: StageTimes | None = None) -> None:
        times = times or StageTimes()
        for obs in self.queue:
            if isinstance(obs, LidarObservation):
                t0 = time.perf_counter()
                self._lidar(obs, times)
                self.frame_ms.append(obs.ms + (time.perf_counter() - t0) * 1e3)
            else:
                self._radar(obs, times)
        self.queue.clear()

    def _start(self, obs: LidarObservation) -> None:
        """The map frame at the first deck: origin straight below the tip (in the level frame
        as the installation has it), z along the deck normal, yaw 0."""
        plane = obs.spin or obs.plane  # the spin's: at the frame's time, not at its returns' mean time
        origin = np.array([0.0, 0.0, plane.abc[2]])  # the level frame's origin is the tip
        n = plane.normal
        pose = np.array([*origin, -math.asin(n[1]), math.atan2(n[0], n[2]), 0.0])
        cov = np.diag([1e-8, 1e-8, float(plane.cov[2, 2]), float(plane.cov[1, 1]), float(plane.cov[0, 0]), 1e-10])
        self.filter.start(obs.t_s, pose, cov, obs.tip_velocity, obs.tip_level)
        self._feeder_mru(obs.t_s)
        self.tips.append(obs.tip_velocity)
        self.pivots.append(obs.t_level_sensor)
        self.t_definition, self.T_level_map0 = obs.t_s, pose_matrix(*pose)

    def _lidar(self, obs: LidarObservation, times: StageTimes) -> None:
        f = self.filter
        self.merges.next_frame()  # a merge due at this frame becomes the model (waiting for it if need be)
        if obs.plane is None and not f.started:
            self.missing.append((obs.t_s, "lidar", obs.status))
            return
        if not f.started:
            self._start(obs)
        else:
            f.predict(obs.t_s, obs.tip_velocity, self.perception.tip_velocity_sigma, obs.tip_level)
            self._feeder_mru(obs.t_s)
        if obs.plane is not None:
            with times.stage("feeder.deck_update"):
                if obs.spin is not None:  # the plane and its rates from the returns' times
                    f.update_deck_spin("deck_spin_lidar", obs.spin.abc, obs.spin.rates, obs.spin.cov)
                else:
                    f.update_deck("deck_lidar", obs.plane.abc, obs.plane.cov)
                self.normals.append((obs.t_s, obs.plane.normal))
        else:
            self.missing.append((obs.t_s, "lidar", obs.status))
            self._record(obs)  # a frame without a deck: its structure has nothing to stand on
            return
        with times.stage("feeder.structure"):  # with the static test of the returns it keeps
            T_map_level = inverse(pose_matrix(*f.x[:6]))
            if self.footprint is None and obs.plane is not None and obs.plane.points_level is not None:
                deck_map = transform(T_map_level, obs.plane.points_level)
                self.footprint = Footprint(deck_map[:, :2], self.cfg.perception.footprint_margin_m)
            keys = obs.static_keys
            structure = self.perception.structure(
                obs, deck_plane(f.x), self.footprint, T_map_level,
                is_static=lambda rows: self.static.static_mask(obs.sample_returns_sensor, keys, rows))
            obs.static_keys = None
        with times.stage("feeder.register"):
            T_guess = T_map_level  # the prediction, after the deck's update
            sigma = float(np.linalg.norm(f.pose_sigma()[[0, 1]])) + 10.0 * float(f.pose_sigma()[5])
            min_points = self.model.cfg.min_points
            if self.model.empty or self.failed_registrations >= self.cfg.rekey_after_failures:
                if len(structure) >= min_points:  # a keyframe with too little to register to is no model
                    self.model.set_keyframe(structure, T_guess)
                    self.failed_registrations = 0
            else:
                reg = self.model.register(structure, T_guess, sigma)
                if reg.status == "ok":
                    v = pose_vector(inverse(reg.T_map_level))
                    xy_yaw, info = condition_on(v, reg.info6, f.x[2:5])
                    # the MRU's angle noise turns this frame about the tip: the deck below moves sideways
                    s_lvl = abs(float(f.x[2])) * self.perception.angle_sigma_rad
                    if self.model.model_frames < self.xy_after_frames:
                        info = yaw_only(info)  # a young model is biased by its few viewpoints: x, y wait
                    f.update_registration(xy_yaw, info, np.diag([s_lvl ** 2, s_lvl ** 2, 0.0]))
                    self.last_registration_t = obs.t_s
                    if self.model.collect(structure, inverse(pose_matrix(*f.x[:6]))):
                        self.merges.start()
                    if self.model.keyframe_size < self.model.cfg.keyframe_frames:
                        self.model.extend_keyframe(structure, inverse(pose_matrix(*f.x[:6])))
                        self.model.keyframe_size += 1
                    elif reg.fitness < self.model.cfg.min_fitness and f.pose_sigma()[0] < 0.05:
                        self.model.set_keyframe(structure, inverse(pose_matrix(*f.x[:6])))
                    self.failed_registrations = 0
                else:
                    self.failed_registrations += 1
                    self.missing.append((obs.t_s, "lidar", f"registration: {reg.status}"))
        if self.lidar_frames % self.cfg.centre_line_every == 0 and len(structure):
            with times.stage("feeder.centre_line"):  # in the map frame, at the filter's pose
                line = centre_line_yaw(transform(inverse(pose_matrix(*f.x[:6])), structure), self.rng)
                if line is not None:
                    self.lines.append(line)
                # the own hull's side among the static returns (a wall: a line in plan), for the
                # calibration's rotation about the vertical
                if len(self.hull_yaws) < self.cfg.hull_edge_frames:  # a constant: a few dozen frames pin it
                    mask = self.static.static_mask(obs.sample_returns_sensor, keys)
                    static_level = obs.sample_sensor[mask] @ obs.R_level_sensor.T + obs.t_level_sensor
                    hull = centre_line_yaw(static_level, self.rng, band_m=(-np.inf, np.inf))
                    if hull is not None and hull[1] >= self.cfg.hull_edge_min_points:
                        self.hull_yaws.append(hull[0])
        self.lidar_frames += 1
        self._record(obs)

    def _radar(self, obs: RadarObservation, times: StageTimes) -> None:
        f = self.filter
        if not f.started:
            return
        if obs.velocity_level is None and obs.plane is None:
            self.missing.append((obs.t_s, "radar", obs.status))  # its detections may still register below
        f.predict(obs.t_s, obs.tip_velocity, self.perception.tip_velocity_sigma, obs.tip_level)
        self._feeder_mru(obs.t_s)
        with times.stage("feeder.radar_update"):
            if obs.velocity_level is not None:
                tip_var = np.eye(3) * self.perception.tip_velocity_sigma ** 2
                f.update_point_velocity(obs.velocity_level, obs.velocity_cov + tip_var, obs.xi_level)
            if obs.plane is not None:
                self._radar_deck(obs)
        with times.stage("feeder.radar_register"):
            self._radar_registration(obs)
        self.radar_frames += 1
        self._record(obs)

    def _radar_registration(self, obs: RadarObservation) -> None:
        """The radar's detections registered to the LiDAR's model (perception/feeder_radar):
        its offset from the LiDAR's registrations learnt while both see the feeder, then,
        with the LiDAR out, x, y and yaw less that offset."""
        cfg, f = self.radar_reg, self.filter
        if (not cfg.enabled or obs.detections_sensor is None or len(obs.detections_sensor) == 0
                or self.model.surface is None or self.model.model_frames < cfg.min_model_frames):
            return
        lidar_out = obs.t_s - self.last_registration_t > cfg.after_s
        if not lidar_out and self.radar_frames % cfg.learn_every:
            return
        if lidar_out and self.radar_reg_offset.n < cfg.min_offset_frames:
            return
        reg = register_radar(self.model.surface, obs.detections_sensor, obs.R_level_sensor, obs.xi_level,
                             self.detection_sigma, f.x[:6], cfg)
        if reg.status != "ok":
            if lidar_out:
                self.missing.append((obs.t_s, "radar", reg.status))
            return
        if not lidar_out:
            self.radar_reg_offset.add(reg.x_y_yaw, f.x[[0, 1, 5]])
            return
        f.update_registration(reg.x_y_yaw - self.radar_reg_offset.mean, reg.info, self.radar_reg_offset.covariance(),
                              kind="radar_registration", max_sigma_m=cfg.max_sigma_m)

    def _feeder_mru(self, t_s: float) -> None:
        """The feeder MRU's sample at a frame's time: the filter steps with the frames (30 a
        second); taking the MRU's 200 a second as well would multiply its updates by seven."""
        if self.feeder_mru is None:
            return
        att = self.feeder_mru.attitude(t_s)
        if att is None:
            self.feeder_mru_gaps += 1
            return
        self.filter.update_feeder_mru(att[0], att[1], *self.feeder_mru_sigma)

    def _radar_deck(self, obs: RadarObservation) -> None:
        """The radar's deck plane is levelled through its own mount, whose error is not the
        LiDAR's: its plane differs from the LiDAR's by a fixed tilt and height (0.08 deg is 5 cm
        at the deck's 40 m of lever). While the LiDAR sees the deck the difference is learnt
        (a running mean); the radar's plane, so corrected, is used only when the LiDAR has had
        no deck for `radar_deck_after_s`."""
        f = self.filter
        a, b, c = deck_plane(f.x)
        x0, y0 = f.x[0], f.x[1]
        diff = obs.plane.abc - np.array([a, b, c])
        d = np.array([diff[0], diff[1], diff[2] + diff[0] * x0 + diff[1] * y0])  # slope, and height at the origin
        last_lidar = self.normals[-1][0] if self.normals else -np.inf
        if obs.t_s - last_lidar <= self.cfg.radar_deck_after_s:
            self.radar_offset_n += 1
            self.radar_offset += (d - self.radar_offset) / min(self.radar_offset_n, 200)
            return
        off = self.radar_offset if self.radar_offset_n >= 20 else np.zeros(3)
        abc = obs.plane.abc - np.array([off[0], off[1], off[2] - off[0] * x0 - off[1] * y0])
        f.update_deck("deck_radar", abc, obs.plane.cov)

    def _record(self, obs: LidarObservation | RadarObservation) -> None:
        self.filter.record()
        self.known.append((obs.t_s, len(self.lines), len(self.hull_yaws)))
        self.tips.append(obs.tip_velocity)
        rpy = self.mru.attitude(obs.t_s)[0]
        self.pivots.append(obs.t_level_sensor if isinstance(obs, LidarObservation) else self.perception.sensor_in_level("lidar", rpy)[1])

    # -- at the end ------------------------------------------------------------------------
    def finish(self) -> FeederResult:
        if self.queue:  # a run shorter than the warm-up: use what the mask has
            self._drain()
        self.merges.close()
        out = self.filter.out
        d = self._frame_data()
        notes: list[str] = []
        tilt, why = levelling_at(d)
        if why is not None:
            notes.append("feeder: levelling not calibrated: " + why)
        if not self.filter.started:
            return FeederResult(np.zeros(0), np.zeros((0, 6)), np.zeros((0, 6)), np.zeros((0, 12)), float("nan"), tilt, None,
                                out.counts, self.frame_ms, ["feeder: no LiDAR deck plane in this run: no estimate"], self.missing)
        if tilt is not None and tilt.rz_sigma_rad is None:
            notes.append("feeder: no straight edge of the own hull among the static returns: the LiDAR mount's rotation "
                         "about the vertical is the survey's")
        if tilt is None:
            notes.append(f"feeder: levelling not calibrated (under {self.cfg.calibration_min_s:g} s of deck planes): "
                         "the surveyed mount and the MRU are taken as they are")
        # offline: the definition from the whole run, applied to every estimate
        final = frame_at(d)
        if final.line is None:
            notes.append("feeder: no straight hull edge in the keyframe: x is along the crane's heading")
        sigmas = (self.perception.mount_sigma_rad["lidar"], self.perception.mru_bias_sigma_rad)
        pose, rates, var = estimates_in_feeder_frame(out.x, out.P, self.tips, self.pivots, final, *sigmas)
        t = np.asarray(out.t_s)
        keep = np.r_[np.diff(t) > 0, True]  # one row per time: the last state recorded at it
        return FeederResult(t[keep], pose[keep], rates[keep], var[keep], float(self.t_definition), final.tilt, final.line, out.counts,
                            self.frame_ms, notes, self.missing, final.T_map_feeder,
                            np.asarray(self.model.keyframe.points) if not self.model.empty else None,
                            self._feeder_mru_summary(), self.merges.records,
                            causal_estimates(out, self.tips, self.pivots, d, keep, *sigmas))

    def _frame_data(self) -> FrameData:
        """The deck normals, the own hull's and the feeder's edges, each with the time it was known."""
        known = np.array(self.known, dtype=float).reshape(-1, 3)  # (t, lines, hull edges) at each record
        when = lambda k, col: known[np.searchsorted(known[:, col], np.arange(k) + 1), 0]  # the count first exceeded i
        started = self.filter.started
        return FrameData(np.array([n[0] for n in self.normals]), np.array([n[1] for n in self.normals]),
                         when(len(self.hull_yaws), 2), np.array(self.hull_yaws), when(len(self.lines), 1),
                         np.array([y for y, _ in self.lines]), self.filter.out.x[0] if started else None, self.T_level_map0,
                         self.cfg.calibration_min_s, self.perception.mount_sigma_rad["lidar"],
                         math.radians(self.cfg.filter.body_yaw_prior_deg))

    def _feeder_mru_summary(self) -> dict | None:
        if self.feeder_mru is None or not self.filter.feeder_mru_started:
            return None
        x, s = (np.degrees(v) for v in self.filter.offsets())
        return {"heading_offset_deg": round(float(x[0]), 4), "heading_offset_sigma_deg": round(float(s[0]), 4),
                "body_yaw_in_map_deg": round(float(x[1]), 4), "body_yaw_sigma_deg": round(float(s[1]), 4),
                "body_tilt_deg": np.round(x[2:], 4).tolist(), "body_tilt_sigma_deg": np.round(s[2:], 4).tolist(),
                "gaps": self.feeder_mru_gaps}
