"""Relative-heave geometry shared by the stages: wire direction, tip, D and D-dot.

Frames: `sensor` is the LiDAR or radar frame; `level` is a frame with world (gravity-
aligned) axes whose origin moves with the sensor: vectors rotate from sensor to level
axes with R_level_sensor = R_world_crane(MRU) R_crane_boomtip R_boomtip_sensor.
"""

from __future__ import annotations

import math

import numpy as np

from boomtip.data.poses import rpy_matrix  # noqa: F401 - part of this module's API
from boomtip.perception.plane_moments import eigh3

E_Z = np.array([0.0, 0.0, 1.0])


def level_rotation_rows(rpy_rad, R_crane_sensor_rows: list[list[float]]) -> list[list[float]]:
    """R_level_sensor = rpy_matrix(rpy) @ R_crane_sensor as three rows of Python floats, from the
    mount's rows (Python floats too, computed once per run). Once per frame of every sensor, and
    everything it feeds on a radar frame (u and its covariance to level axes, the tip) is 3x3:
    a numpy matmul of that size costs ~20 us in a cold cache (BLAS's code and numpy's dispatch
    fetched afresh), nine dot products in floats a fraction of it. The same products as
    rpy_matrix's, summed in order (BLAS's 3x3 product may fuse multiply-adds: the last bit may
    differ from it)."""
    r, p, y = rpy_rad.tolist() if isinstance(rpy_rad, np.ndarray) else (float(v) for v in rpy_rad)
    cr, cp, cy, sr, sp, sy = math.cos(r), math.cos(p), math.cos(y), math.sin(r), math.sin(p), math.sin(y)
    rows = (
        (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
        (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
        (-sp, cp * sr, cp * cr),
    )
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = R_crane_sensor_rows
    return [[a * m00 + b * m10 + c * m20, a * m01 + b * m11 + c * m21, a * m02 + b * m12 + c * m22] for a, b, c in rows]


def mat3_vec(rows, v) -> list[float]:
    """A 3x3 matrix (rows of Python floats) times a 3-vector (any sequence of floats), in floats."""
    x, y, z = v
    return [a * x + b * y + c * z for a, b, c in rows]


def mat3T_vec(rows, v) -> list[float]:
    """The transpose of a 3x3 matrix (rows of Python floats) times a 3-vector, in floats."""
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = rows
    x, y, z = v
    return [a0 * x + b0 * y + c0 * z, a1 * x + b1 * y + c1 * z, a2 * x + b2 * y + c2 * z]


def quad3(m, v) -> float:
    """v^T M v for a 3x3 matrix (rows of Python floats) and a 3-vector, in floats."""
    x, y, z = v
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = m
    return x * (a0 * x + a1 * y + a2 * z) + y * (b0 * x + b1 * y + b2 * z) + z * (c0 * x + c1 * y + c2 * z)


def mount_rotation(T_crane_boomtip: np.ndarray, T_boomtip_sensor: np.ndarray) -> np.ndarray:
    """Sensor axes -> crane-vessel axes: fixed for a run, so callers may compute it once."""
    return T_crane_boomtip[:3, :3] @ T_boomtip_sensor[:3, :3]


def rotation_level_sensor(rpy_crane_rad: np.ndarray, T_crane_boomtip: np.ndarray, T_boomtip_sensor: np.ndarray) -> np.ndarray:
    """Sensor axes -> gravity-aligned axes, from the MRU attitude and the mount (eq. 4.3)."""
    return rpy_matrix(rpy_crane_rad) @ mount_rotation(T_crane_boomtip, T_boomtip_sensor)


def wire_dir_sensor(R_level_sensor: np.ndarray) -> np.ndarray:
    """Gravity's direction (the wire, straight down) in sensor axes: n_w^s."""
    return -R_level_sensor[2]  # R^T (-e_z): the third row, negated (a new array)


def tip_in_sensor(T_boomtip_sensor: np.ndarray) -> np.ndarray:
    """The boom tip (origin of the boom-tip frame) in sensor coordinates."""
    R, t = T_boomtip_sensor[:3, :3], T_boomtip_sensor[:3, 3]
    return -R.T @ t


def heave_distance(plane_sensor: np.ndarray, wire_dir: np.ndarray, p_tip_sensor: np.ndarray) -> float:
    """D: distance from the tip along the wire to the plane n.x + d = 0 (eq. 4.8, from the tip).
    Expects a unit normal and a unit wire direction (perception.plane.wire_plane_distance
    normalises arbitrary inputs first); NaN when the wire is parallel to the plane."""
    plane_sensor = np.asarray(plane_sensor, dtype=np.float64)
    n, d = plane_sensor[:3], plane_sensor[3]
    denom = float(n @ np.asarray(wire_dir, dtype=np.float64))
    if abs(denom) < 1e-6:
        return float("nan")
    return -(float(n @ np.asarray(p_tip_sensor, dtype=np.float64)) + d) / denom


def _floats3(v) -> list[float]:
    return v.tolist() if isinstance(v, np.ndarray) else [float(x) for x in v]


def heave_rate_document(u_level: np.ndarray) -> float:
    """Document 000's D-dot (eq. 4.29): the deck's velocity relative to the sensor projected
    on the wire direction, D-dot = u . n_w with n_w = -e_z. Ignores the deck's rotation."""
    return float(-u_level[2])


def heave_rate_exact(
    u_level: np.ndarray,
    normal_level: np.ndarray,
    omega_feeder_level: np.ndarray,
    omega_crane_level: np.ndarray,
    r_tip_from_sensor_level: np.ndarray,
    D_m: float,
) -> float:
    """Exact D-dot from one radar scan's velocity u plus the deck's normal and spin.

    u = v_f(p_s) - v_s is the feeder's velocity field at the sensor relative to the sensor
    (what the range rates observe; level axes). With p_d = p_t - D e_z the deck point
    below the tip and r = p_t - p_s:
        p_t_dot   = v_s + w_c x r
        v_f(p_d)  = v_f(p_s) + w_f x (r - D e_z)
        D_dot     = n.(p_t_dot - v_f(p_d)) / (n.e_z)
                  = n.(-u + w_c x r - w_f x (r - D e_z)) / (n.e_z)
    Only w_f's components perpendicular to n matter (n.(w x a) = a.(n x w)).
    """
    # Python floats: eleven products per radar frame, where numpy's per-call overhead on
    # 3-vectors would cost more than the arithmetic.
    # Arrays or sequences of floats (the pipeline passes lists: no conversion call per vector).
    ux, uy, uz = _floats3(u_level)
    nx, ny, nz = _floats3(normal_level)
    if nz < 0:
        nx, ny, nz = -nx, -ny, -nz
    cx, cy, cz = _floats3(omega_crane_level)
    fx, fy, fz = _floats3(omega_feeder_level)
    rx, ry, rz = _floats3(r_tip_from_sensor_level)
    qz = rz - float(D_m)  # r - D e_z
    rel_x = -ux + (cy * rz - cz * ry) - (fy * qz - fz * ry)
    rel_y = -uy + (cz * rx - cx * rz) - (fz * rx - fx * qz)
    rel_z = -uz + (cx * ry - cy * rx) - (fx * ry - fy * rx)
    return (nx * rel_x + ny * rel_y + nz * rel_z) / nz  # n need not be unit: the ratio is scale-free


class NormalRate:
    """The deck's angular velocity (perpendicular to its normal) from the normal over time.

    n_dot = w x n gives w_perp = n x n_dot. n_dot is the slope of a local quadratic fit over
    the recent window, evaluated at the query time: causal, and far less noisy than a
    two-frame difference (noise on n_dot falls as window^-1.5). The fit is redone only when
    a new normal arrives; radar frames in between evaluate the cached polynomial.
    """

    def __init__(self, window_s: float = 1.0, min_samples: int = 4, max_jump_deg: float = 1.0) -> None:
        self.window_s = window_s
        self.min_samples = min_samples
        self.max_jump_rad = np.deg2rad(max_jump_deg)
        self.t: list[float] = []
        self.n: list[np.ndarray] = []
        self._n_floats: list[list[float]] = []  # the same normals as Python floats, for the fit's table
        self._coef: np.ndarray | None = None  # fit about self.t[-1], invalidated by add()
        self._refused = 0

    def add(self, t_s: float, normal_level: np.ndarray) -> bool:
        """Add a deck normal; refused (False) when it is further than max_jump_deg from what
        the recent normals predict: a wrong plane must not corrupt the spin for a window; and
        when it is no later than the last one (a repeated or late time stamp says nothing of the
        rate, and equal times would leave the fit without a slope)."""
        if self.t and not t_s > self.t[-1]:
            return False
        n = normal_level / np.linalg.norm(normal_level)
        n = n if n[2] > 0 else -n
        if len(self.t) >= self.min_samples and t_s - self.t[-1] <= self.window_s:
            pred = self._predict_normal(t_s)
            if float(np.arccos(np.clip(pred @ n, -1.0, 1.0))) > self.max_jump_rad:
                self._refused += 1
                if self._refused < 3:
                    return False
                # Three in a row: it is the history that is wrong (a bad start); begin again.
                self.t.clear()
                self.n.clear()
                self._n_floats.clear()
        elif self.t and t_s - self.t[-1] > self.window_s:
            self.t.clear()  # a long gap: the old normals say nothing about now
            self.n.clear()
            self._n_floats.clear()
        self._refused = 0
        self.t.append(t_s)
        self.n.append(n)
        self._n_floats.append(n.tolist())
        while self.t and self.t[0] < t_s - self.window_s:
            self.t.pop(0)
            self.n.pop(0)
            self._n_floats.pop(0)
        self._coef = None
        return True

    def _fit(self) -> list[list[float]]:
        """Coefficients [c0, c1, c2] (each an xyz list) of n(t) = c0 + c1 dt + c2 dt^2 about t[-1]."""
        if self._coef is None:
            k = len(self.t)
            deg = 2 if k >= 6 else 1
            m = deg + 1
            # One table [1, dt, dt^2 | n] and one product give the normal equations' both sides;
            # the system is at most 3x3 and well conditioned (times within one window about the
            # newest sample), solved by its adjugate in Python floats: np.vander, np.linalg.inv
            # and the separate products cost several times the arithmetic (once per LiDAR deck).
            # The table's rows from Python floats in one conversion (a list of arrays converts
            # element by element); the same roundings as numpy's.
            t_last = self.t[-1]
            W = np.array([[1.0, t - t_last, (t - t_last) * (t - t_last), *n] for t, n in zip(self.t, self._n_floats)])
            G = (W[:, :m].T @ W).tolist()  # rows i: [V^T V (m columns) ..., V^T n (3)]
            if deg == 2:
                (a0, a1, a2), (_, b1, b2), (_, _, c2) = (row[:3] for row in G)
                adj = [[b1 * c2 - b2 * b2, a2 * b2 - a1 * c2, a1 * b2 - a2 * b1],
                       [a2 * b2 - a1 * c2, a0 * c2 - a2 * a2, a2 * a1 - a0 * b2],
                       [a1 * b2 - a2 * b1, a2 * a1 - a0 * b2, a0 * b1 - a1 * a1]]
                det = a0 * adj[0][0] + a1 * adj[1][0] + a2 * adj[2][0]
                r0, r1, r2 = (row[3:] for row in G)
                coef = [[(a * x + b * y + c * z) / det for x, y, z in zip(r0, r1, r2)] for a, b, c in adj]
            else:
                (a0, a1, r0), (_, b1, r1) = ((row[0], row[1], row[3:]) for row in G)
                det = a0 * b1 - a1 * a1
                coef = [[(a * x + b * y) / det for x, y in zip(r0, r1)] for a, b in ((b1, -a1), (-a1, a0))]
            # Kept as Python floats: every radar frame evaluates the polynomial at its own time,
            # and a few float products beat numpy's per-call overhead on 3-vectors.
            self._coef = coef if deg == 2 else coef + [[0.0, 0.0, 0.0]]
        return self._coef

    def _predict(self, t_s: float) -> tuple[list[float], list[float]]:
        """Unit normal and the derivative of the (unnormalised) fitted normal at t."""
        (c0, c1, c2), dt = self._fit(), t_s - self.t[-1]
        n_t = [a + b * dt + c * dt * dt for a, b, c in zip(c0, c1, c2)]
        s = math.sqrt(n_t[0] * n_t[0] + n_t[1] * n_t[1] + n_t[2] * n_t[2])
        return [v / s for v in n_t], [b + 2.0 * c * dt for b, c in zip(c1, c2)]

    def _predict_normal(self, t_s: float) -> np.ndarray:
        return np.array(self._predict(t_s)[0])

    def omega(self, t_s: float) -> np.ndarray | None:
        """w_perp at time t (extrapolated from the fit), or None with too few samples."""
        w = self.omega_floats(t_s)
        return None if w is None else np.array(w)

    def omega_floats(self, t_s: float) -> list[float] | None:
        """:meth:`omega` as Python floats (for arithmetic in floats, no array built)."""
        if len(self.t) < self.min_samples:
            return None
        (nx, ny, nz), (dx, dy, dz) = self._predict(t_s)
        return [ny * dz - nz * dy, nz * dx - nx * dz, nx * dy - ny * dx]

    def normal(self, t_s: float) -> np.ndarray | None:
        if not self.n:
            return None
        return self.n[-1]

    def normal_floats(self, t_s: float) -> list[float] | None:
        """:meth:`normal` as Python floats (the same values)."""
        return self._n_floats[-1] if self._n_floats else None


def omega_from_euler_rates(rpy: np.ndarray, rpy_dot: np.ndarray) -> np.ndarray:
    """Angular velocity (world axes) of R = Rz(yaw) Ry(pitch) Rx(roll) from Euler rates;
    one-sample form of data.motion.euler_rates_to_omega_world."""
    return np.array(omega_from_euler_rates_floats(rpy, rpy_dot))


def omega_from_euler_rates_floats(rpy, rpy_dot) -> list[float]:
    """:func:`omega_from_euler_rates` as Python floats."""
    _, p, y = rpy.tolist() if isinstance(rpy, np.ndarray) else rpy
    rd, pd, yd = rpy_dot.tolist() if isinstance(rpy_dot, np.ndarray) else rpy_dot
    cy, sy, cp, sp = math.cos(y), math.sin(y), math.cos(p), math.sin(p)
    return [-sy * pd + cy * cp * rd, cy * pd + sy * cp * rd, yd - sp * rd]


def plane_sigma_at(points_on_plane: np.ndarray, plane: np.ndarray, query: np.ndarray) -> float:
    """1-sigma error of a least-squares plane's offset at `query` (m).

    Regression prediction variance: s^2 (1/N + q^T (X^T X)^-1 q), with X the inliers'
    in-plane coordinates about their centroid, q the query's, s the residual RMS.
    """
    N = len(points_on_plane)
    if N < 4:
        return float("nan")
    c = points_on_plane.mean(axis=0)
    X = points_on_plane - c
    evals, evecs = np.linalg.eigh(X.T @ X)
    return prediction_sigma_of_points(points_on_plane, plane, c, evals, evecs, query)


def prediction_sigma_of_points(pts, plane, c, evals, evecs, query) -> float:
    resid = pts @ plane[:3] + plane[3]
    return prediction_sigma(len(pts), float(resid @ resid), c, evals, evecs, query)


def prediction_sigma(n_points: int, sum_sq_resid: float, centroid: np.ndarray, evals: np.ndarray, evecs: np.ndarray,
                     query: np.ndarray) -> float:
    """:func:`plane_sigma_at` from what a fit already has: the number of points, their summed
    squared residuals to the plane, their centroid and the eigen-decomposition (ascending) of
    their scatter about it. NaN with fewer than 4 points."""
    N = n_points
    if N < 4:
        return float("nan")
    s2 = sum_sq_resid / (N - 3)
    q = (query - centroid) @ evecs[:, 1:]  # in-plane axes: the two largest scatter directions
    var = s2 * (1.0 / N + q[0] ** 2 / evals[1] + q[1] ** 2 / evals[2])
    return float(math.sqrt(max(var, 0.0)))


def fit_plane_heave(points: np.ndarray, wire_dir: np.ndarray, p_tip: np.ndarray, offset_m: float = 0.0) -> tuple[np.ndarray, float, float]:
    """Least-squares plane (normal towards the sensor), D along the wire from the tip, and D's
    1-sigma, all from the scatter's eigenvalues and its least eigenvector (the normal). `offset_m`
    moves the plane that far away from the sensor (points lying on top of the surface wanted)."""
    n_pts = len(points)
    c = np.add.reduce(points, axis=0) / n_pts  # ndarray.mean's arithmetic, without its wrapper
    X = points - c
    A = X.T @ X
    # The 3x3 eigenproblem in Python floats (least_eigvec3): LAPACK's solver through eigh3 is the
    # same normal to ~1e-14, but its code is fetched afresh on each frame (~15-35 us of a cold
    # call); it stays for scatters whose least eigenvalue is not well apart from the next.
    A_rows = A.tolist()
    eig = least_eigvec3(A_rows)
    if eig is None:
        evals, evecs = eigh3(A)
        eig = tuple(evals.tolist()), tuple(evecs[:, 0].tolist())
    (l0, l1, l2), (n0, n1, n2) = eig
    cx, cy, cz = c.tolist()
    d = -(n0 * cx + n1 * cy + n2 * cz)
    if d < 0:
        n0, n1, n2, d = -n0, -n1, -n2, -d
    plane = np.array([n0, n1, n2, d + offset_m])  # normal towards the sensor: a larger d is farther away
    (wx, wy, wz), (px, py, pz) = wire_dir.tolist(), p_tip.tolist()
    denom = n0 * wx + n1 * wy + n2 * wz  # heave_distance's arithmetic
    D = float("nan") if abs(denom) < 1e-6 else -((n0 * px + n1 * py + n2 * pz) + (d + offset_m)) / denom
    if not math.isfinite(D) or n_pts < 4:
        return plane, D, float("nan")
    # prediction_sigma at the wire's point on the plane. The inliers' squared distances to the
    # plane fitted through their centroid along the least eigenvector sum to its eigenvalue.
    # The in-plane term q0^2/l1 + q1^2/l2 (q's coordinates on the in-plane eigenvectors) is
    # q^T B^-1 q for the scatter's in-plane block B, whose inverse is (tr(B) I - B) / det(B)
    # (Cayley-Hamilton): with q projected on the plane, no in-plane eigenvector is needed.
    s2 = max(l0, 0.0) / (n_pts - 3)
    qx, qy, qz = px + D * wx - cx, py + D * wy - cy, pz + D * wz - cz
    t = qx * n0 + qy * n1 + qz * n2
    qx, qy, qz = qx - t * n0, qy - t * n1, qz - t * n2
    q_A_q = quad3(A_rows, (qx, qy, qz))
    in_plane = ((l1 + l2) * (qx * qx + qy * qy + qz * qz) - q_A_q) / (l1 * l2)
    var = s2 * (1.0 / n_pts + in_plane)
    return plane, D, math.sqrt(max(var, 0.0))


def least_eigvec3(a_rows, min_gap: float = 1e-6) -> tuple[tuple[float, float, float], tuple[float, float, float]] | None:
    """The eigenvalues (ascending) of a symmetric 3x3 matrix (rows of Python floats) and the unit
    eigenvector of the least, in floats: the eigenvalues in closed form (sym3_eigvals), the
    eigenvector as the longest cross product of two rows of A - l0 I (each is normal to both rows,
    so parallel to the null vector). Accurate when l0 is well apart from l1, as for points
    spread over a plane; None when l1 - l0 <= min_gap * |l2| (the caller then uses LAPACK)."""
    (a00, a01, a02), (_, a11, a12), (_, _, a22) = a_rows
    l0, l1, l2 = sym3_eigvals_floats(a00, a01, a02, a11, a12, a22)
    if not l1 - l0 > min_gap * abs(l2):
        return None
    b00, b11, b22 = a00 - l0, a11 - l0, a22 - l0
    best, best_sq = None, 0.0
    for c in ((a01 * a12 - a02 * b11, a02 * a01 - b00 * a12, b00 * b11 - a01 * a01),  # row 0 x row 1
              (a01 * b22 - a02 * a12, a02 * a02 - b00 * b22, b00 * a12 - a01 * a02),  # row 0 x row 2
              (b11 * b22 - a12 * a12, a12 * a02 - a01 * b22, a01 * a12 - b11 * a02)):  # row 1 x row 2
        sq = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
        if sq > best_sq:
            best, best_sq = c, sq
    if not 0.0 < best_sq < math.inf:
        return None
    s = math.sqrt(best_sq)
    return (l0, l1, l2), (best[0] / s, best[1] / s, best[2] / s)


def inv3(a: np.ndarray) -> np.ndarray | None:
    """a^-1 for a 3x3 matrix by the adjugate: ~10x cheaper than np.linalg.inv's per-call
    overhead for one tiny matrix. None when singular."""
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = a.tolist()
    adj = np.array([
        [b1 * c2 - b2 * c1, a2 * c1 - a1 * c2, a1 * b2 - a2 * b1],
        [b2 * c0 - b0 * c2, a0 * c2 - a2 * c0, a2 * b0 - a0 * b2],
        [b0 * c1 - b1 * c0, a1 * c0 - a0 * c1, a0 * b1 - a1 * b0],
    ])
    det = a0 * adj[0, 0] + a1 * adj[1, 0] + a2 * adj[2, 0]
    if abs(det) < 1e-300:
        return None
    return adj / det


def sym3_eigvals(a: np.ndarray) -> tuple[float, float, float]:
    """Eigenvalues of a symmetric 3x3 matrix, ascending, in closed form (the trigonometric
    solution of the characteristic cubic). For one tiny matrix per frame this is ~10x cheaper
    than np.linalg.eigvalsh's LAPACK call and wrappers."""
    (a00, a01, a02), (_, a11, a12), (_, _, a22) = a.tolist()
    return sym3_eigvals_floats(a00, a01, a02, a11, a12, a22)


def sym3_eigvals_floats(a00: float, a01: float, a02: float, a11: float, a12: float, a22: float) -> tuple[float, float, float]:
    """:func:`sym3_eigvals` from the upper triangle's six Python floats."""
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    if p1 == 0.0:
        e = sorted((a00, a11, a22))
        return e[0], e[1], e[2]
    p = math.sqrt(((a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * p1) / 6.0)
    if p == 0.0:
        return q, q, q
    b00, b11, b22 = (a00 - q) / p, (a11 - q) / p, (a22 - q) / p
    b01, b02, b12 = a01 / p, a02 / p, a12 / p
    det_b = b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02)
    phi = math.acos(min(1.0, max(-1.0, det_b / 2.0))) / 3.0
    e_max = q + 2.0 * p * math.cos(phi)
    e_min = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return e_min, 3.0 * q - e_max - e_min, e_max


def tip_above_waterline_m(rpy_rad, boom_tip_body_m, waterline_z_m: float) -> float:
    """The boom tip's height above the calm waterline (m): the tip in the crane-vessel body frame
    tilted by the vessel's roll and pitch (its yaw moves nothing up or down) about the point of
    the waterline below the body origin. The vessel's own heave is not in it (the MRU gives none)."""
    r, p = float(rpy_rad[0]), float(rpy_rad[1])
    x, y, z = boom_tip_body_m
    return -math.sin(p) * x + math.cos(p) * math.sin(r) * y + math.cos(p) * math.cos(r) * (z - waterline_z_m)
