"""A scanning sensor's rays as fans (one azimuth, many elevations from one origin), as
`RayCaster.cast_fans` casts them: the rays in a body's frame built from two vectors per fan,
and, per fan, the run of elevations that can reach a box.
"""

from __future__ import annotations

import numpy as np


# Corner c of a box has bits (x, y, z) = (c >> 2, c >> 1, c) & 1; its 12 edges join corners one bit apart.
_CORNER_BITS = (np.arange(8)[:, None] >> np.array([2, 1, 0])) & 1
_EDGES = np.array([(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1])


def box_corners(box_lo: np.ndarray, box_hi: np.ndarray) -> np.ndarray:
    """(8,3): corner c of the box [lo, hi] has bits (x, y, z) = (c >> 2, c >> 1, c) & 1."""
    return np.where(_CORNER_BITS, box_hi, box_lo)


class Fans:
    """A scanning sensor's rays as F fans of N rays from its origin: ray f*N + k points along
    azimuth az[f] (about the sensor z) and elevation el[k] (ascending), i.e. along
    cos(el) u_f + sin(el) z with u_f = (cos az, sin az, 0). Fan f lies in the plane through
    the origin spanned by u_f and z, which is what lets `reaching_box` find, fan by fan, the
    run of elevations that can meet a box. A Fans object holds the buffer its body-frame
    rays are built in: one caster at a time."""

    def __init__(self, dirs: np.ndarray, az_rad: np.ndarray, el_rad: np.ndarray) -> None:
        if len(dirs) != len(az_rad) * len(el_rad) or np.any(np.diff(el_rad) <= 0):
            raise ValueError("Fans: expected F*N rays, fan by fan, with ascending elevations")
        self.dirs, self.az_rad, self.el_rad = dirs, az_rad, el_rad
        self.cos_az, self.sin_az = np.cos(az_rad), np.sin(az_rad)
        self.cos_el, self.sin_el = np.cos(el_rad), np.sin(el_rad)
        self.plane_normals_xy = np.stack([self.cos_az, -self.sin_az])  # (2,F): n_f . x_s = [y, x] @ these (n_f = (-sin az, cos az, 0))
        self.cos_el_ray, self.sin_el_ray = np.tile(self.cos_el, len(az_rad)), np.tile(self.sin_el, len(az_rad))
        self.first_ray = np.arange(len(az_rad)) * len(el_rad)
        self.fan = np.repeat(np.arange(len(az_rad)), len(el_rad))  # (K,) the fan of each ray
        self.wide = np.ptp(az_rad) > np.pi
        self._rays: np.ndarray | None = None  # (K,6) float32, allocated on first use
        self._dirs_h: np.ndarray | None = None  # (K,4) [direction, 1] per ray, for the one-pose product
        self._rays64: np.ndarray | None = None  # (K,6) the one-pose rays before rounding

    def _ray_buffer(self, n: int) -> np.ndarray:
        if self._rays is None:
            self._rays = np.empty((len(self.dirs), 6), dtype=np.float32)
        return self._rays[:n]

    def axes_in(self, R_world_body: np.ndarray, R_world_sensor: np.ndarray) -> np.ndarray:
        """(3,F,3): each fan's plane normal n_f = (-sin az, cos az, 0), its horizontal
        u_f = (cos az, sin az, 0) and the sensor's z, in a body's axes: A e with A = R_b^T R_s
        (poses (M,3,3), M = 1 or one per fan)."""
        R_s = R_world_sensor
        world = np.empty((3, len(self.az_rad), 3))
        world[0] = R_s[:, :, 1] * self.cos_az[:, None] - R_s[:, :, 0] * self.sin_az[:, None]
        world[1] = R_s[:, :, 0] * self.cos_az[:, None] + R_s[:, :, 1] * self.sin_az[:, None]
        world[2] = R_s[:, :, 2]
        axes = R_world_body[:, 0] * world[..., 0:1]  # R_b^T v, written out
        axes += R_world_body[:, 1] * world[..., 1:2]
        axes += R_world_body[:, 2] * world[..., 2:3]
        return axes

    def body_frame_rays_one_pose(self, A: np.ndarray, o: np.ndarray, fans: range | None = None) -> np.ndarray:
        """Rows [origin, direction] of every ray (or of the fans in the range `fans`) in a body
        frame where x_b = A x_s + o (one pose), computed in float64 and rounded once to
        Embree's float32. A view of the buffer the next call overwrites."""
        first, stop = (0, len(self.dirs)) if fans is None else (fans.start * len(self.el_rad), fans.stop * len(self.el_rad))
        if self._dirs_h is None:
            self._dirs_h = np.ones((len(self.dirs), 4))
            self._dirs_h[:, :3] = self.dirs
            self._rays64 = np.empty((len(self.dirs), 6))
        # [o, A d] = [d, 1] @ [[0, A^T], [o, 0]]: every ray's row in one product and one rounding
        # pass, written row after row (the origin's columns filled apart cost as much again).
        # The origin's columns are exact (1 o plus zeros); a direction's is the same dot product.
        M = np.zeros((4, 6))
        M[:3, 3:] = A.T
        M[3, :3] = o
        rays64 = np.matmul(self._dirs_h[first:stop], M, out=self._rays64[:stop - first])
        rays = self._ray_buffer(len(self.dirs))[first:stop]
        rays[...] = rays64
        return rays

    def fans_cutting_box(self, corners: np.ndarray, A: np.ndarray, o: np.ndarray, scale: np.ndarray | None) -> range:
        """The least range of fans holding every fan whose plane cuts a box, `corners` (8,3),
        given in a body frame where x_b = S^-1 (A x_s + o) (one pose; S = diag(scale) or 1): a
        fan whose plane leaves every corner on one side has no ray that can meet the box. A
        corner's distance to fan f's plane, normal n_f = (-sin az, cos az, 0), is n_f . x_s
        with x_s = A^T (S c - o)."""
        x_s = (corners if scale is None else corners * scale) - o
        x_s = x_s @ A  # (8,3) rows x_s^T
        g = x_s[:, 1::-1] @ self.plane_normals_xy  # (8,F): y cos az - x sin az
        lo = np.minimum.reduce(g, axis=0)  # (g.min's values, without its Python wrappers)
        lo *= np.maximum.reduce(g, axis=0)  # <= 0 where the corners are not all on one side (an underflow to 0 only adds a fan)
        cut = (lo <= 0).nonzero()[0]
        return range(0) if len(cut) == 0 else range(int(cut[0]), int(cut[-1]) + 1)

    def body_frame_rays(self, axes: np.ndarray, o: np.ndarray, ray_k: np.ndarray | None = None,
                        fan: np.ndarray | None = None) -> np.ndarray:
        """As `body_frame_rays_one_pose` for the rays (all, or `ray_k` and their fans `fan`,
        fan by fan as `reaching_box` gives them) given the fans' `axes_in` the body and the
        origin o (M = 1 or one per fan): a fan's rays are cos(el) A u_f + sin(el) A z, two
        vectors per fan, not a matrix per ray."""
        n = len(self.dirs) if ray_k is None else len(ray_k)
        rays = self._ray_buffer(n)
        n_fan, n_el = len(self.az_rad), len(self.el_rad)
        if ray_k is None:  # every ray of every fan, one pose per fan
            for i in range(3):
                d = np.multiply.outer(axes[1, :, i], self.cos_el)
                d += np.multiply.outer(axes[2, :, i], self.sin_el)
                rays[:, 3 + i] = d.reshape(-1)
                rays.reshape(n_fan, n_el, 6)[:, :, i] = o[:, i, None]
            return rays
        ce, se = np.take(self.cos_el_ray, ray_k), np.take(self.sin_el_ray, ray_k)
        # Each ray's fan vectors A u_f, A z and origin: the rays come fan by fan, so each fan's
        # column repeated over its rays (a gather along the fans' axis takes 2-3x longer).
        per_fan = np.empty((9, len(self.az_rad)))
        per_fan[0:3], per_fan[3:6], per_fan[6:9] = axes[1].T, axes[2].T, o.T
        g = np.repeat(per_fan, np.bincount(fan, minlength=n_fan), axis=1)  # (9,n)
        for i in range(3):
            d = g[i] * ce
            s = g[3 + i] * se
            d += s
            rays[:, 3 + i] = d
            rays[:, i] = g[6 + i]
        return rays

    def reaching_box(self, box_lo: np.ndarray, box_hi: np.ndarray, axes: np.ndarray, o: np.ndarray,
                     scale: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Indices (ascending) of the rays that can meet a box given in a body frame where
        x_b = S^-1 (A x_s + o) (per pose: M = 1 or one per fan; S = diag(scale) or 1; `axes`
        the fans' `axes_in` the body), and the fan of each.

        The fan's plane cuts the box (an affine image of a box in the sensor frame) in a
        convex polygon whose vertices are where the box's edges meet the plane. If the polygon
        lies where u > 0, the rays reaching it are those with el between its vertices' least
        and greatest angle atan2(z, u); if it lies where u < 0, none; else (the sensor inside
        the box, or a polygon across u = 0) all of the fan."""
        n_fan, n_el = len(self.az_rad), len(self.el_rad)
        corners = box_corners(box_lo, box_hi)  # (8,3), body frame
        # A corner c in fan f's coordinates (distance to the plane, along u_f, along z): e.x_s
        # for e = n_f, u_f, z with x_s = A^T (S c - o), i.e. (S A e).c - (A e).o.
        shift = axes[..., 0] * o[:, 0]  # (3,F), written out: einsum is slower on these
        shift += axes[..., 1] * o[:, 1]
        shift += axes[..., 2] * o[:, 2]
        if scale is not None:
            axes = axes * scale
        g = (corners @ axes.reshape(3 * n_fan, 3).T).reshape(8, 3, n_fan)
        g -= shift
        # Only the fans whose plane has corners on both sides cut the box (most do not).
        cut = np.flatnonzero((g[:, 0].min(axis=0) <= 0) & (g[:, 0].max(axis=0) >= 0))
        g = np.take(g, cut, axis=2).transpose(1, 0, 2)  # (3,8,C)
        # Edge (c0, c1) meets the plane where the distance is 0 (an edge lying in it gives its ends).
        g0, g1 = np.take(g, _EDGES[:, 0], axis=1), np.take(g, _EDGES[:, 1], axis=1)  # (3,12,C)
        s0, s1 = g0[0], g1[0]
        lam = s0 / np.where(s0 != s1, s0 - s1, 1.0)
        u, z = g0[1:] + lam * (g1[1:] - g0[1:])
        u[s0 * s1 > 0] = np.nan  # not a vertex; fmin / fmax skip NaN
        u_min, u_max = np.fmin.reduce(u, axis=0), np.fmax.reduce(u, axis=0)
        front = u_min > 0  # a polygon, all of it where u > 0
        # Where u > 0 the angle atan2(z, u) grows with z / u: two arctangents per fan.
        slope = np.full_like(z, np.nan)
        np.divide(z, u, out=slope, where=u > 0)
        eps = 1e-9  # rad: far above the angles' rounding, far below any ray spacing
        ang_lo = np.arctan(np.fmin.reduce(slope, axis=0)) - eps
        ang_hi = np.arctan(np.fmax.reduce(slope, axis=0)) + eps
        k0, k1 = np.zeros(n_fan, dtype=np.int64), np.zeros(n_fan, dtype=np.int64)
        k0[cut] = np.where(front, np.searchsorted(self.el_rad, ang_lo, "left"), 0)
        # not all in front: the whole fan if part of the polygon is (u >= 0), else (behind) none
        k1[cut] = np.where(front, np.searchsorted(self.el_rad, ang_hi, "right"), np.where(u_max >= 0, n_el, 0))
        length = k1 - k0
        run_first = np.cumsum(length) - length  # where each fan's run starts in the output
        ray_k = np.repeat(self.first_ray + k0 - run_first, length) + np.arange(run_first[-1] + length[-1])
        return ray_k, np.repeat(np.arange(n_fan), length)


def transpose_times(R: np.ndarray, X: np.ndarray) -> np.ndarray:
    """R^T X for stacks (M,3,3) and (M,3,N), written out: numpy's batched products of 3 x 3
    matrices go through a slow generic loop."""
    out = R[:, 0, :, None] * X[:, 0, None, :]
    out += R[:, 1, :, None] * X[:, 1, None, :]
    out += R[:, 2, :, None] * X[:, 2, None, :]
    return out
