"""The built-in scenarios: where they are and their one-line summaries, read without the
scenario models (which import the simulator and the filters), so that listing them is quick."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

__all__ = ["SCENARIO_DIR", "available_scenarios", "scenario_headline"]

# the built-in scenarios ship with the simulator's data (package data of boomtip.data)
SCENARIO_DIR = Path(str(files("boomtip.data").joinpath("scenarios")))


def available_scenarios() -> dict[str, Path]:
    return {p.stem: p for p in sorted(SCENARIO_DIR.glob("*.yaml"))}


def scenario_headline(path: Path) -> tuple[float, str] | None:
    """(duration_s, description) as the file states them; None when it leaves either to the
    defaults or is not a mapping (the caller then loads it in full)."""
    import yaml

    doc = yaml.load(path.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))  # libyaml when built with it
    if not isinstance(doc, dict) or not isinstance(doc.get("duration_s"), (int, float)) or "description" not in doc:
        return None
    return float(doc["duration_s"]), str(doc["description"])
