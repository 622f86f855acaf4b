"""A LiDAR's own beam angles from its sensor-metadata file, so a simulated rig is the rig one
owns: an Ouster sensor-metadata JSON's `beam_altitude_angles` and `beam_azimuth_angles` (deg),
in the flat layout of firmware 2.0-2.3 or under `beam_intrinsics` (2.4+, 3.x)."""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["BeamsFileError", "beam_angles_deg"]


class BeamsFileError(ValueError):
    """A beams file that is missing, unreadable or does not fit the installation; the message names it."""


def beam_angles_deg(path: str | Path, channels: int) -> tuple[np.ndarray, np.ndarray]:
    """(altitude, azimuth offset) of each beam, deg, in the file's order (Ouster: top beam
    first). Refuses a missing or unreadable file, one without the angles, angles that are not
    finite numbers, two beams at one elevation, and a beam count other than `channels`."""
    alt, az = _read(str(Path(path).expanduser().resolve()) if str(path) else "")
    if len(alt) != channels:
        raise BeamsFileError(f"{path}: {len(alt)} beams, expected {channels} (installation.lidar.channels)")
    if len(np.unique(alt)) != len(alt):
        raise BeamsFileError(f"{path}: two beams share an elevation; expected distinct beam_altitude_angles")
    return alt.copy(), az.copy()


@lru_cache(maxsize=8)
def _read(path: str) -> tuple[np.ndarray, np.ndarray]:
    if not path:
        raise BeamsFileError("installation.lidar.beams_file is empty")
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise BeamsFileError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BeamsFileError(f"{path}: cannot be read ({exc})") from None
    except json.JSONDecodeError as exc:
        raise BeamsFileError(f"{path}: not JSON (line {exc.lineno}: {exc.msg}); expected an Ouster sensor-metadata "
                             "file") from None
    section = doc.get("beam_intrinsics", doc) if isinstance(doc, dict) else None
    if not isinstance(section, dict) or "beam_altitude_angles" not in section:
        raise BeamsFileError(f"{path}: no beam_altitude_angles (flat, or under beam_intrinsics); expected an Ouster "
                             "sensor-metadata file")
    angles = []
    for key in ("beam_altitude_angles", "beam_azimuth_angles"):
        raw = section.get(key, [0.0] * len(section["beam_altitude_angles"]))
        try:
            a = np.asarray(raw, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            a = np.array([np.nan])
        if not (len(a) and np.all(np.isfinite(a)) and np.all(np.abs(a) <= 90.0)):
            raise BeamsFileError(f"{path}: {key} must be a list of finite angles in [-90, 90] deg")
        angles.append(a)
    if len(angles[0]) != len(angles[1]):
        raise BeamsFileError(f"{path}: {len(angles[0])} beam_altitude_angles but {len(angles[1])} beam_azimuth_angles")
    return angles[0], angles[1]
