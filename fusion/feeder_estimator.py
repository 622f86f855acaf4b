"""The feeder's 6-DOF estimate from what the feeder pipeline measures: one EKF (feeder_filter)
in a map frame, the levelling's attitude (the crane MRU's angles filtered with its rates, bridged
through gaps in its log), the feeder MRU when there is one, the radar's deck and registration
offsets from the LiDAR's, and at the end the feeder frame's definition (feeder_frame).

Measurements come in as plain arrays in the level frame (origin at the boom tip, levelled with
the MRU's roll and pitch, x along the crane's heading): deck planes z = a x + b y + c (and their
rates), registrations' poses, the radar's point velocity. Every method is one step of a frame;
the chain that calls them holds no estimation state of its own.

Through a gap in the crane MRU's log (`mru_gap.enabled`) the frames are levelled with the MRU's
own forecast (mru_bridge). The forecast's error is one error for the whole gap, not a new draw
per frame: every frame moves the same way, and so does the filter, which averages the frames as
independent. So each frame's measurements carry the forecast's variance (`LevellingAttitude.noise`),
the rows recorded in the gap carry it on top of the filter's covariance, and when the MRU is back
the filter's own covariance gets it once, so that the first true levelling corrects the state
rather than being gated as an outlier. Past `max_sigma_deg` the frames have no attitude and the
estimate pauses until the MRU is back. Only the MRU's samples before the gap are used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.data.frames import AttitudeNoise, LevellingAttitude, MruLog
from boomtip.data.installation import Installation
from boomtip.data.poses import inverse, pose_matrix
from boomtip.fusion.attitude_filter import averaged_rates, complementary_angle_sigma, complementary_attitude
from boomtip.fusion.consistency import consistency_block, flagged_notes
from boomtip.fusion.feeder_filter import FeederFilter, FeederFilterConfig
from boomtip.fusion.feeder_frame import (
    REC_KNOWN,
    REC_P,
    REC_T,
    REC_X,
    RECORD_WIDTH,
    CausalEstimates,
    FrameData,
    causal_estimates,
    frame_at,
    levelling_at,
    records_in_feeder_frame,
    state_record,
)
from boomtip.fusion.level_calibration import Tilt
from boomtip.fusion.models.relative_motion import attitude_pose_cov, condition_on, deck_plane, yaw_only
from boomtip.fusion.mru_bridge import MruBridge, MruGapConfig
from boomtip.fusion.radar_offset import RadarOffset, RadarOffsetConfig
from boomtip.fusion.records import BlockStore, Records

__all__ = ["FeederEstimatorConfig", "FeederEstimator", "FeederEstimate", "DeckMeasurement", "RadarOffsetConfig"]

# the registration's prior sigma: the pose's horizontal sigma plus its yaw's at this lever (m)
REGISTRATION_YAW_LEVER_M = 10.0
# the radar deck's offset from the LiDAR's: a running mean over at most this many frames, used
# once it has this many
RADAR_DECK_OFFSET_FRAMES = 200
RADAR_DECK_OFFSET_MIN_FRAMES = 20
# the first deck's pose: x, y and yaw are the map frame's definition (known exactly), z, roll and
# pitch the deck's
START_XY_VAR_M2 = 1e-8
START_YAW_VAR_RAD2 = 1e-10


class FeederEstimatorConfig(BaseModel):
    """The estimator's settings (`processing.feeder.*`)."""

    model_config = ConfigDict(extra="forbid")

    filter: FeederFilterConfig = FeederFilterConfig()
    mru_tau_s: float = Field(1.0, ge=0, description="time constant of the MRU's complementary filter (0: raw angles)")
    mru_rate_half_window_s: float = Field(0.05, ge=0, le=1, description="the MRU's rates averaged over +- this (the tip's "
                                          "velocity is a rate at the boom's lever; 0: raw rates)")
    use_feeder_mru: bool = Field(True, description="use an MRU on the feeder when the source has its stream")
    radar_deck_after_s: float = Field(0.5, gt=0, description="the radar's deck plane is used once the LiDAR has had none this long")
    mru_gap: MruGapConfig = MruGapConfig()
    calibration_min_s: float = Field(30.0, gt=0, description="deck planes needed before the levelling calibration applies")


