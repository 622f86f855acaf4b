"""The clearance's rate from one radar scan (levelled frame, as perception.lift's): how fast the
load's lowest point and its underside's centre close on the deck below them, from the range
rates of the load's and of the deck's detections.

    detections -> the load's (in its box about the rope's line, as the LiDAR's last fix placed it)
                  and the deck's (near the deck's plane in a ring beyond the load)
    deck: rigid, r_i = b_i . u exactly (perception.doppler) -> u by a robust fit; a point x of
          it moves at u + w_deck x (x - o) relative to the radar, w_deck the deck's spin
    load: its detections' beams lie within a few degrees, too close for a 3-D fit: each one's
          vertical velocity given its horizontal (the hook's, from the hook tracker); their
          robust mean, carried to the lowest point with the load's tilting (w_load, the rope's)
    C-dot = the load's vertical velocity there - the deck's, + the deck's slope times how fast
            the deck slides under the point (the height is over the deck straight below it)

The sensor's own motion (the boom tip slewing, luffing, flexing) is in both velocities alike
and cancels: both are relative to the same radar. Only the hook's horizontal velocity, the
tracker's, is relative to the tip instead: the radar's offset from it turning with the tip adds
centimetres a second at most, which reach the vertical through the load beams' few degrees of
tilt (a millimetre a second). The load is taken to turn with the rope's line; a load swinging
on its slings as well turns otherwise, and its lowest corner's rate with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.perception.doppler import DopplerConfig, doppler_velocity
from boomtip.perception.lift import LoadClearance, chance_lowest, chance_weighted, index_mask, plane_height_at, rope_line_xy
from boomtip.perception.preprocess import PreprocessConfig

__all__ = ["LiftRadarConfig", "ClearanceRate", "measure_clearance_rate", "load_spin"]

STATUS_OK = "ok"
MAD_TO_SIGMA = 1.4826


class LiftRadarConfig(BaseModel):
    """Which radar detections are the load's and the deck's, and how many each needs."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(True, description="the clearance's rate from the radar's Doppler, when the run has a radar")
    load_margin_m: float = Field(0.5, gt=0, description="the load's box grown by this: its detections")
    above_deck_m: float = Field(0.3, ge=0, description="the load's detections lie at least this far above the deck's plane")
    deck_gate_m: float = Field(0.5, gt=0, description="the deck's detections lie this close to the deck's plane")
    deck_ring_m: float = Field(10.0, gt=0, description="the deck's detections: a ring this wide beyond the load's footprint")
    min_load_points: int = Field(5, ge=2)
    min_deck_points: int = Field(20, ge=3)
    outlier_sigmas: float = Field(3.0, gt=0, description="a load detection this many robust sigmas off the median is left out")
    max_fix_age_s: float = Field(0.2, gt=0, description="the LiDAR's fix of the load and deck no older than this")
    deck_spin_sigma_radps: float = Field(0.002, ge=0, description="1-sigma of the deck's spin from its normals")
    unknown_deck_spin_sigma_radps: float = Field(0.05, ge=0, description="1-sigma of the deck's spin before its "
                                                 "normals tell it (a rolling ship's few degrees a second)")
    doppler: DopplerConfig = Field(default_factory=DopplerConfig)
    preprocess: PreprocessConfig = Field(PreprocessConfig(min_range_m=2.0, max_range_m=200.0),
                                         description="the detections' range window")


@dataclass
class ClearanceRate:
    """One scan's rates (m/s, positive when the gap opens) and their 1-sigma; status says why not."""

    status: str
    clearance_rate_mps: float = math.nan  # the lowest point's
    centre_rate_mps: float = math.nan  # the underside centre's
    sigma_mps: float = math.nan
    centre_sigma_mps: float = math.nan
    n_load: int = 0
    n_deck: int = 0
    load_mask: np.ndarray | None = None  # over the scan's detections: the load's (its fit's inliers)
    deck_mask: np.ndarray | None = None  # and the deck's

    @property
    def ok(self) -> bool:
        return self.status == STATUS_OK


