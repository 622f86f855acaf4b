"""Relative-heave solutions: which measurements feed which filter, run causally.

Each solution is one HeaveFilter fed by some measurement methods. Measurements arrive at
their acquisition time plus the sensor's specified latency (the caller stamps
`t_arrival_s`); the estimate at time t uses only what has arrived by t, and the filter places
late measurements at their acquisition time (exact out-of-sequence handling), so a known
latency does not bias the estimate. Fusion takes plain `heave_filter.Measurement`s: it knows
neither perception's types nor the world.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.fusion.consistency import Innovations, consistent_rows
from boomtip.fusion.deck_fallback import radar_deck_bridge
from boomtip.fusion.heave_filter import HeaveFilter, HeaveFilterConfig, Measurement
from boomtip.fusion.tuning import default_jerk_psd, relative_heave_jerk_psd
from boomtip.fusion.wave_predictor import fit_ar, forecast

LIDAR_DISTANCES = ("deck_lidar", "reflectors_lidar")
SOLUTIONS: dict[str, tuple[str, ...]] = {
    "deck_lidar": ("deck_lidar",),
    "deck_radar": ("deck_radar",),
    "reflectors_lidar": ("reflectors_lidar",),
    "doppler_radar": ("doppler_radar",),
    "fused": ("deck_lidar", "doppler_radar_rot", "reflectors_lidar"),
}


class FusionConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    solutions: tuple[Literal["deck_lidar", "deck_radar", "reflectors_lidar", "doppler_radar", "fused"], ...] = tuple(SOLUTIONS)
    output_rate_hz: float = Field(100.0, gt=0)
    gate_chi2_probability: float = Field(0.9999, gt=0, lt=1)
    max_delay_s: float = Field(1.0, ge=0, description="oldest measurement the filters still place in sequence")
    floor_sigma_D_m: float = Field(
        0.5e-3, ge=0, description="added to every D sigma: what no fit sees (surface detail, marker placement, "
        "mesh facets); with ideal sensors a fit claims micrometres and methods that differ by a millimetre gate each other out",
    )
    jerk_psd: float | None = Field(
        None, gt=0, description="white-jerk PSD q [m^2/s^5]; null: from processing.sea_state, else the "
        "working limit (Hs 4 m, Tp 7 s)",
    )
    wave_predictor: bool = Field(True, description="bridge a silence of every sensor with an AR model of the recent D")
    predict_after_s: float = Field(1.0, gt=0, description="silence after which the wave predictor takes over")
    predictor_history_s: float = Field(60.0, gt=5, description="the recent D the AR model is fitted to")
    predictor_rate_hz: float = Field(4.0, gt=0, description="the AR model's sample rate")
    predictor_order: int = Field(12, ge=2, le=64)
    floor_sigma_D_dot_mps: float = Field(
        3e-3, ge=0, description="the same for D-dot: the rotation-aware Doppler's deck spin comes from a 1 s window "
        "of deck normals, an error its velocity fit cannot see (a few mm/s)",
    )
    floor_D_dot_correlation_s: float = Field(1.0, ge=0, description="the D-dot floor is one error over this long (the "
                                             "deck spin's window of normals): frames within it share it (0: independent)")
    lost_sigma_D_m: float = Field(
        0.25, gt=0, description="an estimate whose D sigma exceeds this is lost: written with its reason, never "
        "as a D to use (a crane cannot land a load on a deck known to within a quarter metre)",
    )
    lost_sigma_D_dot_mps: float = Field(0.5, gt=0, description="likewise for D-dot")
    error_correlation_s: float = Field(0.05, ge=0, description="a method's frames closer than this share their "
                                       "errors: each one's variance grows by this over its interval (0: independent)")
    radar_deck_bridge: bool = Field(True, description="through a LiDAR outage the fused solution also takes the radar's deck "
                                    "distance, moved by its offset from the LiDAR's as learnt before (fusion.deck_fallback)")
    radar_deck_after_s: float = Field(0.5, gt=0, description="the LiDAR silent this long: the radar's deck joins")
    radar_deck_window_s: float = Field(30.0, gt=0, description="the radar-minus-LiDAR offset: over this much before")
    noise_memory_s: float = Field(5.0, ge=0, description="a method noisier than its stated sigma has its variance widened "
                                  "to match its recent innovations over about this long (0: the stated sigmas)")


@dataclass
class Estimates:
    solution: str
    t_s: np.ndarray
    x: np.ndarray  # (T,3) D, D_dot, D_ddot
    var: np.ndarray  # (T,3) diagonal of P
    filter_ms: float  # time spent in the filter (adds and estimates)
    inputs: int  # measurements offered
    statuses: dict[str, int]
    lost: "Lost | None" = None  # which estimates are lost, and why: lost_estimates
    innovations: Innovations | None = None  # every update's NIS per stream (fusion.consistency)
    consistent: np.ndarray | None = None  # (T,) bool: no stream's trailing NIS beyond its bound


@dataclass
class Lost:
    """Which of a solution's estimates no measurement holds (per output row), and why."""

    D: np.ndarray  # (T,) bool: the D (and D-ddot) is lost
    D_dot: np.ndarray  # (T,) bool: the D-dot is lost
    why: np.ndarray  # (T,) str: "" where neither is, else the reasons


