"""Installation files: the installation part of a scenario (`lidar.*`, `radar.*`, `mru.*`,
`crane.geometry.boom_tip_m`, ...) as a YAML file of its own, for recordings that do not carry
one (a folder of PCDs, a bag), and a commented template of every key."""

from __future__ import annotations

from pathlib import Path

import yaml
from pydantic import BaseModel, ValidationError

from boomtip.data.installation import Installation
from boomtip.data.io.recording import RecordingError
from boomtip.data.keys import format_validation, leaf_keys


def load_installation(path: str | Path) -> Installation:
    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such installation file") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{path}: not a YAML text file: {exc}") from None
    if raw is None or raw == {}:
        raise RecordingError(f"{path}: empty; expected installation keys (lidar, radar, mru, crane, ...): "
                             "`boomtip installation --template` prints every one")
    if not isinstance(raw, dict):
        raise RecordingError(f"{path}: expected a mapping of installation keys (lidar, radar, mru, crane, ...)")
    if isinstance(raw, dict) and {"boomtip", "installation", "processing"} <= set(raw):  # a run's settings.json
        raw = raw["installation"]
    if "processing" in raw:
        raise RecordingError(f"{path}: key 'processing': an installation file says what the rig is; processing "
                             "settings go in `--processing FILE.yaml` or `--set processing.KEY=VALUE`")
    raw = raw.get("installation", raw) if set(raw) <= {"installation"} else raw
    try:
        return Installation.model_validate(raw)
    except ValidationError as exc:
        raise RecordingError(format_validation(exc, str(path), keys=leaf_keys(Installation()))) from None


def installation_template() -> str:
    """Every installation key with its default and, where the model has one, its meaning."""
    lines = ["# boomtip installation: what the rig's spec sheets and survey say (degrees, metres, seconds).",
             "# `boomtip process PATH --installation THIS_FILE`; unknown keys are refused.", ""]

    def walk(model: BaseModel, indent: int) -> None:
        for name, info in type(model).model_fields.items():
            value = getattr(model, name)
            pad = "  " * indent
            if isinstance(value, BaseModel):
                lines.append(f"{pad}{name}:")
                walk(value, indent + 1)
                continue
            text = yaml.safe_dump({name: list(value) if isinstance(value, tuple) else value}, default_flow_style=True,
                                  width=200).strip().strip("{}")
            note = f"  # {info.description}" if info.description else ""
            lines.append(f"{pad}{text}{note}")

    walk(Installation(), 0)
    return "\n".join(lines) + "\n"
