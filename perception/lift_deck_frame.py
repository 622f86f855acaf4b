"""The feeder's deck frame during a lift: a frame fixed to the feeder, in which the landing point
stays still when the feeder moves under the load.

    first frame with a deck under the load -> the feeder's deck: the returns near that deck's
                                              plane, in grid cells connected to the cells under
                                              the load (the own vessel beyond the gap between
                                              the ships is not connected), its outline a footprint
    each frame (every `register_every_s`)   -> the feeder's returns over the footprint, off the
                                              deck plane, the load and the hook left out,
                                              registered to the first frame's (the feeder chain's
                                              FeederModel: a keyframe, point-to-plane ICP)
    between registrations                   -> the last two poses extrapolated at constant velocity
    the deck measured under the load        -> kept in the deck frame: a frame in which the load
                                              hides it takes it from there, carried by the pose

The deck frame is the levelled frame (z up, world axes, origin at the boom tip) as it was at the
keyframe's instant, carried along with the feeder from then on: `key_t_s` names it. Built from the
settings alone; the frames are the hook pipeline's levelled clouds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy import ndimage
from scipy.spatial import QhullError

from boomtip.data.poses import inverse, pose_matrix, pose_vector, transform
from boomtip.perception.feeder import Footprint
from boomtip.perception.feeder_registration import FeederModel, RegistrationConfig

__all__ = ["DeckFrameConfig", "DeckPose", "DeckFrameTracker", "feeder_deck_cells", "plane_in", "pose_covariance", "point_sigma_m",
           "height_sigma_m"]

GRID_CONNECTIVITY = np.ones((3, 3), dtype=bool)  # cells touching at a corner are connected
POSE_DOF = 6
STAMP_TOLERANCE_S = 1e-6  # frame times are sums of float steps: 0.2 s apart may read 0.19999...


class DeckFrameConfig(BaseModel):
    """`processing.lift.deck_frame`: how the feeder's returns are found and registered."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(True, description="follow the feeder's deck frame, and give the landing point in it")
    deck_band_m: float = Field(0.8, gt=0, description="the feeder deck's returns lie this close to the deck plane found "
                               "under the load, extrapolated over the deck (its tilt's error over tens of metres)")
    cell_m: float = Field(1.0, gt=0, description="grid cell of the deck's returns; the feeder's deck is the cells connected "
                          "to those under the load")
    footprint_margin_m: float = Field(1.5, ge=0, description="the feeder's returns are taken this far beyond the deck's outline")
    structure_band_m: float = Field(0.3, gt=0, description="returns within this of the keyframe's deck plane are deck (they "
                                    "say nothing of x, y and yaw), not structure")
    structure_above_m: float = Field(12.0, gt=0, description="structure taken up to this above the deck")
    structure_below_m: float = Field(3.0, gt=0, description="and down to this below it (bulwarks, the hull's top)")
    keyframe_max_tip_sigma_m: float = Field(0.03, gt=0, description="the deck frame is fixed once the boom tip's place is "
                                            "this sure (the tip tracker's attitude, slew and luff sigma times the boom's "
                                            "length): the levelled frame at the keyframe is the deck frame, its error at the "
                                            "start (decimetres at the tip) would stay in it")
    register_every_s: float = Field(0.2, ge=0, description="a frame is registered this long after the last one (0: every "
                                    "frame); between, the last two poses are extrapolated")
    prior_sigma_m: float = Field(0.1, gt=0, description="the extrapolated pose's sigma handed to the registration (above "
                                 "registration.kiss_above_sigma_m kiss-icp pulls in first)")
    speed_sigma_mps: float = Field(0.5, gt=0, description="the feeder's speed relative to the tip before two registrations "
                                   "give it: the keyframe's pose's sigma grows by this times the time since")
    turn_rate_sigma_radps: float = Field(0.02, gt=0, description="and its rate of turn (a 1 deg roll at a 9 s period: "
                                         "0.012 rad/s), its rotations' sigma likewise")
    prior_rotation_sigma_rad: float = Field(0.01, gt=0, description="a registration's rotations are no surer than this "
                                            "beyond the extrapolated pose's sigma, in a direction its structure leaves free")
    accel_sigma_mps2: float = Field(0.5, gt=0, description="the feeder's acceleration relative to the tip: an extrapolated "
                                    "pose's sigma grows by half of it times the time since the registration squared")
    angular_accel_sigma_radps2: float = Field(0.01, gt=0, description="and its angular acceleration (a 1 deg roll at a 9 s "
                                              "period: 0.008 rad/s^2)")
    fallback_error_correlation_s: float = Field(1.0, ge=0, description="a deck carried by the registrations (the load hiding "
                                                "it) errs alike from frame to frame, and the clearance's filters weigh about "
                                                "this long of frames together: its sigma is widened for them so that those "
                                                "frames, taken as independent, say no more together than one")
    max_extrapolation_s: float = Field(1.0, gt=0, description="no deck frame further than this from a registration")
    rekey_after_failures: int = Field(10, ge=1, description="registrations failed in a row before a new keyframe is taken "
                                      "(a new deck frame)")
    registration: RegistrationConfig = Field(RegistrationConfig(model_merges=()), description="the feeder chain's "
                                             "registration (perception.feeder_registration), on the keyframe alone")


