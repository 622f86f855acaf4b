"""Ray casting against moving rigid bodies with Open3D's Embree scene.

Each body's mesh goes into its own `RaycastingScene` once, in its body frame. Per frame
the rays are moved into each body's frame instead (o_b = R^T (o_w - p), d_b = R^T d_w),
cast, and the nearest hit over all bodies is kept. Rigid transforms keep distances, so
t_hit is the world range. No scene is rebuilt per frame.

`cast_fans` is the scanning sensors' path: their rays are fans (one azimuth, many
elevations) from one origin, so a fan's rays in a body's frame are cos(el) A u_f + sin(el) A z:
two vectors per fan, not a matrix per ray. For fans spread round the sensor it first drops,
per fan, the rays that cannot meet the body's bounding box (or only beyond a closer hit
already found): Embree's cost is mostly per ray, and most of a spinning LiDAR's rays would
miss. The rays are built in float64 and rounded once to Embree's float32, into a buffer kept
between frames.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from boomtip.data.meshes import Body
from boomtip.data.sim.fans import Fans, box_corners, transpose_times


class Hits:
    """The nearest hit of each of K rays. `range_m` (K,) is inf on a miss: float32 from
    `cast_fans` (Embree's t), float64 from `cast`. `body` and `face` (K,) int are -1 on a miss.
    `cos_incidence` (K,) is |cos| of the angle between ray and face normal (0 on a miss);
    `normal_world` (K,3) the unit face normals in world axes, when asked for. `flat_face` (K,)
    int32, when the cast had it at hand (`cast_fans` from a first cast), is the face index over
    all bodies (`face_offsets(bodies)[body] + face`; any value on a miss), the materials' index;
    given it and the offsets, `body` and `face` are derived from it when first read (a frame's
    sensor model reads neither)."""

    def __init__(self, range_m: np.ndarray, body: np.ndarray | None, face: np.ndarray | None,
                 cos_incidence: np.ndarray, normal_world: np.ndarray | None = None,
                 flat_face: np.ndarray | None = None, face_offset: np.ndarray | None = None) -> None:
        if (body is None or face is None) and (flat_face is None or face_offset is None):
            raise ValueError("Hits: body and face, or the flat face index and the bodies' face offsets")
        self.range_m, self._body, self._face = range_m, body, face
        self.cos_incidence, self.normal_world, self.flat_face = cos_incidence, normal_world, flat_face
        self._face_offset = face_offset

    @property
    def hit(self) -> np.ndarray:
        return np.isfinite(self.range_m)

    @property
    def body(self) -> np.ndarray:
        if self._body is None:
            self._split_flat_face()
        return self._body

    @property
    def face(self) -> np.ndarray:
        if self._face is None:
            self._split_flat_face()
        return self._face

    def _split_flat_face(self) -> None:
        hit = self.hit
        flat = np.where(hit, self.flat_face, 0)
        body = np.searchsorted(self._face_offset, flat, side="right") - 1
        self._face = np.where(hit, flat - self._face_offset[body], -1).astype(np.int32)
        self._body = np.where(hit, body, -1).astype(np.int32)


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
        # Bounding boxes, padded well beyond float32 rounding of rays out to kilometres.
        lo = np.array([b.vertices.min(axis=0) for b in bodies])
        hi = np.array([b.vertices.max(axis=0) for b in bodies])
        pad = np.maximum(1e-2, 1e-3 * (hi - lo))
        self.box_lo, self.box_hi = lo - pad, hi + pad
        self.box_corners = [box_corners(l, h) for l, h in zip(self.box_lo, self.box_hi)]  # (8,3) each
        self.face_offset = face_offsets(bodies)
        self._fixed_body_cache: dict[int, tuple[np.ndarray, ...]] = {}
        self._fixed_nearest_cache: dict[int, tuple[np.ndarray, float]] = {}
        self._fills: dict[tuple, np.ndarray] = {}  # rows of one fill value per dtype, for `_pad`

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
            s_ray = None  # a stretched body's scale, per ray or for all
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
            cos_inc[closer] = self._incidence(ans["primitive_normals"].numpy().take(closer, axis=0), rays, closer, s_ray)
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

    def cast_fans(
        self,
        fans: Fans,
        R_world_sensor: np.ndarray,
        p_world_sensor: np.ndarray,
        R_world_body: list[np.ndarray],
        p_world_body: list[np.ndarray],
        scale_body: list[np.ndarray | None] | None = None,
        fixed_hits: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
    ) -> Hits:
        """Cast a scanning sensor's fans of rays (see `Fans`). The sensor pose (M,3,3), (M,3)
        and the bodies' poses are given at M = 1 instant (the whole frame) or at M = F, one per
        fan (motion during the sweep); `scale_body` and `fixed_hits` as in `cast`. The same
        hits as `cast` on these rays in world axes. For fans spread over more than half a turn
        (a spinning LiDAR, most of whose rays never come near a body) only the rays that can
        reach a body's box, nearer than the closest hit found so far, are cast into it; a
        narrower grid sees the ships with most of its rays, and that test would cost more than
        the few misses it saves: with one pose it casts the fans from the first to the last
        whose plane cuts the box (`Fans.fans_cutting_box`), one contiguous block of rays."""
        k = len(fans.dirs)
        m = len(R_world_sensor)
        if m not in (1, len(fans.az_rad)):
            raise ValueError(f"cast_fans: {m} sensor poses for {len(fans.az_rad)} fans (expected 1 or one per fan)")
        best_t = best_body = best_face = cos_inc = None  # set by the first body
        best_flat = None  # the flat face index, kept up from a first cast of one pose on
        nearest = np.inf  # a lower bound of best_t: while the box is nearer, no ray is stopped before it
        pending = None  # a first body's fixed hits, copied only if needed (see below)
        for b, scene in enumerate(self.scenes):
            if fixed_hits is not None and b in fixed_hits:
                if best_t is None and pending is None:
                    pending = b
                    continue
                if best_t is None:
                    best_t, best_body, best_face, cos_inc = self._fixed_arrays(pending, fixed_hits[pending])
                    pending = None
                t, face, c = fixed_hits[b]
                closer = np.flatnonzero(t < best_t)
                best_t[closer], cos_inc[closer] = t[closer], c[closer]
                if best_flat is not None:
                    best_flat[closer] = face[closer] + self.face_offset[b]
                else:
                    best_body[closer], best_face[closer] = b, face[closer]
                nearest = min(nearest, self._fixed_nearest(b, t))
                continue
            if best_t is None and fans.wide:
                if pending is not None:
                    best_t, best_body, best_face, cos_inc = self._fixed_arrays(pending, fixed_hits[pending])
                    nearest = self._fixed_nearest(pending, fixed_hits[pending][0])
                    pending = None
                else:
                    best_t = np.full(k, np.inf, dtype=np.float32)
                    best_body = np.full(k, -1, dtype=np.int32)
                    best_face = np.full(k, -1, dtype=np.int32)
                    cos_inc = np.zeros(k, dtype=np.float32)
            R, p = R_world_body[b], p_world_body[b]
            scale = None if scale_body is None else scale_body[b]
            s_ray = None  # a stretched body's scale, per ray or for all
            # Sensor frame -> body frame: x_b = A x_s + o with A = R_b^T R_s, o = R_b^T (p_s - p_b)
            # (then divided by the body's scale, if stretched).
            if m == 1:  # transpose_times' sums in the same order, on Python floats: no numpy call on 3-vectors
                x, Rl = (p_world_sensor[0] - p[0]).tolist(), R[0].tolist()
                o = np.array([[Rl[0][j] * x[0] + Rl[1][j] * x[1] + Rl[2][j] * x[2] for j in range(3)]])
            else:
                o = transpose_times(R, (p_world_sensor - p)[:, :, None])[:, :, 0]
            axes = None if m == 1 and not fans.wide else fans.axes_in(R, R_world_sensor)
            ray_k = fan = None  # every ray, fan by fan
            fan_range = None  # with one pose, the fans whose plane cuts the box (the rays in between)
            if axes is None:
                A = R[0].T @ R_world_sensor[0]
                fan_range = fans.fans_cutting_box(self.box_corners[b], A, o[0], None if scale is None else scale[0])
                if len(fan_range) == 0:
                    continue
            if fans.wide:
                ray_k, fan = fans.reaching_box(self.box_lo[b], self.box_hi[b], axes, o, scale)
                dist = box_distance(self.box_lo[b], self.box_hi[b], o, scale) if b > 0 else None
                if b > 0 and dist.max() >= nearest:  # rays already stopped before the box need no cast
                    ahead = np.take(best_t, ray_k) > (dist[0] if m == 1 else np.take(dist, fan))
                    ray_k, fan = ray_k[ahead], fan[ahead]
                if len(ray_k) == 0:
                    continue
            if axes is None:  # one pose: one product
                rays = fans.body_frame_rays_one_pose(A, o[0], fan_range)
            else:
                rays = fans.body_frame_rays(axes, o, ray_k, fan)
            if scale is not None:  # after the rounding to float32, as `cast` divides its rays
                s_ray = scale[0] if m == 1 else np.take(scale, fans.fan if fan is None else fan, axis=0)
                rays[:, :3] /= s_ray
                rays[:, 3:] /= s_ray
            ans = scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
            t = ans["t_hit"].numpy()
            first = 0 if fan_range is None else fan_range.start * len(fans.el_rad)  # the rays cast: first, first + len(t)
            if best_t is None:
                # The first cast, of every ray (a miss where its fan was not cast): its answer is
                # the best so far (Open3D's invalid id, 2^32 - 1, reads -1 as int32, and a miss's
                # incidence reads the zero normal), and the fixed hits before it, few, go back
                # where they are at least as close.
                best_t, best_face = t, ans["primitive_ids"].numpy().view(np.int32)
                cos_inc = self._incidence(ans["primitive_normals"].numpy(), rays, None, s_ray)
                best_flat = np.add(best_face, int(self.face_offset[b]), dtype=np.int32)  # (any value on a miss)
                if len(t) < k:
                    best_t, cos_inc, best_flat = (self._pad(x, first, k, fill) for x, fill in ((best_t, np.inf), (cos_inc, 0), (best_flat, -1)))
                best_body = best_face = None  # from best_flat if asked for (see Hits)
                if pending is not None:
                    k_f, t_k, face_k, c_k, flat_k = self._fixed_compact(pending, fixed_hits[pending])
                    farther = best_t.take(k_f) < t_k  # ties to the fixed body, as `cast` (the lower index)
                    if farther.any():
                        nearer = ~farther
                        k_f, t_k, face_k, c_k, flat_k = k_f[nearer], t_k[nearer], face_k[nearer], c_k[nearer], flat_k[nearer]
                    best_t[k_f], cos_inc[k_f], best_flat[k_f] = t_k, c_k, flat_k
                    pending = None
                continue
            nearest = 0.0  # (not worth a pass over the hits: later bodies test every ray)
            closer = np.flatnonzero(t < (best_t[first:first + len(t)] if ray_k is None else best_t.take(ray_k)))
            hit_k = closer + first if ray_k is None else ray_k.take(closer)
            best_t[hit_k] = t.take(closer)
            face = ans["primitive_ids"].numpy().take(closer)
            if best_flat is not None:
                best_flat[hit_k] = face + self.face_offset[b]
            else:
                best_body[hit_k], best_face[hit_k] = b, face
            cos_inc[hit_k] = self._incidence(ans["primitive_normals"].numpy().take(closer, axis=0), rays, closer, s_ray)
        if best_t is None and pending is not None:  # no body cast: the fixed hits alone
            best_t, best_body, best_face, cos_inc = self._fixed_arrays(pending, fixed_hits[pending])
        elif best_t is None:  # no ray could reach a body
            best_t, cos_inc = np.full(k, np.inf, dtype=np.float32), np.zeros(k, dtype=np.float32)
            best_body, best_face = np.full(k, -1, dtype=np.int32), np.full(k, -1, dtype=np.int32)
        return Hits(best_t, best_body, best_face, cos_inc, flat_face=best_flat, face_offset=self.face_offset)

    def _incidence(self, n_b: np.ndarray, rays: np.ndarray, ray_i: np.ndarray | None,
                   s_ray: np.ndarray | None) -> np.ndarray:
        """|cos| of the incidence of `rays` (all, or rows ray_i) on the faces hit, whose unit
        normals `n_b` Embree gave with the hits (zero on a miss), in the body frame, where ray
        and face normal already are (no rotation), one component at a time in float32; a stretched body's (scale `s_ray`, (3,) or
        per ray of `rays`) as `stretched_normal_norm` says."""
        c = n_b[:, 0] * (rays[:, 3] if ray_i is None else rays[:, 3].take(ray_i))
        ci = np.empty_like(c)
        for i in (1, 2):
            np.multiply(n_b[:, i], rays[:, 3 + i] if ray_i is None else rays[:, 3 + i].take(ray_i), out=ci)
            c += ci
        np.abs(c, out=c)
        if s_ray is not None:
            c /= stretched_normal_norm(n_b, s_ray if s_ray.ndim == 1 or ray_i is None else s_ray[ray_i])
        return c

    def _pad(self, x: np.ndarray, first: int, k: int, fill) -> np.ndarray:
        """x as rows first.. of k, the other rows `fill`: one concatenate with views of a
        kept row of fills (each row written once, one numpy call)."""
        key = (x.dtype, fill)
        fills = self._fills.get(key)
        if fills is None or len(fills) < k:
            fills = self._fills[key] = np.full(k, fill, dtype=x.dtype)
        return np.concatenate((fills[:first], x, fills[:k - first - len(x)]))

    def _fixed_arrays(self, b: int, fixed: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[np.ndarray, ...]:
        """Copies of fixed hits on body b as the fans' best hits so far: t, body, face, cos."""
        t, face, c = fixed
        body32, face32 = self._fixed_body_face(b, face)
        return t.copy(), body32.copy(), face32.copy(), c.copy()

    def _fixed_nearest(self, b: int, t: np.ndarray) -> float:
        """The least range of fixed hits `t` on body b, kept while the same come back."""
        cached = self._fixed_nearest_cache.get(b)
        if cached is None or cached[0] is not t:
            cached = self._fixed_nearest_cache[b] = (t, float(t.min()))
        return cached[1]

    def _fixed_compact(self, b: int, fixed: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[np.ndarray, ...]:
        """The rays with a fixed hit on body b and their t, face (int32), cos and flat face
        index, kept as `_fixed_body_face`."""
        self._fixed_body_face(b, fixed[1])
        cached = self._fixed_body_cache[b]
        if len(cached) == 3:
            k = np.flatnonzero(fixed[1] >= 0)
            face = cached[2][k]
            cached = self._fixed_body_cache[b] = (*cached, (k, fixed[0][k], face, fixed[2][k], face + int(self.face_offset[b])))
        return cached[3]

    def _fixed_body_face(self, b: int, face: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Body index (-1 on a miss) and face per ray of fixed hits `face` on body b, as int32
        (the fans' hits: half the memory to copy and gather), kept while the same fixed hits
        come back frame after frame."""
        cached = self._fixed_body_cache.get(b)
        if cached is None or cached[0] is not face:
            cached = self._fixed_body_cache[b] = (face, np.where(face >= 0, b, -1).astype(np.int32), face.astype(np.int32))
        return cached[1], cached[2]

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


def stretched_normal_norm(n_b: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """|S^-1 n| for unit face normals n (K,3) of a body stretched by S = diag(scale) ((3,) or
    (K,3)); 1 where n is 0 (a miss). A ray cast as d' = S^-1 R^T d (unit d) meets a face whose
    world normal is R S^-1 n (the inverse transpose), so |cos| = |n . d'| / |S^-1 n|."""
    m = n_b / scale
    norm = np.sqrt(np.einsum("ij,ij->i", m, m))
    norm[norm == 0] = 1
    return norm


def face_offsets(bodies: list[Body]) -> np.ndarray:
    """(B,) int64: where each body's faces start in the faces of all bodies, in order."""
    return np.concatenate([[0], np.cumsum([len(b.triangles) for b in bodies])[:-1]]).astype(np.int64)


def box_distance(box_lo: np.ndarray, box_hi: np.ndarray, o: np.ndarray, scale: np.ndarray | None) -> np.ndarray:
    """A lower bound of the world distance (M,) from the sensor (o, body frame, per pose) to
    the box: exact for a rigid body; a stretched body's scales shrink it by the smallest."""
    if scale is not None:
        o = o / scale
    gap = np.maximum(np.maximum(box_lo - o, o - box_hi), 0.0)
    d = np.sqrt(np.einsum("mi,mi->m", gap, gap))
    return d if scale is None else d * scale.min(axis=1)
