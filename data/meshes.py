"""Mesh primitives and surface materials shared by the simulator's scene and the known
models that processing fits (the hook block): body labels, radar cross-section classes,
parts with materials, and the primitive builders."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
import trimesh


class Label(IntEnum):
    NONE = 0  # no surface (false alarm)
    SEA = 1
    CRANE_HULL = 2
    CRANE_DECK = 3
    CRANE_STRUCTURE = 4  # superstructure, pedestal, boom
    FEEDER_HULL = 10
    FEEDER_DECK = 11
    FEEDER_BULWARK = 12
    REFLECTOR = 13
    FALSE_BRIGHT = 14  # bright patch that is not a deck marker
    SPRAY = 15  # a weak return from spray in the air
    PRECIPITATION = 16  # a return from rain, snow or fog near the sensor (backscatter)
    MULTIPATH = 17  # a radar ghost: a surface's echo by way of the sea, seen mirrored below it
    CARGO = 20
    HOOK = 30
    ROPE = 31
    LOAD = 32  # a load hanging from the hook (the lift)
    SLING = 33  # the slings between the hook and the load


class RcsClass(IntEnum):
    WEAK = 0  # sea surface, painted wood: often missed
    STEEL = 1  # hull plating, deck, cargo steel
    CORNER = 2  # corner-like structures and markers


# Radar detection probability factor per RCS class (times the scenario's detection probability).
RCS_DETECTION_FACTOR = np.array([0.3, 1.0, 1.0])


@dataclass
class Part:
    mesh: trimesh.Trimesh
    label: Label
    reflectivity: float
    retro: bool = False
    rcs: RcsClass = RcsClass.STEEL
    face_label: np.ndarray | None = None  # per-face override


@dataclass
class Body:
    """A rigid body: one mesh in the body frame plus per-face materials."""

    name: str
    vertices: np.ndarray  # (V,3) float64, body frame
    triangles: np.ndarray  # (F,3) int64
    face_label: np.ndarray  # (F,) int16
    face_reflectivity: np.ndarray  # (F,) float32
    face_retro: np.ndarray  # (F,) bool
    face_rcs: np.ndarray  # (F,) int8
    static_in_world: bool = False
    meta: dict = field(default_factory=dict)

    @classmethod
    def from_parts(cls, name: str, parts: list[Part], **kw) -> "Body":
        verts, tris, lab, refl, retro, rcs = [], [], [], [], [], []
        offset = 0
        for p in parts:
            m = p.mesh
            verts.append(np.asarray(m.vertices, dtype=float))
            tris.append(np.asarray(m.faces, dtype=np.int64) + offset)
            offset += len(m.vertices)
            nf = len(m.faces)
            lab.append(p.face_label if p.face_label is not None else np.full(nf, int(p.label)))
            refl.append(np.full(nf, p.reflectivity))
            retro.append(np.full(nf, p.retro))
            rcs.append(np.full(nf, int(p.rcs)))
        return cls(
            name=name,
            vertices=np.vstack(verts),
            triangles=np.vstack(tris),
            face_label=np.concatenate(lab).astype(np.int16),
            face_reflectivity=np.concatenate(refl).astype(np.float32),
            face_retro=np.concatenate(retro).astype(bool),
            face_rcs=np.concatenate(rcs).astype(np.int8),
            **kw,
        )

    def trimesh(self) -> trimesh.Trimesh:
        return trimesh.Trimesh(self.vertices, self.triangles, process=False)


# ---------------------------------------------------------------------------------------
# Primitive builders


def box(center, extents) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(center))



def cylinder(radius: float, height: float, center, axis=(0, 0, 1), sections: int = 96) -> trimesh.Trimesh:
    m = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    T = trimesh.geometry.align_vectors([0, 0, 1], np.asarray(axis, float) / np.linalg.norm(axis))
    T[:3, 3] = center
    return m.apply_transform(T)
