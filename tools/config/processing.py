"""Processing settings: each stage's parameters and the filters' tuning, with defaults that
hold for any installation and any sea up to Hs 4 m. Nothing here describes the world; a user
may add a sea-state prior from a forecast (`sea_state`), which only sizes the heave filters'
process noise.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from boomtip.data.installation import StrictModel
from boomtip.fusion.feeder_filter import FeederFilterConfig
from boomtip.fusion.hook_config import HookFilterConfig
from boomtip.fusion.solutions import FusionConfig
from boomtip.perception.feeder import FeederConfig
from boomtip.perception.feeder_radar import RadarRegistrationConfig
from boomtip.perception.hook_types import HookConfig
from boomtip.perception.pipeline import PipelineConfig
from boomtip.perception.rope import RopeConfig

HOOK_ESTIMATORS = ("ekf_flexible", "ekf_rigid", "ukf_flexible", "ukf_rigid")


class SeaStatePrior(StrictModel):
    """A forecast's significant wave height and peak period."""

    hs_m: float = Field(gt=0, le=20)
    tp_s: float = Field(gt=1, le=30)


class HookProcessing(StrictModel):
    detector: HookConfig = HookConfig()
    rope: RopeConfig = RopeConfig()
    filter: HookFilterConfig = HookFilterConfig()
    estimators: tuple[Literal["ekf_flexible", "ekf_rigid", "ukf_flexible", "ukf_rigid"], ...] = HOOK_ESTIMATORS


class MruGapConfig(StrictModel):
    """The feeder chain through a gap in the crane MRU's log (tools/feeder_mru_gap)."""

    enabled: bool = Field(False, description="predict the crane's attitude through an MRU gap from its own samples before it "
                          "and process the frames with it (off: the chain pauses until the MRU is back). Off by default: "
                          "better than the pause on a regular sea, mixed on an irregular one (tools/feeder_mru_gap)")
    history_s: float = Field(20.0, gt=2, description="the MRU samples before the gap the AR model is fitted to")
    rate_hz: float = Field(10.0, gt=0, description="the AR model's sample rate")
    order: int = Field(20, ge=2, le=64, description="the AR model's order")
    max_sigma_deg: float = Field(0.05, gt=0, description="past this 1-sigma of the predicted roll or pitch the chain pauses "
                                 "(0.05 deg moves the deck 45 m below by 4 cm)")


class FeederProcessing(StrictModel):
    enabled: bool = Field(True, description="run the feeder's 6-DOF chain beside the heave chain when there is a LiDAR")
    perception: FeederConfig = FeederConfig()
    filter: FeederFilterConfig = FeederFilterConfig()
    mru_tau_s: float = Field(1.0, ge=0, description="time constant of the MRU's complementary filter (0: raw angles)")
    mru_rate_half_window_s: float = Field(0.05, ge=0, le=1, description="the MRU's rates averaged over +- this (the tip's "
                                          "velocity is a rate at the boom's lever; 0: raw rates)")
    use_feeder_mru: bool = Field(True, description="use an MRU on the feeder when the source has its stream")
    radar_deck_after_s: float = Field(0.5, gt=0, description="the radar's deck plane is used once the LiDAR has had none this long")
    register_xy_after_frames: int = Field(50, ge=1, description="a registration's x and y update the filter once the model is "
                                          "merged from this many frames, its yaw from the first: against a model of few "
                                          "viewpoints they are biased (sts-irregular seed 7: 5 cm in y against one frame)")
    rekey_after_failures: int = Field(20, ge=1, description="registrations failed in a row before a new keyframe is taken")
    centre_line_every: int = Field(5, ge=1, description="the hull edge is looked for every this many LiDAR frames")
    hull_edge_min_points: int = Field(200, ge=10, description="the own hull's edge among the static returns counts with this "
                                      "many points on it (the calibration's rotation about the vertical)")
    hull_edge_frames: int = Field(30, ge=3, description="the own hull's edge is looked for in this many frames (it is static: "
                                  "their spread was 0.0001 deg)")
    radar_registration: RadarRegistrationConfig = RadarRegistrationConfig()
    mru_gap: MruGapConfig = MruGapConfig()
    calibration_min_s: float = Field(30.0, gt=0, description="deck planes needed before the levelling calibration applies")


class Processing(StrictModel):
    seed: int = Field(0, ge=0, le=2**31 - 1, description="seed of the stages' random draws (RANSAC, ...)")
    chain: Literal["heave", "hook"] | None = Field(
        None, description="which chain runs; null: the hook chain when the source has an encoder stream, else heave"
    )
    heave: PipelineConfig = PipelineConfig()
    fusion: FusionConfig = FusionConfig()
    hook: HookProcessing = HookProcessing()
    feeder: FeederProcessing = FeederProcessing()
    sea_state: SeaStatePrior | None = None