def lost_estimates(x: np.ndarray, var: np.ndarray, cfg: FusionConfig, max_D_m: float = np.inf) -> Lost:
    """Per estimate (rows of x, var: D, D-dot, D-ddot): a D is lost when its sigma exceeds
    cfg.lost_sigma_D_m (no measurement has held it for a while) or no sensor could measure it
    (at or above the boom tip, beyond the sensors' range); a D-dot when its sigma exceeds
    cfg.lost_sigma_D_dot_mps. Causal: each row judged on its own state. Rows without an
    estimate are not lost (they are not written)."""
    sd = np.sqrt(np.maximum(var[:, :2], 0.0))
    D = x[:, 0]
    have = np.isfinite(D)
    sigma_D = have & (sd[:, 0] > cfg.lost_sigma_D_m)
    range_D = have & ~sigma_D & ~((D > 0.0) & (D <= max_D_m))
    sigma_V = have & (sd[:, 1] > cfg.lost_sigma_D_dot_mps)
    why = np.full(len(D), "", dtype=object)
    for mask, text in ((sigma_D, f"D sigma beyond {cfg.lost_sigma_D_m:g} m"),
                       (range_D, f"D outside the sensors' 0 to {max_D_m:g} m"),
                       (sigma_V, f"D-dot sigma beyond {cfg.lost_sigma_D_dot_mps:g} m/s")):
        why[mask] = np.where(why[mask] == "", "lost: " + text, why[mask] + "; " + text)
    return Lost(sigma_D | range_D, sigma_V, why)


def with_floor(m: Measurement, cfg: FusionConfig, interval_s: float = math.inf) -> Measurement | None:
    """The fit's own sigma plus what no fit sees (a floor per quantity); None for a sigma
    that is not a positive finite number. The D-dot floor is one error shared by the frames
    of `floor_D_dot_correlation_s` (the deck spin's window): a frame interval_s after the last
    of its source carries its variance times that over the interval, so twenty frames in that
    window do not average it away (a LiDAR outage integrates it into D)."""
    if not (np.isfinite(m.sigma) and m.sigma > 0 and np.isfinite(m.value)):
        return None
    if m.quantity == "D":
        return replace(m, sigma=float(np.hypot(m.sigma, cfg.floor_sigma_D_m)))
    shared = max(1.0, cfg.floor_D_dot_correlation_s / interval_s) if interval_s > 0 else 1.0
    return replace(m, sigma=float(np.hypot(m.sigma, cfg.floor_sigma_D_dot_mps * math.sqrt(shared))))


def with_floors(measurements: list[Measurement], cfg: FusionConfig) -> list[Measurement]:
    """with_floor of each (in acquisition order per source, for the intervals); the ones
    without a usable sigma dropped."""
    out, last = [], {}
    for m in sorted(measurements, key=lambda m: m.t_acq_s):
        key = (m.source, m.quantity)
        m2 = with_floor(m, cfg, m.t_acq_s - last.get(key, -math.inf))
        if m2 is not None:
            last[key] = m.t_acq_s
            out.append(m2)
    return out


def shared_errors(measurements: list[Measurement], correlation_s: float) -> list[Measurement]:
    """Each measurement's sigma widened by sqrt(correlation_s / its interval from the last of
    its source) where that interval is shorter: frames that close share their errors (the
    levelling's attitude, the deck's waves), so a faster sensor does not claim more certainty
    per second than independent frames at correlation_s give."""
    if correlation_s <= 0:
        return measurements
    out, last = [], {}
    for m in sorted(measurements, key=lambda m: m.t_acq_s):
        dt = m.t_acq_s - last.get((m.source, m.quantity), -math.inf)
        last[(m.source, m.quantity)] = m.t_acq_s
        out.append(replace(m, sigma=m.sigma * math.sqrt(correlation_s / dt)) if 0 < dt < correlation_s else m)
    return out


