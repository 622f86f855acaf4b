"""Scene meshes: crane vessel, feeder vessel with cargo and deck markers, optional sea.

Each body is one triangle mesh in its own body frame (origin at the waterline, midships,
x forward, z up) and every face carries a material: diffuse reflectivity, a
retro-reflective flag, a radar cross-section class, and a label id so that segmentation
can be scored against the label of the face a ray hit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
import trimesh

from data.scenario import Scenario


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
    CARGO = 20
    HOOK = 30
    ROPE = 31


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


def hull(length_m: float, beam_m: float, z_bottom: float, z_top: float, bow_length_m: float) -> trimesh.Trimesh:
    """A prism hull with a tapered bow, extruded from a convex outline."""
    half_l, half_b = length_m / 2, beam_m / 2
    outline = np.array(
        [
            [-half_l, -half_b],
            [half_l - bow_length_m, -half_b],
            [half_l, -0.15 * beam_m],
            [half_l, 0.15 * beam_m],
            [half_l - bow_length_m, half_b],
            [-half_l, half_b],
        ]
    )
    fan = np.array([[0, i, i + 1] for i in range(1, len(outline) - 1)])  # convex outline: fan triangulation
    m = trimesh.creation.extrude_triangulation(outline, fan, height=z_top - z_bottom)
    m.apply_translation([0, 0, z_bottom])
    return m


def beam_between(p0, p1, width: float) -> trimesh.Trimesh:
    """A square-section box from p0 to p1 (a boom)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = p1 - p0
    length = np.linalg.norm(axis)
    m = trimesh.creation.box(extents=[length, width, width])
    T = trimesh.geometry.align_vectors([1, 0, 0], axis / length)
    T[:3, 3] = (p0 + p1) / 2
    m.apply_transform(T)
    return m


def top_faces_label(mesh: trimesh.Trimesh, z_top: float, top: Label, rest: Label) -> np.ndarray:
    normals = mesh.face_normals
    centers = mesh.triangles_center
    is_top = (normals[:, 2] > 0.99) & (np.abs(centers[:, 2] - z_top) < 1e-6)
    return np.where(is_top, int(top), int(rest)).astype(np.int16)


# ---------------------------------------------------------------------------------------
# The two vessels


def crane_vessel(s: Scenario) -> Body:
    g = s.crane.geometry
    h = hull(g.length_m, g.beam_m, -g.draft_m, g.freeboard_m, bow_length_m=0.15 * g.length_m)
    deck_z = g.freeboard_m
    px, py = g.pedestal_m
    pedestal_top = deck_z + 20.0
    tip = np.asarray(g.boom_tip_m)
    # The boom stops short of the tip so the sensors sit in free space below its end.
    boom_end = tip + np.array([0.0, 0.0, 1.5]) + 1.5 * (np.array([px, py, pedestal_top]) - tip) / np.linalg.norm(
        np.array([px, py, pedestal_top]) - tip
    )
    parts = [
        Part(h, Label.CRANE_HULL, 0.25, face_label=top_faces_label(h, deck_z, Label.CRANE_DECK, Label.CRANE_HULL)),
        Part(box([0.35 * g.length_m, 0, deck_z + 10], [0.12 * g.length_m, 0.8 * g.beam_m, 20]), Label.CRANE_STRUCTURE, 0.6),
        Part(trimesh.creation.cylinder(radius=4.0, height=20.0, transform=trimesh.transformations.translation_matrix([px, py, deck_z + 10])),
             Label.CRANE_STRUCTURE, 0.5),
        Part(beam_between([px, py, pedestal_top], boom_end, width=2.5), Label.CRANE_STRUCTURE, 0.5),
    ]
    return Body.from_parts("crane", parts)


