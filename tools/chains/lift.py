"""The lift chain: the hook chain's frames (levelled with the tracker's attitude, the rope and
the block fitted, the hook tracked) and, on the same levelled cloud, the load under the hook
and the deck below it (perception.lift); at the end, the touchdown forecast
(fusion.lift_forecast) and the hook's estimators.

The clearance C (the load's lowest point's, its corners weighed by their chance to be it) and the height h (the underside centre's above the deck,
which moves with the relative vertical motion alone, not with the load's tilting) are followed
by two filters (fusion.clearance_filters): with the radar's rates (perception.lift_radar), C and
h themselves; without, the wave parts C + l and h + l (l the rope paid out, the hook tracker's).
Once the load has landed (fusion.touchdown) the filters stop: the landing is a step no smooth
model follows, and the rows say "landed at T".

Built from the installation (the LiDAR, the radar, the crane, the block's and the load's models) and the
processing settings; never from the simulated world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from boomtip.data.frames import Frame, FrameSource, Truth
from boomtip.fusion.consistency import flagged_notes
from boomtip.fusion.clearance_filters import ClearanceFilters
from boomtip.fusion.lift_forecast import TouchdownForecasts, touchdown_forecasts
from boomtip.fusion.touchdown import TouchdownDetector
from boomtip.perception.lift import LoadClearance, measure_clearance
from boomtip.perception.lift_doppler import ClearanceRate
from boomtip.perception.lift_radar import ClearanceRatePipeline
from boomtip.perception.residual_spread import ResidualSpread
from boomtip.tools.chains.chain import NullVisualiser
from boomtip.tools.chains.hook import HookChain, HookFrameResult, HookResult
from boomtip.tools.chains.lift_landing import LiftLanding
from boomtip.tools.chains.resources import RunResources
from boomtip.tools.config.processing import Processing
from boomtip.tools.report import lift as outputs

CLEARANCE_SOURCE, HEIGHT_SOURCE = "lidar_clearance", "lidar_height"
RATE_SOURCE, HEIGHT_RATE_SOURCE = "radar_clearance_rate", "radar_height_rate"


@dataclass
class LiftFrameResult(HookFrameResult):
    """A LiDAR frame's hook work and the load's clearance in it."""

    clearance: LoadClearance | None = None


@dataclass
class LiftRadarFrame:
    """A radar scan's detections (levelled frame; None when not levelled) and the rates from it."""

    t_s: float
    points_level: np.ndarray | None
    rate: ClearanceRate
    sensor: str = "radar"


@dataclass
class LiftResult:
    hook: HookResult
    rows: dict[str, np.ndarray]  # the lift's per-frame rows as columns (lift_estimates.csv)
    forecasts: TouchdownForecasts