def jerk_psd(cfg: FusionConfig, sea_state: tuple[float, float] | None = None) -> float:
    """q from the configuration, else from a forecast (hs_m, tp_s), else the working limit."""
    if cfg.jerk_psd is not None:
        return cfg.jerk_psd
    if sea_state is not None:
        return relative_heave_jerk_psd(*sea_state)
    return default_jerk_psd()


def filter_config(cfg: FusionConfig, q: float) -> HeaveFilterConfig:
    return HeaveFilterConfig(jerk_psd=q, gate_chi2_probability=cfg.gate_chi2_probability, max_delay_s=cfg.max_delay_s,
                             noise_memory_s=cfg.noise_memory_s)


def run_solution(name: str, measurements: list[Measurement], cfg: FusionConfig, duration_s: float,
                 sea_state: tuple[float, float] | None = None, methods: tuple[str, ...] | None = None,
                 t_start_s: float = 0.0, max_D_m: float = np.inf) -> Estimates:
    """One solution over every method's measurements (`source` = method name), causally, on
    the output grid of integer ticks of 1 / output_rate_hz. `methods` overrides the
    solution's own sources (a fused solution falling back on the radar's deck). max_D_m: the
    sensors' range, beyond which a D is lost (lost_estimates)."""
    methods = methods or SOLUTIONS[name]
    own = [m for m in measurements if m.source in methods]
    if name == "fused" and cfg.radar_deck_bridge and "deck_radar" not in methods:  # through a LiDAR outage
        lidar_D = tuple(m for m in methods if m in LIDAR_DISTANCES)
        own += radar_deck_bridge(measurements, lidar_D, "deck_radar", cfg.radar_deck_after_s, cfg.radar_deck_window_s)
    # the fits' own sigmas shared by close frames first, then the floors (the D-dot floor's own sharing)
    inputs = with_floors(shared_errors([m for m in own if np.isfinite(m.sigma) and m.sigma > 0 and np.isfinite(m.value)],
                                       cfg.error_correlation_s), cfg)
    streams = {m.source for m in inputs}
    inputs.sort(key=lambda m: (m.t_arrival_s, m.t_acq_s))
    initial_D = None
    if name == "doppler_radar":
        # Doppler alone measures no distance: start from the radar's first deck detection, then
        # integrate D-dot (document 000 reports the resulting drift).
        first = next((m for m in measurements if m.source == "deck_radar" and np.isfinite(m.value)), None)
        initial_D = first.value if first else None
    filt = HeaveFilter(filter_config(cfg, jerk_psd(cfg, sea_state)), initial_D=initial_D)
    first = int(np.ceil(t_start_s * cfg.output_rate_hz - 1e-6))
    last = int(np.floor((t_start_s + duration_s) * cfg.output_rate_hz + 1e-6))
    ticks = np.arange(first, max(last, first - 1) + 1)
    t_out = ticks / cfg.output_rate_hz
    x = np.full((len(t_out), 3), np.nan)
    var = np.full((len(t_out), 3), np.nan)
    statuses: dict[str, int] = {}
    waves = _WaveBridge(cfg)
    sys_var_D = 0.0  # the latest accepted D's systematic variance: a bias the filter cannot see
    clock_s = {"D": 0.0, "D_dot": 0.0}  # the latest accepted D's and D-dot's time-stamp sigma: the same kind of bias
    j = 0
    t0 = time.perf_counter()
    for k, (tick, t) in enumerate(zip(ticks, t_out)):
        # Compare in ticks of the output grid: 15 * 0.01 > 0.15 in floating point.
        while j < len(inputs) and inputs[j].t_arrival_s * cfg.output_rate_hz <= tick + 1e-6:
            for seed in waves.handover(filt.last_time_s):  # the bridge's end state re-seeds the filter
                filt.add(seed)
            st = filt.add(inputs[j])
            statuses[st] = statuses.get(st, 0) + 1
            if st in ("accepted", "reinitialised"):
                clock_s[inputs[j].quantity] = inputs[j].sigma_clock_s
                if inputs[j].quantity == "D":
                    sys_var_D = inputs[j].sigma_systematic ** 2
            j += 1
        if np.isfinite(filt.last_time_s) and t * cfg.output_rate_hz >= filt.last_time_s * cfg.output_rate_hz - 1e-6:
            xk, Pk = filt.estimate(max(t, filt.last_time_s))
            x[k] = xk
            var[k] = np.diag(Pk)
            var[k, 0] += sys_var_D + (xk[1] * clock_s["D"]) ** 2  # a D read at the wrong instant: off by D-dot dt
            var[k, 1] += (xk[2] * clock_s["D_dot"]) ** 2
            if cfg.wave_predictor and name != "doppler_radar":
                waves.step(tick, t, t - filt.last_time_s, x[k], var[k])
    innovations = filt.innovations().only(streams)  # not the wave bridge's hand-over
    filter_ms = (time.perf_counter() - t0) * 1e3
    return Estimates(name, t_out, x, var, filter_ms, len(inputs), statuses, lost_estimates(x, var, cfg, max_D_m),
                     innovations, consistent_rows(t_out, innovations))


