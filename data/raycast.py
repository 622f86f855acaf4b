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
        for b in bodies:
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(
                o3d.core.Tensor(b.vertices.astype(np.float32)), o3d.core.Tensor(b.triangles.astype(np.uint32))
            )
            self.scenes.append(scene)

    def cast(
        self,
        origins_world: np.ndarray,
        dirs_world: np.ndarray,
        R_world_body: list[np.ndarray],
        p_world_body: list[np.ndarray],
        pose_index: np.ndarray | None = None,
    ) -> Hits:
        """Cast K rays (unit directions) against all bodies.

        R_world_body[b] is (M,3,3) and p_world_body[b] is (M,3): the pose of body b at M
        instants; `pose_index` (K,) says which instant each ray belongs to (scene motion
        during a sweep). With M = 1, pose_index may be None.
        """
        k = len(origins_world)
        best_t = np.full(k, np.inf)
        best_body = np.full(k, -1, dtype=np.int64)
        best_face = np.full(k, -1, dtype=np.int64)
        best_n_body = np.zeros((k, 3))
        idx = np.zeros(k, dtype=np.int64) if pose_index is None else pose_index
        for b, scene in enumerate(self.scenes):
            if pose_index is None:  # one pose for the whole frame: one matrix product
                R0 = R_world_body[b][0]
                o_b = (origins_world - p_world_body[b][0]) @ R0  # rows: R^T (o - p)
                d_b = dirs_world @ R0
            else:
                R = R_world_body[b][idx]  # (K,3,3)
                o_b = np.einsum("kji,kj->ki", R, origins_world - p_world_body[b][idx])
                d_b = np.einsum("kji,kj->ki", R, dirs_world)
            rays = o3d.core.Tensor(np.hstack([o_b, d_b]).astype(np.float32))
            ans = scene.cast_rays(rays)
            t = ans["t_hit"].numpy().astype(float)
            closer = t < best_t
            best_t[closer] = t[closer]
            best_body[closer] = b
            best_face[closer] = ans["primitive_ids"].numpy()[closer].astype(np.int64)
            best_n_body[closer] = ans["primitive_normals"].numpy()[closer]
        # Normals back to world axes with the pose of the body each ray hit.
        normal_world = np.zeros((k, 3))
        for b in range(len(self.scenes)):
            m = best_body == b
            if not m.any():
                continue
            if pose_index is None:
                normal_world[m] = best_n_body[m] @ R_world_body[b][0].T
            else:
                normal_world[m] = np.einsum("kij,kj->ki", R_world_body[b][idx[m]], best_n_body[m])
        return Hits(best_t, best_body, best_face, normal_world)
