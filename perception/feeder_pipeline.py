"""The feeder's perception per frame: cloud in, what it says of the feeder's pose out.

    LiDAR frame -> levelled, the deck plane (refitted from the heave pipeline's deck, with its
                   spin), the structure off the deck (static returns and the own vessel removed),
                   registered to the feeder's model (keyframe, frames merged), the hull edges
    radar frame -> the feeder point's velocity (from the heave pipeline's Doppler fit), the
                   radar's deck plane, its detections registered to the model

The first `static.warmup_s` of frames are held back: until then nothing says which returns are
static in the sensor frame; `observe` then hands them over in order, and frames from there on
as they come. Registration starts from the estimator's prediction (`register`), and the model
grows from the estimate after its update (`keep`): the pipeline holds the model, the estimator
the state. `observe` (and `ready`) touch only the per-frame side (the static test, the held-back
frames), `structure`, `register` and `keep` only the model's: the first may run ahead in
another process, each frame handed over with its static returns as the test said then. Through a gap in the crane MRU's log the deck and Doppler stages run on the frame
levelled with the forecast attitude (HeavePipeline.levelled_stages), and every covariance
carries the forecast's noise. A LiDAR frame's structure is registered only when the last one
registered is `register_min_interval_s` older (every other frame at 20 Hz); every frame's deck is fused.
"""

from __future__ import annotations

import math
from concurrent.futures import Executor

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.data.frames import Frame, LevellingAttitude
from boomtip.data.installation import Installation
from boomtip.data.poses import transform
from boomtip.perception.feeder import FeederConfig, FeederPerception, Footprint, LidarObservation, RadarObservation, centre_line_yaw
from boomtip.perception.feeder_merges import BackgroundMerges
from boomtip.perception.feeder_radar import RadarRegistration, RadarRegistrationConfig, register_radar
from boomtip.perception.feeder_registration import FeederModel, Registration6
from boomtip.perception.pipeline import FrameResult, HeavePipeline
from boomtip.perception.static_returns import StaticReturns
from boomtip.perception.timing import StageTimes

__all__ = ["FeederPipelineConfig", "FeederPipeline", "DECK_STAGES"]

# the heave pipeline's deck stages, which the feeder reuses: counted in the feeder's frame time
DECK_STAGES = ("deck.preprocess", "deck.planes", "deck.refine", "deck.intersect")
FEEDER_SEED_SALT = 13  # the run's seed and this: the pipeline's own random draws (centre lines)
# a keyframe that fits the frames badly is renewed only once the estimate is this sure of x (m)
REKEY_MAX_SIGMA_M = 0.05


class FeederPipelineConfig(BaseModel):
    """The pipeline's settings (`processing.feeder.*`)."""

    model_config = ConfigDict(extra="forbid")

    perception: FeederConfig = FeederConfig()
    register_xy_after_frames: int = Field(50, ge=1, description="a registration's x and y update the filter once the model is "
                                          "merged from this many frames, its yaw from the first: against a model of few "
                                          "viewpoints they are biased")
    rekey_after_failures: int = Field(20, ge=1, description="registrations failed in a row before a new keyframe is taken")
    register_min_interval_s: float = Field(0.075, ge=0, description="a LiDAR frame's structure is registered when the last "
                                           "frame registered is at least this much older (every frame at 10 Hz, every other at "
                                           "20 Hz): the filter takes registrations closer than its error correlation time (0.1 s) "
                                           "as sharing their errors, so more frequent ones cost their time for no information; "
                                           "the deck plane of every frame is fused (0: every frame registered)")
    centre_line_every: int = Field(5, ge=1, description="the hull edge is looked for every this many LiDAR frames")
    hull_edge_min_points: int = Field(200, ge=10, description="the own hull's edge among the static returns counts with this "
                                      "many points on it (the calibration's rotation about the vertical)")
    hull_edge_frames: int = Field(30, ge=3, description="the own hull's edge is looked for in this many frames (it is static: "
                                  "a few dozen frames pin it)")
    radar_registration: RadarRegistrationConfig = RadarRegistrationConfig()