@dataclass(frozen=True)
class DeckMeasurement:
    """A deck plane z = a x + b y + c in the level frame, its covariance and unit normal; with
    `rates`, the plane's rate of change over the sweep too (the deck's spin), one measurement
    with their joint 6x6 covariance."""

    abc: np.ndarray
    cov: np.ndarray
    normal: np.ndarray
    rates: np.ndarray | None = None


@dataclass
class FeederEstimate:
    """The run's estimate, in the feeder frame as defined from the whole run (offline) and as a
    live controller had it (online)."""

    t_s: np.ndarray  # (T,)
    pose: np.ndarray  # (T, 6) x, y, z (m), roll, pitch, yaw (rad): the feeder frame in the heading frame
    rates: np.ndarray  # (T, 6)
    var: np.ndarray  # (T, 12) variances of pose and rates
    t_definition_s: float  # the first LiDAR frame: where the feeder frame is defined
    tilt: Tilt | None  # the final levelling calibration
    centre_line: tuple[float, int] | None  # yaw of the centre line in the map frame, frames it was found in
    counts: dict
    notes: list[str] = field(default_factory=list)
    T_map_feeder: np.ndarray | None = None  # the feeder frame in the map frame
    feeder_mru: dict | None = None  # the feeder MRU's offsets as estimated, when there is one
    online: CausalEstimates | None = None
    consistency: dict | None = None  # per update kind: its innovations' consistency (fusion.consistency)


