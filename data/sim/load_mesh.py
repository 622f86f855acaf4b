"""The meshes of a lift's load (data/loads.py's kinds) and its slings, in the load frame:
origin at the centre of the load's underside, z up, x along its length."""

from __future__ import annotations

import numpy as np
import trimesh

from boomtip.data.meshes import Label, Part, box

SLING_WIDTH_M = 0.06  # a wire sling's apparent thickness
BLADE_FRAME_HEIGHT_M = 0.6  # the transport frame under a blade section


def _blade_section(length_m: float, width_m: float, height_m: float) -> list[Part]:
    """A blade's root section on a transport frame: an elliptic tube along x on a flat frame."""
    frame_h = min(BLADE_FRAME_HEIGHT_M, 0.3 * height_m)
    tube_h = height_m - frame_h
    tube = trimesh.creation.cylinder(radius=0.5, height=length_m, sections=32)
    tube.apply_transform(trimesh.geometry.align_vectors([0, 0, 1], [1, 0, 0]))
    tube.apply_scale([1.0, width_m, tube_h])
    tube.apply_translation([0.0, 0.0, frame_h + tube_h / 2])
    return [Part(box([0, 0, frame_h / 2], [length_m, width_m, frame_h]), Label.LOAD, 0.35),
            Part(tube, Label.LOAD, 0.7)]


def load_parts(kind: str, size_m: tuple[float, float, float], sling_height_m: float) -> list[Part]:
    """The load in its own frame (origin under its centre), with four slings from its top
    corners to the hook at `sling_height_m` above its top."""
    length, width, height = size_m
    if kind == "blade_section":
        parts = _blade_section(length, width, height)
    else:
        parts = [Part(box([0, 0, height / 2], [length, width, height]), Label.LOAD, 0.35)]
    if sling_height_m > 0:
        hook = np.array([0.0, 0.0, height + sling_height_m])
        for sx in (-1, 1):
            for sy in (-1, 1):
                corner = np.array([sx * length / 2, sy * width / 2, height])
                parts.append(Part(_strut(corner, hook, SLING_WIDTH_M), Label.SLING, 0.3))
    return parts


def _strut(p0: np.ndarray, p1: np.ndarray, width_m: float) -> trimesh.Trimesh:
    """A thin square bar from p0 to p1."""
    d = p1 - p0
    m = trimesh.creation.box(extents=[width_m, width_m, float(np.linalg.norm(d))])
    T = trimesh.geometry.align_vectors([0, 0, 1], d / np.linalg.norm(d))
    T[:3, 3] = (p0 + p1) / 2
    return m.apply_transform(T)
