"""Processing settings: each stage's parameters and the filters' tuning, with defaults that
hold for any installation and any sea up to Hs 4 m. Nothing here describes the world; a user
may add a sea-state prior from a forecast (`sea_state`), which only sizes the heave filters'
process noise.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from boomtip.data.installation import StrictModel
from boomtip.fusion.feeder_estimator import FeederEstimatorConfig
from boomtip.fusion.hook_config import HookFilterConfig
from boomtip.fusion.heave_filter import HeaveFilterConfig
from boomtip.fusion.solutions import FusionConfig
from boomtip.perception.feeder_pipeline import FeederPipelineConfig
from boomtip.perception.hook_types import HookConfig
from boomtip.perception.lift import LiftConfig
from boomtip.perception.lift_deck_frame import DeckFrameConfig
from boomtip.perception.lift_doppler import LiftRadarConfig
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


class FeederProcessing(FeederPipelineConfig, FeederEstimatorConfig):
    """The feeder's 6-DOF estimate: its pipeline's settings and its estimator's, one flat section."""

    enabled: bool = Field(True, description="run the feeder's 6-DOF chain beside the heave chain when there is a LiDAR")


class LiftProcessing(StrictModel):
    """The lift chain's own stages: the load and the deck below it, the clearance's filter and
    its forecast."""

    detector: LiftConfig = LiftConfig()
    radar: LiftRadarConfig = Field(LiftRadarConfig(), description="the clearance's rate from the radar's Doppler")
    filter: HeaveFilterConfig = Field(HeaveFilterConfig(), description="both lift filters' tuning (the relative-heave "
                                      "filter's model), on C and h with the radar's rates, else on C + l and h + l")
    landing_offset_rate_sigma_mps: float = Field(0.01, gt=0, description="how fast the load's centre may wander from "
                                                 "the rope's line (the slings' give, the load turning on them: a load "
                                                 "slung from the hook swings with it, its centre's offset drifts by "
                                                 "millimetres a second): the landing point's filter (fusion.landing_filter)")
    landing_error_correlation_s: float = Field(0.5, ge=0, description="one frame's load-centre error (where the beams "
                                               "fall on its edges) lasts about this long, as the load moves across "
                                               "them: frames closer than this are not taken as independent")
    deck_frame: DeckFrameConfig = Field(DeckFrameConfig(), description="the feeder's deck frame, the landing point's "
                                        "(perception.lift_deck_frame)")
    lost_sigma_m: float = Field(0.1, gt=0, description="a clearance whose sigma exceeds this is lost: left empty in "
                                "lift_estimates.csv with the reason (no frame has held it for a while)")
    landed_hold_s: float = Field(0.5, gt=0, description="the load has landed once its measured clearance has stayed at "
                                 "zero (within 3 sigma, or 3 cm) this long (fusion.touchdown)")
    horizon_s: float = Field(8.0, gt=0, le=60, description="the touchdown forecast's horizon")
    forecast_history_s: float = Field(40.0, gt=5, le=600, description="the forecast's AR model is fitted to this much "
                                      "of the recent relative motion")


class Processing(StrictModel):
    seed: int = Field(0, ge=0, le=2**31 - 1, description="seed of the stages' random draws (RANSAC, ...)")
    chain: Literal["heave", "hook", "lift"] | None = Field(
        None, description="which chain runs; null: the hook chain when the source has an encoder stream, else heave"
    )
    heave: PipelineConfig = PipelineConfig()
    fusion: FusionConfig = FusionConfig()
    hook: HookProcessing = HookProcessing()
    feeder: FeederProcessing = FeederProcessing()
    lift: LiftProcessing = LiftProcessing()
    sea_state: SeaStatePrior | None = None
