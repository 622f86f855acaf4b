"""Ray casting against moving rigid bodies with Open3D's Embree scene.

Each body's mesh goes into its own `RaycastingScene` once, in its body frame. Per frame
the rays are moved into each body's frame instead (o_b = R^T (o_w - p), d_b = R^T d_w),
cast, and the nearest hit over all bodies is kept. Rigid transforms keep distances, so
t_hit is the world range. No scene is rebuilt per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from boomtip.data.meshes import Body


@dataclass
class Hits:
    range_m: np.ndarray  # (K,) inf on a miss
    body: np.ndarray  # (K,) int, -1 on a miss
    face: np.ndarray  # (K,) int, -1 on a miss
    cos_incidence: np.ndarray  # (K,) |cos| of the angle between ray and face normal (0 on a miss)
    normal_world: np.ndarray | None = None  # (K,3) unit face normals, world axes, when asked for

    @property
    def hit(self) -> np.ndarray:
        return np.isfinite(self.range_m)


class RayCaster:
    def __init__(self, bodies: list[Body]) -> None:
        self.bodies = bodies
        self.scenes = []
        self.face_normals = []
        self.face_normals32 = []
        for b in bodies:
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(
                o3d.core.Tensor(b.vertices.astype(np.float32)), o3d.core.Tensor(b.triangles.astype(np.uint32))
            )
            self.scenes.append(scene)
            tri = b.vertices[b.triangles]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            self.face_normals.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12))
            self.face_normals32.append(self.face_normals[-1].astype(np.float32))

    def cast(
        self,
        origins_world: np.ndarray,
        dirs_world: np.ndarray,
        R_world_body: list[np.ndarray],
        p_world_body: list[np.ndarray],
        pose_index: np.ndarray | None = None,
        scale_body: list[np.ndarray | None] | None = None,
        fixed_hits: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
        want_normals: bool = False,
    ) -> Hits:
        """Cast K rays (unit directions) against all bodies. `origins_world` is (K,3) or (3,).

        R_world_body[b] is (M,3,3) and p_world_body[b] is (M,3): the pose of body b at M
        instants; `pose_index` (K,) says which instant each ray belongs to (scene motion
        during a sweep). With M = 1, pose_index may be None. `scale_body[b]` (M,3), when
        given, stretches body b along its own axes before the pose (a rope of varying length).
        `fixed_hits[b] = (t, face, cos_incidence)` gives body b's hits directly (see
        `cast_in_body_frame`). World normals are computed only with `want_normals`.
        """
        k = len(dirs_world)
        origins_world = np.broadcast_to(origins_world, (k, 3)) if origins_world.ndim == 1 else origins_world
        best_t = np.full(k, np.inf, dtype=np.float32)
        best_body = np.full(k, -1, dtype=np.int64)
        best_face = np.full(k, -1, dtype=np.int64)
        idx = np.zeros(k, dtype=np.int64) if pose_index is None else pose_index
        rays = np.empty((k, 6), dtype=np.float32)
        cos_inc = np.zeros(k, dtype=np.float32)
        for b, scene in enumerate(self.scenes):
            if fixed_hits is not None and b in fixed_hits:
                # A body rigidly attached to the sensor's mount: its hits (t, face) were cast
                # once and are the same every frame.
                t, face, _ = fixed_hits[b]
                closer = np.flatnonzero(t < best_t)
                best_t[closer] = t[closer]
                best_body[closer] = b
                best_face[closer] = face[closer]
                cos_inc[closer] = fixed_hits[b][2][closer]
                continue
            R, p = R_world_body[b], p_world_body[b]
            if pose_index is None:  # one pose for the whole frame: one matrix product
                rays[:, :3] = (origins_world[:1] - p[0]) @ R[0] if origins_world.strides[0] == 0 else (origins_world - p[0]) @ R[0]
                rays[:, 3:] = dirs_world @ R[0]
            else:
                rays[:, :3] = np.einsum("kji,kj->ki", R[idx], origins_world - p[idx])  # R^T (o - p)
                rays[:, 3:] = np.einsum("kji,kj->ki", R[idx], dirs_world)
            scale = None if scale_body is None else scale_body[b]
            if scale is not None:
                # A body stretched along its axes (the rope): x_world = R (S x_b) + p. The ray
                # parameter t is preserved by this affine map, so casting S^-1 R^T (o - p) along
                # S^-1 R^T d still returns world distances.
                s_ray = scale[0] if pose_index is None else scale[idx]
                rays[:, :3] /= s_ray
                rays[:, 3:] /= s_ray
            ans = scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
            t = ans["t_hit"].numpy()
            closer = np.flatnonzero(t < best_t)
            best_t[closer] = t[closer]
            best_body[closer] = b
            face = ans["primitive_ids"].numpy()[closer]
            best_face[closer] = face
            # Incidence in the body frame, where ray and face normal already are (no rotation);
            # one gather of the rays, float32 throughout. Rotated unit rays stay unit; only a
            # stretched body's rays need normalising.
            d_b = rays[closer][:, 3:]
            c = np.abs(np.einsum("ij,ij->i", self.face_normals32[b][face], d_b))
            if scale is not None:
                c /= np.sqrt(np.einsum("ij,ij->i", d_b, d_b))
            cos_inc[closer] = c
        range_m = np.where(best_body >= 0, best_t.astype(np.float64), np.inf)
        if not want_normals:
            return Hits(range_m, best_body, best_face, cos_inc)
        # Normals from the precomputed face normals of the faces hit, rotated to world axes.
        normal_world = np.zeros((k, 3))
        for b in range(len(self.scenes)):
            m = np.flatnonzero(best_body == b)
            if len(m) == 0:
                continue
            n_b = self.face_normals[b][best_face[m]]
            if scale_body is not None and scale_body[b] is not None:  # normals: inverse transpose of S
                sc = scale_body[b][0] if pose_index is None else scale_body[b][idx[m]]
                n_b = n_b / sc
                n_b /= np.linalg.norm(n_b, axis=-1, keepdims=True)
            R = R_world_body[b]
            normal_world[m] = n_b @ R[0].T if pose_index is None else np.einsum("kij,kj->ki", R[idx[m]], n_b)
        return Hits(range_m, best_body, best_face, cos_inc, normal_world)

    def cast_in_body_frame(self, b: int, origin_body: np.ndarray, dirs_body: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Hits (t, face, |cos incidence|; inf, -1, 0 on a miss) of rays given in body b's own
        frame: for a body that carries the sensor, cast once and pass as `fixed_hits`."""
        rays = np.empty((len(dirs_body), 6), dtype=np.float32)
        rays[:, :3] = origin_body
        rays[:, 3:] = dirs_body
        ans = self.scenes[b].cast_rays(o3d.core.Tensor.from_numpy(rays))
        t = ans["t_hit"].numpy().copy()
        hit = np.isfinite(t)
        face = np.where(hit, ans["primitive_ids"].numpy().astype(np.int64), -1)
        cos_inc = np.zeros(len(t), dtype=np.float32)
        cos_inc[hit] = np.abs(np.einsum("ij,ij->i", self.face_normals[b][face[hit]], dirs_body[hit]))
        return t, face, cos_inc
