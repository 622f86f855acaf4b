"""The simulated world: everything a real installation does not know.

Both ships' geometry and motion, the sea, the cargo, how the sensors really behave (their
true noise, dropouts, intensities), the hook scene and its programme, and `mismatch`: how
reality deviates from the installation (mount errors, MRU bias and lag, clock offsets, crane
parameters, an elastic rope, wind, encoder biases). Only the simulator reads it; perception
and fusion are built from the installation and their own settings alone.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import math

from pydantic import Field, field_validator, model_validator
from scipy.spatial.transform import Rotation

from boomtip.data.installation import LidarSpec, Mount, RadarSpec, require_finite, StrictModel
from boomtip.data.sim.lift_scene import LiftScene

DOFS = ("surge", "sway", "heave", "roll", "pitch", "yaw")


class Sinusoid(StrictModel):
    amplitude: float = Field(0.0, description="m for surge/sway/heave, deg for roll/pitch/yaw")
    period_s: float = Field(10.0, gt=0)
    phase_deg: float = 0.0


class Motion(StrictModel):
    surge: Sinusoid = Sinusoid()
    sway: Sinusoid = Sinusoid()
    heave: Sinusoid = Sinusoid()
    roll: Sinusoid = Sinusoid()
    pitch: Sinusoid = Sinusoid()
    yaw: Sinusoid = Sinusoid()


class IrregularSea(StrictModel):
    """Irregular sea added on top of the sinusoids: a JONSWAP spectrum of wave elevation,
    turned into each DOF through a per-DOF gain (m or deg per metre of wave)."""

    enabled: bool = False
    hs_m: float = Field(2.0, gt=0, le=20, description="significant wave height")
    tp_s: float = Field(10.0, gt=0, le=30, description="peak period")
    gamma: float = Field(3.3, ge=1.0, description="JONSWAP peak enhancement")
    n_components: int = Field(64, ge=4, le=4096)
    response: dict[Literal["surge", "sway", "heave", "roll", "pitch", "yaw"], float] = Field(
        default_factory=lambda: {"heave": 0.5, "roll": 0.4, "pitch": 0.6}
    )


class CraneHull(StrictModel):
    length_m: float = Field(216.0, gt=0)
    beam_m: float = Field(49.0, gt=0)
    freeboard_m: float = Field(10.0, gt=0, description="main deck above the waterline")
    draft_m: float = Field(8.0, gt=0)
    pedestal_m: tuple[float, float] = (10.0, -8.0)


class FeederGeometry(StrictModel):
    length_m: float = Field(95.0, gt=0)
    beam_m: float = Field(22.0, gt=0)
    freeboard_m: float = Field(4.0, gt=0)
    draft_m: float = Field(5.0, gt=0)
    bulwark_height_m: float = Field(1.2, ge=0)
    position_m: tuple[float, float, float] = Field(
        (0.0, -41.0, 0.0), description="feeder body origin in the world at rest (waterline)"
    )


class Reflectors(StrictModel):
    """Retro-reflective deck markers (tape patches) along both deck edges, as laid."""

    enabled: bool = True
    spacing_m: float = Field(8.0, gt=0)
    size_m: float = Field(1.0, gt=0)
    inset_m: float = Field(1.5, ge=0, description="distance from the bulwark inboard")
    height_m: float = Field(0.002, ge=0, le=0.5, description="markers' true height above the deck")
    false_bright_points: int = Field(0, ge=0, description="extra bright patches on cargo/bulwarks that are not markers")


class Vessel(StrictModel):
    motion: Motion = Motion()
    irregular: IrregularSea = IrregularSea()


class CraneVessel(Vessel):
    geometry: CraneHull = CraneHull()


Windows = list[tuple[float, float]]


class _Outages(StrictModel):
    """A sensor that can go silent: [start, end] windows (seconds) in which it gives nothing."""

    outages_s: Windows = Field(default_factory=list, description="[start, end] windows in which the sensor gives nothing")

    @field_validator("outages_s")
    @classmethod
    def _windows(cls, v: Windows) -> Windows:
        return check_windows(v)


def check_windows(v: Windows) -> Windows:
    for a, b in v:
        if not (math.isfinite(a) and math.isfinite(b) and 0 <= a < b):
            raise ValueError(f"each window is [start, end] seconds with 0 <= start < end, got {[a, b]}")
    return v


class FeederMru(_Outages):
    """An MRU on the feeder (document 004's second MRU; off by default: boomtip's aim is
    nothing on the feeder). Its noise is the installation's `feeder_mru` data sheet; how it
    really deviates is here."""

    enabled: bool = False
    bias_deg: tuple[float, float, float] = Field(
        (0.01, -0.01, 0.5), description="roll, pitch, yaw; the yaw's is the offset between the two ships' heading references"
    )
    lag_s: float = Field(0.002, ge=0, le=1, description="it reports the attitude this much late, unstated")

    @model_validator(mode="after")
    def _check(self) -> "FeederMru":
        require_finite(self.bias_deg, "feeder.mru.bias_deg")
        return self


class FeederVessel(Vessel):
    geometry: FeederGeometry = FeederGeometry()
    cargo: bool = False
    reflectors: Reflectors = Reflectors()
    mru: FeederMru = FeederMru()


class Spray(StrictModel):
    """Spray in the air above the sea: a fraction of the LiDAR's rays return early and weakly
    from droplets at a height within the band (world z above the waterline)."""

    probability: float = Field(0.0, ge=0, le=1, description="chance that a ray returns from spray first")
    height_m: tuple[float, float] = Field((0.5, 8.0), description="the band of heights the spray fills")
    reflectivity: float = Field(0.02, ge=0, le=1)

    @model_validator(mode="after")
    def _band(self) -> "Spray":
        lo, hi = self.height_m
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"sea.spray.height_m: expected [low, high] with low < high, got {[lo, hi]}")
        return self


class Sea(StrictModel):
    clutter: bool = Field(False, description="LiDAR/radar returns from the sea surface")
    clutter_probability: float = Field(0.02, ge=0, le=1)
    reflectivity: float = Field(0.05, ge=0, le=1)
    spray: Spray = Spray()


class RadarBehaviour(_Outages):
    """How the radar really behaves beyond its spec sheet."""

    multipath_probability: float = Field(0.0, ge=0, le=1, description="chance that a beam's hit above the sea (whether "
                                         "or not its direct echo is detected) also comes back by way of the sea: a "
                                         "ghost at its mirror image below the waterline, with the image's range rate, "
                                         "detected where that image is in the field of view and range")


class MruBehaviour(_Outages):
    """How the MRU really behaves beyond its spec sheet (bias and lag: `mismatch`), and its
    faults: glitches (a wild attitude for a few samples, within the sensor's range) and
    freezes (the last sample repeated)."""

    glitches_s: Windows = Field(default_factory=list, description="[start, end] windows in which the MRU reports "
                                "glitch_rpy_deg instead of the attitude")
    glitch_rpy_deg: tuple[float, float, float] = Field((89.9, -89.9, 0.0), description="what a glitch reports")
    frozen_s: Windows = Field(default_factory=list, description="[start, end] windows in which the MRU repeats its "
                              "last sample (a stuck sensor)")

    @field_validator("glitches_s", "frozen_s")
    @classmethod
    def _fault_windows(cls, v: Windows) -> Windows:
        return check_windows(v)


class LidarBehaviour(_Outages):
    """How the LiDAR really behaves beyond its spec sheet."""

    weak_return_noise_gain: float = Field(3.0, ge=1, description="range noise grows as sqrt(I_ref/I) up to this factor")
    intensity_noise: float = Field(0.0, ge=0, description="relative 1-sigma intensity noise")
    dropout_probability: float = Field(0.0, ge=0, lt=1)
    retro_gain: float = Field(25.0, gt=0, description="retro-reflector peak gain over a white diffuse target")
    retro_lobe_deg: float = Field(25.0, gt=0, le=90)
    extinction_per_km: float = Field(0.0, ge=0, le=100, description="rain or fog: two-way attenuation exp(-2 alpha r)")
    backscatter_probability: float = Field(0.0, ge=0, le=1, description="rain, snow or fog: chance that a ray returns "
                                           "from a drop near the sensor first, whether or not it meets a surface")
    backscatter_scale_m: float = Field(3.0, gt=0, le=100, description="such returns' distance beyond min_range_m: "
                                       "exponential with this mean (the nearest drops return the most light)")
    backscatter_reflectivity: float = Field(0.002, ge=0, le=1, description="a drop's return against a white target's at "
                                            "the same range")
    detection_threshold: float = Field(0.002, ge=0, description="weaker returns (after attenuation) are not detected")
    motion_during_sweep: bool = Field(False, description="move the scene while the frame is scanned")


class HookScene(StrictModel):
    """The hook scene (document 002): enabled, the scene is the crane vessel with a moving
    boom, rope and block instead of the ship-to-ship pair; the vessel's waves are
    `crane.motion.roll` and `crane.motion.pitch` (about the vessel origin)."""

    enabled: bool = False
    program: Literal["hook-1", "hook-2", "hook-3", "hook-4"] = Field(
        "hook-1", description="joint motion programme of document 002 section 5.2"
    )
    flexible: bool = Field(True, description="flexible boom in the truth simulation")
    deck_cargo: bool = Field(True, description="cargo on the crane vessel's deck below the hook")
    drag_area_m2: float = Field(8.0, ge=0, description="block and load area the wind sees")


class EncoderBias(StrictModel):
    slew: float = 0.0
    luff: float = 0.0


class Mismatch(StrictModel):
    """How reality deviates from the installation. Defaults: none."""

    lidar_mount_rpy_deg: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="true LiDAR mount = surveyed mount rotated by these (sensor axes)"
    )
    radar_mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mru_bias_deg: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="roll, pitch, yaw")
    mru_lag_s: float = Field(0.0, ge=0, le=1, description="the MRU reports the attitude this much late, unstated")
    lidar_clock_offset_s: float = Field(0.0, ge=-1, le=1, description="LiDAR time stamps minus true time")
    radar_clock_offset_s: float = Field(0.0, ge=-1, le=1)
    boom_stiffness: float = Field(1.0, gt=0, le=10, description="true k_f = nominal x this")
    boom_damping: float = Field(1.0, ge=0, le=10, description="true c_f = nominal x this")
    hook_mass: float = Field(1.0, gt=0, le=10, description="true hook and load mass = nominal x this")
    boom_mass: float = Field(1.0, gt=0, le=10)
    rope_ea_n: float | None = Field(
        None, gt=0, description="axial stiffness EA of the whole reeving, N (stretch m g l / EA); null = rigid"
    )
    wind_mps: tuple[float, float] = Field((0.0, 0.0), description="steady wind on block and load, world x, y")
    wind_gusts: bool = Field(False, description="gusts on that wind along its direction: the offshore (NPD, ISO "
                             "19901-1) gust spectrum of its mean speed, drawn with the run's seed")
    encoder_bias_deg: EncoderBias = EncoderBias()
    lidar_noise_scale: float = Field(1.0, ge=0, le=100, description="true LiDAR range noise = stated x this")
    radar_noise_scale: float = Field(1.0, ge=0, le=100, description="true radar range, angle and range-rate noise = "
                                     "stated x this")

    @model_validator(mode="after")
    def _angles_and_wind_finite(self) -> "Mismatch":
        for name in ("lidar_mount_rpy_deg", "radar_mount_rpy_deg", "mru_bias_deg", "wind_mps"):
            require_finite(getattr(self, name), f"mismatch.{name}")
        return self


# A scenario that says nothing of its mismatch still deviates from its installation, as a real
# rig does (its survey, its MRU, its clocks, its crane); `mismatch: {}` is a perfect world.
DEFAULT_MISMATCH = Mismatch(
    lidar_mount_rpy_deg=(0.01, -0.01, 0.02), radar_mount_rpy_deg=(-0.02, 0.02, 0.01), mru_bias_deg=(0.005, -0.005, 0.02),
    mru_lag_s=0.002, lidar_clock_offset_s=0.001, radar_clock_offset_s=-0.001, boom_stiffness=0.95, boom_damping=1.1,
    hook_mass=1.02, boom_mass=0.97, rope_ea_n=1.5e11, wind_mps=(4.0, -2.0),
    encoder_bias_deg=EncoderBias(slew=0.004, luff=-0.004),
)


class Randomize(StrictModel):
    """Draw `mismatch` from documented distributions (data.sim.randomize) instead of taking it
    as written: a study over seeds is then a study over worlds."""

    enabled: bool = False
    seed: int | None = Field(None, ge=0, le=2**31 - 1, description="the draws' seed (null: the run's seed)")
    scale: float = Field(1.0, ge=0, le=3, description="every distribution's width times this (0: the nominal world, "
                         "no mismatch)")


class World(StrictModel):
    truth_rate_hz: float = Field(200.0, gt=0, le=10000)
    crane: CraneVessel = CraneVessel()
    feeder: FeederVessel = FeederVessel()
    sea: Sea = Sea()
    lidar: LidarBehaviour = LidarBehaviour()
    radar: RadarBehaviour = RadarBehaviour()
    mru: MruBehaviour = MruBehaviour()
    hook: HookScene = HookScene()
    lift: LiftScene = LiftScene()
    mismatch: Mismatch = DEFAULT_MISMATCH
    randomize: Randomize = Randomize()


# ---------------------------------------------------------------------------------------
# The sensors as they really are: the spec, how they behave, and where they really point


class Lidar(LidarSpec, LidarBehaviour):
    """The true LiDAR the simulator casts: spec sheet + behaviour (its true pose on the boom
    tip is `true_T_boomtip_sensor`)."""


class Radar(RadarSpec, RadarBehaviour):
    """The true radar the simulator casts: spec sheet + behaviour."""


def true_lidar(spec: LidarSpec, world: World) -> Lidar:
    """The LiDAR as it really is: its spec, the world's behaviour, its noise as the world scales it."""
    real = Lidar.model_validate({**spec.model_dump(), **world.lidar.model_dump()})
    # a copy, not validated: a scaled noise may lie beyond what a spec sheet may state
    return real.model_copy(update={"range_noise_m": spec.range_noise_m * world.mismatch.lidar_noise_scale})


def true_radar(spec: RadarSpec, world: World) -> Radar:
    """The radar as it really is: its spec, the world's behaviour, every noise as the world scales it."""
    k = world.mismatch.radar_noise_scale
    noises = ("range_noise_m", "azimuth_noise_deg", "elevation_noise_deg", "range_rate_noise_mps")
    real = Radar.model_validate({**spec.model_dump(), **world.radar.model_dump()})
    return real.model_copy(update={n: getattr(spec, n) * k for n in noises})


def in_windows(t_s: np.ndarray, windows: Windows) -> np.ndarray:
    """Which times fall inside any [start, end) window."""
    t = np.asarray(t_s, dtype=float)
    out = np.zeros(t.shape, dtype=bool)
    for a, b in windows:
        out |= (t >= a) & (t < b)
    return out


def true_T_boomtip_sensor(surveyed: Mount, error_rpy_deg) -> np.ndarray:
    """The surveyed mount rotated by an error about the sensor's own axes (matrices, not Euler
    angles: the default mount's pitch of 90 deg is a gimbal lock)."""
    T = surveyed.matrix()
    T[:3, :3] = T[:3, :3] @ Rotation.from_euler("xyz", error_rpy_deg, degrees=True).as_matrix()
    return T


def mru_faults(t: np.ndarray, rpy: np.ndarray, rate: np.ndarray, glitches_s, glitch_rpy_rad: np.ndarray,
               frozen_s) -> tuple[np.ndarray, np.ndarray]:
    """The MRU's samples with its faults: inside a glitch window the glitch's attitude (rates
    as they were); inside a frozen window the last sample before it, bit for bit."""
    rpy, rate = rpy.copy(), rate.copy()
    rpy[in_windows(t, glitches_s)] = glitch_rpy_rad
    for a, b in frozen_s:
        inside = np.flatnonzero((t >= a) & (t < b))
        if len(inside) and inside[0] > 0:
            rpy[inside], rate[inside] = rpy[inside[0] - 1], rate[inside[0] - 1]
    return rpy, rate