@dataclass
class DeckPose:
    """The deck frame at an instant: T_deck_level (level -> deck frame, 4x4), its covariance
    (x, y, z, rotations about the level axes; 6x6) and the keyframe's time naming the frame."""

    T_deck_level: np.ndarray
    cov6: np.ndarray
    key_t_s: float


def feeder_deck_cells(points_level: np.ndarray, deck_plane: np.ndarray, seed_xy: np.ndarray, band_m: float,
                      cell_m: float) -> np.ndarray:
    """The feeder deck's returns (x, y; level frame): those within `band_m` of the plane
    z = a + b x + c y in the grid cells connected to the cells of `seed_xy` (the deck under
    the load). Empty when no seed falls on the deck."""
    a, b, c = deck_plane
    near = np.abs(points_level[:, 2] - (a + b * points_level[:, 0] + c * points_level[:, 1])) < band_m
    xy = points_level[near, :2]
    if not len(xy) or not len(seed_xy):
        return np.zeros((0, 2))
    lo = np.minimum(xy.min(axis=0), seed_xy.min(axis=0))
    cells = np.floor((xy - lo) / cell_m).astype(np.int64)
    grid = np.zeros(cells.max(axis=0) + 1, dtype=bool)
    grid[cells[:, 0], cells[:, 1]] = True
    labels, _ = ndimage.label(grid, structure=GRID_CONNECTIVITY)
    seeds = np.floor((seed_xy - lo) / cell_m).astype(np.int64)
    seeds = seeds[np.all((seeds >= 0) & (seeds < grid.shape), axis=1)]
    seed_labels = labels[seeds[:, 0], seeds[:, 1]]
    seed_labels = seed_labels[seed_labels > 0]
    if not len(seed_labels):
        return np.zeros((0, 2))
    deck = labels == np.bincount(seed_labels).argmax()
    return xy[deck[cells[:, 0], cells[:, 1]]]


