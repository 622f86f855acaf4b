"""The one interface every frame source implements: recordings on disk and live simulation.

A source exposes its metadata (the installation: sensors and mounts as surveyed), the MRU
log, the encoders when it has them, the ground truth when it has one, and iterates frames of both sensors in acquisition order.
A frame that could not be read still comes out, with `error` set, so a long run records
it as missing and goes on.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Iterator, NamedTuple

import numpy as np

from boomtip.data.installation import Installation

SENSORS = ("lidar", "radar")
LIDAR_FIELDS = ("intensity", "t", "label")
RADAR_FIELDS = ("range", "azimuth", "elevation", "range_rate", "label")
BODIES = ("crane", "feeder")
BODY_COLUMNS = ("x", "y", "z", "roll", "pitch", "yaw", "vx", "vy", "vz", "wx", "wy", "wz")
TRUTH_COLUMNS = ("t", "D", "D_dot") + tuple(f"{b}_{c}" for b in BODIES for c in BODY_COLUMNS)
MRU_COLUMNS = ("t", "roll", "pitch", "yaw", "roll_rate", "pitch_rate", "yaw_rate")
HOOK_TRUTH_COLUMNS = (
    "t",
    "hook_x", "hook_y", "hook_z", "hook_vx", "hook_vy", "hook_vz",
    "hook_rel_x", "hook_rel_y", "hook_rel_z", "hook_rel_vx", "hook_rel_vy", "hook_rel_vz",
    "tip_x", "tip_y", "tip_z", "slew", "luff", "hoist", "boom_deflection", "sway_a", "sway_b",
    "crane_roll", "crane_pitch",
)
# the lift's: the hook's (hook_*, tip_*: in the frame the hook chain estimates them in, which turns
# with the crane vessel's roll and pitch but not its surge, sway and heave), and the load over the feeder's deck (clearance: its lowest point's height
# above the deck below it; landing: its underside's centre dropped onto the deck, feeder body frame,
# and relative to the boom tip in world axes; load: its underside's centre, world; contact: 1 once it rests on
# the deck; centre_clearance: the underside centre's height above the deck below it, relative_vz
# its rate, the load's vertical velocity relative to the deck; feeder_rel_*: the feeder's body frame's origin
# relative to the boom tip, world axes, feeder_roll/pitch/yaw its orientation: what places the deck frame)
LIFT_TRUTH_COLUMNS = HOOK_TRUTH_COLUMNS + ("clearance", "clearance_rate", "centre_clearance", "relative_vz", "landing_x",
                                          "landing_y", "landing_rel_x", "landing_rel_y", "feeder_rel_x", "feeder_rel_y",
                                          "feeder_rel_z", "feeder_roll", "feeder_pitch", "feeder_yaw", "load_x", "load_y",
                                          "load_z", "contact")
ENCODER_COLUMNS = ("t", "slew", "luff", "hoist")


@dataclass
class Frame:
    sensor: str  # "lidar" or "radar"
    index: int  # per-sensor frame number
    t_s: float  # acquisition time (frame start), seconds from the run start
    points_sensor: np.ndarray  # (N,3) float64, sensor frame, metres
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    path: str | None = None  # file it came from, for error messages
    error: str | None = None  # why the frame is unusable (corrupt file, ...)

    def __len__(self) -> int:
        return len(self.points_sensor)


@dataclass
class MruLog:
    """Attitude samples (the crane vessel's, or the feeder's): Euler angles (rad) and their
    time derivatives (rad/s)."""

    t_s: np.ndarray
    rpy_rad: np.ndarray  # (N,3) roll, pitch, yaw; R = Rz(yaw) Ry(pitch) Rx(roll)
    rpy_rate_radps: np.ndarray  # (N,3)
    max_gap_s: float = 0.1  # beyond this gap between samples the log has no attitude

    @classmethod
    def from_columns(cls, cols: dict[str, np.ndarray]) -> "MruLog":
        """From the columns of an mru.csv; gaps longer than 0.1 s, or 5 sample periods if that
        is longer, hold no attitude."""
        t = np.array(cols["t"], dtype=float)  # a copy: a view would keep the whole table read
        period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
        return cls(t, np.column_stack([cols["roll"], cols["pitch"], cols["yaw"]]),
                   np.column_stack([cols["roll_rate"], cols["pitch_rate"], cols["yaw_rate"]]),
                   max_gap_s=max(0.1, 5.0 * period))

    @classmethod
    def level(cls, t0_s: float, t1_s: float) -> "MruLog":
        """A level boom-tip frame over [t0, t1] (with a second's margin): the attitude of an
        installation with `attitude: level`, which has no attitude stream."""
        return cls(np.array([t0_s - 1.0, t1_s + 1.0]), np.zeros((2, 3)), np.zeros((2, 3)), max_gap_s=np.inf)

    def attitude(self, t_s: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Attitude and rates at time t, linearly interpolated; None when t falls outside the
        log or inside a gap longer than max_gap_s (the caller records a missing measurement)."""
        j = sample_after(self.t_s, self.max_gap_s, t_s)
        if j is None:
            return None
        if len(self.t_s) == 1:
            return self.rpy_rad[0], self.rpy_rate_radps[0]
        t0, t1 = self.t_s[j - 1 : j + 1].tolist()
        w = 0.0 if t1 == t0 else (t_s - t0) / (t1 - t0)
        # Six numbers in Python floats: numpy's per-operation overhead on 3-vectors costs more
        # than the arithmetic, and this runs once per frame of every sensor.
        a0, a1 = self.rpy_rad[j - 1 : j + 1].tolist()
        r0, r1 = self.rpy_rate_radps[j - 1 : j + 1].tolist()
        rpy = [x0 + w * ((x1 - x0 + math.pi) % (2 * math.pi) - math.pi) for x0, x1 in zip(a0, a1)]
        rate = [x0 + w * (x1 - x0) for x0, x1 in zip(r0, r1)]
        return np.array(rpy), np.array(rate)


class AttitudeNoise(NamedTuple):
    """1-sigma of the attitude processing levels its clouds with: of the angles, of the rates, and
    of the boom tip's velocity relative to the vessel that the rates give at the tip's lever."""

    angle_rad: float
    rate_radps: float
    tip_velocity_mps: float

    @classmethod
    def of_installation(cls, installation: Installation, angle_sigma_rad: float | None = None,
                        rates_averaged_over: int = 1) -> "AttitudeNoise":
        """The MRU's stated noise, its rates averaged over `rates_averaged_over` samples, its angles
        `angle_sigma_rad` when the caller filters them (else the stated angle noise)."""
        rate_sigma = math.radians(installation.mru.rate_noise_degps)
        lever_m = float(np.linalg.norm(installation.T_crane_boomtip()[:3, 3]))
        return cls(math.radians(installation.mru.angle_noise_deg) if angle_sigma_rad is None else angle_sigma_rad,
                   rate_sigma / math.sqrt(rates_averaged_over),
                   lever_m * rate_sigma / math.sqrt(rates_averaged_over))

    def with_forecast(self, var: np.ndarray, lever_m: float) -> "AttitudeNoise":
        """This noise with a forecast attitude's error added (var: the variances of roll, pitch,
        yaw and their rates; the larger of roll's and pitch's for the tilt)."""
        angle_var, rate_var = max(var[0], var[1]), max(var[3], var[4])
        return AttitudeNoise(math.sqrt(self.angle_rad ** 2 + angle_var), math.sqrt(self.rate_radps ** 2 + rate_var),
                             math.sqrt(self.tip_velocity_mps ** 2 + lever_m ** 2 * rate_var))


class LevellingAttitude(NamedTuple):
    """The attitude a frame is levelled with, its noise, and, through a gap in the MRU's log,
    the variances of the forecast it is (None where the MRU measured it)."""

    rpy_rad: np.ndarray
    rpy_rate_radps: np.ndarray
    noise: AttitudeNoise
    forecast_var: np.ndarray | None = None


def sample_after(t_log_s: np.ndarray, max_gap_s: float, t_s: float) -> int | None:
    """The index of the first sample of a log (times t_log_s) at or after t_s, at least 1 (0 for
    a one-sample log), or None when t_s falls outside the log or inside a gap longer than
    max_gap_s: whether the log has a value at t_s."""
    t = t_log_s
    if len(t) == 0 or t_s < t[0] - 1e-9 or t_s > t[-1] + 1e-9:
        return None
    if len(t) == 1:
        return 0
    j = min(max(int(t.searchsorted(t_s)), 1), len(t) - 1)  # the method: np.searchsorted's wrapper costs more
    t0, t1 = t[j - 1 : j + 1].tolist()
    return None if t1 - t0 > max_gap_s else j


@dataclass
class Truth:
    """Ground-truth table: columns of TRUTH_COLUMNS at the truth rate."""

    columns: dict[str, np.ndarray]

    @property
    def t_s(self) -> np.ndarray:
        return self.columns["t"]

    def at(self, name: str, t_s: np.ndarray) -> np.ndarray:
        """A column linearly interpolated at times t (truth rate is 200 Hz by default); NaN
        outside the truth's span, so a truth that ends early scores nothing beyond its end
        instead of holding its last value."""
        t = self.columns["t"]
        return np.interp(t_s, t, self.columns[name], left=np.nan, right=np.nan)

    @property
    def end_s(self) -> float:
        return float(self.columns["t"][-1]) if len(self.columns["t"]) else float("nan")


@dataclass
class SourceMeta:
    """What a source says about itself. Processing is built from `installation` and
    `processing` alone; `provenance` (the full simulated scenario, world included) is for
    reproducibility and scoring only and never reaches perception or fusion."""

    installation: Installation
    duration_s: float
    name: str = "recording"
    processing: dict = field(default_factory=dict)  # processing settings the source asks for (raw keys)
    provenance: dict | None = None
    t_start_s: float = 0.0  # the source's first time stamp: outputs and scoring start here
    # The source's own clock at t = 0 (a bag's epoch seconds, an Ouster sensor's clock): every
    # source is read with t counted from its first stamp (data/io/loaders.py, Rebased)
    t_origin_s: float = 0.0
    notes: list[str] = field(default_factory=list)  # what the loader had to assume (the report repeats them)

    @property
    def T_crane_boomtip(self) -> np.ndarray:
        """4x4, boom tip in the crane-vessel body frame (as surveyed)."""
        return self.installation.T_crane_boomtip()

    @property
    def T_boomtip_sensor(self) -> dict[str, np.ndarray]:
        """Sensor name -> 4x4 mount as surveyed."""
        return self.installation.T_boomtip_sensor()


class FrameSource(ABC):
    """Frames from somewhere: `for frame in source` yields both sensors in time order."""

    meta: SourceMeta
    mru: MruLog
    truth: Truth | None
    # Crane joint encoders, a stream like the MRU log: t, slew, luff (rad), hoist (m); None
    # when the source has none (ship-to-ship runs).
    encoders: dict[str, np.ndarray] | None = None
    # An MRU on the feeder (document 004's second MRU): its body's attitude in its own heading
    # frame and the rates, the crane MRU's columns; None when the feeder has none.
    feeder_mru: MruLog | None = None

    @abstractmethod
    def __iter__(self) -> Iterator[Frame]: ...

    @abstractmethod
    def __len__(self) -> int: ...

    @property
    def duration_s(self) -> float:
        return self.meta.duration_s