class LiftChain:
    name = "lift"

    def __init__(self, source: FrameSource, processing: Processing, resources: RunResources | None = None) -> None:
        inst = source.meta.installation
        model = inst.lift.load_model
        self.hook = HookChain(source, processing, resources, load_mass_kg=model.mass() if model is not None else 0.0)
        self.load_size_m = model.dimensions() if model is not None else None
        if model is None:
            self.hook.warnings.append("no load model (installation.lift.load_model): the clearance is the lowest load "
                                      "point seen, which from above is the top, not the underside")
        self.cfg = processing.lift
        self.block_height_m = self.hook.pipeline.cfg.block_height_m
        self.lidar_noise = (inst.lidar.range_noise_m, inst.lidar.angular_step_rad)
        self.filters = ClearanceFilters(self.cfg.filter, (CLEARANCE_SOURCE, HEIGHT_SOURCE, RATE_SOURCE, HEIGHT_RATE_SOURCE))
        self.landing = LiftLanding(self.cfg, self.load_size_m, inst.crane.geometry.boom_length_m, inst.lidar.rate_hz)
        self.touchdown = TouchdownDetector(self.cfg.landed_hold_s)
        self.deck_z_m: float | None = None  # the deck's last height under the load, the next frame's prior
        self.top_spread = ResidualSpread()  # the load top's residual spread over the frames so far
        self.hoist = (math.nan, math.nan)  # the rope's length and rate (the hook tracker's) at the last frame
        self.rows: list[dict] = []
        # the radar: the clearance's rates from its Doppler, about the last LiDAR fix
        self.radar = ClearanceRatePipeline(inst, self.cfg.radar, self.cfg.detector, self.load_size_m, self.block_height_m,
                                           processing.seed, processing.heave.doppler_band_sigmas,
                                           processing.heave.doppler_band_floor_mps) \
            if inst.radar.enabled and self.cfg.radar.enabled else None

    def frames(self, source: FrameSource):
        return self.hook.frames(source)

    def process(self, frame: Frame) -> LiftFrameResult | LiftRadarFrame | None:
        if frame.sensor == "radar":
            if self.radar is None:
                return None
            if self.touchdown.landed_s is not None:  # the filters stopped (the scan drawn as nothing)
                return LiftRadarFrame(frame.t_s, None, ClearanceRate("landed"))
            rate, points_level = self.radar.process(frame)
            if rate.ok:
                self.filters.add_rates(frame.t_s, (rate.clearance_rate_mps, rate.sigma_mps),
                                       (rate.centre_rate_mps, rate.centre_sigma_mps))
            return LiftRadarFrame(frame.t_s, points_level, rate)
        res = self.hook.process(frame)
        if res is None:
            return None
        out = LiftFrameResult(**vars(res))
        row = {"t": frame.t_s, "status": res.row.get("status", "no levelled frame")}
        if res.points_level is not None and self.hook.tracker is not None:
            with out.times.stage("lift.clearance"):
                p_hook, cov_hook = self.hook.tracker.estimate()
                obs = out.clearance = measure_clearance(res.points_level, p_hook, self.block_height_m, self.load_size_m,
                                                        self.cfg.detector, self.deck_z_m, *self.lidar_noise,
                                                        t_s=frame.t_s, top_spread=self.top_spread,
                                                        deck_fallback=self.landing.deck_fallback(frame.t_s, p_hook))
                self.hoist = self.hook.tracker.hoist()
            if obs.top_spread is not None:
                self.top_spread = obs.top_spread
            row.update(outputs.observation_row(obs))
            if self.touchdown.update(frame.t_s, obs.clearance_m, obs.sigma_m):  # a frame without one breaks the run
                row.update(outputs.landed_row(obs if obs.ok else None, self.touchdown.landed_s, self.hoist[0]))
                self.rows.append(row)
                return out
            if obs.ok:
                self.deck_z_m = obs.deck_z_m
                if self.radar is not None:
                    self.radar.add_fix(frame.t_s, obs, self.hook.tracker.tip_attitude(), p_hook, self.hook.tracker.velocity())
                row.update(self.landing.update(frame.t_s, obs, p_hook, cov_hook, res.points_level,
                                               self.hook.tracker.tip_attitude_sigma_rad(), out.times))
                sigma_m, centre_sigma_m = self.landing.filter_sigmas(obs)
                with out.times.stage("lift.filter"):
                    self.filters.add_heights(frame.t_s, (obs.clearance_m, sigma_m), (obs.centre_clearance_m, centre_sigma_m),
                                             self.hoist)
        else:
            self.touchdown.update(frame.t_s, math.nan, math.nan)
        if self.touchdown.landed_s is not None:  # landed: the filters stopped
            row.update(outputs.landed_row(None, self.touchdown.landed_s, self.hoist[0]))
        else:
            row.update(outputs.estimate_row(*self.filters.estimates(frame.t_s), self.filters.offset(self.hoist), self.hoist[0],
                                            self.cfg.lost_sigma_m))
        self.rows.append(row)
        return out

    def finish(self) -> LiftResult:
        # the hook's model (a pendulum on a taut rope, the load's mass on it) ends at the landing
        hook = self.hook.finish_until(self.touchdown.landed_s)
        rows = outputs.as_columns(self.rows)
        forecasts = touchdown_forecasts(rows["t"], rows["height_m"], rows["hoist_m"], self.cfg.horizon_s,
                                        self.cfg.forecast_history_s, rows["height_m"] - rows["clearance_m"])
        return LiftResult(hook, rows, forecasts)

    def outputs(self, out: Path, result: LiftResult) -> list[str]:
        names = self.hook.outputs(out, result.hook)
        outputs.write_estimates(out / "lift_estimates.csv", result.rows)
        outputs.write_forecasts(out / "lift_forecast.csv", result.forecasts)
        return names + ["lift_estimates.csv", "lift_forecast.csv"]

    def kpis(self, result: LiftResult, truth: Truth | None, windows: list[tuple[float, float]] = ()) -> dict:
        k = self.hook.kpis(result.hook, outputs.until_touchdown(truth), windows)
        if self.touchdown.landed_s is not None and result.hook.runs:
            k["hook"]["estimators_note"] += (f"; the estimators stop at the landing found at {self.touchdown.landed_s:.2f} s "
                                             "(the load on the deck, the rope slack: not the pendulum they model)")
        if truth is not None and "contact" in truth.columns:
            k["hook"]["estimators_note"] += ", scored until the load's touchdown (the rope slack after it)"
        k["lift"] = outputs.lift_kpis(result.rows, result.forecasts, truth, self.filters.filters(), self.touchdown.landed_s)
        if self.landing.deck_frame is not None:
            k["lift"]["deck_frame"] = self.landing.kpis()
        if self.radar is not None:
            k["lift"]["radar"] = outputs.radar_kpis(self.radar.statuses, self.radar.times_ms, self.filters.restarts)
            if not self.filters.ever_followed_rates:
                k["warnings"] = k.get("warnings", []) + [
                    "the radar gave no clearance rate (lift.radar.statuses say why): the rates are the LiDAR's heights' alone"]
        k.setdefault("consistency", {})["lift"] = consistency = k["lift"].pop("consistency")
        notes = flagged_notes(consistency, "lift")
        if notes:
            k["warnings"] = k.get("warnings", []) + notes
        return k

    def report(self, out: Path, kpis: dict, result: LiftResult, truth: Truth | None, pictures=None) -> list[str]:
        names = self.hook.report_text(out, kpis, result.hook, outputs.until_touchdown(truth))
        return sorted(set(names) | set(outputs.write_lift_report(out, kpis["lift"], result, truth)))

    def visualiser(self, path: Path, source: FrameSource):
        from boomtip.tools.report.recording.lift import LiftRerunLogger

        return LiftRerunLogger(path, source, gate_radius_m=self.hook.pipeline.cfg.prior_radius_m)

    def visualise_result(self, viz, result: LiftResult, truth: Truth | None) -> None:
        self.hook.visualise_result(viz, result.hook, outputs.until_touchdown(truth))
        if isinstance(viz, NullVisualiser):
            return
        rows = result.rows
        truth_m = truth.at("clearance", rows["t"]) if truth is not None and "clearance" in truth.columns else None
        viz.log_clearance(rows["t"], rows["clearance_m"], rows["sigma_m"], truth_m)

