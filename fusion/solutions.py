"""Relative-heave solutions: which measurements feed which filter, run causally.

Each solution is one HeaveFilter fed by some measurement methods. Measurements arrive at
their acquisition time plus the sensor's latency (scenario key `<sensor>.latency_s`); the
estimate at time t uses only what has arrived by t, and the filter places late
measurements at their acquisition time (exact out-of-sequence handling), so a known
latency does not bias the estimate.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.data.scenario import Scenario
from boomtip.fusion.heave_filter import HeaveFilter, HeaveFilterConfig, Measurement, jerk_psd_from_sea_state
from boomtip.fusion.tuning import relative_heave_components
from boomtip.perception.pipeline import SENSOR_OF, Measurement as Row

SOLUTIONS: dict[str, tuple[str, ...]] = {
    "deck_lidar": ("deck_lidar",),
    "deck_radar": ("deck_radar",),
    "reflectors_lidar": ("reflectors_lidar",),
    "doppler_radar": ("doppler_radar",),
    "fused": ("deck_lidar", "doppler_radar_rot", "reflectors_lidar"),
}


class FusionConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    solutions: tuple[str, ...] = tuple(SOLUTIONS)
    output_rate_hz: float = Field(100.0, gt=0)
    gate_chi2_probability: float = Field(0.9999, gt=0, lt=1)
    max_delay_s: float = Field(1.0, ge=0, description="oldest measurement the filters still place in sequence")
    floor_sigma_D_m: float = Field(
        0.5e-3, ge=0, description="added to every D sigma: what no fit sees (surface detail, marker placement, "
        "mesh facets); with ideal sensors a fit claims micrometres and methods that differ by a millimetre gate each other out",
    )
    floor_sigma_D_dot_mps: float = Field(
        3e-3, ge=0, description="the same for D-dot: the rotation-aware Doppler's deck spin comes from a 1 s window "
        "of deck normals, an error its velocity fit cannot see (1.4-3.5 mm/s rms in the evaluation scenarios)",
    )


@dataclass
class Estimates:
    solution: str
    t_s: np.ndarray
    x: np.ndarray  # (T,3) D, D_dot, D_ddot
    var: np.ndarray  # (T,3) diagonal of P
    filter_ms: float  # time spent in the filter (adds and estimates)
    inputs: int  # measurements offered
    statuses: dict[str, int]


def measurement_sigma(row: Row, s: Scenario, cfg: "FusionConfig | None" = None) -> float:
    """The fit's own sigma plus what the fit cannot see: the wire direction's error from the
    MRU (D x tan(deck tilt) x angle noise, with the scenario's tilt) for D measurements, and
    a floor for unmodelled detail."""
    cfg = cfg or FusionConfig()
    sigma = row.sigma if np.isfinite(row.sigma) and row.sigma > 0 else np.nan
    if row.quantity == "D":
        tilt = np.deg2rad(max(abs(s.feeder.motion.pitch.amplitude), abs(s.feeder.motion.roll.amplitude)) +
                          max(abs(s.crane.motion.pitch.amplitude), abs(s.crane.motion.roll.amplitude)))
        mru = abs(row.value) * np.tan(tilt) * np.deg2rad(s.mru.angle_noise_deg)
        return float(np.sqrt(sigma**2 + mru**2 + cfg.floor_sigma_D_m**2))
    return float(np.hypot(sigma, cfg.floor_sigma_D_dot_mps))


def filter_config(s: Scenario, cfg: FusionConfig) -> HeaveFilterConfig:
    q = jerk_psd_from_sea_state(relative_heave_components(s))
    return HeaveFilterConfig(jerk_psd=max(q, 1e-6), gate_chi2_probability=cfg.gate_chi2_probability, max_delay_s=cfg.max_delay_s)


def run_solution(name: str, rows: list[Row], s: Scenario, cfg: FusionConfig, duration_s: float) -> Estimates:
    methods = SOLUTIONS[name]
    latency = {"lidar": s.lidar.latency_s, "radar": s.radar.latency_s}
    inputs = []
    for r in rows:
        if r.method in methods and r.ok:
            sigma = measurement_sigma(r, s, cfg)
            if np.isfinite(sigma) and sigma > 0:
                arrival = r.t_s + latency[SENSOR_OF[r.method]]
                inputs.append(Measurement(r.t_s, arrival, r.quantity, r.value, sigma, r.method))
    inputs.sort(key=lambda m: (m.t_arrival_s, m.t_acq_s))
    initial_D = None
    if name == "doppler_radar":
        # Doppler alone measures no distance: start from the radar's first deck detection, then
        # integrate D-dot (document 000 reports the resulting drift).
        first = next((r for r in rows if r.method == "deck_radar" and r.ok), None)
        initial_D = first.value if first else None
    filt = HeaveFilter(filter_config(s, cfg), initial_D=initial_D)
    t_out = np.arange(int(np.floor(duration_s * cfg.output_rate_hz)) + 1) / cfg.output_rate_hz
    x = np.full((len(t_out), 3), np.nan)
    var = np.full((len(t_out), 3), np.nan)
    statuses: dict[str, int] = {}
    j = 0
    t0 = time.perf_counter()
    for k, t in enumerate(t_out):
        while j < len(inputs) and inputs[j].t_arrival_s <= t + 1e-9:
            st = filt.add(inputs[j])
            statuses[st] = statuses.get(st, 0) + 1
            j += 1
        if np.isfinite(filt.last_time_s) and t >= filt.last_time_s:
            xk, Pk = filt.estimate(t)
            x[k] = xk
            var[k] = np.diag(Pk)
    filter_ms = (time.perf_counter() - t0) * 1e3
    return Estimates(name, t_out, x, var, filter_ms, len(inputs), statuses)
