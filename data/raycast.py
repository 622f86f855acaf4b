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

from data.scene import Body


@dataclass
class Hits:
    range_m: np.ndarray  # (K,) inf on a miss
    body: np.ndarray  # (K,) int, -1 on a miss
    face: np.ndarray  # (K,) int, -1 on a miss
    normal_world: np.ndarray  # (K,3) unit face normal of the hit, world axes

    @property
    def hit(self) -> np.ndarray:
        return np.isfinite(self.range_m)


class RayCaster:
    def __init__(self, bodies: list[Body]) -> None:
        self.bodies = bodies
        self.scenes = []
        self.face_normals = []
        for b in bodies:
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(
                o3d.core.Tensor(b.vertices.astype(np.float32)), o3d.core.Tensor(b.triangles.astype(np.uint32))
            )
            self.scenes.append(scene)
            tri = b.vertices[b.triangles]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            self.face_normals.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12))

    def cast(
        self,
        origins_world: np.ndarray,
        dirs_world: np.ndarray,
        R_world_body: list[np.ndarray],
        p_world_body: list[np.ndarray],
        pose_index: np.ndarray | None = None,
        scale_body: list[np.ndarray | None] | None = None,
    ) -> Hits:
        """Cast K rays (unit directions) against all bodies. `origins_world` is (K,3) or (3,).

        R_world_body[b] is (M,3,3) and p_world_body[b] is (M,3): the pose of body b at M
        instants; `pose_index` (K,) says which instant each ray belongs to (scene motion
        during a sweep). With M = 1, pose_index may be None. `scale_body[b]` (M,3), when
        given, stretches body b along its own axes before the pose (a rope of varying length).
        """
        k = len(dirs_world)
        origins_world = np.broadcast_to(origins_world, (k, 3)) if origins_world.ndim == 1 else origins_world
        best_t = np.full(k, np.inf, dtype=np.float32)
        best_body = np.full(k, -1, dtype=np.int64)
        best_face = np.full(k, -1, dtype=np.int64)
        idx = np.zeros(k, dtype=np.int64) if pose_index is None else pose_index
        rays = np.empty((k, 6), dtype=np.float32)
        for b, scene in enumerate(self.scenes):
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
            if b == 0:  # first body: no comparison needed
                best_t[:] = t
                hit0 = np.isfinite(t)
                best_body[hit0] = 0
                best_face[hit0] = ans["primitive_ids"].numpy()[hit0]
                continue
            closer = np.flatnonzero(t < best_t)
            best_t[closer] = t[closer]
            best_body[closer] = b
            best_face[closer] = ans["primitive_ids"].numpy()[closer]
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
        range_m = np.where(best_body >= 0, best_t.astype(np.float64), np.inf)
        return Hits(range_m, best_body, best_face, normal_world)
