"""Perception stages as a library: each runs on one frame of your own points.

Every stage takes an (N, 3) numpy array or an Open3D point cloud (legacy or tensor), with
configurations, random generator and stage timer optional::

    from boomtip.perception import detect_deck

    deck = detect_deck(points, wire_dir_sensor=[0, 0, -1], p_tip_sensor=[0, 0, 0])
    print(deck.status, deck.D_m)

Stages: ``preprocess``, ``ransac_plane``, ``fit_plane_lsq``, ``multi_plane_deck``,
``detect_deck``, ``detect_reflectors``, ``doppler_velocity``, ``fit_rope``, ``detect_hook``,
``heave_distance``; see ``__all__`` for their configurations and results. The per-frame
pipelines that compose them: ``HeavePipeline``, ``FeederPipeline``, ``HookPipeline``.

Names load on first use (PEP 562): the hook stage pulls in Open3D and trimesh (about a second),
which a user of the deck stages, or of any one submodule, need not pay for.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

# Imported now, not lazily: the submodule of the same name would otherwise shadow the function as
# soon as anything imports it (importing a submodule sets the package attribute).
from boomtip.perception.preprocess import PreprocessConfig, preprocess

if TYPE_CHECKING:
    from boomtip.perception.cloud import as_points
    from boomtip.perception.deck import LIDAR_DECK, RADAR_DECK, DeckConfig, DeckResult, detect_deck
    from boomtip.perception.doppler import DopplerConfig, DopplerFit, doppler_velocity
    from boomtip.perception.geometry import heave_distance
    from boomtip.perception.hook import HookConfig, HookDetection, detect_hook
    from boomtip.perception.multi_plane import MultiPlaneConfig, MultiPlaneResult, multi_plane_deck
    from boomtip.perception.plane import PlaneFit, RansacConfig, fit_plane_lsq, ransac_plane
    from boomtip.perception.reflectors import ReflectorConfig, ReflectorResult, detect_reflectors
    from boomtip.perception.rope import RopeConfig, RopeFix, fit_rope
    from boomtip.perception.timing import StageTimes
    from boomtip.perception.pipeline import HeavePipeline
    from boomtip.perception.feeder_pipeline import FeederPipeline
    from boomtip.perception.hook_pipeline import HookPipeline

_SOURCE = {
    "as_points": "cloud",
    "StageTimes": "timing",
    "ransac_plane": "plane", "fit_plane_lsq": "plane", "RansacConfig": "plane", "PlaneFit": "plane",
    "multi_plane_deck": "multi_plane", "MultiPlaneConfig": "multi_plane", "MultiPlaneResult": "multi_plane",
    "detect_deck": "deck", "DeckConfig": "deck", "DeckResult": "deck", "LIDAR_DECK": "deck", "RADAR_DECK": "deck",
    "detect_reflectors": "reflectors", "ReflectorConfig": "reflectors", "ReflectorResult": "reflectors",
    "doppler_velocity": "doppler", "DopplerConfig": "doppler", "DopplerFit": "doppler",
    "fit_rope": "rope", "RopeConfig": "rope", "RopeFix": "rope",
    "detect_hook": "hook", "HookConfig": "hook", "HookDetection": "hook",
    "heave_distance": "geometry",
    "HeavePipeline": "pipeline", "FeederPipeline": "feeder_pipeline", "HookPipeline": "hook_pipeline",
}

__all__ = [
    "preprocess", "PreprocessConfig",
    "ransac_plane", "fit_plane_lsq", "RansacConfig", "PlaneFit",
    "multi_plane_deck", "MultiPlaneConfig", "MultiPlaneResult",
    "detect_deck", "DeckConfig", "DeckResult", "LIDAR_DECK", "RADAR_DECK",
    "detect_reflectors", "ReflectorConfig", "ReflectorResult",
    "doppler_velocity", "DopplerConfig", "DopplerFit",
    "fit_rope", "RopeConfig", "RopeFix",
    "detect_hook", "HookConfig", "HookDetection",
    "heave_distance",
    "as_points", "StageTimes",
    "HeavePipeline", "FeederPipeline", "HookPipeline",
]


def __getattr__(name: str):
    module = _SOURCE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # once: later lookups do not come here
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
