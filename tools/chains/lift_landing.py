"""The lift's landing point, wired from its parts: the load's centre measured in a levelled frame,
its offset from the rope's line filtered (fusion.landing_filter), relative to the boom tip; and
the same point in the feeder's deck frame (perception.lift_deck_frame), where it stays still as
the feeder moves."""

from __future__ import annotations

import math

import numpy as np

from boomtip.fusion.landing_filter import LandingOffsetFilter
from boomtip.perception.lift import LoadClearance, footprint_radius_m, rope_line_xy
from boomtip.perception.lift_deck_frame import DeckFrameTracker
from boomtip.perception.timing import StageTimes
from boomtip.tools.config.processing import LiftProcessing
from boomtip.tools.report import lift as outputs


class LiftLanding:
    """Built from the lift's settings, the load's size (None: no model), the boom's length and
    the LiDAR's frame rate (installation)."""

    def __init__(self, cfg: LiftProcessing, load_size_m: tuple[float, float, float] | None, boom_length_m: float,
                 lidar_rate_hz: float) -> None:
        self.offset = LandingOffsetFilter(cfg.landing_offset_rate_sigma_mps, cfg.landing_error_correlation_s)
        self.deck_frame = DeckFrameTracker(cfg.deck_frame) if cfg.deck_frame.enabled else None
        self.boom_length_m = boom_length_m
        # a carried deck's error is shared by the frames of its correlation time: the filters' sigma widened by their root
        self.fallback_widening = math.sqrt(max(1.0, cfg.deck_frame.fallback_error_correlation_s * lidar_rate_hz))
        self.load_column_m = footprint_radius_m(load_size_m, cfg.detector) + cfg.detector.load_margin_m

    def update(self, t_s: float, obs: LoadClearance, p_hook: np.ndarray, cov_hook: np.ndarray, points_level: np.ndarray,
               tip_attitude_sigma_rad: float, times: StageTimes) -> dict:
        """A measured frame's landing point row: relative to the tip (levelled frame) and in the deck frame."""
        line = rope_line_xy(p_hook, obs.underside_centre_m[2])
        self.offset.update(t_s, obs.underside_centre_m[:2] - line, obs.centre_sigma_m)
        # the rope's line at the underside is the hook's, scaled down the rope: its variance too
        line_var = (obs.underside_centre_m[2] / p_hook[2]) ** 2 * 0.5 * float(np.trace(cov_hook[:2, :2]))
        landing_xy, var_m2 = line + self.offset.x, self.offset.predicted_var(t_s) + line_var
        row = outputs.landing_row(landing_xy, var_m2)
        if self.deck_frame is None:
            return row
        landing_level = np.array([landing_xy[0], landing_xy[1], obs.landing_z_m])
        if self.deck_frame.due(t_s) or obs.deck_hidden is not None:  # the next frame's deck, if hidden too, from a fresh pose
            # the levelled frame's origin: the slew and luff's error at the boom's end, the tilt's at the deck
            tip_sigma_m = max(self.boom_length_m, float(np.linalg.norm(landing_level))) * tip_attitude_sigma_rad
            with times.stage("lift.deck_frame"):
                self.deck_frame.update(t_s, points_level, obs.deck_plane, points_level[obs.deck_mask, :2],
                                       obs.underside_centre_m[:2], self.load_column_m, tip_sigma_m)
        if obs.deck_hidden is None:
            self.deck_frame.remember_deck(t_s, obs.deck_plane, obs.deck_sigma_m)
        placed = self.deck_frame.landing_in_deck(t_s, landing_level, math.sqrt(var_m2))
        if placed is not None:
            row.update(outputs.deck_landing_row(*placed, self.deck_frame.key_t_s))
        return row

    def deck_fallback(self, t_s: float, hook_level: np.ndarray) -> tuple[np.ndarray, float] | None:
        """The deck plane below the hook from the feeder's predicted pose, and its 1-sigma there:
        for a frame whose returns show too little of the deck about the load."""
        return None if self.deck_frame is None else self.deck_frame.deck_plane_at(t_s, hook_level[:2])

    def filter_sigmas(self, obs: LoadClearance) -> tuple[float, float]:
        """The sigmas of C and of the centre's height as the clearance's filters are to take them:
        a carried deck's error, shared by the frames of its correlation time, widened by their
        root (the frame's own sigma, as measured, stays for the rows and the touchdown test)."""
        if obs.deck_hidden is None:
            return obs.sigma_m, obs.centre_height_sigma_m
        shared_var_m2 = (self.fallback_widening**2 - 1.0) * obs.deck_sigma_m**2
        return math.sqrt(obs.sigma_m**2 + shared_var_m2), math.sqrt(obs.centre_height_sigma_m**2 + shared_var_m2)

    def kpis(self) -> dict | None:
        """The deck frame's registrations by outcome and its keyframe's time."""
        if self.deck_frame is None:
            return None
        return {"registrations": dict(sorted(self.deck_frame.statuses.items())), "keyframe_s": self.deck_frame.key_t_s}
