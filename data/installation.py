"""The installation: what a real rig documents on a spec sheet or a survey, and all that
processing (perception and fusion) may know about the hardware.

Sensor patterns, rates, fields of view, resolutions, specified noise and latency; the mounts
as surveyed (`T_boomtip_sensor`); the boom tip on the crane vessel; the crane's geometry and
nominal dynamics (document 002 Table 4.1); the rope's nominal radius; the block model; the deck
markers' height; the MRU's and the encoders' specs. The simulated world may deviate from all of
it (`world.mismatch`); processing never learns by how much.

Angles are degrees here (the YAML edge) and radians inside the code.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from scipy.spatial.transform import Rotation

from boomtip.data.loads import LoadKind, load_mass, load_size


MAX_ANGLE_DEG = 360.0  # a mount angle beyond a turn is a unit or typing error


class StrictModel(BaseModel):
    # Unknown keys are errors: a misspelt key silently falling back to a default is the worst
    # kind of configuration bug. No installation or world quantity is infinite or NaN.
    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)


def require_finite(values, what: str):
    if not all(math.isfinite(float(v)) for v in values):
        raise ValueError(f"{what} must be finite, got {list(values)}")
    return values


class Mount(StrictModel):
    """A sensor's pose on the boom tip as surveyed: T_boomtip_sensor."""

    xyz_m: tuple[float, float, float] = (0.0, 0.0, -0.5)
    # Default: sensor x (boresight) straight down, y along the ship, z across (see README).
    rpy_deg: tuple[float, float, float] = (90.0, 90.0, 0.0)
    accuracy_deg: float = Field(0.0, ge=0, le=10, description="the survey's 1-sigma per rotation axis")

    @field_validator("xyz_m", "rpy_deg")
    @classmethod
    def _is_finite(cls, v):
        return require_finite(v, "a mount")

    @field_validator("rpy_deg")
    @classmethod
    def _is_an_angle(cls, v):
        if any(abs(a) > MAX_ANGLE_DEG for a in v):
            raise ValueError(f"mount angles are degrees within +-{MAX_ANGLE_DEG:g}, got {list(v)}")
        return v

    def matrix(self) -> np.ndarray:
        return mount_matrix(self.xyz_m, self.rpy_deg)


