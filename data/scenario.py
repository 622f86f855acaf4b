"""Scenario files: typed models with defaults, YAML loading and dotted `--set` overrides.

A scenario fully describes a simulated run: both vessels' geometry and motion, the sea,
and the sensors at the boom tip. Angles are degrees here (the YAML/CLI edge) and radians
everywhere inside the code.
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

SCENARIO_DIR = Path(__file__).parent / "scenarios"
DOFS = ("surge", "sway", "heave", "roll", "pitch", "yaw")


class ScenarioError(ValueError):
    """A scenario could not be loaded: unknown name or key, bad value. The message names it."""


class _Model(BaseModel):
    # Unknown keys are errors: a misspelt key silently falling back to a default is the
    # worst kind of scenario bug.
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class Sinusoid(_Model):
    amplitude: float = Field(0.0, description="m for surge/sway/heave, deg for roll/pitch/yaw")
    period_s: float = Field(10.0, gt=0)
    phase_deg: float = 0.0


class Motion(_Model):
    surge: Sinusoid = Sinusoid()
    sway: Sinusoid = Sinusoid()
    heave: Sinusoid = Sinusoid()
    roll: Sinusoid = Sinusoid()
    pitch: Sinusoid = Sinusoid()
    yaw: Sinusoid = Sinusoid()


class IrregularSea(_Model):
    """Irregular sea added on top of the sinusoids: a JONSWAP spectrum of wave elevation,
    turned into each DOF through a per-DOF gain (m or deg per metre of wave)."""

    enabled: bool = False
    hs_m: float = Field(2.0, gt=0, description="significant wave height")
    tp_s: float = Field(10.0, gt=0, description="peak period")
    gamma: float = Field(3.3, ge=1.0, description="JONSWAP peak enhancement")
    n_components: int = Field(64, ge=4, le=4096)
    response: dict[Literal["surge", "sway", "heave", "roll", "pitch", "yaw"], float] = Field(
        default_factory=lambda: {"heave": 0.5, "roll": 0.4, "pitch": 0.6}
    )


class CraneGeometry(_Model):
    length_m: float = Field(216.0, gt=0)
    beam_m: float = Field(49.0, gt=0)
    freeboard_m: float = Field(10.0, gt=0, description="main deck above the waterline")
    draft_m: float = Field(8.0, gt=0)
    pedestal_m: tuple[float, float] = (10.0, -8.0)
    boom_tip_m: tuple[float, float, float] = Field(
        (10.0, -40.0, 52.0), description="boom tip in the crane-vessel body frame"
    )


class FeederGeometry(_Model):
    length_m: float = Field(95.0, gt=0)
    beam_m: float = Field(22.0, gt=0)
    freeboard_m: float = Field(4.0, gt=0)
    draft_m: float = Field(5.0, gt=0)
    bulwark_height_m: float = Field(1.2, ge=0)
    position_m: tuple[float, float, float] = Field(
        (0.0, -41.0, 0.0), description="feeder body origin in the world at rest (waterline)"
    )


class Reflectors(_Model):
    """Retro-reflective deck markers (tape patches) along both deck edges."""

    enabled: bool = True
    spacing_m: float = Field(8.0, gt=0)
    size_m: float = Field(1.0, gt=0)
    inset_m: float = Field(1.5, ge=0, description="distance from the bulwark inboard")
    height_m: float = Field(0.002, ge=0, le=0.5, description="markers' height above the deck (tape thickness)")
    false_bright_points: int = Field(
        0, ge=0, description="extra bright patches on cargo/bulwarks that are not markers"
    )


class Vessel(_Model):
    motion: Motion = Motion()
    irregular: IrregularSea = IrregularSea()


class CraneVessel(Vessel):
    geometry: CraneGeometry = CraneGeometry()


class FeederVessel(Vessel):
    geometry: FeederGeometry = FeederGeometry()
    cargo: bool = False
    reflectors: Reflectors = Reflectors()


class Sea(_Model):
    clutter: bool = Field(False, description="LiDAR/radar returns from the sea surface")
    clutter_probability: float = Field(0.02, ge=0, le=1)
    reflectivity: float = Field(0.05, ge=0, le=1)


class Mount(_Model):
    xyz_m: tuple[float, float, float] = (0.0, 0.0, -0.5)
    # Default: sensor x (boresight) straight down, y along the ship, z across (see README).
    rpy_deg: tuple[float, float, float] = (90.0, 90.0, 0.0)


class Lidar(_Model):
    enabled: bool = True
    pattern: Literal["grid", "spinning"] = "grid"
    rate_hz: float = Field(10.0, gt=0, le=1000)
    latency_s: float = Field(0.0, ge=0)
    # grid pattern (document 000 Table 5.3)
    fov_h_deg: float = Field(120.0, gt=0, le=360)
    fov_v_deg: float = Field(30.0, gt=0, le=180)
    res_h_deg: float = Field(0.5, gt=0, le=90)
    res_v_deg: float = Field(0.5, gt=0, le=90)
    # spinning pattern (Ouster OS1 class): uniform channel elevations over fov_v of the channels
    channels: int = Field(64, ge=1, le=512)
    channel_fov_deg: float = Field(45.0, gt=0, le=180)
    columns: int = Field(1024, ge=8, le=8192)
    min_range_m: float = Field(0.5, ge=0)
    max_range_m: float = Field(300.0, gt=0)
    range_noise_m: float = Field(0.0, ge=0, description="1-sigma range noise for a strong return")
    range_resolution_m: float = Field(0.0, ge=0, description="range quantisation step, 0 = off")
    weak_return_noise_gain: float = Field(
        3.0, ge=1, description="range noise grows as sqrt(I_ref/I) up to this factor"
    )
    intensity_noise: float = Field(0.0, ge=0, description="relative 1-sigma intensity noise")
    dropout_probability: float = Field(0.0, ge=0, lt=1)
    retro_gain: float = Field(25.0, gt=0, description="retro-reflector peak gain over a white diffuse target")
    retro_lobe_deg: float = Field(25.0, gt=0, le=90)
    motion_during_sweep: bool = Field(False, description="move the scene while the frame is scanned")
    sweep_fraction: float = Field(
        1.0, gt=0, le=1, description="fraction of the frame period the grid scan takes"
    )
    mount: Mount = Mount()

    @model_validator(mode="after")
    def _ranges(self) -> "Lidar":
        if self.min_range_m >= self.max_range_m:
            raise ValueError("lidar.min_range_m must be below lidar.max_range_m")
        return self


class Radar(_Model):
    enabled: bool = True
    rate_hz: float = Field(20.0, gt=0, le=1000)
    latency_s: float = Field(0.0, ge=0)
    fov_az_deg: float = Field(60.0, gt=0, le=360)
    fov_el_deg: float = Field(12.0, gt=0, le=180)
    res_az_deg: float = Field(1.0, gt=0, le=90)
    res_el_deg: float = Field(1.5, gt=0, le=90)
    min_range_m: float = Field(0.5, ge=0)
    max_range_m: float = Field(300.0, gt=0)
    range_noise_m: float = Field(0.0, ge=0)
    azimuth_noise_deg: float = Field(0.0, ge=0)
    elevation_noise_deg: float = Field(0.0, ge=0)
    range_rate_noise_mps: float = Field(0.0, ge=0)
    detection_probability: float = Field(1.0, gt=0, le=1)
    false_alarms_per_scan: float = Field(0.0, ge=0)
    max_abs_range_rate_mps: float = Field(10.0, gt=0, description="false alarms draw range rates within this")
    mount: Mount = Mount(xyz_m=(0.3, 0.0, -0.5))

    @model_validator(mode="after")
    def _ranges(self) -> "Radar":
        if self.min_range_m >= self.max_range_m:
            raise ValueError("radar.min_range_m must be below radar.max_range_m")
        return self


class Mru(_Model):
    rate_hz: float = Field(200.0, gt=0, le=10000)
    latency_s: float = Field(0.0, ge=0)
    angle_noise_deg: float = Field(0.0, ge=0)
    rate_noise_degps: float = Field(0.0, ge=0)


class Encoders(_Model):
    """Crane joint encoders (document 002, 4.5.1): slew, luff, hoist."""

    rate_hz: float = Field(100.0, gt=0, le=10000)
    latency_s: float = Field(0.0, ge=0)
    angle_noise_deg: float = Field(0.1, ge=0)
    hoist_noise_m: float = Field(0.01, ge=0)


class Hook(_Model):
    """Crane, rope and lower block (document 002). Enabled, the scene is the crane vessel
    with a moving boom, rope and block instead of the ship-to-ship pair; the vessel's waves
    are `crane.motion.roll` and `crane.motion.pitch` (about the vessel origin)."""

    enabled: bool = False
    program: Literal["hook-1", "hook-2", "hook-3", "hook-4"] = Field(
        "hook-1", description="joint motion programme of document 002 section 5.2"
    )
    flexible: bool = Field(True, description="flexible boom in the truth simulation")
    boom_length_m: float = Field(150.0, gt=0, description="L")
    boom_foot_offset_m: float = Field(10.0, description="b: boom foot from the slewing axis")
    boom_foot_height_m: float = Field(40.0, description="h: boom foot above the crane base")
    crane_base_m: tuple[float, float, float] = Field((50.0, -20.0, 10.0), description="c, vessel frame")
    hook_mass_kg: float = Field(1e6, gt=0)
    boom_mass_kg: float = Field(2e6, gt=0)
    boom_stiffness_nm_per_rad: float = Field(2e11, gt=0, description="k_f")
    boom_damping: float = Field(2e9, ge=0, description="c_f, J s/rad")
    block_height_m: float = Field(4.0, gt=1, le=8)
    rope_radius_m: float = Field(0.04, gt=0)
    deck_cargo: bool = Field(True, description="cargo on the crane vessel's deck below the hook")
    encoders: Encoders = Encoders()


class Scenario(_Model):
    name: str = "custom"
    description: str = ""
    seed: int = Field(0, ge=0)
    duration_s: float = Field(60.0, gt=0)
    truth_rate_hz: float = Field(200.0, gt=0)
    crane: CraneVessel = CraneVessel()
    feeder: FeederVessel = FeederVessel()
    sea: Sea = Sea()
    lidar: Lidar = Lidar()
    radar: Radar = Radar()
    mru: Mru = Mru()
    hook: Hook = Hook()

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        return v.strip() or "custom"


# ---------------------------------------------------------------------------------------
# Loading and overrides


def available_scenarios() -> dict[str, Path]:
    return {p.stem: p for p in sorted(SCENARIO_DIR.glob("*.yaml"))}


def valid_keys(model: BaseModel | None = None) -> list[str]:
    """Every dotted key a scenario accepts (leaves only), e.g. `lidar.rate_hz`."""
    data = (model or Scenario()).model_dump(mode="json")

    def walk(prefix: str, node: Any) -> list[str]:
        if isinstance(node, dict) and node:
            out: list[str] = []
            for k, v in node.items():
                out += walk(f"{prefix}.{k}" if prefix else k, v)
            return out
        return [prefix]

    return walk("", data)


def _nearest(key: str, keys: list[str]) -> str:
    close = difflib.get_close_matches(key, keys, n=5, cutoff=0.5)
    if not close:  # fall back on keys sharing the last component
        leaf = key.rsplit(".", 1)[-1]
        close = [k for k in keys if k.rsplit(".", 1)[-1] == leaf][:5]
    return ", ".join(close) if close else "(none close; `boomtip scenarios --keys` lists all)"


def _format_validation(err: ValidationError, source: str, overridden: dict[str, str] | None = None) -> str:
    lines = []
    for e in err.errors():
        key = ".".join(str(p) for p in e["loc"])
        if overridden and key in overridden:  # the user's --set, not the file, supplied this value
            got = e.get("input")
            lines.append(f"--set {overridden[key]}: key '{key}': {e['msg']} (got {got!r})")
            continue
        if e["type"] == "extra_forbidden":
            lines.append(f"{source}: unknown key '{key}'; nearest valid keys: {_nearest(key, valid_keys())}")
        else:
            got = e.get("input")
            got_s = "" if isinstance(got, (dict, list)) else f" (got {got!r})"
            lines.append(f"{source}: key '{key or '<root>'}': {e['msg']}{got_s}")
    return "\n".join(lines)


def parse_override(text: str) -> tuple[str, Any]:
    """`lidar.rate_hz=20` -> ("lidar.rate_hz", 20). Values are parsed as YAML scalars/lists."""
    if "=" not in text:
        raise ScenarioError(f"--set '{text}': expected dotted.key=value")
    key, raw = text.split("=", 1)
    key = key.strip()
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        raise ScenarioError(f"--set '{text}': value is not valid YAML: {exc}") from None
    return key, value


def apply_overrides(data: dict, overrides: list[str]) -> dict:
    """Apply dotted overrides to a raw scenario dict, refusing unknown keys."""
    keys = valid_keys()
    prefixes = {k.rsplit(".", i)[0] for k in keys for i in range(k.count(".") + 1)}
    for text in overrides:
        key, value = parse_override(text)
        if key not in prefixes and not key.startswith(("crane.irregular.response.", "feeder.irregular.response.")):
            raise ScenarioError(f"--set: unknown scenario key '{key}'; nearest valid keys: {_nearest(key, keys)}")
        node = data
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ScenarioError(f"--set: '{key}' goes below a value that is not a mapping")
        node[parts[-1]] = value
    return data


def load_scenario(name_or_path: str | Path, overrides: list[str] | None = None) -> Scenario:
    """Load a built-in scenario by name or a YAML file by path, then apply `--set` overrides."""
    text = str(name_or_path)
    builtin = available_scenarios()
    if text in builtin:
        path = builtin[text]
    else:
        path = Path(text)
        if not path.is_file():
            raise ScenarioError(
                f"scenario '{text}' is neither a built-in scenario ({', '.join(builtin)}) nor a file"
            )
    try:
        raw = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ScenarioError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(raw, dict):
        raise ScenarioError(f"{path}: expected a mapping of scenario keys at the top level")
    raw.setdefault("name", path.stem)
    raw = apply_overrides(raw, overrides or [])
    overridden = {parse_override(o)[0]: o for o in overrides or []}
    return scenario_from_dict(raw, source=str(path), overridden=overridden)


def scenario_from_dict(raw: dict, source: str = "scenario", overridden: dict[str, str] | None = None) -> Scenario:
    try:
        return Scenario.model_validate(raw)
    except ValidationError as exc:
        raise ScenarioError(_format_validation(exc, source, overridden)) from None


def scenario_to_yaml(scenario: Scenario) -> str:
    return yaml.safe_dump(scenario.model_dump(mode="json"), sort_keys=False)
