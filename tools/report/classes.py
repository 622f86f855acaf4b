"""The classes of what boomtip draws, one table for the rerun recording's AnnotationContext and
for the pictures (plots/detections.png): the same id, name and colour wherever a class appears."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CLASSES", "DetectionClass", "by_name", "rgb"]


@dataclass(frozen=True)
class DetectionClass:
    id: int
    name: str  # the key code uses
    label: str  # what a legend says
    colour: str  # "#rrggbb"


CLASSES = (
    DetectionClass(1, "cloud", "LiDAR returns", "#c8c8c8"),
    DetectionClass(2, "deck", "deck plane inliers", "#1f77b4"),
    DetectionClass(3, "deck_radar", "radar deck plane", "#ff7f0e"),
    DetectionClass(4, "bright", "bright returns (reflector candidates)", "#ffbb33"),
    DetectionClass(5, "markers", "reflector markers", "#d62728"),
    DetectionClass(6, "wire", "wire to the deck (D)", "#e6b800"),
    DetectionClass(7, "tip", "boom tip", "#000000"),
    DetectionClass(8, "hook_segment", "hook block points", "#ff2828"),
    DetectionClass(9, "hook_near", "points near the hook", "#5a8cff"),
    DetectionClass(10, "rope", "rope points and axis", "#ff8c00"),
    DetectionClass(11, "hook_block", "fitted block model", "#b000b0"),
    DetectionClass(12, "feeder_model", "feeder structure (registered model)", "#50c8ff"),
    DetectionClass(13, "estimate", "estimate and its 3 sigma", "#28dc50"),
    DetectionClass(14, "truth", "truth (simulated runs)", "#ffffff"),
    DetectionClass(15, "crane_vessel", "crane vessel", "#8c8c96"),
    DetectionClass(16, "feeder_vessel", "feeder vessel", "#4b6e91"),
    DetectionClass(17, "boom", "boom", "#b4a050"),
    DetectionClass(18, "cargo", "cargo and load", "#b46e3c"),
    DetectionClass(19, "load", "the load under the hook (the lift)", "#ff5ad2"),
    DetectionClass(20, "clearance", "the clearance: the load's lowest point to the deck, and the landing point", "#00e6e6"),
)
_BY_NAME = {c.name: c for c in CLASSES}


def by_name(name: str) -> DetectionClass:
    return _BY_NAME[name]


def rgb(colour: str) -> list[int]:
    """"#rrggbb" -> [r, g, b] in 0..255."""
    return [int(colour[i : i + 2], 16) for i in (1, 3, 5)]