def mount_matrix(xyz_m, rpy_deg) -> np.ndarray:
    """4x4 T_boomtip_sensor from a translation (m) and roll/pitch/yaw (deg, R = Rz Ry Rx)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy_deg, degrees=True).as_matrix()
    T[:3, 3] = xyz_m
    return T


class LidarSpec(StrictModel):
    enabled: bool = True
    pattern: Literal["grid", "spinning"] = "grid"
    rate_hz: float = Field(10.0, gt=0, le=1000)
    clock_sigma_s: float = Field(0.001, ge=0, le=1, description="1-sigma of its time stamps against the MRU's clock (the "
                                 "sync method's: NTP about 1 ms, PTP about 1 us): a D read at the wrong instant is off by "
                                 "D-dot times the offset, an error no averaging removes")
    latency_s: float = Field(0.0, ge=0, le=10)
    # grid pattern (document 000 Table 5.3)
    fov_h_deg: float = Field(120.0, gt=0, le=360)
    fov_v_deg: float = Field(30.0, gt=0, le=180)
    res_h_deg: float = Field(0.5, gt=0, le=90)
    res_v_deg: float = Field(0.5, gt=0, le=90)
    sweep_fraction: float = Field(1.0, gt=0, le=1, description="fraction of the frame period the grid scan takes")
    # spinning pattern (Ouster OS1 class): uniform channel elevations over channel_fov_deg
    channels: int = Field(64, ge=1, le=512)
    channel_fov_deg: float = Field(45.0, gt=0, le=180)
    beams_file: str = Field("", description="spinning pattern: an Ouster sensor-metadata JSON whose beam_altitude_angles "
                            "and beam_azimuth_angles the channels take instead of a uniform fan over channel_fov_deg "
                            "(its beam count must be `channels`; a path relative to the working folder)")
    columns: int = Field(1024, ge=8, le=8192)
    min_range_m: float = Field(0.5, ge=0)
    max_range_m: float = Field(300.0, gt=0)
    range_noise_m: float = Field(0.0, ge=0, le=10, description="specified 1-sigma range noise, strong return")
    range_resolution_m: float = Field(0.0, ge=0, le=10, description="range quantisation step, 0 = off")
    returns: Literal["strongest", "last", "first", "dual"] = Field(
        "strongest", description="the return mode the sensor is configured with, where a ray meets more than one "
        "target (a drop in the air, then a surface): the strongest, the last or the first return, or both (dual)")
    beam_divergence_mrad: float = Field(0.0, ge=0, le=50, description="the beam's full divergence at 1/e^2 (data "
                                        "sheet; an OS1's is about 2.2 mrad): near a depth edge its footprint spans two "
                                        "surfaces and the return mixes them; 0 = a line")
    return_separation_m: float = Field(0.75, gt=0, le=20, description="the least range between two returns of one "
                                       "beam the sensor tells apart (its pulse's extent): nearer, they merge into one "
                                       "at a range between them")
    mount: Mount = Mount()

    @model_validator(mode="after")
    def _ranges(self) -> "LidarSpec":
        if self.min_range_m >= self.max_range_m:
            raise ValueError("lidar.min_range_m must be below lidar.max_range_m")
        if self.beam_divergence_mrad > 1e3 * self.finest_step_rad:  # a footprint spanning rays is no beam of this scan
            raise ValueError(f"lidar.beam_divergence_mrad = {self.beam_divergence_mrad:g}: expected below the scan's finest "
                             f"spacing, {1e3 * self.finest_step_rad:.2f} mrad")
        return self

    @property
    def finest_step_rad(self) -> float:
        """The smaller of the two beam spacings."""
        if self.pattern == "spinning":
            return min(2 * math.pi / self.columns, math.radians(self.channel_fov_deg) / max(self.channels - 1, 1))
        return math.radians(min(self.res_h_deg, self.res_v_deg))

    @property
    def angular_step_rad(self) -> float:
        """The larger of the two beam spacings: what limits a small object's edges."""
        if self.pattern == "spinning":
            return max(2 * math.pi / self.columns, math.radians(self.channel_fov_deg) / max(self.channels - 1, 1))
        return math.radians(max(self.res_h_deg, self.res_v_deg))


