"""The relative-heave pipeline: one frame in, measurements of D and D-dot out.

    LiDAR frame -> deck_lidar (D), reflectors_lidar (D)
    radar frame -> deck_radar (D), doppler_radar (D-dot, document 000), doppler_radar_rot (D-dot, exact)

The pipeline keeps the only state the methods need across frames: the latest deck plane
(for the rotation-aware Doppler) and the deck normal's history (for the deck's spin).
Each stage reports its own time; a row's time_ms is the sum of the stages its method ran plus
an equal share of the frame's attitude stage (FRAME_STAGES: the MRU lookup and level rotation
that every method of the frame takes as input), so that the frame's rows count it once between
them, not once each.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.data.frames import Frame, MruLog
from boomtip.data.installation import Installation
from boomtip.perception.deck import LIDAR_DECK, RADAR_DECK, DeckConfig, DeckResult, detect_deck, status_ok
from boomtip.perception.doppler import DopplerConfig, DopplerFit, doppler_velocity
from boomtip.perception.doppler_alias import WAIT_S, alias_prior_level, unwrap_range_rates
from boomtip.perception.doppler_gate import above_deck_only, beyond_deck_margin_m, doppler_band_mps
from boomtip.perception.geometry import (
    NormalRate,
    heave_rate_document,
    heave_rate_exact,
    level_rotation_rows,
    mat3_vec,
    mat3T_vec,
    mount_rotation,
    omega_from_euler_rates_floats,
    quad3,
    tip_above_waterline_m,
    tip_in_sensor,
)
from boomtip.perception.preprocess import PreprocessConfig
from boomtip.perception.reflectors import ReflectorConfig, ReflectorResult, detect_reflectors
from boomtip.perception.timing import StageTimes

METHODS = ("deck_lidar", "deck_radar", "reflectors_lidar", "doppler_radar", "doppler_radar_rot")
QUANTITY = {"deck_lidar": "D", "deck_radar": "D", "reflectors_lidar": "D", "doppler_radar": "D_dot", "doppler_radar_rot": "D_dot"}
SENSOR_OF = {"deck_lidar": "lidar", "reflectors_lidar": "lidar", "deck_radar": "radar", "doppler_radar": "radar", "doppler_radar_rot": "radar"}
# Each method's own stages. The two Doppler methods share one preprocessing and fit, and each
# counts it in full: it is that method's own maths, which it would run alone.
STAGES = {
    "deck_lidar": ("deck.preprocess", "deck.planes", "deck.refine", "deck.intersect"),
    "reflectors_lidar": ("reflectors.threshold", "reflectors.markers", "reflectors.plane"),
    "deck_radar": ("radar_deck.preprocess", "radar_deck.planes", "radar_deck.refine", "radar_deck.intersect"),
    "doppler_radar": ("doppler.preprocess", "doppler.fit", "doppler.document"),
    "doppler_radar_rot": ("doppler.preprocess", "doppler.fit", "doppler.rotation"),
}
# The frame's input to all its methods, once per frame: each row carries an equal share of it.
FRAME_STAGES = ("attitude",)
SENSOR_IDS = {"lidar": 1, "radar": 2}


class PipelineConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    methods: tuple[Literal["deck_lidar", "deck_radar", "reflectors_lidar", "doppler_radar", "doppler_radar_rot"], ...] = METHODS
    deck_lidar: DeckConfig = LIDAR_DECK
    deck_radar: DeckConfig = RADAR_DECK
    reflectors: ReflectorConfig = ReflectorConfig()
    doppler: DopplerConfig = DopplerConfig(start="trimmed")  # its band: from the radar's spec unless set here
    doppler_band_sigmas: float = Field(4.0, gt=0, description="Doppler inlier band: this many sigmas of the radar's "
                                       "stated range-rate noise and Doppler bin (uniform within a bin)")
    doppler_band_floor_mps: float = Field(0.1, gt=0, description="narrowest Doppler band: what the rigid-deck model "
                                          "leaves unexplained (the deck's spin across the footprint)")
    doppler_preprocess: PreprocessConfig = PreprocessConfig(min_range_m=2.0, max_range_m=150.0)
    normal_window_s: float = Field(1.0, gt=0, description="window of deck normals used for the deck's spin")
    max_deck_age_s: float = Field(0.5, gt=0, description="the rotation-aware Doppler uses a deck plane at most this old")
    max_abs_D_dot_mps: float = Field(15.0, gt=0, description="no sea moves a deck faster: beyond it a D-dot is implausible")
    deck_prior_tol_m: float = Field(0.5, gt=0, description="a deck plane must lie this near its prior (the reflectors' D)")
    beyond_waterline_m: float = Field(0.0, ge=0, description="a deck's D may pass the tip's height above the calm "
                                      "waterline by this much (the crane vessel's heave, which the MRU does not give): "
                                      "a feeder's deck stands higher above the sea than the crane vessel heaves")


def carried_deck_prior(cfg: PipelineConfig, t_s: float, last: tuple[float, float] | None) -> tuple[float | None, float]:
    """The last deck (t, D) carried forward as the deck search's prior and its tolerance (growing
    with its age at the sea's fastest D-dot); none once it is older than max_deck_age_s."""
    if last is not None and abs(t_s - last[0]) <= cfg.max_deck_age_s:  # abs: a frame may come late
        return last[1], cfg.deck_prior_tol_m + cfg.max_abs_D_dot_mps * abs(t_s - last[0])
    return None, 0.0