class _WaveBridge:
    """Keeps the recent D on the predictor's grid while the sensors speak; when every one has
    been silent for `predict_after_s`, replaces the constant-acceleration extrapolation by the
    AR forecast (fusion.wave_predictor) from the last fresh sample, variance and all."""

    def __init__(self, cfg: FusionConfig) -> None:
        self.cfg = cfg
        self.every = max(1, int(round(cfg.output_rate_hz / cfg.predictor_rate_hz)))
        self.dt = self.every / cfg.output_rate_hz
        self.keep = int(cfg.predictor_history_s / self.dt)
        self.hist: list[float] = []
        self.hist_var = 0.0
        self.t_last = float("nan")
        self.model = None
        self.fc: tuple[np.ndarray, np.ndarray] | None = None
        self.last_out: tuple[float, float, float, float, float] | None = None

    def handover(self, t_filter_s: float) -> list[Measurement]:
        """When the sensors speak again after a bridge: the forecast's last D and D-dot as
        measurements, so the filter (whose extrapolation ran away meanwhile) restarts there."""
        if not self.model or self.last_out is None:
            return []
        t, D, V, var_D, var_V = self.last_out
        self.model = self.fc = self.last_out = None
        if not t > t_filter_s:
            return []
        return [Measurement(t, t, "D", D, float(np.sqrt(var_D)), "wave_predictor"),
                Measurement(t, t, "D_dot", V, float(np.sqrt(var_V)), "wave_predictor")]

    def step(self, tick: int, t: float, silence_s: float, x: np.ndarray, var: np.ndarray) -> None:
        if silence_s <= self.cfg.predict_after_s:
            self.model = self.fc = self.last_out = None
            # history only from estimates a measurement has just corrected (not extrapolations)
            if tick % self.every == 0 and silence_s <= 0.5 * self.cfg.predict_after_s:
                if self.hist and abs(t - self.t_last - self.dt) > 1e-6:
                    self.hist = []  # a hole in the history: start it again
                self.hist.append(float(x[0]))
                self.hist = self.hist[-self.keep:]
                self.t_last, self.hist_var = t, float(var[0])
            return
        if self.model is None:
            enough = len(self.hist) >= max(3 * self.cfg.predictor_order, self.keep // 3)  # 20 s of a 60 s history
            self.model = fit_ar(np.array(self.hist), self.cfg.predictor_order, self.dt) if enough else False
        if not self.model:
            return
        u = (t - self.t_last) / self.dt  # forecast steps since the last fresh sample
        need = int(np.ceil(u)) + 2
        if self.fc is None or len(self.fc[0]) < need:
            self.fc = forecast(self.model, np.array(self.hist), max(need, 2 * (len(self.fc[0]) if self.fc else 8)))
        grid = np.arange(1, len(self.fc[0]) + 1)
        values = np.concatenate([[self.hist[-1]], self.fc[0]])
        variance = np.concatenate([[0.0], self.fc[1]])
        x[0] = np.interp(u, np.concatenate([[0.0], grid]), values)
        x[1] = np.interp(u, np.concatenate([[0.0], grid]), np.gradient(values, self.dt))
        x[2] = np.nan
        var[0] = np.interp(u, np.concatenate([[0.0], grid]), variance) + self.hist_var
        var[1] = var[0] * (2 * np.pi / 8.0) ** 2  # D-dot of a wave of ~8 s: its D's sigma times omega
        self.last_out = (t, float(x[0]), float(x[1]), float(var[0]), float(var[1]))