class RadarSpec(StrictModel):
    enabled: bool = True
    rate_hz: float = Field(20.0, gt=0, le=1000)
    clock_sigma_s: float = Field(0.001, ge=0, le=1, description="1-sigma of its time stamps against the MRU's clock (the "
                                 "sync method's: NTP about 1 ms, PTP about 1 us): a D read at the wrong instant is off by "
                                 "D-dot times the offset, an error no averaging removes")
    latency_s: float = Field(0.0, ge=0, le=10)
    fov_az_deg: float = Field(60.0, gt=0, le=360)
    fov_el_deg: float = Field(12.0, gt=0, le=180)
    res_az_deg: float = Field(1.0, gt=0, le=90)
    res_el_deg: float = Field(1.5, gt=0, le=90)
    min_range_m: float = Field(0.5, ge=0)
    max_range_m: float = Field(300.0, gt=0)
    range_noise_m: float = Field(0.0, ge=0, le=100)
    azimuth_noise_deg: float = Field(0.0, ge=0, le=90)
    elevation_noise_deg: float = Field(0.0, ge=0, le=90)
    range_rate_noise_mps: float = Field(0.0, ge=0, le=100)
    detection_probability: float = Field(1.0, gt=0, le=1)
    false_alarms_per_scan: float = Field(0.0, ge=0)
    max_abs_range_rate_mps: float = Field(10.0, gt=0, description="largest range rate the radar reports")
    range_resolution_m: float = Field(0.0, ge=0, le=10, description="range bin width (data sheet: c / 2B, about "
                                      "4 cm for 4 GHz of sweep): each detection's range is a bin's; 0 = not quantised")
    range_rate_resolution_mps: float = Field(0.0, ge=0, le=10, description="Doppler bin width (data sheet), 0 = not quantised")
    angle_resolution_deg: float = Field(0.0, ge=0, le=45, description="angle bin width, azimuth and elevation alike (the "
                                        "angle FFT's grid): each detection's angles are a bin's; 0 = not quantised")
    unambiguous_range_rate_mps: float = Field(0.0, ge=0, le=100, description="the radar's unambiguous range rate (data "
                                              "sheet): it reports a rate beyond it wrapped into [-v, v), as FMCW radars do; "
                                              "0 = never wraps")
    velocity_field: str = Field("", description="recorded clouds: the field holding the radial velocity ('' = guess: "
                                "range_rate, doppler, radial_velocity, velocity, v_r)")
    velocity_sign: Literal[1, -1] = Field(1, description="recorded clouds: +1 if that field grows with the range "
                                          "(receding targets positive), -1 if approaching targets are positive")
    mount: Mount = Mount(xyz_m=(0.3, 0.0, -0.5))

    @model_validator(mode="after")
    def _ranges(self) -> "RadarSpec":
        if self.min_range_m >= self.max_range_m:
            raise ValueError("radar.min_range_m must be below radar.max_range_m")
        return self


class MruSpec(StrictModel):
    """A motion reference unit (the crane vessel's; `feeder_mru`: one on the feeder), as its
    data sheet states it."""

    rate_hz: float = Field(200.0, gt=0, le=10000)
    latency_s: float = Field(0.0, ge=0, le=10)
    angle_noise_deg: float = Field(0.0, ge=0, le=10)
    rate_noise_degps: float = Field(0.0, ge=0, le=100)
    bias_accuracy_deg: float = Field(0.0, ge=0, le=10, description="1-sigma of the roll/pitch static error (data sheet)")


class EncoderSpec(StrictModel):
    """Crane joint encoders (document 002, 4.5.1): slew, luff, hoist."""

    rate_hz: float = Field(100.0, gt=0, le=10000)
    latency_s: float = Field(0.0, ge=0, le=10)
    angle_noise_deg: float = Field(0.1, ge=0, le=10)
    hoist_noise_m: float = Field(0.01, ge=0, le=10)


class CraneGeometry(StrictModel):
    """Where the boom tip is (ship-to-ship runs: a fixed tip) and, for the hook chain, the
    crane's geometry of document 002 Table 4.1."""

    boom_tip_m: tuple[float, float, float] = Field(
        (10.0, -40.0, 52.0), description="boom tip in the crane-vessel body frame (fixed-tip runs)"
    )
    waterline_z_m: float | None = Field(None, description="the calm waterline's height in the crane-vessel body frame, "
                                        "as surveyed (the built-in scenarios' body frame has its origin on it: 0): the "
                                        "tip's height above the sea follows, and no plane below the sea is taken for the "
                                        "deck. null: not surveyed, no such bound")
    boom_length_m: float = Field(150.0, gt=0, description="L")
    boom_foot_offset_m: float = Field(10.0, description="b: boom foot from the slewing axis")
    boom_foot_height_m: float = Field(40.0, description="h: boom foot above the crane base")
    crane_base_m: tuple[float, float, float] = Field((50.0, -20.0, 10.0), description="c, vessel frame")

    @field_validator("boom_tip_m", "crane_base_m")
    @classmethod
    def _is_finite(cls, v):
        return require_finite(v, "a crane position")

    @model_validator(mode="after")
    def _tip_above_the_sea(self) -> "CraneGeometry":
        if self.waterline_z_m is not None and not self.boom_tip_m[2] > self.waterline_z_m:
            raise ValueError(f"crane.geometry.waterline_z_m = {self.waterline_z_m:g} m: the waterline must lie below the "
                             f"boom tip (boom_tip_m z = {self.boom_tip_m[2]:g} m)")
        return self


