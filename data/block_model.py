"""The known crane lower block (hook block) and its rope, shared by the simulator and perception.

Block frame: origin = the REFERENCE POINT = the rope attachment at the top centre of the
block (the pendulum's suspension end, what the hook filter's r(a, b, l) models), z up, the
block hanging below the origin, x along the block's long axis (the sheave plane), y along
the sheave axle. Metres.

Layout for the default height of 4 m (widths are fixed, extra height goes into the body):

    z =  0.00  reference point (rope attachment), 5 cm above the sheave crowns
    z = -0.05  crowns of 3 sheaves (radius 0.75 m, 0.26 m thick, axle along y at z = -0.80,
               at y = -0.40, 0, +0.40): the rounded shapes a LiDAR above sees
    z = -0.80  flat top of the block body (box 2.5 x 1.2 x 2.2 m, x y z)
    z = -3.00  bottom of the body; crosshead / trunnion (cylinder along x) below it
    z = -4.00  bottom of the hook (shank + a C-shaped bowl from a few boxes, opening
               towards +x, so the block is NOT symmetric under a 180 deg yaw below the
               body; from above only the symmetric top is visible)

Everything is labelled Label.HOOK; painted steel (yellow), reflectivity 0.45-0.55.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import trimesh

from boomtip.data.meshes import Label, Part, box, cylinder

__all__ = [
    "AMBIGUOUS_SHIFTS_M",
    "SHEAVE_RADIUS_M",
    "SHEAVE_CROWN_Z_M",
    "BODY_TOP_Z_M",
    "BODY_XY_M",
    "lower_block_parts",
    "lower_block_mesh",
    "visible_model_points",
    "rope_mesh",
]

NOMINAL_HEIGHT_M = 4.0
SHEAVE_RADIUS_M = 0.75
SHEAVE_THICKNESS_M = 0.26
SHEAVE_Y_M = (-0.40, 0.0, 0.40)
SHEAVE_CROWN_Z_M = -0.05  # the rope attachment sits 5 cm above the sheave crowns
# Block-frame shifts that map the visible top almost onto itself: one sheave pitch along the axle.
# When part of the block is hidden, a fit to the visible points alone can land one pitch off.
AMBIGUOUS_SHIFTS_M = ((0.0, SHEAVE_Y_M[1] - SHEAVE_Y_M[0], 0.0), (0.0, SHEAVE_Y_M[0] - SHEAVE_Y_M[1], 0.0))
AXLE_Z_M = SHEAVE_CROWN_Z_M - SHEAVE_RADIUS_M  # -0.80
BODY_TOP_Z_M = AXLE_Z_M  # the sheaves' lower halves sit inside the body
BODY_XY_M = (2.5, 1.2)
BODY_HEIGHT_NOMINAL_M = 2.2
# Below the body: trunnion (0.44) + shank and hook (0.56) = 1.0 m at any height.
BELOW_BODY_M = NOMINAL_HEIGHT_M - (-BODY_TOP_Z_M) - BODY_HEIGHT_NOMINAL_M  # 1.0


def lower_block_parts(height_m: float = 4.0) -> list[Part]:
    """The lower block as scene Parts in the block frame (see the module docstring).

    ``height_m`` is the total height from the reference point to the bottom of the hook (3-5 m
    typical); widths stay fixed and the body box takes the difference from the 4 m nominal.
    """
    body_h = BODY_HEIGHT_NOMINAL_M + (height_m - NOMINAL_HEIGHT_M)
    if body_h < 0.5:
        h_min = NOMINAL_HEIGHT_M - BODY_HEIGHT_NOMINAL_M + 0.5
        raise ValueError(f"height_m={height_m} too small for the block model (minimum {h_min} m)")
    parts: list[Part] = []
    for y in SHEAVE_Y_M:
        sheave = cylinder(SHEAVE_RADIUS_M, SHEAVE_THICKNESS_M, [0.0, y, AXLE_Z_M], axis=(0, 1, 0), sections=64)
        parts.append(Part(sheave, Label.HOOK, 0.45))
    z_bottom = BODY_TOP_Z_M - body_h
    body = box([0.0, 0.0, BODY_TOP_Z_M - body_h / 2], [BODY_XY_M[0], BODY_XY_M[1], body_h])
    parts.append(Part(body, Label.HOOK, 0.55))
    # Crosshead / trunnion: a cross pin along x under the body, with the hook shank through it.
    parts.append(Part(cylinder(0.22, 1.6, [0.0, 0.0, z_bottom - 0.22], axis=(1, 0, 0), sections=32), Label.HOOK, 0.5))
    # Hook: shank, then a C-shaped bowl (back, bottom bar, tip) opening towards +x.
    zb = z_bottom - 0.44  # below the trunnion
    parts.append(Part(cylinder(0.13, 0.30, [0.0, 0.0, zb - 0.15], sections=24), Label.HOOK, 0.5))
    z_end = z_bottom - BELOW_BODY_M  # bottom of the hook = -height_m
    parts.append(Part(box([-0.05, 0.0, (zb - 0.30 + z_end) / 2], [0.24, 0.24, (zb - 0.30) - z_end]), Label.HOOK, 0.5))
    parts.append(Part(box([0.25, 0.0, z_end + 0.12], [0.84, 0.24, 0.24]), Label.HOOK, 0.5))
    parts.append(Part(box([0.59, 0.0, z_end + 0.30], [0.16, 0.20, 0.40]), Label.HOOK, 0.5))
    return parts


def lower_block_mesh(height_m: float = 4.0) -> trimesh.Trimesh:
    """All parts of :func:`lower_block_parts` concatenated into one mesh (block frame)."""
    return trimesh.util.concatenate([p.mesh for p in lower_block_parts(height_m)])


def visible_model_points(
    mesh: trimesh.Trimesh,
    n: int = 2000,
    up=(0.0, 0.0, 1.0),
    *,
    occlusion: bool = True,
    view_height_m: tuple[float, ...] = (10.0, 1000.0),
    view_offset_m: float = 0.5,
    seed: int = 0,
) -> np.ndarray:
    """(n, 3) points on the surfaces a LiDAR above the block sees, in the block frame.

    Samples (area-weighted, seeded) the faces whose normal has a positive component along ``up``
    and, with ``occlusion``, also the vertical ones; with ``occlusion`` (default) a sample is kept
    only if it is the first surface hit from at least one viewpoint above the block: at heights
    ``view_height_m`` along ``up`` and offsets of 0 or +-``view_offset_m`` across (the LiDAR sits
    beside the rope's suspension point, and the beams diverge over the block). This drops what a
    LiDAR above never sees (the body top under the sheaves, the hook under the body, the outer
    walls) and keeps what it does see at a slant (the sides of the sheaves through the gaps
    between them). Vectorised: one Open3D ray cast for all samples and viewpoints.
    Without ``occlusion``: all upward-facing faces (normal . up > 0), nothing culled.
    """
    up = np.asarray(up, dtype=float)
    up = up / np.linalg.norm(up)
    nz = mesh.face_normals @ up
    faces = np.flatnonzero(nz > -1e-6 if occlusion else nz > 1e-3)
    sub = mesh.submesh([faces], append=True, repair=False)
    rng = np.random.default_rng(seed)
    # Oversample, cull the occluded samples, keep n.
    m = 8 * n if occlusion else n
    area = sub.area_faces
    f = rng.choice(len(area), size=m, p=area / area.sum())
    tri = sub.triangles[f]
    u, v = rng.random(m), rng.random(m)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    pts = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
    if occlusion:
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                            o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
        e1 = np.cross(up, [1.0, 0, 0] if abs(up[0]) < 0.9 else [0, 1.0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(up, e1)
        top = float((mesh.vertices @ up).max())
        offs = view_offset_m * np.array([-1.0, 0.0, 1.0])
        views = np.array([(top + h) * up + a * e1 + b * e2 for h in view_height_m for a in offs for b in offs])
        # Rays from each viewpoint to each sample: visible if the first hit is the sample itself.
        # One cast per viewpoint, not one for all: all at once (18 x 48,000 rays with Open3D's
        # answers) would peak at about 125 MB for a model of a few hundred kB.
        visible = np.zeros(m, dtype=bool)
        rays = np.empty((m, 6), dtype=np.float32)
        for view in views:
            vec = pts - view  # (m, 3)
            dist = np.linalg.norm(vec, axis=-1)
            rays[:, :3], rays[:, 3:] = view, vec / dist[:, None]
            t = scene.cast_rays(o3d.core.Tensor.from_numpy(rays))["t_hit"].numpy()
            tol = 2e-3 + 2e-6 * dist  # float32 rounding at the long range
            visible |= t > dist - tol
        pts = pts[visible]
    if len(pts) < n:
        raise ValueError(f"only {len(pts)} visible samples for n={n}")
    return pts[:n]


def rope_mesh(radius_m: float = 0.04, sections: int = 24) -> trimesh.Trimesh:
    """A rope: a cylinder of unit length along +z from z = 0 to z = 1 (scale z to the rope length).

    24 sides, so the rope is round to 0.3 mm: with 8 its faces would lie 3.7-4.0 cm from the axis
    (radius 4 cm), and the rope fit (perception.rope), which takes the surface to be the radius
    from the axis, would read that relief as a tilt (a few cm at 200 m).

    Embree's ray parameter is preserved under affine maps, so the simulator can cast rays
    transformed by the inverse of the scaling pose and still read world distances.
    """
    m = trimesh.creation.cylinder(radius=radius_m, height=1.0, sections=sections)
    m.apply_translation([0.0, 0.0, 0.5])
    return m