def load_spin(hook_m: np.ndarray, hook_velocity_mps: np.ndarray) -> np.ndarray:
    """The hanging load's angular velocity (rad/s, levelled axes): it turns with the rope's line
    from the tip, r x r_dot / |r|^2 (its spin about the rope itself moves no point vertically)."""
    return np.cross(hook_m, hook_velocity_mps) / float(hook_m @ hook_m)


def _vertical_at(omega: np.ndarray, lever_m: np.ndarray) -> float:
    """The vertical velocity a spin omega gives a point lever_m away: (omega x lever)_z."""
    return float(omega[0] * lever_m[1] - omega[1] * lever_m[0])


def _load_vertical(b: np.ndarray, rate: np.ndarray, v_horizontal: np.ndarray, noise_mps: float,
                   cfg: LiftRadarConfig) -> tuple[float, float, np.ndarray] | None:
    """The load's vertical velocity relative to the radar from its detections' beams b (N,3) and
    range rates, given its horizontal velocity at each (N,2): (mean, 1-sigma, inliers)."""
    vz = (rate - np.einsum("ij,ij->i", b[:, :2], v_horizontal)) / b[:, 2]
    med = float(np.median(vz))
    spread = max(MAD_TO_SIGMA * float(np.median(np.abs(vz - med))), noise_mps)
    keep = np.abs(vz - med) <= cfg.outlier_sigmas * spread
    if np.count_nonzero(keep) < cfg.min_load_points:
        return None
    n = np.count_nonzero(keep)
    sigma = max(float(np.std(vz[keep])), noise_mps) / math.sqrt(n)
    return float(vz[keep].mean()), sigma, keep