def doppler_inputs(frame: Frame, pc: PreprocessConfig) -> tuple[np.ndarray, np.ndarray] | None:
    """A radar frame's detections for the Doppler fit: the points (sensor frame, m; the fit
    normalises them to beam directions) and range rates (m/s) of the finite detections within
    the range window. None without a range_rate field. The radar reports each detection's
    range; without it, the norm of the point."""
    rr = frame.fields.get("range_rate")
    if rr is None:
        return None
    rng_m = frame.fields.get("range")
    if rng_m is None:
        rng_m = np.sqrt(np.einsum("ij,ij->i", frame.points_sensor, frame.points_sensor))
    # The bounds as numpy float64 scalars: a float32 range is compared in float64 (NEP 50), as
    # after a conversion to float64 (exact), without that conversion's call and array.
    keep = rng_m >= np.float64(max(pc.min_range_m, 1e-6))
    keep &= rng_m <= np.float64(pc.max_range_m)
    keep &= np.isfinite(rr)  # NaN compares False
    idx = keep.nonzero()[0]
    if len(idx) == len(keep):  # every detection kept: no gathers
        return frame.points_sensor, rr.astype(np.float64)
    # a few detections beyond the window in most scans: take is ~3x faster than a boolean gather
    return frame.points_sensor.take(idx, axis=0), rr.take(idx).astype(np.float64)


@dataclass
class Measurement:
    t_s: float
    method: str
    quantity: str
    value: float
    sigma: float
    time_ms: float
    status: str
    # 1-sigma of what does not average out over frames: the levelling's stated bias (mount
    # survey and MRU static accuracy) through the measured deck tilt
    sigma_systematic: float = 0.0

    @property
    def ok(self) -> bool:
        return status_ok(self.status)


@dataclass
class FrameResult:
    frame: Frame
    measurements: list[Measurement]
    times: StageTimes
    deck_lidar: DeckResult | None = None
    deck_radar: DeckResult | None = None
    reflectors: ReflectorResult | None = None
    doppler: DopplerFit | None = None
    extras: dict = field(default_factory=dict)