class FeederEstimator:
    """Built from the crane MRU's log, the installation (the tip's lever, the stated accuracies)
    and the settings; a feeder MRU's log when the source has one. The recorded states (a row per
    frame, fusion.feeder_frame's layout) go to `store` a block at a time: in memory by default."""

    def __init__(self, mru: MruLog, installation: Installation, cfg: FeederEstimatorConfig, radar: RadarOffsetConfig,
                 feeder_mru: MruLog | None = None, store: BlockStore | None = None) -> None:
        self.cfg = cfg
        # the levelling's attitude: the MRU's angles filtered with its rates (attitude_filter)
        log = complementary_attitude(mru, cfg.mru_tau_s) if cfg.mru_tau_s > 0 else mru
        log, n_rates = averaged_rates(log, cfg.mru_rate_half_window_s)
        g = cfg.mru_gap
        self.mru: MruLog | MruBridge = MruBridge(log, g.history_s, g.rate_hz, g.order, math.radians(g.max_sigma_deg)) if g.enabled else log
        angle_sigma = complementary_angle_sigma(math.radians(installation.mru.angle_noise_deg),
                                                math.radians(installation.mru.rate_noise_degps), cfg.mru_tau_s,
                                                1.0 / installation.mru.rate_hz)
        self.noise = AttitudeNoise.of_installation(installation, angle_sigma, n_rates)
        self.rates_averaged_over = n_rates
        self.lever_m = float(np.linalg.norm(installation.T_crane_boomtip()[:3, 3]))
        self.mount_sigma_rad = installation.levelling_bias_sigma_rad("lidar")
        self.mru_bias_sigma_rad = math.radians(installation.mru.bias_accuracy_deg)
        self.filter = FeederFilter(cfg.filter)
        self.feeder_mru = feeder_mru if (feeder_mru is not None and cfg.use_feeder_mru) else None
        self.feeder_mru_sigma = (math.radians(installation.feeder_mru.angle_noise_deg),
                                 math.radians(installation.feeder_mru.rate_noise_degps))
        self.feeder_mru_gaps = 0
        self.radar = radar
        self.radar_offset = RadarOffset(radar.offset_frames)
        self.radar_deck_offset, self.radar_deck_offset_n = np.zeros(3), 0  # radar deck - LiDAR deck: slopes, height
        self.last_registration_t = -math.inf
        self.radar_frames = 0
        self.normals: list[tuple[float, np.ndarray]] = []  # LiDAR deck normals (level frame) for the calibration
        self.t_definition: float | None = None
        self.T_level_map0: np.ndarray | None = None
        # the filter's state at each frame, with the tip's velocity, the LiDAR's place and the
        # edges known (feeder_frame.state_record); the first state whole (the map frame's first deck)
        self.records = Records(RECORD_WIDTH, store)
        self.x_start: np.ndarray | None = None
        # through an MRU gap: the last forecast's angle variance (in a gap, or after it until the
        # first LiDAR frame), whether the tip's place was let go, and each forecast frame's angle
        # variance by (time, sensor): a frame may be fused after later ones were levelled (the
        # pipeline holds frames back through its warm-up)
        self.gap_angle_var: float | None = None
        self.gap_tip_reset = False
        self.forecast_frames: dict[tuple[float, str], float] = {}

    # -- the attitude --------------------------------------------------------------------
    def attitude(self, t_s: float, sensor: str) -> LevellingAttitude | None:
        """The attitude to level a frame at t_s with, and its noise; None where there is none (a
        gap in the MRU's log, beyond the forecast's limit). Through a gap, the forecast with its
        variance; the first frames after it take the MRU's own attitude back (see _mru_back).
        `levelling` then `adopt`: the first reads the log only (a perception worker may call it)."""
        att = self.levelling(t_s)
        self.adopt(att, t_s, sensor)
        return att

    def levelling(self, t_s: float) -> LevellingAttitude | None:
        """The attitude at t_s from the MRU's log (or its forecast through a gap); changes nothing here."""
        got = self.mru.attitude_var(t_s) if isinstance(self.mru, MruBridge) else self.mru.attitude(t_s)
        if got is None:
            return None
        rpy, rpy_rate, *var = got
        var = var[0] if var else None
        if var is None or not var.any():
            return LevellingAttitude(rpy, rpy_rate, self.noise)
        return LevellingAttitude(rpy, rpy_rate, self.noise.with_forecast(var, self.lever_m), var)

    def adopt(self, att: LevellingAttitude | None, t_s: float, sensor: str) -> None:
        """A frame at t_s levelled with `att` (from `levelling`), in time order: through a gap
        its forecast's variance is kept for the frame's fusion; after one the MRU takes over."""
        if att is None:
            return
        if att.forecast_var is None:
            self._mru_back(sensor)
            return
        self.gap_angle_var, self.gap_tip_reset = max(att.forecast_var[0], att.forecast_var[1]), False
        self.forecast_frames[(t_s, sensor)] = self.gap_angle_var

    def _mru_back(self, sensor: str) -> None:
        """The first frames with the MRU's own attitude after a gap. The tip's place jumps from
        the forecast levelling's to the measured one's: the first step is predicted with the
        tip's velocity instead (that jump would move the state by decimetres, and the next decks
        would be gated). The state carries the gap's error: the first LiDAR frame's deck and
        registration fix it."""
        if self.gap_angle_var is None or not self.filter.started:
            return
        if not self.gap_tip_reset:
            self.filter.tip_position, self.gap_tip_reset = None, True
        if sensor == "lidar":
            self.filter.P[:6, :6] += attitude_pose_cov(self.filter.x[:3], self.gap_angle_var)
            self.gap_angle_var = None

    # -- per frame -----------------------------------------------------------------------
    @property
    def started(self) -> bool:
        return self.filter.started

    def lidar_deck(self, t_s: float, tip_level: np.ndarray, tip_velocity: np.ndarray, lidar_level: np.ndarray,
                   noise: AttitudeNoise, deck: DeckMeasurement | None) -> bool:
        """A LiDAR frame: the filter predicted to it (started at the first deck) and its deck
        fused. False when the frame has no deck: before the first, nothing happened; after, the
        prediction (the caller records it)."""
        if not self.filter.started:
            if deck is None:
                return False
            self._start(t_s, deck, tip_level, tip_velocity, lidar_level)
        else:
            self.filter.predict(t_s, tip_velocity, noise.tip_velocity_mps, tip_level)
            self._feeder_mru(t_s)
        if deck is None:
            return False
        if deck.rates is not None:  # the plane and its rates from the returns' times
            self.filter.update_deck_spin("deck_spin_lidar", deck.abc, deck.rates, deck.cov)
        else:
            self.filter.update_deck("deck_lidar", deck.abc, deck.cov)
        self.normals.append((t_s, deck.normal))
        return True

    def _start(self, t_s: float, deck: DeckMeasurement, tip_level: np.ndarray, tip_velocity: np.ndarray,
               lidar_level: np.ndarray) -> None:
        """The map frame at the first deck: origin straight below the tip (in the level frame
        as the installation has it), z along the deck normal, yaw 0."""
        origin = np.array([0.0, 0.0, deck.abc[2]])  # the level frame's origin is the tip
        n = deck.normal
        pose = np.array([*origin, -math.asin(n[1]), math.atan2(n[0], n[2]), 0.0])
        cov = np.diag([START_XY_VAR_M2, START_XY_VAR_M2, float(deck.cov[2, 2]), float(deck.cov[1, 1]),
                       float(deck.cov[0, 0]), START_YAW_VAR_RAD2])
        self.filter.start(t_s, pose, cov, tip_velocity, tip_level)
        self.x_start = self.filter.x.copy()
        self.records.append(state_record(t_s, self.filter.x, self.filter.P, tip_velocity, lidar_level, (t_s, 0, 0)))
        self._forecast_row(t_s, "lidar", keep=True)  # the frame's own record() row takes it too
        self._feeder_mru(t_s)
        self.t_definition, self.T_level_map0 = t_s, pose_matrix(*pose)

    def predict(self, t_s: float, tip_level: np.ndarray, tip_velocity: np.ndarray, noise: AttitudeNoise) -> None:
        """To a radar frame's time (the filter has started)."""
        self.filter.predict(t_s, tip_velocity, noise.tip_velocity_mps, tip_level)
        self._feeder_mru(t_s)

    def map_pose(self) -> np.ndarray:
        """T_map_level: the level frame in the map frame, at the current state."""
        return inverse(pose_matrix(*self.filter.x[:6]))

    def deck_plane(self) -> np.ndarray:
        """The deck plane (a, b, c) in the level frame at the current state."""
        return deck_plane(self.filter.x)

    def registration_sigma_m(self) -> float:
        """How far a registration's start may be off: the pose's horizontal sigma and its yaw's at a lever."""
        s = self.filter.pose_sigma()
        return float(np.linalg.norm(s[[0, 1]])) + REGISTRATION_YAW_LEVER_M * float(s[5])

    def position_sigma_x_m(self) -> float:
        return float(self.filter.pose_sigma()[0])

    def update_registration(self, t_s: float, pose_map_level: np.ndarray, info6: np.ndarray, young_model: bool,
                            noise: AttitudeNoise) -> None:
        """A LiDAR registration: the level frame's pose in the map (x, y, z, roll, pitch, yaw)
        with its 6x6 information, conditioned on the state's z, roll and pitch (the deck's); a
        young model (few viewpoints) is biased in x and y, so only its yaw is taken."""
        f = self.filter
        xy_yaw, info = condition_on(pose_map_level, info6, f.x[2:5])
        # the MRU's angle noise turns this frame about the tip: the deck below moves sideways
        s_lvl = abs(float(f.x[2])) * noise.angle_rad
        if young_model:
            info = yaw_only(info)
        f.update_registration(xy_yaw, info, np.diag([s_lvl ** 2, s_lvl ** 2, 0.0]))
        self.last_registration_t = t_s

    def update_radar(self, t_s: float, velocity_level: np.ndarray | None, velocity_cov: np.ndarray | None,
                     xi_level: np.ndarray, deck: DeckMeasurement | None, noise: AttitudeNoise) -> None:
        """A radar frame's point velocity (the feeder's point at the radar, xi) and deck plane."""
        if velocity_level is not None:
            tip_var = np.eye(3) * noise.tip_velocity_mps ** 2
            self.filter.update_point_velocity(velocity_level, velocity_cov + tip_var, xi_level)
        if deck is not None:
            self._radar_deck(t_s, deck)

    def _radar_deck(self, t_s: float, deck: DeckMeasurement) -> None:
        """The radar's deck plane is levelled through its own mount, whose error is not the
        LiDAR's: its plane differs from the LiDAR's by a fixed tilt and height (0.08 deg is 5 cm
        at the deck's 40 m of lever). While the LiDAR sees the deck the difference is learnt
        (a running mean); the radar's plane, so corrected, is used only when the LiDAR has had
        no deck for `radar_deck_after_s`."""
        f = self.filter
        a, b, c = deck_plane(f.x)
        x0, y0 = f.x[0], f.x[1]
        diff = deck.abc - np.array([a, b, c])
        d = np.array([diff[0], diff[1], diff[2] + diff[0] * x0 + diff[1] * y0])  # slope, and height at the origin
        last_lidar = self.normals[-1][0] if self.normals else -np.inf
        if t_s - last_lidar <= self.cfg.radar_deck_after_s:
            self.radar_deck_offset_n += 1
            self.radar_deck_offset += (d - self.radar_deck_offset) / min(self.radar_deck_offset_n, RADAR_DECK_OFFSET_FRAMES)
            return
        off = self.radar_deck_offset if self.radar_deck_offset_n >= RADAR_DECK_OFFSET_MIN_FRAMES else np.zeros(3)
        abc = deck.abc - np.array([off[0], off[1], off[2] - off[0] * x0 - off[1] * y0])
        f.update_deck("deck_radar", abc, deck.cov)

    def radar_registration_wanted(self, t_s: float) -> str | None:
        """Whether this radar frame's registration to the model is wanted: "learn" (the LiDAR
        registers: every learn_every-th frame teaches the offset), "update" (the LiDAR is out
        and the offset is known), or None."""
        if not self.radar.enabled:
            return None
        if t_s - self.last_registration_t > self.radar.after_s:
            return "update" if self.radar_offset.n >= self.radar.min_offset_frames else None
        return None if self.radar_frames % self.radar.learn_every else "learn"

    def radar_registration(self, wanted: str, x_y_yaw: np.ndarray, info: np.ndarray) -> None:
        """The radar's registration (x, y, yaw in the map, its information): learnt as an offset
        from the state while the LiDAR registers, else the state updated with it less that offset."""
        f = self.filter
        if wanted == "learn":
            self.radar_offset.add(x_y_yaw, f.x[[0, 1, 5]])
            return
        f.update_registration(x_y_yaw - self.radar_offset.mean, info, self.radar_offset.covariance(),
                              kind="radar_registration", max_sigma_m=self.radar.max_sigma_m)

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

    def record(self, t_s: float, sensor: str, tip_velocity: np.ndarray, lidar_level: np.ndarray, edges_known: tuple[int, int]) -> None:
        """Keep the state at the frame's time (once per frame, after its updates), with what the
        feeder frame's definition needs of it: the tip's velocity, the LiDAR's place in the level
        frame (the levelling turns about it), and how many centre lines and hull edges were known."""
        if sensor == "radar":
            self.radar_frames += 1
        f = self.filter
        self.records.append(state_record(f.t_s, f.x, f.P, tip_velocity, lidar_level, (t_s, *edges_known)))
        self._forecast_row(t_s, sensor)

    def _forecast_row(self, t_s: float, sensor: str, keep: bool = False) -> None:
        """The row just recorded of a frame levelled with a forecast: its error on top of the filter's."""
        frames = self.forecast_frames
        angle_var = frames.get((t_s, sensor)) if keep else frames.pop((t_s, sensor), None)
        if angle_var is not None:
            row = self.records.last
            row[REC_P].reshape(12, 12)[:6, :6] += attitude_pose_cov(row[REC_X][:3], angle_var)

    # -- at the end ------------------------------------------------------------------------
    def finish(self, lines: list[tuple[float, int]], hull_yaws: list[float]) -> FeederEstimate:
        """The estimate in the feeder frame, from the centre lines (map frame) and the own hull's
        edges (level frame) the pipeline found."""
        updates = self.filter.updates
        d = self._frame_data(lines, hull_yaws)
        notes: list[str] = []
        tilt, why = levelling_at(d)
        if why is not None:
            notes.append("feeder: levelling not calibrated: " + why)
        if not self.filter.started:
            return FeederEstimate(np.zeros(0), np.zeros((0, 6)), np.zeros((0, 6)), np.zeros((0, 12)), float("nan"), tilt, None,
                                  updates.counts, ["feeder: no LiDAR deck plane in this run: no estimate"])
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
        sigmas = (self.mount_sigma_rad, self.mru_bias_sigma_rad)
        t = self.records.column(REC_T)
        keep = np.r_[np.diff(t) > 0, True]  # one row per time: the last state recorded at it
        pose, rates, var = (v[keep] for v in records_in_feeder_frame(self.records, np.zeros(len(t), int), [final], *sigmas))
        consistency = consistency_block(updates.innovations)
        notes += flagged_notes(consistency, "feeder")
        return FeederEstimate(t[keep], pose, rates, var, float(self.t_definition), final.tilt, final.line,
                              updates.counts, notes, final.T_map_feeder, self._feeder_mru_summary(),
                              causal_estimates(self.records, d, keep, *sigmas), consistency)

    def _frame_data(self, lines: list[tuple[float, int]], hull_yaws: list[float]) -> FrameData:
        """The deck normals, the own hull's and the feeder's edges, each with the time it was known."""
        known = self.records.column(REC_KNOWN)  # (the frame's t, lines, hull edges) at each record
        # the time the count first exceeded i; an edge no record counted (a run whose filter never
        # started, one found after the last frame) is known only at the end
        t_known = np.r_[known[:, 0], np.inf]
        when = lambda k, col: t_known[np.searchsorted(known[:, col], np.arange(k) + 1)]
        started = self.filter.started
        return FrameData(np.array([n[0] for n in self.normals]), np.array([n[1] for n in self.normals]),
                         when(len(hull_yaws), 2), np.array(hull_yaws), when(len(lines), 1),
                         np.array([y for y, _ in lines]), self.x_start if started else None, self.T_level_map0,
                         self.cfg.calibration_min_s, self.mount_sigma_rad, math.radians(self.cfg.filter.body_yaw_prior_deg))

    def _feeder_mru_summary(self) -> dict | None:
        if self.feeder_mru is None or not self.filter.feeder_mru_started:
            return None
        x, s = (np.degrees(v) for v in self.filter.offsets())
        return {"heading_offset_deg": round(float(x[0]), 4), "heading_offset_sigma_deg": round(float(s[0]), 4),
                "body_yaw_in_map_deg": round(float(x[1]), 4), "body_yaw_sigma_deg": round(float(s[1]), 4),
                "body_tilt_deg": np.round(x[2:], 4).tolist(), "body_tilt_sigma_deg": np.round(s[2:], 4).tolist(),
                "gaps": self.feeder_mru_gaps}

