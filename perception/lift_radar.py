"""Radar scans -> the clearance's rates (perception.lift_doppler), about the LiDAR's last fix of
the load and the deck: the scan levelled at the tip with that frame's attitude (a scan lies
within `max_fix_age_s` of it, tens of milliseconds at the sensors' rates: the waves turn the tip
by a fraction of a milliradian meanwhile, which tilts the relative horizontal velocity into the
vertical by as much, a millimetre a second), and the deck's spin from the fixes' deck planes
over time. Built from the installation (the radar's mount and noise,
the load's model, the block) and the settings; never from the simulated world."""

from __future__ import annotations

import math

import numpy as np

from boomtip.data.frames import Frame
from boomtip.data.installation import Installation
from boomtip.perception.doppler_gate import doppler_band_mps
from boomtip.perception.geometry import NormalRate
from boomtip.perception.hook_pipeline import level_at_tip
from boomtip.perception.lift import LiftConfig, LoadClearance, footprint_radius_m
from boomtip.perception.lift_doppler import ClearanceRate, LiftRadarConfig, measure_clearance_rate
from boomtip.perception.pipeline import doppler_inputs
from boomtip.perception.timing import StageTimes

__all__ = ["ClearanceRatePipeline"]

RADAR_SEED_SALT = 0x11F7  # the scans' draws (the deck's Doppler fit), apart from the hook's
DECK_SPIN_WINDOW_S = 1.0  # the deck's spin from its normals over this long


class ClearanceRatePipeline:
    def __init__(self, installation: Installation, cfg: LiftRadarConfig, detector: LiftConfig,
                 load_size_m: tuple[float, float, float] | None, block_height_m: float, seed: int = 0,
                 band_sigmas: float = 4.0, band_floor_mps: float = 0.1) -> None:
        radar = installation.radar
        if "inlier_threshold_mps" not in cfg.doppler.model_fields_set:  # the radar's data sheet sets the band
            cfg = cfg.model_copy(update={"doppler": cfg.doppler.model_copy(
                update={"inlier_threshold_mps": doppler_band_mps(radar, band_sigmas, band_floor_mps)})})
        self.cfg, self.seed = cfg, seed
        self.T_tip_radar = radar.mount.matrix()
        self.range_rate_noise_mps = radar.range_rate_noise_mps
        self.footprint_radius_m = footprint_radius_m(load_size_m, detector)
        self.load_height_m = load_size_m[2] if load_size_m else math.inf
        self.block_height_m = block_height_m
        self.deck_spin = NormalRate(DECK_SPIN_WINDOW_S)
        self.last_fix: tuple | None = None  # (t, LoadClearance, tip attitude, hook position, its velocity and covariance)
        self.statuses: dict[str, int] = {}
        self.times_ms: list[float] = []

    def add_fix(self, t_s: float, fix: LoadClearance, tip_attitude: tuple[float, float, float], hook_m: np.ndarray,
                hook_velocity: tuple[np.ndarray, np.ndarray]) -> None:
        """A LiDAR frame's fix (ok), the tip's attitude it was levelled with and the hook then
        (its position; its velocity and that's covariance, relative to the tip)."""
        self.deck_spin.add(t_s, np.array([-fix.deck_plane[1], -fix.deck_plane[2], 1.0]))
        self.last_fix = (t_s, fix, tip_attitude, hook_m, hook_velocity)

    def process(self, frame: Frame) -> tuple[ClearanceRate, np.ndarray | None]:
        """The scan's rates, and its detections levelled (None when it was not levelled)."""
        times = StageTimes()
        with times.stage("lift.radar"):
            out, points_level = self._rates(frame)
        self.statuses[out.status] = self.statuses.get(out.status, 0) + 1
        self.times_ms.append(times.total())
        return out, points_level

    def _rates(self, frame: Frame) -> tuple[ClearanceRate, np.ndarray | None]:
        if frame.error is not None:
            return ClearanceRate(f"unreadable frame: {frame.error}"), None
        if self.last_fix is None or abs(frame.t_s - self.last_fix[0]) > self.cfg.max_fix_age_s:
            return ClearanceRate("no recent LiDAR fix of the load and deck"), None
        inputs = doppler_inputs(frame, self.cfg.preprocess)
        if inputs is None:
            return ClearanceRate("frame has no range_rate field"), None
        _, fix, attitude, hook_m, (hook_v, hook_v_cov) = self.last_fix
        levelled = level_at_tip(inputs[0], self.T_tip_radar, *attitude)
        return measure_clearance_rate(
            levelled.points_level, levelled.sensor_level, inputs[1], fix, self.footprint_radius_m, self.load_height_m, hook_m,
            hook_v, hook_v_cov, self.deck_spin.omega(frame.t_s), self.block_height_m, self.cfg, self.range_rate_noise_mps,
            np.random.default_rng([self.seed, RADAR_SEED_SALT, frame.index])), levelled.points_level