def attitude_sigma_D(D_m: float, plane_sensor: np.ndarray, wire_sensor: np.ndarray, sigma_rad: float) -> float:
    """1-sigma of D from the wire direction's error (the MRU's stated angle noise): tilting the
    wire by a small angle moves where it meets a plane tilted by theta from it by
    D tan(theta) per radian."""
    cos_t = min(abs(float(plane_sensor[:3] @ wire_sensor)), 1.0)
    tan_t = math.sqrt(max(1.0 - cos_t * cos_t, 0.0)) / max(cos_t, 1e-6)
    return abs(D_m) * tan_t * sigma_rad


class HeavePipeline:
    """Composes the stages; `process(frame)` returns that frame's measurements. Built from
    the installation (mounts, tip, MRU spec, marker height) and the processing settings."""

    def __init__(self, installation: Installation, mru: MruLog, cfg: PipelineConfig | None = None, seed: int = 0) -> None:
        self.installation, self.mru = installation, mru
        self.unambiguous_mps = installation.radar.unambiguous_range_rate_mps  # 0: the radar's rates never wrap
        self.beyond_deck_m = beyond_deck_margin_m(installation.radar.range_noise_m, installation.radar.range_resolution_m)
        self.cfg = cfg or PipelineConfig()
        self.seed = seed
        T_crane_boomtip, T_boomtip_sensor = installation.T_crane_boomtip(), installation.T_boomtip_sensor()
        self.p_tip = {s: tip_in_sensor(T_boomtip_sensor[s]) for s in ("lidar", "radar")}
        # The mount is fixed: sensor axes -> crane-vessel axes once, the MRU attitude per frame.
        self.R_crane_sensor = {s: mount_rotation(T_crane_boomtip, T_boomtip_sensor[s]) for s in ("lidar", "radar")}
        # the same as Python floats: the per-frame 3x3 arithmetic runs in floats (level_rotation_rows)
        self._R_crane_sensor_rows = {s: R.tolist() for s, R in self.R_crane_sensor.items()}
        self._p_tip_floats = {s: p.tolist() for s, p in self.p_tip.items()}
        self.normals = {"lidar": NormalRate(self.cfg.normal_window_s), "radar": NormalRate(self.cfg.normal_window_s)}
        self.last_deck: dict[str, tuple[float, float]] = {}  # sensor -> (t, D)
        self.last_doppler: tuple[float, np.ndarray] | None = None  # (t, u_sensor): prior for the next scan
        self.last_doppler_level: tuple[float, np.ndarray] | None = None  # (t, u_level): the next scan's alias prior
        self.first_radar_t: float | None = None  # the radar's first scan (the alias prior's wait)
        self.alias_prior_seen = False  # whether any scan has had an alias prior
        self.recent_decks = {"lidar": [], "radar": []}  # sensor -> its last two decks (t, D): the alias prior's D-dot
        self.mru_sigma_rad = float(np.deg2rad(installation.mru.angle_noise_deg))  # the MRU's stated noise
        self.bias_sigma_rad = {s: installation.levelling_bias_sigma_rad(s) for s in ("lidar", "radar")}
        if "inlier_threshold_mps" not in self.cfg.doppler.model_fields_set:
            self.cfg = self.cfg.model_copy(update={"doppler": self.cfg.doppler.model_copy(
                update={"inlier_threshold_mps": doppler_band_mps(installation.radar, self.cfg.doppler_band_sigmas,
                                                                 self.cfg.doppler_band_floor_mps)})})
        if "marker_height_m" not in self.cfg.reflectors.model_fields_set:  # the markers as the crew laid them
            self.cfg = self.cfg.model_copy(update={"reflectors": self.cfg.reflectors.model_copy(
                update={"marker_height_m": installation.markers.height_m})})

    def _wants(self, sensor: str) -> list[str]:
        return [m for m in self.cfg.methods if SENSOR_OF[m] == sensor
                and (m != "reflectors_lidar" or self.installation.markers.enabled)]

    def _rows(self, frame: Frame, results: dict[str, tuple[float, float, str]], times: StageTimes) -> list[Measurement]:
        rows = []
        share_ms = times.total(*FRAME_STAGES) / max(len(results), 1)
        for m, (v, s, status) in results.items():
            if status_ok(status):
                bad = self._implausible(frame.sensor, QUANTITY[m], v, s)
                status = bad or status
                if bad:
                    v, s = np.nan, np.nan
            rows.append(Measurement(frame.t_s, m, QUANTITY[m], v, s, times.total(*STAGES[m]) + share_ms, status))
        return rows

    def _implausible(self, sensor: str, quantity: str, value: float, sigma: float) -> str | None:
        """Why a value cannot be right, before it says ok: not finite, a D outside the sensor's
        range, a D-dot faster than any sea moves a deck (the installation's bounds)."""
        if not (math.isfinite(value) and math.isfinite(sigma)):
            return f"implausible: value {value:g} with sigma {sigma:g}"
        if sigma <= 0:  # every point agreeing exactly is no measurement of certainty
            return (f"degenerate fit: sigma {sigma:g} (the points agree exactly: too few, or values quantised "
                    "to one bin)")
        if quantity == "D":
            spec = getattr(self.installation, sensor)
            if not 0.0 < value <= spec.max_range_m:
                return f"implausible D = {value:.4g} m (expected 0 to the {sensor}'s {spec.max_range_m:g} m range)"
        elif abs(value) > self.cfg.max_abs_D_dot_mps:
            return f"implausible D-dot = {value:.4g} m/s (expected |D-dot| <= {self.cfg.max_abs_D_dot_mps:g} m/s)"
        return None

    def process(self, frame: Frame) -> FrameResult:
        times = StageTimes()
        wanted = self._wants(frame.sensor)
        if frame.error is not None:
            return FrameResult(frame, self._rows(frame, {m: (np.nan, np.nan, f"unreadable frame: {frame.error}") for m in wanted}, times), times)
        with times.stage("attitude"):
            att = self.mru.attitude(frame.t_s)
            if att is not None:
                rpy, rpy_rate = att
                # geometry.rotation_level_sensor with the mount's rotation cached, in floats; the
                # rotation and the wire (its third row negated: wire_dir_sensor) in one conversion
                R_rows = level_rotation_rows(rpy, self._R_crane_sensor_rows[frame.sensor])
                R_and_wire = np.array([*R_rows, [-v for v in R_rows[2]]])
                R_ls, wire = R_and_wire[:3], R_and_wire[3]
        if att is None:
            status = f"no MRU attitude at t={frame.t_s:.3f} s (outside the log or in a gap)"
            return FrameResult(frame, self._rows(frame, {m: (np.nan, np.nan, status) for m in wanted}, times), times)
        if len(frame) == 0:
            return FrameResult(frame, self._rows(frame, {m: (np.nan, np.nan, "empty frame") for m in wanted}, times), times)
        rng = self.frame_rng(frame)
        out = FrameResult(frame, [], times, extras={"R_level_sensor": R_ls, "wire_dir_sensor": wire})
        results: dict[str, tuple[float, float, str]] = {}
        p_tip = self.p_tip[frame.sensor]
        if frame.sensor == "lidar":
            # Reflectors first: their D (markers lie on the deck) is the deck search's prior, so
            # a sea that returns echoes below the deck is not taken for it.
            if "reflectors_lidar" in wanted:
                intensity = frame.fields.get("intensity")
                if intensity is None:
                    results["reflectors_lidar"] = (np.nan, np.nan, "frame has no intensity field")
                else:
                    out.reflectors = ref = detect_reflectors(frame.points_sensor, intensity, wire, p_tip, self.cfg.reflectors, rng, times)
                    sigma = ref.sigma_m
                    if ref.status == "ok":
                        sigma = math.hypot(sigma, attitude_sigma_D(ref.D_m, ref.plane_sensor, wire, self.mru_sigma_rad))
                    results["reflectors_lidar"] = (ref.D_m, sigma, ref.status)
            if "deck_lidar" in wanted:
                prior, tol = self._deck_prior(frame.t_s, "lidar", out.reflectors)
                out.deck_lidar = deck = detect_deck(frame.points_sensor, wire, p_tip, self.cfg.deck_lidar, rng, times, "deck",
                                                    prior_D_m=prior, prior_tol_m=tol, max_D_m=self.max_deck_D(rpy))
                results["deck_lidar"] = self._deck_row(deck, wire, p_tip, frame.t_s, "lidar", R_ls)
        else:
            if "deck_radar" in wanted:
                # the latest deck of either sensor as the prior: the sea's echoes make a plane below the deck
                # (its mirror image), and without a prior the lowest plane would be taken for it
                decks = [d for d in (self.last_deck.get("lidar"), self.last_deck.get("radar")) if d is not None]
                prior, tol = carried_deck_prior(self.cfg, frame.t_s, max(decks, key=lambda d: d[0]) if decks else None)
                out.deck_radar = deck = detect_deck(frame.points_sensor, wire, p_tip, self.cfg.deck_radar, rng, times, "radar_deck",
                                                    prior_D_m=prior, prior_tol_m=tol, max_D_m=self.max_deck_D(rpy))
                results["deck_radar"] = self._deck_row(deck, wire, p_tip, frame.t_s, "radar", R_ls)
            if {"doppler_radar", "doppler_radar_rot"} & set(wanted):
                results.update(self._doppler(frame, wanted, R_rows, rpy, rpy_rate, rng, times, out))
        out.measurements = self._rows(frame, results, times)
        planes = {"deck_lidar": out.deck_lidar, "reflectors_lidar": out.reflectors, "deck_radar": out.deck_radar}
        for row in out.measurements:
            fit = planes.get(row.method)
            if row.ok and fit is not None:
                row.sigma_systematic = attitude_sigma_D(row.value, fit.plane_sensor, wire, self.bias_sigma_rad[frame.sensor])
        return out

    def levelled_stages(self, frame: Frame, rpy_rad: np.ndarray, last_deck: dict[str, tuple[float, float]]) -> FrameResult:
        """The deck (and, for a radar frame, the Doppler fit) of a frame levelled with `rpy_rad`
        instead of the MRU's attitude (a forecast through a gap in its log): the pipeline's own
        stages, settings and random draws for the frame, reading the pipeline and changing nothing
        in it. No measurement rows. last_deck: sensor -> (t, D) of the last deck found this way
        (updated here); the later of it and the pipeline's own is the deck search's prior."""
        times = StageTimes()
        wire = -np.array(level_rotation_rows(rpy_rad, self._R_crane_sensor_rows[frame.sensor])[2])
        p_tip = self.p_tip[frame.sensor]
        rng = self.frame_rng(frame)
        out = FrameResult(frame, [], times)
        cfg = self.cfg
        sensors = ("lidar", "radar") if frame.sensor == "radar" else ("lidar",)  # the radar's, as in process
        decks = [d for s in sensors for d in (last_deck.get(s), self.last_deck.get(s)) if d is not None]
        prior, tol = carried_deck_prior(cfg, frame.t_s, max(decks, key=lambda d: d[0]) if decks else None)  # the latest
        if frame.sensor == "lidar":
            out.deck_lidar = deck = detect_deck(frame.points_sensor, wire, p_tip, cfg.deck_lidar, rng, times, "deck",
                                                prior_D_m=prior, prior_tol_m=tol, max_D_m=self.max_deck_D(rpy_rad))
        else:
            out.deck_radar = deck = detect_deck(frame.points_sensor, wire, p_tip, cfg.deck_radar, rng, times, "radar_deck",
                                                prior_D_m=prior, prior_tol_m=tol, max_D_m=self.max_deck_D(rpy_rad))
            inputs = doppler_inputs(frame, cfg.doppler_preprocess)
            if inputs is not None:  # as in process: what lies beyond this scan's deck is no deck
                inputs = above_deck_only(*inputs, deck, self.beyond_deck_m)
            if inputs is not None and len(inputs[0]) >= 3:
                wraps = self.unambiguous_mps > 0
                R_rows = level_rotation_rows(rpy_rad, self._R_crane_sensor_rows[frame.sensor]) if wraps else None
                rates = self._on_prior_branch(inputs[0], inputs[1], R_rows, self._alias_prior(frame.t_s))
                if rates is not None:
                    out.doppler = doppler_velocity(inputs[0], rates, cfg.doppler, rng, None)
        if deck.ok:
            last_deck[frame.sensor] = (frame.t_s, deck.D_m)
        return out

    def _alias_prior(self, t_s: float) -> np.ndarray | None:
        """The velocity (level axes) a scan's wrapped rates are unwrapped about (doppler_alias)."""
        decks = [self.recent_decks["lidar"], self.recent_decks["radar"]]
        return alias_prior_level(t_s, self.last_doppler_level, decks, self.unambiguous_mps)

    def _on_prior_branch(self, pts, rates, R_rows, u_prior) -> np.ndarray | None:
        """The rates as reported by a radar that never wraps; else put back on u_prior's branch
        (R_rows: level from sensor), None without a prior."""
        if self.unambiguous_mps <= 0:
            return rates
        if u_prior is None:
            return None
        return unwrap_range_rates(pts, rates, self.unambiguous_mps, mat3T_vec(R_rows, u_prior))

    def frame_rng(self, frame: Frame) -> np.random.Generator:
        """The frame's random draws (RANSAC), from the run's seed, the sensor and the frame's index."""
        return np.random.default_rng([self.seed, SENSOR_IDS[frame.sensor], frame.index])

    def max_deck_D(self, rpy_rad) -> float | None:
        """How far down the wire a deck can lie: to the calm sea below the tip (None: the waterline unknown)."""
        geometry = self.installation.crane.geometry
        if geometry.waterline_z_m is None:
            return None
        return tip_above_waterline_m(rpy_rad, geometry.boom_tip_m, geometry.waterline_z_m) + self.cfg.beyond_waterline_m

    def _deck_prior(self, t_s: float, sensor: str, reflectors: ReflectorResult | None) -> tuple[float | None, float]:
        """Where the deck is expected: this frame's reflector D, else the last deck of this
        sensor carried forward (the tolerance grows with its age at the sea's fastest D-dot)."""
        if reflectors is not None and reflectors.status == "ok" and self._implausible(sensor, "D", reflectors.D_m, 1.0) is None:
            return reflectors.D_m, self.cfg.deck_prior_tol_m
        return carried_deck_prior(self.cfg, t_s, self.last_deck.get(sensor))

    def _deck_row(self, deck: DeckResult, wire, p_tip, t_s: float, sensor: str, R_ls) -> tuple[float, float, str]:
        if not deck.ok:
            return (np.nan, np.nan, deck.status)
        self.normals[sensor].add(t_s, R_ls @ deck.plane_sensor[:3])
        self.last_deck[sensor] = (t_s, deck.D_m)
        self.recent_decks[sensor] = [*self.recent_decks[sensor][-1:], (t_s, deck.D_m)]
        sigma = math.hypot(deck.sigma_m, attitude_sigma_D(deck.D_m, deck.plane_sensor, wire, self.mru_sigma_rad))
        return (deck.D_m, sigma, deck.status)

    def _doppler(self, frame, wanted, R_rows, rpy, rpy_rate, rng, times, out) -> dict:
        res: dict[str, tuple[float, float, str]] = {}
        with times.stage("doppler.preprocess"):
            inputs = doppler_inputs(frame, self.cfg.doppler_preprocess)
            if inputs is None:
                return {m: (np.nan, np.nan, "frame has no range_rate field") for m in wanted if m.startswith("doppler")}
            pts, range_rate_mps = inputs
            pts, range_rate_mps = above_deck_only(pts, range_rate_mps, out.deck_radar, self.beyond_deck_m)
            if self.unambiguous_mps > 0:  # the radar's wrapped rates back on the prior's branch
                u_prior = self._alias_prior(frame.t_s)
                self.first_radar_t = frame.t_s if self.first_radar_t is None else self.first_radar_t
                self.alias_prior_seen |= u_prior is not None
                if u_prior is None and not self.alias_prior_seen and frame.t_s - self.first_radar_t > WAIT_S:
                    u_prior = np.zeros(3)  # never a deck nor a velocity: the rates as reported
                range_rate_mps = self._on_prior_branch(pts, range_rate_mps, R_rows, u_prior)
                if range_rate_mps is None:
                    return {m: (np.nan, np.nan, "Doppler alias unknown: no recent velocity or deck distances yet")
                            for m in wanted if m.startswith("doppler")}
        with times.stage("doppler.fit"):
            prior = self.last_doppler[1] if self.last_doppler and frame.t_s - self.last_doppler[0] <= 0.2 else None
            fit = doppler_velocity(pts, range_rate_mps, self.cfg.doppler, rng, prior) if len(pts) >= 3 else None
            if fit is not None:  # to level axes, where D-dot is defined (Python floats: 3x3 algebra)
                u_level = mat3_vec(R_rows, fit.velocity_sensor.tolist())
                cov = fit.covariance.tolist()  # sensor axes: each method takes the variance it needs
        out.doppler = fit
        self.last_doppler = (frame.t_s, fit.velocity_sensor) if fit is not None else None
        self.last_doppler_level = (frame.t_s, np.array(u_level)) if fit is not None else self.last_doppler_level
        if fit is None:
            return {m: (np.nan, np.nan, f"no Doppler velocity ({len(pts)} detections or degenerate beams)") for m in wanted if m.startswith("doppler")}
        if "doppler_radar" in wanted:
            with times.stage("doppler.document"):
                var = quad3(cov, R_rows[2])  # R C R^T's (2, 2) element
                res["doppler_radar"] = (heave_rate_document(u_level), math.sqrt(var) if var >= 0.0 else math.nan, "ok")
        if "doppler_radar_rot" in wanted:
            with times.stage("doppler.rotation"):
                res["doppler_radar_rot"] = self._doppler_rot(frame.t_s, u_level, cov, R_rows, rpy, rpy_rate,
                                                             self._p_tip_floats[frame.sensor])
        return res

    def _doppler_rot(self, t_s, u_level, cov_sensor, R_rows, rpy, rpy_rate, p_tip) -> tuple[float, float, str]:
        """u_level, the rotation's rows, the tip (sensor axes) and the fit's covariance (sensor
        axes) as Python floats: every vector here is 3-long."""
        # Deck normal, spin and D from the LiDAR when it has a recent deck, else from the radar.
        for sensor in ("lidar", "radar"):
            last = self.last_deck.get(sensor)
            if last is None or t_s - last[0] > self.cfg.max_deck_age_s:
                continue
            omega_f = self.normals[sensor].omega_floats(t_s)
            if omega_f is None:
                continue
            n = self.normals[sensor].normal_floats(t_s)
            omega_c = omega_from_euler_rates_floats(rpy, rpy_rate)
            r_tip = mat3_vec(R_rows, p_tip)
            value = heave_rate_exact(u_level, n, omega_f, omega_c, r_tip, last[1])
            # Besides the fit: an attitude error tilts the (large) horizontal relative velocity
            # into the vertical when u is levelled; the MRU's stated noise sizes that term.
            tilt_var = (math.hypot(u_level[0], u_level[1]) * self.mru_sigma_rad) ** 2
            # n^T (R C R^T) n = (R^T n)^T C (R^T n): the level covariance is never formed
            sigma = math.sqrt(quad3(cov_sensor, mat3T_vec(R_rows, n)) + tilt_var) / abs(n[2])
            return (value, sigma, "ok")
        return (np.nan, np.nan, "no recent deck plane for the deck's normal and spin")
