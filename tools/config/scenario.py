"""Scenario files: world + installation (+ processing overrides), YAML loading and dotted
`--set` overrides.

A scenario's `world` section is what only the simulator sees (data/sim/world.py), its
`installation` what a real rig documents (data/installation.py), and `processing` the
settings of perception and fusion (tools/config/processing.py). Keys are written in full
(`world.crane.motion.heave.amplitude`) or, where unambiguous, without their section
(`crane.motion.heave.amplitude`, `lidar.rate_hz`): each short key is resolved to the one
section that has it. Angles are degrees here (the YAML/CLI edge), radians inside the code.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from boomtip.data.io.beams import BeamsFileError, beam_angles_deg
from boomtip.data.keys import format_validation, leaf_keys, nearest_keys, settings_dump
from boomtip.data.sim.run import SimulatedRun
from boomtip.tools.config.catalog import SCENARIO_DIR, available_scenarios  # noqa: F401 (this module's API)
from boomtip.tools.config.processing import Processing


class ScenarioError(ValueError):
    """A scenario could not be loaded: unknown name or key, bad value. The message names it."""


class Scenario(SimulatedRun):
    """A simulated run (the world, simulation only; the installation, what processing may know)
    and, optionally, processing settings that differ from the defaults."""

    processing: Processing = Processing()

    def processing_settings(self) -> dict:
        return settings_dump(self.processing, exclude_unset=True)


SECTIONS = ("world", "installation", "processing")
TOP_LEVEL = ("name", "description", "seed", "duration_s") + SECTIONS


# ---------------------------------------------------------------------------------------
# Loading and overrides


def valid_keys(model: BaseModel | None = None) -> list[str]:
    """Every dotted key a scenario accepts (leaves only), e.g. `installation.lidar.rate_hz`."""
    return leaf_keys(model or Scenario())


def _nearest(key: str, keys: list[str]) -> str:
    return nearest_keys(key, keys)


def _format_validation(err: ValidationError, source: str, overridden: dict[str, str] | None = None) -> str:
    return format_validation(err, source, keys=valid_keys(), overridden=overridden)


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


_FREE_KEYS = ".irregular.response."  # a dict of per-DOF gains: any DOF name may be added


def _key_index() -> tuple[list[str], set[str]]:
    keys = valid_keys()
    return keys, {k.rsplit(".", i)[0] for k in keys for i in range(k.count(".") + 1)}


def resolve_key(key: str, where: str = "--set") -> str:
    """The full dotted key for `key`: as given when valid, else the one section that has it
    (`lidar.rate_hz` -> `installation.lidar.rate_hz`). Unknown or ambiguous keys are refused
    with the candidates."""
    keys, prefixes = _key_index()

    def known(k: str) -> bool:
        return k in prefixes or (_FREE_KEYS in k and k.split(_FREE_KEYS)[0] + _FREE_KEYS[:-1] in prefixes)

    if known(key):
        return key
    if key.split(".")[0] not in SECTIONS:
        hits = [f"{sec}.{key}" for sec in SECTIONS if known(f"{sec}.{key}")]
        if len(hits) == 1:
            return hits[0]
        if len(hits) > 1:
            raise ScenarioError(f"{where}: key '{key}' is in more than one section; write one of {', '.join(hits)}")
    raise ScenarioError(f"{where}: unknown scenario key '{key}'; nearest valid keys: {_nearest(key, keys)}")


def set_key(data: dict, key: str, value: Any, where: str) -> None:
    node = data
    parts = key.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise ScenarioError(f"{where}: '{key}' goes below a value that is not a mapping")
    node[parts[-1]] = value


def _flatten(node: Any, prefix: str = "") -> list[tuple[str, Any]]:
    if isinstance(node, dict) and node and not prefix.endswith(_FREE_KEYS[1:-1]):
        out: list[tuple[str, Any]] = []
        for k, v in node.items():
            out += _flatten(v, f"{prefix}.{k}" if prefix else str(k))
        return out
    return [(prefix, node)]


def sectioned(raw: dict, source: str) -> dict:
    """A scenario mapping with every key under its section: keys written without one
    (`lidar: {rate_hz: 20}`, the layout before sections) are resolved leaf by leaf."""
    out: dict = {}
    for key, value in _flatten(raw):
        full = key if key.split(".")[0] in TOP_LEVEL else resolve_key(key, source)
        set_key(out, full, value, source)
    return out


def apply_overrides(data: dict, overrides: list[str]) -> tuple[dict, dict[str, str]]:
    """Apply dotted overrides to a raw scenario dict, refusing unknown keys. Returns the dict
    and, per full key, the override text that set it (for error messages)."""
    overridden: dict[str, str] = {}
    for text in overrides:
        key, value = parse_override(text)
        full = resolve_key(key)
        set_key(data, full, value, "--set")
        overridden[full] = text
    return data, overridden


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
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ScenarioError(f"{path}: not valid YAML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{path}: byte {exc.start}: not UTF-8 text; expected a YAML scenario") from None
    if raw is None:
        raise ScenarioError(f"{path}: empty; expected scenario keys (world, installation, processing; "
                            "`boomtip scenarios --show sts-loaded` prints a full one)")
    if not isinstance(raw, dict):
        raise ScenarioError(f"{path}: expected a mapping of scenario keys at the top level")
    raw.setdefault("name", path.stem)
    raw = sectioned(raw, str(path))
    raw, overridden = apply_overrides(raw, overrides or [])
    return scenario_from_dict(raw, source=str(path), overridden=overridden)


def scenario_from_dict(raw: dict, source: str = "scenario", overridden: dict[str, str] | None = None) -> Scenario:
    if not isinstance(raw, dict):
        raise ScenarioError(f"{source}: expected a mapping of scenario keys")
    try:
        scenario = Scenario.model_validate(raw)
    except ValidationError as exc:
        raise ScenarioError(_format_validation(exc, source, overridden)) from None
    lidar = scenario.installation.lidar
    if lidar.beams_file and lidar.pattern == "spinning":  # refused here, with its key, not mid-simulation
        try:
            beam_angles_deg(lidar.beams_file, lidar.channels)
        except BeamsFileError as exc:
            raise ScenarioError(f"installation.lidar.beams_file: {exc}") from None
    return scenario


def scenario_to_yaml(scenario: Scenario) -> str:
    return yaml.safe_dump(scenario.model_dump(mode="json"), sort_keys=False)