def measure_clearance_rate(points_level: np.ndarray, origin_level: np.ndarray, range_rate_mps: np.ndarray,
                           fix: LoadClearance, footprint_radius_m: float, height_m: float, hook_m: np.ndarray,
                           hook_velocity_mps: np.ndarray, hook_velocity_cov: np.ndarray, deck_spin_radps: np.ndarray | None,
                           block_height_m: float, cfg: LiftRadarConfig, range_rate_noise_mps: float,
                           rng: np.random.Generator) -> ClearanceRate:
    """The rates of one scan: its detections levelled (points_level (N,3), the radar at
    origin_level), their range rates (positive receding); the LiDAR's last fix of the load and
    deck, the load's reach from the rope's line and its height (inf: unknown); the hook
    (position, velocity relative to the tip and its covariance) and the deck's spin (None:
    unknown, taken as none with its sigma)."""
    if not fix.ok:
        return ClearanceRate("no LiDAR fix of the load and deck")
    ok = np.all(np.isfinite(points_level), axis=1) & np.isfinite(range_rate_mps)
    pts, rate = points_level[ok], range_rate_mps[ok]
    if len(pts) < cfg.min_load_points:
        return ClearanceRate(f"too few detections: {len(pts)} in the scan")
    rel = pts - origin_level
    b = rel / np.linalg.norm(rel, axis=1, keepdims=True)
    d = np.linalg.norm(pts[:, :2] - rope_line_xy(hook_m, pts[:, 2]), axis=1)
    lowest, centre = fix.lowest_point_m, fix.underside_centre_m
    inner = footprint_radius_m + cfg.load_margin_m
    top = max(lowest[2], centre[2]) + height_m
    deck_z = plane_height_at(fix.deck_plane, pts[:, :2])
    load = (d <= inner) & (pts[:, 2] >= min(lowest[2], centre[2]) - cfg.load_margin_m)
    load &= (pts[:, 2] <= min(top + cfg.load_margin_m, hook_m[2] - block_height_m)) & (pts[:, 2] >= deck_z + cfg.above_deck_m)
    deck = (d > inner) & (d <= inner + cfg.deck_ring_m) & (np.abs(pts[:, 2] - deck_z) <= cfg.deck_gate_m)
    n_load, n_deck = int(np.count_nonzero(load)), int(np.count_nonzero(deck))
    if n_load < cfg.min_load_points or n_deck < cfg.min_deck_points:
        return ClearanceRate(f"too few detections: {n_load} on the load, {n_deck} on the deck", n_load=n_load, n_deck=n_deck)
    spin_load = load_spin(hook_m, hook_velocity_mps)
    along = hook_velocity_mps[:2] + np.cross(spin_load, pts[load] - hook_m)[:, :2]  # each load point's horizontal velocity
    load_fit = _load_vertical(b[load], rate[load], along, range_rate_noise_mps, cfg)
    deck_fit = doppler_velocity(rel[deck], rate[deck], cfg.doppler, rng, None)
    if load_fit is None or deck_fit is None:
        return ClearanceRate("no Doppler fit of the load or the deck", n_load=n_load, n_deck=n_deck)
    vz_load, sigma_load, inliers = load_fit
    # the hook's horizontal velocity, common to every load detection, reaches the vertical
    # through their mean beam's tilt: an error that no number of detections averages out
    b_mean = b[load][inliers].mean(axis=0)
    tilt = b_mean[:2] / b_mean[2]
    var_load = sigma_load**2 + float(tilt @ hook_velocity_cov[:2, :2] @ tilt)
    seen = pts[load][inliers].mean(axis=0)  # where the load's mean velocity holds
    spin_deck = np.zeros(3) if deck_spin_radps is None else deck_spin_radps
    spin_deck_sigma = cfg.deck_spin_sigma_radps if deck_spin_radps is not None else cfg.unknown_deck_spin_sigma_radps
    u_deck, cov_u_deck = deck_fit.velocity_sensor, deck_fit.covariance
    slope = fix.deck_plane[1:]  # dz/dx, dz/dy of the deck
    # the height above the deck straight below a point rises at minus the deck's velocity there
    # along a = (slope, -1): its vertical, less its slope times how fast it slides under the point
    a = np.array([slope[0], slope[1], -1.0])

    def closing(point: np.ndarray) -> tuple[float, float]:
        v_load = vz_load + _vertical_at(spin_load, point - seen)
        below = np.array([point[0], point[1], plane_height_at(fix.deck_plane, point[:2])])  # the deck's point under it
        lever = below - origin_level
        v_deck = u_deck + np.cross(spin_deck, lever)
        v_load_along = hook_velocity_mps[:2] + np.cross(spin_load, point - hook_m)[:2]
        rate = v_load + float(a @ v_deck) - float(slope @ v_load_along)
        # a . (w x lever) = w . (lever x a): the spin's error through the whole lever, the slope's way too
        var = var_load + float(a @ cov_u_deck @ a) + (spin_deck_sigma * float(np.linalg.norm(np.cross(lever, a)))) ** 2
        return rate, math.sqrt(var)

    # which corner is the lowest is itself uncertain when others lie within their sigmas of it:
    # the rate is each one's, weighted by its chance to be the lowest (their mixture's mean and
    # spread), not the one that happened to look lowest in this fix
    cand = fix.candidates_m if len(fix.candidates_m) else lowest[None, :]
    sigmas = (fix.candidate_sigmas_m if len(fix.candidate_sigmas_m) == len(cand) else np.full(len(cand), fix.sigma_m))
    chance = chance_lowest(cand[:, 2] - plane_height_at(fix.deck_plane, cand[:, :2]), sigmas)
    rates = np.array([closing(p) for p in cand])
    c_dot, s_c = chance_weighted(chance, rates[:, 0], rates[:, 1] ** 2)
    h_dot, s_h = closing(centre)
    load_idx, deck_idx = np.flatnonzero(ok)[load][inliers], np.flatnonzero(ok)[deck][deck_fit.inlier_mask]
    return ClearanceRate(STATUS_OK, c_dot, h_dot, s_c, s_h, n_load, n_deck, index_mask(len(ok), load_idx), index_mask(len(ok), deck_idx))
