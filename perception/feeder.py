"""Cloud in, feeder measurement out: what one frame says about the feeder's pose.

Frames: `sensor`; `level`, the crane vessel's heading frame at the boom tip as the
installation knows it (origin at the boom tip, levelled with the MRU's roll and pitch, x along
the crane's heading: rotations R_level_sensor = Ry(pitch) Rx(roll) R_crane_sensor). The origin
is the tip, not the vessel's reference point, because that is where the sensors are: a levelling
error (mount or MRU bias) then turns everything about a point metres from the sensors, which the
deck-normal calibration corrects, instead of about a point 50 m below them, which it cannot.

- LiDAR: the deck plane (from the heave chain's deck stage, refitted in the level frame with
  its covariance) and the feeder's structure above and beside the deck, with the returns that
  are static in the sensor frame removed, ready for registration.
- Radar: the Doppler fit turned into the level-frame velocity of the feeder's point at the
  radar (the crane's own rotation, from the MRU rates, removed), and the radar's deck plane.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from boomtip.data.frames import AttitudeNoise
from boomtip.data.installation import Installation
from boomtip.perception.deck_spin import DeckSpin, deck_point_times, level_at_own_time, spin_plane_in_level
from boomtip.perception.feeder_registration import RegistrationConfig
from boomtip.perception.geometry import (
    mount_rotation,
    omega_from_euler_rates,
    rpy_matrix,
)
from boomtip.perception.preprocess import voxel_downsample
from boomtip.perception.static_returns import StaticReturnsConfig
from pydantic import BaseModel, ConfigDict, Field


class FeederConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    static: StaticReturnsConfig = StaticReturnsConfig()
    registration: RegistrationConfig = RegistrationConfig()
    deck_band_m: float = Field(0.2, gt=0, description="returns within this of the deck plane are deck, not structure")
    structure_below_m: float = Field(8.0, gt=0, description="structure considered down to this below the deck (hull sides)")
    structure_above_m: float = Field(30.0, gt=0, description="and up to this above it")
    plane_inflation: float = Field(20.0, ge=1, description="deck-plane covariance x this: one scan's residuals are correlated")
    min_plane_points: int = Field(50, ge=3)
    footprint_margin_m: float = Field(2.0, ge=0, description="structure is taken this far beyond the deck's outline")
    spin: bool = Field(True, description="with per-point times, the deck plane and its spin (roll, pitch, heave rates) "
                       "as one measurement (perception/deck_spin); without, the plane alone")
    spin_min_span_s: float = Field(0.02, gt=0, description="deck returns spread over less time than this: the plane alone")


@dataclass
class PlaneLevel:
    """A deck plane z = a x + b y + c in the level frame, with its covariance."""

    abc: np.ndarray
    cov: np.ndarray
    normal: np.ndarray  # unit, up
    n_points: int
    points_level: np.ndarray | None = None  # its inliers (at most 2000): the feeder's footprint


@dataclass
class LidarObservation:
    t_s: float
    sample_sensor: np.ndarray  # the frame sampled (sensor frame), masked and levelled when registered (empty when not)
    R_level_sensor: np.ndarray
    t_level_sensor: np.ndarray  # the sensor's position in the level frame
    plane: PlaneLevel | None
    status: str
    tip_level: np.ndarray = field(default_factory=lambda: np.zeros(3))  # the tip's place and velocity in the vessel's heading frame (MRU)
    tip_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ms: float = 0.0  # time spent on it so far (the chain adds its own)
    stage_ms: dict[str, float] = field(default_factory=dict)  # those ms by stage
    sample_returns_sensor: np.ndarray | None = None  # the measured return each sample stands for (its voxel's first): beams for the static test
    static_keys: tuple | None = None  # those returns' keys in the static test, computed once when counted
    static_mask: np.ndarray | None = None  # which of those returns are static, as the test said when the frame was handed over
    spin: DeckSpin | None = None  # the deck plane and its rates from the returns' times, when they span the sweep
    noise: AttitudeNoise | None = None  # the attitude's noise as the frame was levelled
    to_register: bool = True  # its structure is registered (else only its deck plane is fused: the pipeline's cadence)


@dataclass
class RadarObservation:
    t_s: float
    velocity_level: np.ndarray | None  # of the feeder's point at the radar, m/s
    velocity_cov: np.ndarray | None
    xi_level: np.ndarray  # the radar's position in the level frame
    plane: PlaneLevel | None
    status: str
    tip_level: np.ndarray = field(default_factory=lambda: np.zeros(3))
    tip_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    detections_sensor: np.ndarray | None = None  # the frame's points, for a registration to the feeder model
    R_level_sensor: np.ndarray | None = None  # the radar's axes in the level frame (its origin: xi_level)
    noise: AttitudeNoise | None = None  # the attitude's noise as the frame was levelled
    lidar_level: np.ndarray | None = None  # the LiDAR's position in the level frame at the frame's attitude


def plane_in_level(points_level: np.ndarray, inflation: float) -> PlaneLevel:
    """Least-squares z = a x + b y + c through deck points (level frame) and the covariance
    of (a, b, c), s^2 (A^T A)^-1 about the centroid mapped back to the origin."""
    c = points_level.mean(axis=0)
    q = points_level - c
    A = np.column_stack([q[:, 0], q[:, 1], np.ones(len(q))])
    AtA = A.T @ A
    coef = np.linalg.solve(AtA, A.T @ q[:, 2])
    res = q[:, 2] - A @ coef
    s2 = float(res @ res) / max(len(q) - 3, 1)
    cov_c = s2 * np.linalg.inv(AtA) * inflation
    a, b, c0 = coef
    J = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-c[0], -c[1], 1.0]])  # (a, b, c0) -> (a, b, c)
    abc = np.array([a, b, c[2] + c0 - a * c[0] - b * c[1]])
    n = np.array([-a, -b, 1.0]) / math.sqrt(a * a + b * b + 1.0)
    return PlaneLevel(abc, J @ cov_c @ J.T, n, len(q))


class FeederPerception:
    """Built from the installation (mounts, tip) and the settings."""

    def __init__(self, installation: Installation, cfg: FeederConfig | None = None, rates_averaged_over: int = 1,
                 angle_sigma_rad: float | None = None) -> None:
        self.installation = installation
        self.cfg = cfg or FeederConfig()
        T_cb, T_bs = installation.T_crane_boomtip(), installation.T_boomtip_sensor()
        self.R_crane_sensor = {s: mount_rotation(T_cb, T_bs[s]) for s in ("lidar", "radar")}
        # the sensors' positions relative to the tip, crane-vessel axes
        self.t_crane_sensor = {s: (T_cb @ T_bs[s])[:3, 3] - T_cb[:3, 3] for s in ("lidar", "radar")}
        self.t_crane_tip = T_cb[:3, 3]
        # The attitude's noise as the caller levels with it: the MRU's stated rate noise over the
        # samples the caller averages each rate of, its angle noise (less when the caller filters
        # the angles: the feeder estimator's attitude_filter takes 0.02 deg to under 0.002), the tip's
        # velocity at the boom's lever. A frame may bring its own (a forecast through an MRU gap).
        self.noise = AttitudeNoise.of_installation(installation, angle_sigma_rad, rates_averaged_over)
        self.mount_sigma_rad = {s: installation.levelling_bias_sigma_rad(s) for s in ("lidar", "radar")}

    @property
    def angle_sigma_rad(self) -> float:
        return self.noise.angle_rad

    @property
    def rate_sigma_radps(self) -> float:
        return self.noise.rate_radps

    @property
    def tip_velocity_sigma(self) -> float:
        return self.noise.tip_velocity_mps

    @staticmethod
    def R_level(rpy: np.ndarray) -> np.ndarray:
        return rpy_matrix(np.array([rpy[0], rpy[1], 0.0]))

    @staticmethod
    def omega_level(rpy: np.ndarray, rpy_rate: np.ndarray) -> np.ndarray:
        """The crane vessel's angular velocity in the level frame, less the yaw rate that turns
        the frame itself."""
        w_world = omega_from_euler_rates(rpy, rpy_rate)
        cy, sy = math.cos(rpy[2]), math.sin(rpy[2])
        return np.array([cy * w_world[0] + sy * w_world[1], -sy * w_world[0] + cy * w_world[1], w_world[2] - rpy_rate[2]])

    def tip_motion(self, rpy: np.ndarray, rpy_rate: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The tip's place and velocity in the vessel's heading frame at its reference point."""
        q = self.R_level(rpy) @ self.t_crane_tip
        return q, np.cross(self.omega_level(rpy, rpy_rate), q)

    def sensor_in_level(self, sensor: str, rpy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R_l = self.R_level(rpy)
        return R_l @ self.R_crane_sensor[sensor], R_l @ self.t_crane_sensor[sensor]

    def deck_points_level(self, deck, R_ls: np.ndarray, t_ls: np.ndarray) -> np.ndarray | None:
        """The heave chain's deck inliers in the level frame; None without enough of them."""
        if deck is None or not deck.ok or deck.fit is None:
            return None
        pts = deck.points_used[deck.fit.inlier_mask]
        return pts @ R_ls.T + t_ls if len(pts) >= self.cfg.min_plane_points else None

    def deck_plane(self, sensor: str, deck, R_ls: np.ndarray, t_ls: np.ndarray, extra_tilt_sigma_rad: float = 0.0,
                   pts_level: np.ndarray | None = None) -> PlaneLevel | None:
        """The heave chain's deck fit (its inliers, pts_level when the caller has them)
        refitted in the level frame."""
        pts_level = self.deck_points_level(deck, R_ls, t_ls) if pts_level is None else pts_level
        if pts_level is None:
            return None
        plane = plane_in_level(pts_level, self.cfg.plane_inflation)
        plane.points_level = pts_level[:: max(1, len(pts_level) // 2000)]
        if extra_tilt_sigma_rad > 0:
            # The MRU's noise (and another sensor's mount) tilt this frame's levelling about the
            # sensor: the slopes change, and the height at the origin by the sensor's lever.
            J = np.array([[1.0, 0.0], [0.0, 1.0], [-t_ls[0], -t_ls[1]]])
            plane.cov = plane.cov + extra_tilt_sigma_rad ** 2 * (J @ J.T)
        return plane

    def deck_spin(self, deck, pts_level: np.ndarray, points_sensor: np.ndarray, point_times: np.ndarray,
                  t_ls: np.ndarray, omega_level: np.ndarray, noise: AttitudeNoise | None = None) -> DeckSpin | None:
        """The heave chain's deck inliers (pts_level: levelled at the frame's time), each moved
        to its own time, fitted with the plane and its rates (perception/deck_spin); None
        without times that span the sweep."""
        t = deck_point_times(points_sensor, point_times, deck.points_used, deck.fit.inlier_mask)
        if t is None or float(t.max() - t.min()) < self.cfg.spin_min_span_s:
            return None
        t = t.astype(np.float64)
        pts = level_at_own_time(pts_level, t, omega_level)
        spin = spin_plane_in_level(pts, t, self.cfg.plane_inflation)
        if spin is None:
            return None
        # The levelling's noise tilts the plane about the sensor (as deck_plane's), the MRU rates'
        # the spin removed from it; the tip's velocity (the rate's reference) is known to its sigma.
        noise = noise or self.noise
        J = np.array([[1.0, 0.0], [0.0, 1.0], [-t_ls[0], -t_ls[1]]])
        spin.cov[:3, :3] += noise.angle_rad ** 2 * (J @ J.T)
        spin.cov[3:, 3:] += noise.rate_radps ** 2 * (J @ J.T)
        spin.cov[5, 5] += noise.tip_velocity_mps ** 2
        return spin

    def lidar(self, t_s: float, points_sensor: np.ndarray, rpy: np.ndarray, rpy_rate: np.ndarray, deck,
              point_times: np.ndarray | None = None, noise: AttitudeNoise | None = None) -> LidarObservation:
        """point_times: each point's time from t_s (the frame's `t` field), when the sensor has them;
        noise: the attitude's, when not the nominal one."""
        noise = noise or self.noise
        R_ls, t_ls = self.sensor_in_level("lidar", rpy)
        finite = np.isfinite(np.einsum("ij->i", points_sensor))  # a non-finite coordinate makes the row's sum so
        pts = points_sensor if finite.all() else points_sensor[finite]
        sample, returns = pts, pts
        if self.cfg.registration.sample_m > 0 and len(pts):
            sample, first = voxel_downsample(pts, self.cfg.registration.sample_m)
            returns = pts[first]
        pts_level = self.deck_points_level(deck, R_ls, t_ls)
        plane = self.deck_plane("lidar", deck, R_ls, t_ls, extra_tilt_sigma_rad=noise.angle_rad, pts_level=pts_level)
        status = "ok" if plane is not None else (f"no deck plane ({deck.status})" if deck is not None else "no deck plane")
        spin = None
        if plane is not None and self.cfg.spin and point_times is not None and len(point_times) == len(points_sensor):
            spin = self.deck_spin(deck, pts_level, points_sensor, point_times, t_ls, self.omega_level(rpy, rpy_rate), noise)
        return LidarObservation(t_s, sample, R_ls, t_ls, plane, status, *self.tip_motion(rpy, rpy_rate),
                                sample_returns_sensor=returns, spin=spin, noise=noise)

    def structure(self, obs: LidarObservation, plane_abc: np.ndarray, footprint: Footprint | None = None,
                  T_map_level: np.ndarray | None = None,
                  is_static: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
        """The frame's feeder returns off the deck plane, in the level frame: the deck's own
        points (which say nothing of x, y, yaw) left out, with a footprint only those over the
        feeder's deck (its vertical walls heaving along themselves look static in the sensor
        frame, and the own vessel's hull side, beyond the gap between the ships, does not), and
        the static returns removed. `is_static(rows)`: the static test of those rows of the
        sample, asked last, of the returns the geometry keeps (a third of a frame: the test's
        gathers at hashed slots are its cost)."""
        pts = obs.sample_sensor @ obs.R_level_sensor.T
        pts += obs.t_level_sensor  # in place: a broadcast add into a new (N, 3) array cost twice the product
        a, b, c = plane_abc
        h = (pts[:, 2] - a * pts[:, 0] - b * pts[:, 1] - c) / math.sqrt(a * a + b * b + 1.0)
        keep = ((h > self.cfg.deck_band_m) & (h < self.cfg.structure_above_m)) | \
               ((h < -self.cfg.deck_band_m) & (h > -self.cfg.structure_below_m))
        rows = np.flatnonzero(keep)  # before the footprint: its test costs a dot product per hull face and point
        if footprint is not None and T_map_level is not None:
            p = pts[rows]
            x_map = p @ T_map_level[0, :3] + T_map_level[0, 3]  # one matrix-vector product a coordinate: a third of
            y_map = p @ T_map_level[1, :3] + T_map_level[1, 3]  # the (N, 3) x (3, 2) product's time
            rows = rows[footprint.contains_xy(x_map, y_map)]
        if is_static is not None:
            rows = rows[~is_static(rows)]
        return pts[rows]

    def radar(self, t_s: float, rpy: np.ndarray, rpy_rate: np.ndarray, doppler, deck,
              detections_sensor: np.ndarray | None = None, noise: AttitudeNoise | None = None) -> RadarObservation:
        noise = noise or self.noise
        R_ls, t_ls = self.sensor_in_level("radar", rpy)
        tip = self.tip_motion(rpy, rpy_rate)
        plane = self.deck_plane("radar", deck, R_ls, t_ls, extra_tilt_sigma_rad=math.hypot(self.mount_sigma_rad["radar"], noise.angle_rad))
        lidar_level = self.sensor_in_level("lidar", rpy)[1]
        if doppler is None:
            return RadarObservation(t_s, None, None, t_ls, plane, "no Doppler velocity", *tip, detections_sensor, R_ls, noise, lidar_level)
        u = R_ls @ doppler.velocity_sensor
        # The crane's rotation (level frame, less its yaw rate, which turns the frame itself)
        # carries the radar: add it back to get the feeder point's velocity in the level frame.
        v = u + np.cross(self.omega_level(rpy, rpy_rate), t_ls)
        lever = float(np.linalg.norm(t_ls))
        cov = R_ls @ doppler.covariance @ R_ls.T + np.eye(3) * ((lever * noise.rate_radps) ** 2
                                                                + (float(np.linalg.norm(u)) * noise.angle_rad) ** 2)
        return RadarObservation(t_s, v, cov, t_ls, plane, "ok", *tip, detections_sensor, R_ls, noise, lidar_level)


class Footprint:
    """The feeder deck's outline in the map frame (the convex hull of its deck points), grown
    by a margin for the bulwarks and hull sides: a convex polygon as half-planes."""

    def __init__(self, deck_xy_map: np.ndarray, margin_m: float) -> None:
        from scipy.spatial import ConvexHull

        hull = ConvexHull(deck_xy_map)
        self.equations = hull.equations  # (F, 3): n . p + c <= 0 inside, n unit
        self.margin_m = margin_m

    def contains(self, xy: np.ndarray) -> np.ndarray:
        return self.contains_xy(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]))

    def contains_xy(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        # face by face (a dozen), each vectorised over the points: numpy's all() along a short
        # axis of an (N, F) array would be most of the test's time
        inside = np.ones(len(x), dtype=bool)
        for nx, ny, c in self.equations:  # loop over the hull's faces, not points
            inside &= x * nx + y * ny + c <= self.margin_m
        return inside


def centre_line_yaw(points_map: np.ndarray, rng: np.random.Generator, band_m: tuple[float, float] = (0.2, 2.5),
                    tol_m: float = 0.15, hypotheses: int = 300, max_angle_deg: float = 45.0,
                    max_scored: int = 2000) -> tuple[float, int] | None:
    """The direction of the feeder's centre line in the map frame (z = deck normal): the
    longest straight edge among the returns just above the deck (bulwarks, hull edges,
    coaming sides), within max_angle_deg of the map's x (the crane's heading when the feeder
    came alongside). Returns (yaw, inliers) or None. RANSAC in 2-D, vectorised over
    hypotheses; the winner refitted by total least squares on its inliers."""
    z = points_map[:, 2]
    xy = points_map[(z > band_m[0]) & (z < band_m[1]), :2]
    if len(xy) < 20:
        return None
    # hypotheses are scored on at most max_scored of the points (a 128-channel LiDAR's band holds
    # ten times more, and scoring is hypotheses x points); the winner is refitted on all of them
    scored = xy if len(xy) <= max_scored else xy[rng.choice(len(xy), max_scored, replace=False)]
    i, j = rng.integers(0, len(scored), (2, hypotheses))
    d = scored[j] - scored[i]
    length = np.linalg.norm(d, axis=1)
    ok = length > 2.0
    ang = np.arctan2(d[:, 1], d[:, 0])
    ang = (ang + np.pi / 2) % np.pi - np.pi / 2  # a line's direction, not a vector's
    ok &= np.abs(ang) < np.radians(max_angle_deg)
    if not ok.any():
        return None
    i, d, length = i[ok], d[ok], length[ok]
    nrm = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
    # distances of every point to every hypothesis, in blocks of 500 points: a block's (500, H)
    # product stays in the cache, where the whole (N, H) one (megabytes) costs page faults
    offset = np.einsum("hj,hj->h", scored[i], nrm)
    counts = np.zeros(len(nrm), dtype=np.int64)
    for start in range(0, len(scored), 500):  # blocks of points, each vectorised
        dist = scored[start:start + 500] @ nrm.T
        dist -= offset
        np.abs(dist, out=dist)
        counts += np.count_nonzero(dist < tol_m, axis=0)
    best = int(np.argmax(counts))
    point, normal = scored[i[best]], nrm[best]
    for _ in range(4):  # refit on the band about the last fit: RANSAC's line clips a thick edge unevenly
        inl = xy[np.abs((xy - point) @ normal) < tol_m]
        point = inl.mean(axis=0)
        _, _, Vt = np.linalg.svd(inl - point, full_matrices=False)
        normal = Vt[1]
    ux, uy = Vt[0]
    yaw = (math.atan2(uy, ux) + math.pi / 2) % math.pi - math.pi / 2
    return yaw, len(inl)