def plane_in(T_to_from: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """A plane z = a + b x + c y given in one frame, in another (T_to_from: from -> to)."""
    a, b, c = plane
    R, t = T_to_from[:3, :3], T_to_from[:3, 3]
    n, p0 = R @ np.array([-b, -c, 1.0]), R @ np.array([0.0, 0.0, a]) + t
    return np.array([p0[2] + (n[0] * p0[0] + n[1] * p0[1]) / n[2], -n[0] / n[2], -n[1] / n[2]])


def pose_covariance(info6: np.ndarray, prior_cov6: np.ndarray) -> np.ndarray:
    """The covariance of a registration's pose from its information (6x6) and its prior's
    covariance: a direction the structure leaves free keeps the prior's variance instead of none
    (a pseudo-inverse) or an infinite one."""
    return np.linalg.inv(info6 + np.linalg.inv(prior_cov6))


def point_cov_m2(cov6: np.ndarray, point_level: np.ndarray, origin_level: np.ndarray) -> np.ndarray:
    """A level point's 3x3 covariance in a frame whose pose (translation and small rotations
    about the level axes through `origin_level`) has covariance cov6: it moves by dt + dw x r."""
    r = point_level - origin_level
    J = np.zeros((3, POSE_DOF))
    J[:, :3] = np.eye(3)
    J[:, 3:] = [[0.0, r[2], -r[1]], [-r[2], 0.0, r[0]], [r[1], -r[0], 0.0]]  # dw x r = -[r]x dw
    return J @ cov6 @ J.T


def point_sigma_m(cov6: np.ndarray, point_level: np.ndarray, origin_level: np.ndarray) -> float:
    """Its horizontal 1-sigma per axis (as point_cov_m2)."""
    cov = point_cov_m2(cov6, point_level, origin_level)
    return math.sqrt(max(0.5 * float(cov[0, 0] + cov[1, 1]), 0.0))


def height_sigma_m(cov6: np.ndarray, point_level: np.ndarray, origin_level: np.ndarray) -> float:
    """Its vertical 1-sigma (as point_cov_m2)."""
    return math.sqrt(max(float(point_cov_m2(cov6, point_level, origin_level)[2, 2]), 0.0))


class DeckFrameTracker:
    """The deck frame over a lift's frames: `update` with each levelled frame, `pose_at` between."""

    def __init__(self, cfg: DeckFrameConfig | None = None) -> None:
        self.cfg = cfg or DeckFrameConfig()
        self.model: FeederModel | None = None
        self.footprint: Footprint | None = None
        self.deck_plane_key = np.zeros(3)  # the keyframe's deck plane z = a + b x + c y (deck frame)
        self.key_t_s = math.nan
        self.key_sigma_m = math.nan  # the levelled frame's origin's 1-sigma at the keyframe: the deck frame's own error
        self.poses: list[tuple[float, np.ndarray, np.ndarray]] = []  # the last two registrations: (t, pose vector, cov6)
        self.last_try_s = -math.inf
        self.failures = 0
        self.statuses: dict[str, int] = {}  # registrations by outcome
        # the last deck plane measured (deck frame, z = a + b x + c y) and its height's 1-sigma
        self.deck_seen: tuple[np.ndarray, float] | None = None

    def due(self, t_s: float) -> bool:
        """Whether the frame at t_s is to be registered: `register_every_s` after the last, and
        every frame until two registrations give the feeder's velocity."""
        return len(self.poses) < 2 or t_s - self.last_try_s >= self.cfg.register_every_s - STAMP_TOLERANCE_S

    def update(self, t_s: float, points_level: np.ndarray, deck_plane_level: np.ndarray, deck_xy_level: np.ndarray,
               load_xy_level: np.ndarray, load_radius_m: float, tip_sigma_m: float = 0.0) -> str:
        """A levelled frame with the deck plane under the load (z = a + b x + c y), that deck's
        returns (x, y) and the load's centre and radius (its returns and the hook's left out);
        `tip_sigma_m` how sure the levelled frame's origin is. Returns the frame's outcome
        (counted in `statuses`)."""
        self.last_try_s = t_s
        if self.model is not None and self.failures < self.cfg.rekey_after_failures:
            status = self._register(t_s, points_level, load_xy_level, load_radius_m)
        elif not tip_sigma_m <= self.cfg.keyframe_max_tip_sigma_m:
            status = "the boom tip's place not yet settled"
        else:
            status = self._keyframe(t_s, points_level, deck_plane_level, deck_xy_level, load_xy_level, load_radius_m)
            self.key_sigma_m = tip_sigma_m if status == "keyframe" else self.key_sigma_m
        self.statuses[status] = self.statuses.get(status, 0) + 1
        return status

    def _keyframe(self, t_s, points_level, deck_plane_level, deck_xy_level, load_xy_level, load_radius_m) -> str:
        cfg = self.cfg
        deck_xy = feeder_deck_cells(points_level, deck_plane_level, deck_xy_level, cfg.deck_band_m, cfg.cell_m)
        try:
            footprint = Footprint(deck_xy, cfg.footprint_margin_m)
        except (QhullError, ValueError):  # too few cells, or all in a line (one scan line across the deck)
            return "no feeder deck around the load's"
        structure = self._structure(points_level, np.eye(4), load_xy_level, load_radius_m, footprint, deck_plane_level)
        if len(structure) < cfg.registration.min_points:
            return f"too little feeder structure for a keyframe ({len(structure)} returns)"
        self.footprint, self.deck_plane_key = footprint, np.asarray(deck_plane_level, float)
        # a new deck frame: a deck remembered in the old one is not in it
        self.model, self.deck_seen = FeederModel(cfg.registration), None
        self.model.set_keyframe(structure, np.eye(4))
        self.key_t_s, self.failures = t_s, 0
        self.poses = [(t_s, np.zeros(POSE_DOF), np.zeros((POSE_DOF, POSE_DOF)))]
        return "keyframe"

    def _register(self, t_s, points_level, load_xy_level, load_radius_m) -> str:
        cfg, guess = self.cfg, self.pose_at(t_s)
        if guess is None:  # the last registration too old to extrapolate: from it, re-acquired
            T_guess, prior_sigma_m = pose_matrix(*self.poses[-1][1]), 3.0 * cfg.registration.kiss_above_sigma_m
            prior_cov6 = np.zeros((POSE_DOF, POSE_DOF))
        else:  # the guess's sigma on the deck below the tip, where the structure is (not at the tip, 80 m above)
            below_tip = np.array([0.0, 0.0, self.deck_plane_key[0]])
            T_guess, prior_cov6 = guess.T_deck_level, guess.cov6
            prior_sigma_m = max(cfg.prior_sigma_m, point_sigma_m(guess.cov6, below_tip, inverse(T_guess)[:3, 3]))
        structure = self._structure(points_level, T_guess, load_xy_level, load_radius_m, self.footprint, self.deck_plane_key)
        reg = self.model.register(structure, T_guess, prior_sigma_m)
        if reg.status != "ok":
            self.failures += 1
            return reg.status
        self.failures = 0
        prior_cov6 = prior_cov6 + np.diag([prior_sigma_m**2] * 3 + [cfg.prior_rotation_sigma_rad**2] * 3)
        cov6 = pose_covariance(reg.info6, prior_cov6)
        self.poses = (self.poses + [(t_s, pose_vector(reg.T_map_level), cov6)])[-2:]
        return "ok"

    def _structure(self, points_level: np.ndarray, T_deck_level: np.ndarray, load_xy_level: np.ndarray, load_radius_m: float,
                   footprint: Footprint, deck_plane_deck: np.ndarray) -> np.ndarray:
        """The feeder's returns off its deck plane (deck frame) over its footprint (placed by
        T_deck_level), the load's column (the load, its slings, the block and rope above it) left out."""
        cfg = self.cfg
        p = transform(T_deck_level, points_level)
        a, b, c = deck_plane_deck
        h = p[:, 2] - (a + b * p[:, 0] + c * p[:, 1])
        keep = ((h > cfg.structure_band_m) & (h < cfg.structure_above_m)) | \
               ((h < -cfg.structure_band_m) & (h > -cfg.structure_below_m))
        keep &= np.hypot(points_level[:, 0] - load_xy_level[0], points_level[:, 1] - load_xy_level[1]) > load_radius_m
        rows = np.flatnonzero(keep)
        rows = rows[footprint.contains_xy(p[rows, 0], p[rows, 1])]
        return points_level[rows]

    def pose_at(self, t_s: float) -> DeckPose | None:
        """The deck frame at t_s from the last two registrations at constant velocity, their
        errors carried through the extrapolation and grown by the accelerations since the last;
        None before a registration or too far from one."""
        if not self.poses:
            return None
        t1, x1, cov1 = self.poses[-1]
        dt = t_s - t1
        if abs(dt) > self.cfg.max_extrapolation_s:
            return None
        x, cov = x1, cov1.copy()
        if len(self.poses) == 1:  # the keyframe alone: nothing says how fast the feeder moves
            cov[:3, :3] += np.eye(3) * (self.cfg.speed_sigma_mps * dt) ** 2
            cov[3:, 3:] += np.eye(3) * (self.cfg.turn_rate_sigma_radps * dt) ** 2
        elif t1 > self.poses[0][0]:
            t0, x0, cov0 = self.poses[0]
            k = dt / (t1 - t0)
            step = x1 - x0
            step[3:] = (step[3:] + math.pi) % (2.0 * math.pi) - math.pi
            x, cov = x1 + k * step, (1.0 + k) ** 2 * cov1 + k**2 * cov0
        growth = 0.5 * dt * dt
        cov[:3, :3] += np.eye(3) * (growth * self.cfg.accel_sigma_mps2) ** 2
        cov[3:, 3:] += np.eye(3) * (growth * self.cfg.angular_accel_sigma_radps2) ** 2
        return DeckPose(pose_matrix(*x), cov, self.key_t_s)

    def remember_deck(self, t_s: float, deck_plane_level: np.ndarray, sigma_m: float) -> None:
        """A deck plane measured under the load (level frame, z = a + b x + c y; its height's
        1-sigma): kept in the deck frame, where it moves with the feeder, for frames that show
        too little of the deck. The pose's error now is not added: it and the pose's error when
        the plane is carried back are both registrations' to the same keyframe, largely shared,
        and the carried plane's sigma adds the later one."""
        pose = self.pose_at(t_s)
        if pose is not None and np.all(np.isfinite(deck_plane_level)) and math.isfinite(sigma_m):
            self.deck_seen = plane_in(pose.T_deck_level, deck_plane_level), sigma_m

    def deck_plane_at(self, t_s: float, xy_level: np.ndarray) -> tuple[np.ndarray, float] | None:
        """The last deck plane measured, carried to t_s by the feeder's predicted pose (level frame),
        and its height's 1-sigma at xy_level: the measurement's and the pose's there."""
        pose = self.pose_at(t_s)
        if pose is None or self.deck_seen is None:
            return None
        plane_deck, sigma_m = self.deck_seen
        T_level_deck = inverse(pose.T_deck_level)
        plane = plane_in(T_level_deck, plane_deck)
        point = np.array([xy_level[0], xy_level[1], plane[0] + plane[1] * xy_level[0] + plane[2] * xy_level[1]])
        return plane, math.hypot(sigma_m, height_sigma_m(pose.cov6, point, T_level_deck[:3, 3]))

    def landing_in_deck(self, t_s: float, landing_level: np.ndarray, landing_sigma_m: float) -> tuple[np.ndarray, float] | None:
        """The landing point (level frame) in the deck frame and its horizontal 1-sigma per axis:
        the point's own, the deck frame's pose's at it, and the levelled frame's origin's at the
        keyframe (which the deck frame keeps)."""
        pose = self.pose_at(t_s)
        if pose is None:
            return None
        origin_level = inverse(pose.T_deck_level)[:3, 3]
        sigma_pose = point_sigma_m(pose.cov6, landing_level, origin_level)
        sigma_m = math.sqrt(landing_sigma_m**2 + sigma_pose**2 + self.key_sigma_m**2)  # the frame's own error with them
        return transform(pose.T_deck_level, landing_level[None, :])[0], sigma_m