class FeederPipeline:
    """Built from the installation (mounts, tip, the radar's stated noise), the settings, the
    attitude's nominal noise, the run's seed and the heave pipeline whose deck and Doppler
    stages it reuses."""

    def __init__(self, installation: Installation, cfg: FeederPipelineConfig, stages: FeederPerception, seed: int,
                 heave: HeavePipeline | None = None, merge_executor: Executor | None = None) -> None:
        self.cfg = cfg
        self.stages = stages
        self.static = StaticReturns(cfg.perception.static)
        self.model = FeederModel(cfg.perception.registration)
        self.merges = BackgroundMerges(self.model, merge_executor)
        # frames the model must be merged from before a registration's x and y update the filter:
        # at most its last merge's (no merges at all: the first keyframe's one frame)
        self.xy_after_frames = min(cfg.register_xy_after_frames, max(cfg.perception.registration.model_merges, default=1))
        self.rng = np.random.default_rng([seed, FEEDER_SEED_SALT])
        self.heave = heave
        self.forecast_decks: dict[str, tuple[float, float]] = {}  # the decks found with a forecast levelling
        radar = installation.radar  # a bin's uniform error, bin / sqrt(12), beside the noise
        angle_bin = math.radians(radar.angle_resolution_deg) / math.sqrt(12.0)
        self.detection_sigma = (math.hypot(radar.range_noise_m, radar.range_resolution_m / math.sqrt(12.0)),
                                math.hypot(math.radians(radar.azimuth_noise_deg), angle_bin),
                                math.hypot(math.radians(radar.elevation_noise_deg), angle_bin))
        self.queue: list[LidarObservation | RadarObservation] = []
        self.footprint: Footprint | None = None  # the deck's outline in the map frame, from the first deck
        self.failed_registrations = 0  # in a row: after rekey_after_failures a new keyframe is taken
        self.lines: list[tuple[float, int]] = []  # the centre line's yaw in the map frame, every few frames
        self.hull_yaws: list[float] = []  # the own hull's edge in the level frame, every few frames
        self.lidar_frames = 0
        self.last_registered_s = -math.inf  # the last LiDAR frame whose structure is to be registered
        self.missing: list[tuple[float, str, str]] = []  # (t, sensor, why)

    # -- per frame -----------------------------------------------------------------------
    def observe(self, frame: Frame, heave: FrameResult | None, att: LevellingAttitude) -> list[LidarObservation | RadarObservation]:
        """The frame's observation, levelled with `att`; returns the observations ready to fuse,
        in time order (none during the warm-up, then all those held back)."""
        if att.forecast_var is not None and self.heave is not None:
            heave = self.heave.levelled_stages(frame, att.rpy_rad, self.forecast_decks)
        if frame.sensor == "lidar":
            times = StageTimes()
            with times.stage("feeder.returns"):  # sampled, levelled, the deck plane taken over
                obs = self.stages.lidar(frame.t_s, frame.points_sensor, att.rpy_rad, att.rpy_rate_radps,
                                        heave.deck_lidar if heave is not None else None, frame.fields.get("t"), att.noise)
            # the static test counts the frames registered (those it tests): at the same spacing
            # its window holds fewer of them, alike for a fraction-of-frames test
            obs.to_register = self.chosen_for_registration(frame.t_s)
            if obs.to_register:
                with times.stage("feeder.static_count"):
                    obs.static_keys = self.static.add(frame.t_s, obs.sample_returns_sensor)
            if obs.plane is None:
                self.missing.append((obs.t_s, "lidar", obs.status))
            # the feeder's time per LiDAR frame: this, the fusion's, and the deck stage it reuses
            times.ms["feeder.deck_reused"] = heave.times.total(*DECK_STAGES) if heave is not None else 0.0  # the heave chain's deck stage
            obs.stage_ms, obs.ms = dict(times.ms), times.total()
        else:
            obs = self.stages.radar(frame.t_s, att.rpy_rad, att.rpy_rate_radps, heave.doppler if heave is not None else None,
                                    heave.deck_radar if heave is not None else None, frame.points_sensor, att.noise)
        self.queue.append(obs)
        return self.ready() if self.static.ready else []

    def ready(self) -> list[LidarObservation | RadarObservation]:
        """The observations held back (at the end of a run shorter than the warm-up: with what
        the static test has), each LiDAR frame with its static returns as the test says now:
        what the fusion of these frames uses, so that the fusion may run apart from the test."""
        out, self.queue = self.queue, []
        for obs in out:
            if isinstance(obs, LidarObservation) and not obs.to_register:  # only its deck is fused: its returns let go
                obs.static_keys = obs.sample_returns_sensor = None
                obs.sample_sensor = np.zeros((0, 3))
            elif isinstance(obs, LidarObservation):
                times = StageTimes()
                with times.stage("feeder.static_mask"):
                    obs.static_mask = self.static.static_mask(obs.sample_returns_sensor, obs.static_keys)
                obs.stage_ms.update(times.ms)
                obs.ms += times.total()
                obs.static_keys = obs.sample_returns_sensor = None  # the test's inputs: not needed past here
        return out

    def next_lidar_frame(self, times: StageTimes | None = None) -> None:
        """At the start of each LiDAR frame's fusion: a merge of the model due now becomes it."""
        with (times or StageTimes()).stage("feeder.merges"):  # waited for, when it runs beside the frames
            self.merges.next_frame()

    def structure(self, obs: LidarObservation, T_map_level: np.ndarray, deck_abc: np.ndarray,
                  times: StageTimes | None = None) -> np.ndarray:
        """The frame's structure (level frame) off the deck plane `deck_abc`, over the feeder's
        footprint (taken from the first deck, placed in the map by T_map_level), static returns
        removed."""
        if self.footprint is None and obs.plane is not None and obs.plane.points_level is not None:
            deck_map = transform(T_map_level, obs.plane.points_level)
            self.footprint = Footprint(deck_map[:, :2], self.cfg.perception.footprint_margin_m)
        with (times or StageTimes()).stage("feeder.structure"):
            return self.stages.structure(obs, deck_abc, self.footprint, T_map_level, is_static=lambda rows: self.static_of(obs)[rows])

    def static_of(self, obs: LidarObservation) -> np.ndarray:
        """Which of the frame's returns are static: as `ready` handed it over, else as the test says now."""
        if obs.static_mask is None:
            obs.static_mask = self.static.static_mask(obs.sample_returns_sensor, obs.static_keys)
        return obs.static_mask

    def chosen_for_registration(self, t_s: float) -> bool:
        """Whether the LiDAR frame at t_s is to be registered (`register_min_interval_s` after the
        last one chosen, which it then becomes): decided from the frames' times alone, where the
        frame is perceived, so that a frame not registered costs no static test either (neither
        counted nor tested)."""
        if t_s - self.last_registered_s < self.cfg.register_min_interval_s:
            return False
        self.last_registered_s = t_s
        return True

    def register(self, obs: LidarObservation, structure: np.ndarray, T_map_level_guess: np.ndarray,
                 prior_sigma_m: float, times: StageTimes | None = None) -> Registration6 | None:
        """The structure registered to the model from the guess; None when there is nothing to
        register to (the frame becomes the first keyframe, or a new one after
        `rekey_after_failures` failures) or the registration failed (counted as missing)."""
        if self.model.empty or self.failed_registrations >= self.cfg.rekey_after_failures:
            if len(structure) >= self.model.cfg.min_points:  # a keyframe with too little to register to is no model
                self.model.set_keyframe(structure, T_map_level_guess)
                self.failed_registrations = 0
            return None
        with (times or StageTimes()).stage("feeder.registration"):
            reg = self.model.register(structure, T_map_level_guess, prior_sigma_m)
        if reg.status != "ok":
            self.failed_registrations += 1
            self.missing.append((obs.t_s, "lidar", f"registration: {reg.status}"))
            return None
        return reg

    @property
    def young_model(self) -> bool:
        """A model merged from fewer than `register_xy_after_frames` frames: its few viewpoints
        bias a registration's x and y."""
        return self.model.model_frames < self.xy_after_frames

    def keep(self, obs: LidarObservation, structure: np.ndarray, reg: Registration6 | None, T_map_level: np.ndarray,
             sigma_x_m: float, times: StageTimes | None = None) -> None:
        """After the estimate's update (T_map_level, its x sigma): a registered frame grows the
        model (collected for its merges, the keyframe filled or renewed); every few frames the
        feeder's centre line and the own hull's edge are looked for. `times`: their stages' ms."""
        times = times if times is not None else StageTimes()
        if reg is not None:
            with times.stage("feeder.model"):
                due = self.model.collect(structure, T_map_level, reg.source_sampled)
            if due:
                with times.stage("feeder.merges"):  # inline without an executor, else only started
                    self.merges.start()
            with times.stage("feeder.model"):
                if self.model.keyframe_size < self.model.cfg.keyframe_frames:
                    self.model.extend_keyframe(structure, T_map_level)
                    self.model.keyframe_size += 1
                elif reg.fitness < self.model.cfg.min_fitness and sigma_x_m < REKEY_MAX_SIGMA_M:
                    self.model.set_keyframe(structure, T_map_level)
            self.failed_registrations = 0
        with times.stage("feeder.lines"):
            self._lines(obs, structure, T_map_level)
        obs.static_keys = obs.static_mask = None
        self.lidar_frames += 1

    def _lines(self, obs: LidarObservation, structure: np.ndarray, T_map_level: np.ndarray) -> None:
        """Every few frames: the feeder's centre line (map frame) and the own hull's edge (level frame)."""
        if self.lidar_frames % self.cfg.centre_line_every == 0 and len(structure):
            line = centre_line_yaw(transform(T_map_level, structure), self.rng)  # in the map frame, at the estimate's pose
            if line is not None:
                self.lines.append(line)
            # the own hull's side among the static returns (a wall: a line in plan), for the
            # calibration's rotation about the vertical
            if len(self.hull_yaws) < self.cfg.hull_edge_frames:  # a constant: a few dozen frames pin it
                static_level = obs.sample_sensor[self.static_of(obs)] @ obs.R_level_sensor.T + obs.t_level_sensor
                hull = centre_line_yaw(static_level, self.rng, band_m=(-np.inf, np.inf))
                if hull is not None and hull[1] >= self.cfg.hull_edge_min_points:
                    self.hull_yaws.append(hull[0])

    @property
    def edges_known(self) -> tuple[int, int]:
        """How many centre lines and own-hull edges have been found so far."""
        return len(self.lines), len(self.hull_yaws)

    def register_radar(self, obs: RadarObservation, pose_guess: np.ndarray, count_failure: bool) -> RadarRegistration | None:
        """The radar's detections registered to the model (x, y, yaw from the pose guess's z,
        roll, pitch); None without detections, before the model is merged from
        `min_model_frames`, or when it fails (counted as missing when `count_failure`)."""
        cfg = self.cfg.radar_registration
        if (not cfg.enabled or obs.detections_sensor is None or len(obs.detections_sensor) == 0
                or self.model.surface is None or self.model.model_frames < cfg.min_model_frames):
            return None
        reg = register_radar(self.model.surface, obs.detections_sensor, obs.R_level_sensor, obs.xi_level,
                             self.detection_sigma, pose_guess, cfg)
        if reg.status != "ok":
            if count_failure:
                self.missing.append((obs.t_s, "radar", reg.status))
            return None
        return reg

    def finish(self) -> np.ndarray | None:
        """At the end of the run: merges still running stopped; the model's points (map frame)."""
        self.merges.close()
        return np.asarray(self.model.keyframe.points) if not self.model.empty else None