class CraneDynamics(StrictModel):
    """Nominal dynamics (document 002 Table 4.1): what the filter's model assumes."""

    hook_mass_kg: float = Field(1e6, gt=0, description="nominal hook and load mass")
    boom_mass_kg: float = Field(2e6, gt=0)
    boom_stiffness_nm_per_rad: float = Field(2e11, gt=0, description="k_f")
    boom_damping: float = Field(2e9, ge=0, description="c_f, J s/rad")


class CraneSpec(StrictModel):
    geometry: CraneGeometry = CraneGeometry()
    dynamics: CraneDynamics = CraneDynamics()
    rope_radius_m: float = Field(0.04, gt=0, le=0.5, description="hoist rope's nominal radius")
    rope_ea_n: float | None = Field(
        None, gt=0, description="nominal axial stiffness EA of the whole reeving (N); null: rigid"
    )
    block_height_m: float = Field(4.0, gt=1, le=8, description="height of the known block model")


class MarkerSpec(StrictModel):
    """Retro-reflective deck markers the crew lays on the feeder deck (known tape)."""

    enabled: bool = Field(True, description="markers are laid on the deck (false: the reflectors method does not run)")
    height_m: float = Field(0.002, ge=0, le=0.5, description="markers' height above the deck (tape thickness)")


class LoadModel(StrictModel):
    """The load the crane lowers, as the crew knows it (data/loads.py): its kind and size."""

    kind: LoadKind = Field("container20", description="container20, container40, blade_section or box")
    size_m: tuple[float, float, float] | None = Field(None, description="length, width, height (m); null: the kind's "
                                                       "standard size (a box has none: give it)")
    mass_kg: float | None = Field(None, gt=0, description="null: the kind's typical mass")

    def dimensions(self, key: str = "installation.lift.load_model.size_m") -> tuple[float, float, float]:
        return load_size(self.kind, self.size_m, key)

    def mass(self) -> float:
        return load_mass(self.kind, self.mass_kg)

    @model_validator(mode="after")
    def _has_a_size(self) -> "LoadModel":
        self.dimensions()
        return self


class LiftSpec(StrictModel):
    load_model: LoadModel | None = Field(None, description="the load the crane lowers, as known (kind, size, mass); "
                                         "null: unknown (the lift's clearance from its lowest points seen)")


class Installation(StrictModel):
    lidar: LidarSpec = LidarSpec()
    radar: RadarSpec = RadarSpec()
    mru: MruSpec = MruSpec()
    feeder_mru: MruSpec = Field(MruSpec(), description="the feeder's MRU, used when a source has its stream "
                                "(`feeder_mru`): its data sheet")
    encoders: EncoderSpec = EncoderSpec()
    crane: CraneSpec = CraneSpec()
    markers: MarkerSpec = MarkerSpec()
    lift: LiftSpec = LiftSpec()
    attitude: Literal["mru", "level"] = Field(
        "mru", description="'level': no attitude stream; the boom-tip frame is taken as level"
    )

    def T_crane_boomtip(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, 3] = self.crane.geometry.boom_tip_m
        return T

    def T_boomtip_sensor(self) -> dict[str, np.ndarray]:
        return {"lidar": self.lidar.mount.matrix(), "radar": self.radar.mount.matrix()}

    def levelling_bias_sigma_rad(self, sensor: str) -> float:
        """1-sigma of a sensor's constant levelling tilt: its mount survey and the MRU's static
        accuracy (independent), a bias that no averaging over frames removes."""
        return math.radians(math.hypot(getattr(self, sensor).mount.accuracy_deg, self.mru.bias_accuracy_deg))

    def sensors(self) -> tuple[str, ...]:
        return tuple(s for s in ("lidar", "radar") if getattr(self, s).enabled)
