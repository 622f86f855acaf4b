"""A run's processing settings from what the user says on the command line, and the record of
a run's settings that lets anyone repeat it (OUT/settings.json).

Processing settings come, last one winning, from: the defaults; the source's own (a boomtip
recording's meta.json); a YAML file (`--processing FILE.yaml`, keys with or without the
`processing:` section); `--set processing.KEY=VALUE` (or a key without its section where only
processing has it). Unknown keys and bad values are refused with the key.
"""

from __future__ import annotations

import subprocess
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import yaml
from pydantic import ValidationError

from boomtip.data.keys import format_validation, leaf_keys
from boomtip.tools.config.processing import Processing
from boomtip.tools.config.scenario import ScenarioError, parse_override, resolve_key, sectioned, set_key

__all__ = ["processing_settings", "boomtip_version", "boomtip_commit"]

PROCESSING = "processing"
SETTINGS_FILE_KEYS = {"boomtip", "installation", PROCESSING}  # a run's settings.json holds these (and more)


def _merge(base: dict, extra: dict) -> dict:
    out = dict(base)
    for k, v in extra.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _processing_file(path: Path) -> dict:
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such processing file") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{path}: not a YAML text file: {exc}") from None
    if not raw:
        raise ScenarioError(f"{path}: empty; expected processing keys (e.g. `heave: {{deck_lidar: ...}}`, `feeder: ...`)")
    if not isinstance(raw, dict):
        raise ScenarioError(f"{path}: expected a mapping of processing keys")
    if set(raw) == {PROCESSING} or (PROCESSING in raw and SETTINGS_FILE_KEYS <= set(raw)):  # a section, or a settings.json
        raw = raw[PROCESSING]
    full = sectioned({PROCESSING: raw}, str(path))
    extra = set(full) - {PROCESSING}
    if extra:
        raise ScenarioError(f"{path}: keys {sorted(extra)} are not processing settings")
    _validated(full[PROCESSING], str(path))  # the file's own errors name the file
    return full[PROCESSING]


def _validated(data: dict, source: str) -> Processing:
    try:
        return Processing.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(format_validation(exc, source, f"{PROCESSING}.", keys=leaf_keys(Processing(), PROCESSING))) from None


def processing_settings(source_settings: dict, file: Path | None = None, overrides: list[str] | None = None) -> Processing:
    """The run's processing settings (see the module), validated."""
    data = dict(source_settings or {})
    if file is not None:
        data = _merge(data, _processing_file(Path(file)))
    wrapped = {PROCESSING: data}
    for text in overrides or []:
        key, value = parse_override(text)
        full = resolve_key(key)
        if not full.startswith(PROCESSING + "."):
            raise ScenarioError(f"--set '{text}': {full} is not a processing setting; a recording's world and "
                                "installation are what they are (the installation: --installation FILE)")
        set_key(wrapped, full, value, "--set")
    return _validated(wrapped[PROCESSING], "processing settings")


def boomtip_version() -> str:
    try:
        return version("boomtip")
    except PackageNotFoundError:
        return "unknown"


def boomtip_commit(root: Path | None = None) -> str | None:
    """The git commit of the code that runs, when it runs from boomtip's own checkout (an
    editable install); None for an installed package, even one inside another repository.
    root: where boomtip's code is (default: this file's checkout)."""
    root = Path(root or Path(__file__).resolve().parents[2]).resolve()  # tools/config/settings.py -> the root
    git = ["git", "--no-optional-locks", "-C", str(root)]
    try:
        top = subprocess.run([*git, "rev-parse", "--show-toplevel", "HEAD"], capture_output=True, text=True, timeout=5)
        lines = top.stdout.splitlines()
        if top.returncode != 0 or len(lines) != 2 or Path(lines[0]).resolve() != root:
            return None
        dirty = subprocess.run([*git, "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                               text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    return lines[1] + ("+local changes" if dirty.stdout.strip() else "")
