"""The loads a crane lowers onto a feeder's deck: their kinds and standard sizes, shared by the
simulator (data/sim/load_mesh.py) and processing (`installation.lift.load_model`).

Load frame: origin at the centre of the load's underside, z up, x along its length. The
standard sizes are the ISO 668 freight containers' outer dimensions and a blade section's
bounding box; a `box` has no standard size and must be given one.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

LoadKind = Literal["container20", "container40", "blade_section", "box"]

# length, width, height (m) and mass (kg): ISO 668 1CC / 1AA outer sizes at a typical gross mass;
# a blade's root section on its transport frame
STANDARD_SIZE_M: dict[str, tuple[float, float, float]] = {
    "container20": (6.058, 2.438, 2.591),
    "container40": (12.192, 2.438, 2.591),
    "blade_section": (14.0, 3.6, 3.2),
}
STANDARD_MASS_KG: dict[str, float] = {"container20": 20000.0, "container40": 28000.0, "blade_section": 18000.0}
BOX_MASS_KG = 10000.0  # a box given no mass


def load_size(kind: str, size_m: tuple[float, float, float] | None, key: str) -> tuple[float, float, float]:
    """The load's length, width and height: as given, else the kind's standard size. A `box`
    without a size is refused, naming the key."""
    if size_m is not None:
        if not all(np.isfinite(size_m)) or min(size_m) <= 0:
            raise ValueError(f"{key}: a load's size must be three positive lengths (m), got {list(size_m)}")
        return tuple(float(v) for v in size_m)
    if kind not in STANDARD_SIZE_M:
        raise ValueError(f"{key}: a '{kind}' load has no standard size; give its [length, width, height] in metres")
    return STANDARD_SIZE_M[kind]


def load_mass(kind: str, mass_kg: float | None) -> float:
    """The load's mass: as given, else the kind's typical one (a box: BOX_MASS_KG)."""
    return float(mass_kg) if mass_kg is not None else STANDARD_MASS_KG.get(kind, BOX_MASS_KG)
