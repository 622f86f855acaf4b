"""Sensor models at the boom tip: LiDAR (grid or spinning), radar, MRU.

Sensor frame convention: a ray with azimuth az (about the sensor z axis, from x) and
elevation el (towards z) points along [cos el cos az, cos el sin az, sin el]. With the
default mount the boresight x looks straight down, y runs along the ship and z across.

The pattern functions give ray directions and per-ray timing; the measure functions turn
ray-cast hits into what the sensor reports (noise, quantisation, intensity, dropouts).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from boomtip.data.io.beams import beam_angles_deg
from boomtip.data.sim.fans import Fans
from boomtip.data.sim.footprint import thinned_returns, with_second_returns
from boomtip.data.sim.raycast import Hits, face_offsets
from boomtip.data.sim.world import Lidar, Radar
from boomtip.data.meshes import RCS_DETECTION_FACTOR, Body, Label

INTENSITY_REFERENCE_RANGE_M = 50.0  # a white diffuse target at normal incidence here reads 1.0


def spherical_dirs(az_rad: np.ndarray, el_rad: np.ndarray) -> np.ndarray:
    ce = np.cos(el_rad)
    return np.stack([ce * np.cos(az_rad), ce * np.sin(az_rad), np.sin(el_rad)], axis=-1)


def axis_grid(fov_deg: float, res_deg: float) -> np.ndarray:
    """Angles (rad) covering a FOV centred on 0 at the given resolution, both ends included."""
    n = int(np.floor(fov_deg / res_deg + 1e-9)) + 1
    half = (n - 1) * res_deg / 2
    return np.deg2rad(np.linspace(-half, half, n))


@dataclass(frozen=True)
class ScanPattern:
    dirs_sensor: np.ndarray  # (K,3) unit
    column: np.ndarray  # (K,) which firing column each ray belongs to
    column_time_s: np.ndarray  # (C,) time offset of each column from the frame start
    fans: Fans  # the same rays as fans, one per azimuth (for the ray caster)

    @cached_property
    def ray_time_s32(self) -> np.ndarray:
        """(K,) float32: each ray's column time, the points' `t` field."""
        return np.take(self.column_time_s, self.column).astype(np.float32)

    @cached_property
    def dirs_rows32b(self) -> np.ndarray:
        """(K,4) the directions padded to 32-byte rows: one gather of a row costs less than
        three gathers of a float each."""
        rows = np.zeros((len(self.dirs_sensor), 4))
        rows[:, :3] = self.dirs_sensor
        return rows


def lidar_pattern(cfg: Lidar) -> ScanPattern:
    if cfg.pattern == "grid":
        az = axis_grid(cfg.fov_h_deg, cfg.res_h_deg)
        el = axis_grid(cfg.fov_v_deg, cfg.res_v_deg)
        # The grid scans column by column (one azimuth, all elevations) across sweep_fraction of the period.
        column_time = np.arange(len(az)) / len(az) * cfg.sweep_fraction / cfg.rate_hz
    else:
        az = np.arange(cfg.columns) * (2 * np.pi / cfg.columns)
        el = np.deg2rad(np.linspace(-cfg.channel_fov_deg / 2, cfg.channel_fov_deg / 2, cfg.channels))
        column_time = np.arange(cfg.columns) / cfg.columns / cfg.rate_hz  # one revolution per frame
        if cfg.beams_file:
            el, shift = beam_pattern(cfg)
            column = (np.arange(len(az))[:, None] + shift[None, :]) % len(az)
            dirs = spherical_dirs(*(g.ravel() for g in np.meshgrid(az, el, indexing="ij")))
            return ScanPattern(dirs, column.ravel(), column_time, Fans(dirs, az, el))
    az_g, el_g = np.meshgrid(az, el, indexing="ij")
    column = np.repeat(np.arange(len(az)), len(el))
    dirs = spherical_dirs(az_g.ravel(), el_g.ravel())
    return ScanPattern(dirs, column, column_time, Fans(dirs, az, el))


def beam_pattern(cfg: Lidar) -> tuple[np.ndarray, np.ndarray]:
    """The elevations (rad, ascending, as the fans need them) of a beams file's channels and, per
    channel, the columns its azimuth offset shifts its firing by. A ray at column azimuth a of
    a beam with Ouster offset d points at a - d (ouster-sdk's sign); the ray at fan azimuth f is
    so fired d / column-step columns later, rounded: each beam's azimuth within half a column
    of the file's, its elevation exact."""
    alt_deg, az_deg = beam_angles_deg(cfg.beams_file, cfg.channels)
    order = np.argsort(alt_deg, kind="stable")
    step_deg = 360.0 / cfg.columns
    return np.deg2rad(alt_deg[order]), np.round(az_deg[order] / step_deg).astype(np.int64)


def radar_pattern(cfg: Radar) -> ScanPattern:
    az = axis_grid(cfg.fov_az_deg, cfg.res_az_deg)
    el = axis_grid(cfg.fov_el_deg, cfg.res_el_deg)
    az_g, el_g = np.meshgrid(az, el, indexing="ij")
    dirs = spherical_dirs(az_g.ravel(), el_g.ravel())
    return ScanPattern(dirs, np.zeros(len(dirs), dtype=np.int64), np.zeros(1), Fans(dirs, az, el))


@dataclass
class FaceLookup:
    """Per-hit material lookup across bodies (flat arrays, offset per body)."""

    label: np.ndarray
    reflectivity: np.ndarray
    retro: np.ndarray
    rcs: np.ndarray
    offset: np.ndarray

    @classmethod
    def from_bodies(cls, bodies: list[Body]) -> "FaceLookup":
        return cls(
            np.concatenate([b.face_label for b in bodies]).astype(np.int32),  # the frames' label dtype
            np.concatenate([b.face_reflectivity for b in bodies]),
            np.concatenate([b.face_retro for b in bodies]),
            np.concatenate([b.face_rcs for b in bodies]),
            face_offsets(bodies),  # the caster's: its flat face index reads these arrays
        )

    @cached_property
    def reflectivity_signed(self) -> np.ndarray:
        """The reflectivity with its sign bit set on retro-reflecting faces: one gather gives
        both (the LiDAR's intensity and which returns are retro)."""
        if np.signbit(self.reflectivity).any():
            raise ValueError("FaceLookup: a face reflectivity is negative (its sign marks the retro-reflectors)")
        return np.where(self.retro, -self.reflectivity, self.reflectivity)

    def flat(self, hits: Hits, mask: np.ndarray) -> np.ndarray:
        return self.offset[hits.body[mask]] + hits.face[mask]


def random_words32(rng: np.random.Generator, n: int) -> np.ndarray:
    """n uniform uint32 words: the generator's raw 64-bit outputs seen as pairs of 32-bit
    words. Numpy's float draws take their words one at a time through a function pointer;
    the raw outputs come at about half the cost, and a probability or a 24-bit uniform needs
    no more than a word."""
    return rng.bit_generator.random_raw((n + 1) // 2).view(np.uint32)[:n]


@lru_cache(maxsize=16)
def word_threshold(probability: float) -> int:
    """T with P(word < T) = T / 2^32 the probability to within 2^-32: a draw `word < T` is an
    event of that probability."""
    return math.ceil(probability * 2.0 ** 32)  # (2^32 for a probability of 1: every word is below)


def standard_normal32(rng: np.random.Generator, n: int) -> np.ndarray:
    """n standard normal draws (float32) by Box-Muller from n 24-bit uniforms (`random_words32`
    shifted). Written out because it takes about half the time of `Generator.standard_normal`
    (float32 or 64) on the LiDAR's tens of thousands of draws per frame; 24-bit uniforms limit
    the tails to 5.8 sigma, plenty for per-cent intensity and centimetre range noise."""
    half = (n + 1) // 2
    words = random_words32(rng, 2 * half)
    np.right_shift(words, 8, out=words)
    u = words.astype(np.float32)  # exact below 2^24: a uniform in [0, 1) is u 2^-24
    radius, angle = u[:half], u[half:]
    # 1 - u in (0, 1] (a finite log) and the angle 2 pi u, each scaled by 2^-24 in one product.
    np.subtract(np.float32(2.0 ** 24), radius, out=radius)
    radius *= np.float32(2.0 ** -24)
    np.log(radius, out=radius)
    radius *= np.float32(-2)
    np.sqrt(radius, out=radius)
    angle *= np.float32(2 * np.pi * 2.0 ** -24)
    out = np.empty(2 * half, dtype=np.float32)
    np.cos(angle, out=out[:half])
    np.sin(angle, out=out[half:])
    both = out.reshape(2, half)
    np.multiply(both, radius, out=both)  # cos and sin halves in one call
    return out[:n]


@lru_cache(maxsize=16)
def range_window(min_m: float, max_m: float, dtype) -> tuple[np.generic, np.generic]:
    """The window [min_m, max_m] in `dtype`: the least value >= min_m and the greatest <= max_m,
    so that ranges of that dtype compare in it as their float64 values would (float32 ranges
    need no widening, a pass over every ray)."""
    lo, hi = np.asarray(min_m, dtype=dtype)[()], np.asarray(max_m, dtype=dtype)[()]
    if float(lo) < min_m:
        lo = np.nextafter(lo, dtype.type(np.inf))
    if float(hi) > max_m:
        hi = np.nextafter(hi, dtype.type(-np.inf))
    return lo, hi


def lidar_measure(
    cfg: Lidar,
    hits: Hits,
    pattern: ScanPattern,
    dirs_world: np.ndarray,
    faces: FaceLookup,
    sea_body: int | None,
    sea_probability: float,
    rng: np.random.Generator,
    spray=None,
    origin_z_world: np.ndarray | float = 0.0,
    second_returns: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Turn LiDAR hits into points (sensor frame) and fields intensity, t, label; a dual-return
    footprint's `second_returns` (data/sim/footprint.py) join them, thinned alike. With `spray`
    (world.sea.spray) some rays return early from droplets in its height band (world z), given
    the rays' directions `dirs_world` and origin heights `origin_z_world` (needed only then).
    The arithmetic runs in place on the returns kept, in float32 for the fans' ranges (Embree's
    t: its rounding, 4 um at 50 m, is far below any range noise or resolution) and the
    intensities; the points are float64."""
    r_all = hits.range_m  # float32 (the fans') or float64 (`cast`'s), compared as float64
    lo, hi = range_window(cfg.min_range_m, cfg.max_range_m, r_all.dtype)
    keep = r_all >= lo
    keep &= r_all <= hi  # a miss (inf) fails the max
    idx = keep.nonzero()[0]  # (np.flatnonzero's result, without its two Python wrappers)
    # The clutter and dropout draws are made for the returns in range only (most of a
    # spinning LiDAR's rays miss), as 32-bit words: a probability needs no more.
    if sea_body is not None:  # sea clutter: only a fraction of sea hits return
        not_sea = hits.body.take(idx) != sea_body
        idx = idx[not_sea | (random_words32(rng, len(idx)) < word_threshold(sea_probability))]
    if cfg.dropout_probability > 0:
        idx = idx[random_words32(rng, len(idx)) >= word_threshold(cfg.dropout_probability)]
    if hits.flat_face is not None:  # the caster's, one gather (the same face_offsets)
        f = hits.flat_face.take(idx).astype(np.intp)  # (int32: widened once for both lookups)
    else:
        f = faces.offset.take(hits.body.take(idx))
        f += hits.face.take(idx)
    r = r_all.take(idx)
    cos_inc = hits.cos_incidence.take(idx)  # |n . d| of unit vectors: at most 1 but for rounding
    np.maximum(cos_inc, 1e-3, out=cos_inc)  # (the retro lobe's arccos clips its few at 1)
    intensity = faces.reflectivity_signed.take(f)  # negative on retro-reflectors, made positive below
    intensity *= cos_inc  # diffuse (Lambert)
    label = faces.label.take(f)
    if second_returns is not None and len(second_returns[0]):  # a dual-return sensor's farther surface
        second_returns = thinned_returns(second_returns, faces.offset, sea_body, sea_probability, cfg.dropout_probability, rng)
        idx, r, cos_inc, intensity, label = with_second_returns(idx, r, cos_inc, intensity, label, second_returns, faces, lo, hi)
    if spray is not None and spray.probability > 0 and len(idx):
        # a droplet at a height z in the band, met by a downward ray before its surface
        z0 = np.broadcast_to(np.asarray(origin_z_world, dtype=float), r_all.shape)[idx]
        down = -dirs_world[idx, 2]
        z = rng.uniform(*spray.height_m, len(idx))
        r_spray = np.where(down > 1e-3, (z0 - z) / np.maximum(down, 1e-3), np.inf)
        hit = (rng.random(len(idx)) < spray.probability) & (r_spray > cfg.min_range_m) & (r_spray < r)
        r = np.where(hit, r_spray.astype(r.dtype), r)  # (the returns' own dtype, spray or not)
        intensity = np.where(hit, spray.reflectivity, intensity)  # (a droplet is no retro-reflector)
        label = np.where(hit, int(Label.SPRAY), label)
    if cfg.backscatter_probability > 0:
        idx, r, intensity, label, cos_inc = backscatter(cfg, r_all, hi, idx, r, intensity, label, cos_inc, rng)
    # Retro-reflectors send light back towards the source in a narrow lobe around normal
    # incidence. Only the few retro hits need the transcendental functions.
    retro_i = np.signbit(intensity).nonzero()[0]
    if len(retro_i):
        inc = np.arccos(np.minimum(cos_inc.take(retro_i), 1.0))
        lobe = cfg.retro_gain * np.exp(-((inc / math.radians(cfg.retro_lobe_deg)) ** 2))
        intensity[retro_i] = np.maximum(lobe, -intensity.take(retro_i))
    spread = np.divide(r.dtype.type(INTENSITY_REFERENCE_RANGE_M), r)
    spread *= spread
    intensity *= spread  # (r_ref / r)^2
    if cfg.extinction_per_km > 0:  # rain or fog: the light is attenuated out and back
        intensity *= np.exp(-2e-3 * cfg.extinction_per_km * r)
        seen = intensity >= cfg.detection_threshold
        idx, r, intensity, label = idx[seen], r[seen], intensity[seen], label[seen]
    n = len(idx)
    noise = standard_normal32(rng, 2 * n) if (cfg.intensity_noise > 0 or cfg.range_noise_m > 0) else None
    if cfg.intensity_noise > 0:
        factor = noise[:n] * cfg.intensity_noise
        factor += 1
        intensity *= np.maximum(factor, 0.05, out=factor)
    if cfg.range_noise_m > 0:
        # Weaker returns are noisier: sigma grows as 1/sqrt(intensity) from 1 at intensity 1
        # up to the gain's cap, i.e. sigma / sqrt(intensity clipped to [cap^-2, 1]).
        sigma = np.maximum(intensity, max(cfg.weak_return_noise_gain ** -2, 1e-9))
        np.minimum(sigma, 1.0, out=sigma)
        np.sqrt(sigma, out=sigma)
        np.divide(r.dtype.type(cfg.range_noise_m), sigma, out=sigma)
        sigma *= noise[n:]
        r += sigma  # r is this function's own array from here on (a gather or np.where)
    r = r.astype(np.float64, copy=False)
    if cfg.range_resolution_m > 0:  # in float64: float32's steps of the resolution would bias ranges by 2e-8
        np.divide(r, cfg.range_resolution_m, out=r)
        np.rint(r, out=r)
        r *= cfg.range_resolution_m
    points = np.empty((n, 3))
    dirs = pattern.dirs_rows32b.take(idx, axis=0)
    for i in range(3):
        np.multiply(dirs[:, i], r, out=points[:, i])
    if cfg.motion_during_sweep:
        t_offset = pattern.ray_time_s32.take(idx)
    else:
        t_offset = np.zeros(n, dtype=np.float32)
    return points, {"intensity": intensity.astype(np.float32, copy=False), "t": t_offset, "label": label}


def backscatter(cfg: Lidar, r_all: np.ndarray, max_range_m: float, idx: np.ndarray, r: np.ndarray,
                intensity: np.ndarray, label: np.ndarray, cos_inc: np.ndarray, rng: np.random.Generator):
    """Rain, snow or fog: a ray, any ray (one that met nothing too), returns from a drop near the
    sensor with `backscatter_probability`, at min_range_m plus an exponential distance, if that
    comes before its surface. A ray that met nothing reports the drop; one with a surface reports
    what the sensor's return mode (`returns`) keeps of the two: the first (the drop), the last
    (the surface), the stronger at the sensor, or both (dual: the drop as a point of its own).
    Returns the returns kept, `idx` (the rays, in order) and their values."""
    drops = np.flatnonzero(random_words32(rng, len(r_all)) < word_threshold(cfg.backscatter_probability))
    r_drop = (cfg.min_range_m + rng.exponential(cfg.backscatter_scale_m, len(drops))).astype(r.dtype)
    at = np.searchsorted(idx, drops)
    had = at < len(idx)
    had[had] = idx[at[had]] == drops[had]  # the ray had a return in range (a surface, or spray)
    kept_r = np.full(len(drops), max_range_m)
    kept_r[had] = r[at[had]]
    first = r_drop < kept_r  # the drop comes before it (or before the range's end)
    drops, r_drop, at, had = drops[first], r_drop[first], at[first], had[first]
    if cfg.returns in ("first", "strongest"):
        replace = had.copy()
        if cfg.returns == "strongest":  # at the sensor: reflectivity over range squared (a retro-reflector: stronger)
            surface = intensity[at[had]]
            replace[had] = (~np.signbit(surface)) & (cfg.backscatter_reflectivity / r_drop[had] ** 2
                                                   > surface / r[at[had]].astype(float) ** 2)
        i = at[replace]
        r[i], intensity[i], label[i] = r_drop[replace], cfg.backscatter_reflectivity, int(Label.PRECIPITATION)
    new = ~had if cfg.returns != "dual" else np.ones(len(drops), bool)  # dual: every drop a point of its own
    idx = np.concatenate([idx, drops[new]])
    order = np.argsort(idx, kind="stable")  # the returns in ray order, as without drops
    n_new = len(idx) - len(r)
    return (idx.take(order), np.concatenate([r, r_drop[new]]).take(order),
            _appended(intensity, n_new, cfg.backscatter_reflectivity, order),
            _appended(label, n_new, int(Label.PRECIPITATION), order), _appended(cos_inc, n_new, 1.0, order))


def _appended(values: np.ndarray, n: int, value, order: np.ndarray) -> np.ndarray:
    """`values` and n copies of `value`, in `order`."""
    return np.concatenate([values, np.full(n, value, dtype=values.dtype)]).take(order)


def quantised(values: np.ndarray, step: float) -> np.ndarray:
    """Values on a grid of `step` (the nearest bin's centre); as they are for a step of 0."""
    return np.rint(values / step) * step if step > 0 else values


def multipath_ghosts(cfg: Radar, p_world: np.ndarray, v_world: np.ndarray, echoes: np.ndarray, origin_world: np.ndarray,
                     v_sensor: np.ndarray, R_world_sensor: np.ndarray, rng: np.random.Generator):
    """Radar echoes by way of the sea (the plane z = 0): of the surface points above it
    (`echoes`: a mask over the beams' hits, world points and velocities), each with
    `multipath_probability`, a ghost at its mirror image below the waterline, moving as the
    image does (its vertical velocity reversed), where that image is in the field of view and
    range. Returns (directions in the sensor frame, ranges, range rates)."""
    cand = np.flatnonzero(echoes & (p_world[:, 2] > 0))
    cand = cand[rng.random(len(cand)) < cfg.multipath_probability]
    mirror = np.array([1.0, 1.0, -1.0])
    to_image = p_world[cand] * mirror - origin_world
    r = np.linalg.norm(to_image, axis=1)
    u_world = to_image / np.maximum(r, 1e-9)[:, None]
    rate = np.einsum("ij,ij->i", u_world, v_world[cand] * mirror - v_sensor)
    u_sensor = u_world @ R_world_sensor  # R^T u, row by row
    az, el = np.arctan2(u_sensor[:, 1], u_sensor[:, 0]), np.arcsin(np.clip(u_sensor[:, 2], -1, 1))
    seen = ((np.abs(az) <= math.radians(cfg.fov_az_deg) / 2) & (np.abs(el) <= math.radians(cfg.fov_el_deg) / 2)
            & (r >= cfg.min_range_m) & (r <= cfg.max_range_m))
    return u_sensor[seen], r[seen], rate[seen]


def radar_measure(
    cfg: Radar,
    hits: Hits,
    pattern: ScanPattern,
    range_rate_true_mps: np.ndarray,
    faces: FaceLookup,
    sea_body: int | None,
    sea_probability: float,
    rng: np.random.Generator,
    ghosts: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Turn radar beam hits into detections: x y z (sensor frame), range, azimuth, elevation,
    range_rate (d range / dt, positive when the range grows) and label. `ghosts`: multipath
    echoes (directions in the sensor frame, ranges, true range rates), measured alike."""
    keep = hits.hit & (hits.range_m >= cfg.min_range_m) & (hits.range_m <= cfg.max_range_m)
    f_all = np.zeros(len(keep), dtype=np.int64)
    f_all[keep] = faces.flat(hits, keep)
    p_det = cfg.detection_probability * RCS_DETECTION_FACTOR[faces.rcs[f_all]]
    if sea_body is not None:
        p_det = np.where(hits.body == sea_body, sea_probability, p_det)
    keep &= rng.random(len(keep)) < p_det
    idx = np.flatnonzero(keep)
    d, r_true, rr_true = pattern.dirs_sensor[idx], hits.range_m[idx], range_rate_true_mps[idx]
    label = faces.label[f_all[idx]]
    if ghosts is not None and len(ghosts[1]):
        d, r_true, rr_true = (np.concatenate([a, g]) for a, g in zip((d, r_true, rr_true), ghosts))
        label = np.concatenate([label, np.full(len(ghosts[1]), int(Label.MULTIPATH), dtype=label.dtype)])
    n = len(d)
    rng_m = r_true + cfg.range_noise_m * rng.standard_normal(n)
    az = np.arctan2(d[:, 1], d[:, 0]) + np.deg2rad(cfg.azimuth_noise_deg) * rng.standard_normal(n)
    el = np.arcsin(np.clip(d[:, 2], -1, 1)) + np.deg2rad(cfg.elevation_noise_deg) * rng.standard_normal(n)
    rr = rr_true + cfg.range_rate_noise_mps * rng.standard_normal(n)
    # False alarms: uniform in the field of view, range and range rate.
    n_fa = rng.poisson(cfg.false_alarms_per_scan) if cfg.false_alarms_per_scan > 0 else 0
    if n_fa:
        az = np.concatenate([az, np.deg2rad(rng.uniform(-cfg.fov_az_deg / 2, cfg.fov_az_deg / 2, n_fa))])
        el = np.concatenate([el, np.deg2rad(rng.uniform(-cfg.fov_el_deg / 2, cfg.fov_el_deg / 2, n_fa))])
        rng_m = np.concatenate([rng_m, rng.uniform(cfg.min_range_m, cfg.max_range_m, n_fa)])
        rr = np.concatenate([rr, rng.uniform(-cfg.max_abs_range_rate_mps, cfg.max_abs_range_rate_mps, n_fa)])
        label = np.concatenate([label, np.full(n_fa, int(Label.NONE), dtype=np.int32)])
    # An FMCW radar's detections, false ones too, sit in its range, Doppler and angle FFTs' bins (data sheet widths).
    rng_m, rr = quantised(rng_m, cfg.range_resolution_m), quantised(rr, cfg.range_rate_resolution_mps)
    az, el = (quantised(a, math.radians(cfg.angle_resolution_deg)) for a in (az, el))
    if cfg.unambiguous_range_rate_mps > 0:  # its Doppler ambiguity: rates wrap into [-v, v), a bin's too
        v = cfg.unambiguous_range_rate_mps
        rr = np.mod(rr + v, 2.0 * v) - v
    points = spherical_dirs(az, el) * rng_m[:, None]
    fields = {
        "range": rng_m.astype(np.float32),
        "azimuth": az.astype(np.float32),
        "elevation": el.astype(np.float32),
        "range_rate": rr.astype(np.float32),
        "label": label,
    }
    return points, fields
