"""Scene meshes: crane vessel, feeder vessel with cargo and deck markers, optional sea.

Each body is one triangle mesh in its own body frame (origin at the waterline, midships,
x forward, z up) and every face carries a material: diffuse reflectivity, a
retro-reflective flag, a radar cross-section class, and a label id so that segmentation
can be scored against the label of the face a ray hit.
"""

from __future__ import annotations

import numpy as np
import trimesh

from boomtip.data.meshes import Body, Label, Part, RcsClass, box, cylinder
from boomtip.data.sim.run import SimulatedRun

FALSE_BRIGHT_SEED_SALT = 101  # the run's seed plus this: where the bright patches that are not markers lie
BULWARK_THICKNESS_M = 0.3


def lofted_hull(
    length_m: float, beam_m: float, z_keel: float, z_deck: float, bow_length_m: float, n_stations: int = 60
) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A ship hull lofted through cross sections: flat bottom, round bilge, wall sides, and a
    bow that narrows with flare (narrower at the keel than at the deck), closed by a flat
    deck and a transom. Returns the mesh and a per-face mask of the (flat) deck faces."""
    half_b = beam_m / 2
    x_bow0 = length_m / 2 - bow_length_m
    # Stations: even along the parallel body, denser in the bow where the shape changes.
    x = np.concatenate([
        np.linspace(-length_m / 2, x_bow0, n_stations // 2, endpoint=False),
        x_bow0 + bow_length_m * np.sin(np.linspace(0, np.pi / 2, n_stations - n_stations // 2)),
    ])
    u = np.clip((x - x_bow0) / bow_length_m, 0, 1)  # 0 aft of the bow, 1 at the stem
    hb_deck = np.maximum(half_b * np.sqrt(1 - u**2), 0.02 * half_b)
    hb_keel = np.maximum(hb_deck * (1 - 0.7 * u), 0.01 * half_b)  # flare: narrower low down
    z_k = z_keel + (z_deck - z_keel) * 0.35 * u**2  # the keel rises towards the stem
    bilge = np.minimum(2.5, 0.8 * hb_keel)
    # Half section (starboard), keel centre -> deck edge: bottom, bilge arc, side.
    nb, na, ns = 4, 6, 5
    tb = np.linspace(0, 1, nb, endpoint=False)
    ta = np.linspace(0, np.pi / 2, na, endpoint=False)
    ts = np.linspace(0, 1, ns)
    y_half = np.hstack([
        tb[None] * (hb_keel - bilge)[:, None],
        (hb_keel - bilge)[:, None] + bilge[:, None] * np.sin(ta)[None],
        hb_keel[:, None] + ts[None] * (hb_deck - hb_keel)[:, None],
    ])
    z_half = np.hstack([
        np.repeat(z_k[:, None], nb, axis=1),
        z_k[:, None] + bilge[:, None] * (1 - np.cos(ta))[None],
        (z_k + bilge)[:, None] + ts[None] * (z_deck - z_k - bilge)[:, None],
    ])
    # Full section from the port deck edge through the keel to the starboard deck edge.
    y_sec = np.hstack([-y_half[:, :0:-1], y_half])
    z_sec = np.hstack([z_half[:, :0:-1], z_half])
    n_s, n_p = y_sec.shape
    verts = np.stack([np.repeat(x[:, None], n_p, axis=1), y_sec, z_sec], axis=-1).reshape(-1, 3)
    vid = np.arange(n_s * n_p).reshape(n_s, n_p)
    a, b, c, d = vid[:-1, :-1], vid[1:, :-1], vid[1:, 1:], vid[:-1, 1:]
    # Wound so that normals point out of the hull (positive volume), deck normals up.
    shell = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    # Deck: strips between consecutive stations' deck edges.
    pl, sb = vid[:, 0], vid[:, -1]
    deck = np.concatenate([np.stack([pl[:-1], pl[1:], sb[1:]], -1), np.stack([pl[:-1], sb[1:], sb[:-1]], -1)])
    # Transom and stem: fans from each end section's centroid.
    ends = []
    for i in (0, n_s - 1):
        centre = len(verts)
        verts = np.vstack([verts, [x[i], 0.0, (z_sec[i].min() + z_deck) / 2]])
        ring = np.append(vid[i], vid[i, 0])
        fan = np.stack([np.full(n_p, centre), ring[:-1], ring[1:]], -1)
        ends.append(fan[:, ::-1] if i == 0 else fan)  # transom faces aft, stem faces forward
    faces = np.concatenate([shell, deck, *ends])
    is_deck = np.zeros(len(faces), dtype=bool)
    is_deck[len(shell):len(shell) + len(deck)] = True
    return trimesh.Trimesh(verts, faces, process=False), is_deck


def patch(center, size_x: float, size_y: float) -> trimesh.Trimesh:
    """A flat, upward-facing rectangle (tape on a deck): no side walls for grazing rays to hit."""
    cx, cy, cz = center
    hx, hy = size_x / 2, size_y / 2
    v = np.array([[cx - hx, cy - hy, cz], [cx + hx, cy - hy, cz], [cx + hx, cy + hy, cz], [cx - hx, cy + hy, cz]])
    return trimesh.Trimesh(v, np.array([[0, 1, 2], [0, 2, 3]]), process=False)




def lattice_boom(p0, p1, width0: float, width1: float, panels: int = 36, member: float = 0.35) -> trimesh.Trimesh:
    """A lattice crane boom: four chords tapering from width0 to width1, with lacing."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = (p1 - p0) / np.linalg.norm(p1 - p0)
    side = np.cross(axis, [0, 0, 1.0])
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-9 else np.array([0, 1.0, 0])
    up = np.cross(side, axis)
    s = np.linspace(0, 1, panels + 1)
    centre = p0[None] + s[:, None] * (p1 - p0)[None]
    half = (width0 + s * (width1 - width0))[:, None] / 2
    corners = [centre + half * (i * side + j * up) for i, j in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    members = []
    for k in range(4):
        c0, c1 = corners[k], corners[(k + 1) % 4]
        for i in range(panels):
            members.append((c0[i], c0[i + 1]))  # chord segment
            members.append((c0[i], c1[i + 1]) if i % 2 == 0 else (c1[i], c0[i + 1]))  # lacing diagonal
        members.append((c0[0], c1[0]))
    return trimesh.util.concatenate([beam_between(a, b, member) for a, b in members])


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


# ---------------------------------------------------------------------------------------
# The two vessels


def crane_vessel(s: SimulatedRun) -> Body:
    g = s.world.crane.geometry
    deck_z = g.freeboard_m
    h, is_deck = lofted_hull(g.length_m, g.beam_m, -g.draft_m, deck_z, bow_length_m=0.15 * g.length_m, n_stations=90)
    px, py = g.pedestal_m
    pedestal_top = deck_z + 20.0
    tip = np.asarray(s.installation.crane.geometry.boom_tip_m)
    foot = np.array([px, py, pedestal_top + 2.0])
    # The boom stops short of the tip so the sensors sit in free space below its end.
    boom_end = tip + np.array([0.0, 0.0, 2.0]) + 1.5 * (foot - tip) / np.linalg.norm(foot - tip)
    x_acc = 0.32 * g.length_m  # accommodation and helideck forward
    parts = [
        Part(h, Label.CRANE_HULL, 0.25, face_label=np.where(is_deck, int(Label.CRANE_DECK), int(Label.CRANE_HULL))),
        Part(box([x_acc, 0, deck_z + 6], [22, 0.8 * g.beam_m, 12]), Label.CRANE_STRUCTURE, 0.6),
        Part(box([x_acc + 2, 0, deck_z + 15], [16, 0.6 * g.beam_m, 6]), Label.CRANE_STRUCTURE, 0.6),
        Part(cylinder(11.0, 0.6, [x_acc + 8, 0, deck_z + 18.5]), Label.CRANE_STRUCTURE, 0.5),
        Part(cylinder(4.0, 20.0, [px, py, deck_z + 10]), Label.CRANE_STRUCTURE, 0.5),
        Part(box([px - 4, py + 3, pedestal_top + 3], [10, 8, 6]), Label.CRANE_STRUCTURE, 0.55),  # crane house
        Part(lattice_boom(foot, boom_end, 3.0, 1.2), Label.CRANE_STRUCTURE, 0.5),
    ]
    return Body.from_parts("crane", parts)


def _blade(length_m: float, root_chord_m: float, tip_chord_m: float, center, stations: int = 60, ring: int = 24) -> trimesh.Trimesh:
    """A wind-turbine blade lying flat along x: elliptical sections tapering root to tip."""
    t = np.linspace(0, 1, stations)
    chord = root_chord_m + (tip_chord_m - root_chord_m) * t**0.7
    thick = np.where(t < 0.1, chord * 0.9, chord * 0.22)  # round root, thin aerofoil outboard
    th = np.linspace(0, 2 * np.pi, ring, endpoint=False)
    ys = 0.5 * chord[:, None] * np.cos(th)[None]
    zs = 0.5 * thick[:, None] * np.sin(th)[None]
    xs = np.repeat((t * length_m)[:, None], ring, axis=1)
    v = np.stack([xs, ys, zs], -1).reshape(-1, 3)
    vid = np.arange(stations * ring).reshape(stations, ring)
    nxt = np.roll(vid, -1, axis=1)
    a, b, c, d = vid[:-1], vid[1:], nxt[1:], nxt[:-1]
    f = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    caps = []
    for i in (0, stations - 1):
        ci = len(v)
        v = np.vstack([v, [t[i] * length_m, 0, 0]])
        caps.append(np.stack([np.full(ring, ci), vid[i], np.roll(vid[i], -1)], -1))
    m = trimesh.Trimesh(v, np.concatenate([f, *caps]), process=False)
    return m.apply_translation(center)


def _cargo_parts(s: SimulatedRun) -> list[Part]:
    """Wind-turbine parts and containers on the feeder deck (body frame)."""
    g = s.world.feeder.geometry
    z = g.freeboard_m
    half_b = g.beam_m / 2
    parts: list[Part] = []
    # Transition pieces: upright cylinders with a top flange.
    for x in (-24.0, -12.0):
        parts.append(Part(cylinder(3.0, 9.0, [x, 0.35 * half_b, z + 4.5]), Label.CARGO, 0.55))
        parts.append(Part(cylinder(3.3, 0.3, [x, 0.35 * half_b, z + 9.15]), Label.CARGO, 0.5))
    # A tower section lying on two saddles.
    parts.append(Part(cylinder(2.5, 24.0, [-12.0, -0.5 * half_b, z + 3.3], axis=(1, 0, 0)), Label.CARGO, 0.5))
    for x in (-20.0, -4.0):
        parts.append(Part(box([x, -0.5 * half_b, z + 0.5], [1.0, 4.0, 1.0]), Label.CARGO, 0.4))
    # A blade rack: two frames carrying three blades.
    for x in (8.0, 30.0):
        parts.append(Part(box([x, -0.45 * half_b, z + 1.5], [1.5, 5.0, 3.0]), Label.CARGO, 0.45))
    for k, dz in enumerate((3.4, 4.4, 5.4)):
        parts.append(Part(_blade(36.0, 3.6, 0.8, [4.0, -0.45 * half_b + (k - 1) * 1.2, z + dz]), Label.CARGO, 0.7))
    # Containers, one stack two high, and a 40 ft unit.
    for x in (-32.0, -25.5):
        parts.append(Part(box([x, -0.62 * half_b, z + 1.3], [6.1, 2.44, 2.6]), Label.CARGO, 0.35))
    parts.append(Part(box([-28.75, -0.62 * half_b, z + 3.9], [6.1, 2.44, 2.6]), Label.CARGO, 0.35))
    parts.append(Part(box([14.0, 0.6 * half_b, z + 1.3], [12.2, 2.44, 2.6]), Label.CARGO, 0.4))
    return parts


def open_deck_x(s: SimulatedRun) -> tuple[float, float]:
    """Fore and aft limits of the open cargo deck (between accommodation and forecastle)."""
    g = s.world.feeder.geometry
    return -g.length_m / 2 + 0.16 * g.length_m, g.length_m / 2 - 0.15 * g.length_m


def _marker_centers(s: SimulatedRun) -> np.ndarray:
    g, r = s.world.feeder.geometry, s.world.feeder.reflectors
    x0, x1 = open_deck_x(s)
    xs = np.arange(x0 + r.size_m, x1 - r.size_m / 2, r.spacing_m)
    y = g.beam_m / 2 - r.inset_m - r.size_m / 2
    return np.array([[x, sy * y] for sy in (-1, 1) for x in xs])


def feeder_vessel(s: SimulatedRun) -> Body:
    g = s.world.feeder.geometry
    z = g.freeboard_m
    h, is_deck = lofted_hull(g.length_m, g.beam_m, -g.draft_m, z, bow_length_m=0.15 * g.length_m)
    parts = [Part(h, Label.FEEDER_HULL, 0.3, face_label=np.where(is_deck, int(Label.FEEDER_DECK), int(Label.FEEDER_HULL)))]
    x0, x1 = open_deck_x(s)
    # Accommodation aft and a forecastle forward: structures the deck detector must not take for the deck.
    parts.append(Part(box([(-g.length_m / 2 + x0) / 2, 0, z + 6], [x0 + g.length_m / 2, 0.8 * g.beam_m, 12]), Label.FEEDER_HULL, 0.6))
    parts.append(Part(box([(x1 + g.length_m / 2 - 0.02 * g.length_m) / 2, 0, z + 1.25],
                          [g.length_m / 2 - 0.02 * g.length_m - x1, 0.5 * g.beam_m, 2.5]), Label.FEEDER_HULL, 0.4))
    bh, t = g.bulwark_height_m, BULWARK_THICKNESS_M
    if bh > 0:
        for sy in (-1, 1):
            parts.append(Part(box([(x0 + x1) / 2, sy * (g.beam_m / 2 - t / 2), z + bh / 2], [x1 - x0, t, bh]), Label.FEEDER_BULWARK, 0.4))
    for x in np.arange(x0 + 4, x1, 15.0):  # mooring bollards along both edges
        for sy in (-1, 1):
            parts.append(Part(cylinder(0.3, 0.8, [x, sy * (g.beam_m / 2 - 0.9), z + 0.4], sections=24), Label.FEEDER_BULWARK, 0.4))
    r = s.world.feeder.reflectors
    if r.enabled:
        # Retro-reflective tape, reflectors.height_m proud of the deck.
        for cx, cy in _marker_centers(s):
            parts.append(Part(patch([cx, cy, z + r.height_m], r.size_m, r.size_m), Label.REFLECTOR, 0.9, retro=True,
                              rcs=RcsClass.CORNER))
    if s.world.feeder.cargo:
        parts += _cargo_parts(s)
    if r.false_bright_points > 0:
        # Bright patches that are not deck markers: on bulwark tops, seeded.
        rng = np.random.default_rng(s.seed + FALSE_BRIGHT_SEED_SALT)
        xs = rng.uniform(x0 + 1, x1 - 1, r.false_bright_points)
        for x in xs:
            side = rng.choice([-1, 1])
            parts.append(Part(patch([x, side * (g.beam_m / 2 - t / 2), z + bh + 0.002], 0.6, t),
                              Label.FALSE_BRIGHT, 0.9, retro=True))
    body = Body.from_parts("feeder", parts)
    body.meta["marker_centers_body"] = _marker_centers(s) if r.enabled else np.zeros((0, 2))
    return body


def sea_surface(s: SimulatedRun, half_size_m: float = 2000.0) -> Body:
    m = box([0, 0, -0.05], [2 * half_size_m, 2 * half_size_m, 0.1])
    return Body.from_parts("sea", [Part(m, Label.SEA, s.world.sea.reflectivity, rcs=RcsClass.WEAK)], static_in_world=True)


def feeder_deck_plane_body(s: SimulatedRun) -> np.ndarray:
    """The feeder's cargo deck plane [a, b, c, d] (n.x + d = 0) in the feeder body frame."""
    return np.array([0.0, 0.0, 1.0, -s.world.feeder.geometry.freeboard_m])


def build_bodies(s: SimulatedRun) -> list[Body]:
    bodies = [crane_vessel(s), feeder_vessel(s)]
    if s.world.sea.clutter:
        bodies.append(sea_surface(s))
    return bodies