def _cargo_parts(s: Scenario) -> list[Part]:
    """Wind-turbine parts and containers on the feeder deck (body frame)."""
    g = s.feeder.geometry
    z = g.freeboard_m
    half_b = g.beam_m / 2
    parts: list[Part] = []
    # Transition pieces: upright cylinders.
    for x in (-32.0, -20.0):
        parts.append(Part(trimesh.creation.cylinder(radius=3.0, height=9.0, sections=32,
                                                    transform=trimesh.transformations.translation_matrix([x, 0.35 * half_b, z + 4.5])),
                          Label.CARGO, 0.55))
    # A blade rack: long, low frame with the blades on top.
    parts.append(Part(box([22.0, -0.45 * half_b, z + 2.0], [36.0, 4.5, 4.0]), Label.CARGO, 0.45))
    # Containers, one stack two high.
    for i, x in enumerate((-40.0, -33.0)):
        parts.append(Part(box([x, -0.55 * half_b, z + 1.3], [6.1, 2.44, 2.6]), Label.CARGO, 0.35))
    parts.append(Part(box([-36.5, -0.55 * half_b, z + 3.9], [6.1, 2.44, 2.6]), Label.CARGO, 0.35))
    parts.append(Part(box([4.0, 0.55 * half_b, z + 1.3], [12.2, 2.44, 2.6]), Label.CARGO, 0.4))
    return parts


def _marker_centers(s: Scenario) -> np.ndarray:
    g, r = s.feeder.geometry, s.feeder.reflectors
    half_l = g.length_m / 2 - 0.15 * g.length_m  # stay off the tapered bow
    xs = np.arange(-g.length_m / 2 + r.inset_m + r.size_m, half_l, r.spacing_m)
    y = g.beam_m / 2 - r.inset_m - r.size_m / 2
    return np.array([[x, sy * y] for sy in (-1, 1) for x in xs])


def feeder_vessel(s: Scenario) -> Body:
    g = s.feeder.geometry
    z = g.freeboard_m
    h = hull(g.length_m, g.beam_m, -g.draft_m, z, bow_length_m=0.15 * g.length_m)
    parts = [Part(h, Label.FEEDER_HULL, 0.3, face_label=top_faces_label(h, z, Label.FEEDER_DECK, Label.FEEDER_HULL))]
    bh, t = g.bulwark_height_m, 0.3
    if bh > 0:
        straight = g.length_m * 0.85
        x_mid = -g.length_m / 2 + straight / 2
        for sy in (-1, 1):
            parts.append(Part(box([x_mid, sy * (g.beam_m / 2 - t / 2), z + bh / 2], [straight, t, bh]), Label.FEEDER_BULWARK, 0.4))
        parts.append(Part(box([-g.length_m / 2 + t / 2, 0, z + bh / 2], [t, g.beam_m, bh]), Label.FEEDER_BULWARK, 0.4))
    r = s.feeder.reflectors
    if r.enabled:
        # Retro-reflective tape patches, 2 mm proud of the deck.
        for cx, cy in _marker_centers(s):
            parts.append(Part(box([cx, cy, z + 0.001], [r.size_m, r.size_m, 0.002]), Label.REFLECTOR, 0.9, retro=True,
                              rcs=RcsClass.CORNER))
    if s.feeder.cargo:
        parts += _cargo_parts(s)
    if r.false_bright_points > 0:
        # Bright patches that are not deck markers: on bulwark tops and cargo sides, seeded.
        rng = np.random.default_rng(s.seed + 101)
        xs = rng.uniform(-g.length_m / 2 + 2, g.length_m / 2 - 0.2 * g.length_m, r.false_bright_points)
        for x in xs:
            side = rng.choice([-1, 1])
            parts.append(Part(box([x, side * (g.beam_m / 2 - t / 2), z + bh + 0.001], [0.6, t, 0.002]),
                              Label.FALSE_BRIGHT, 0.9, retro=True))
    body = Body.from_parts("feeder", parts)
    body.meta["marker_centers_body"] = _marker_centers(s) if r.enabled else np.zeros((0, 2))
    return body


def sea_surface(s: Scenario, half_size_m: float = 2000.0) -> Body:
    m = box([0, 0, -0.05], [2 * half_size_m, 2 * half_size_m, 0.1])
    return Body.from_parts("sea", [Part(m, Label.SEA, s.sea.reflectivity, rcs=RcsClass.WEAK)], static_in_world=True)


def feeder_deck_plane_body(s: Scenario) -> np.ndarray:
    """The feeder's cargo deck plane [a, b, c, d] (n.x + d = 0) in the feeder body frame."""
    return np.array([0.0, 0.0, 1.0, -s.feeder.geometry.freeboard_m])


def build_bodies(s: Scenario) -> list[Body]:
    bodies = [crane_vessel(s), feeder_vessel(s)]
    if s.sea.clutter:
        bodies.append(sea_surface(s))
    return bodies
