"""The deck plane and its spin in one frame: a plane whose height and slopes change linearly
over the frame's sweep, fitted to the deck returns with their own times: the deck normal's
spin gives the roll and pitch rates.

A scanning LiDAR's deck returns span its sweep (a grid's columns, a spinning head's
revolution: 0.05-0.1 s). Fitted in the level frame at the tip with each point's time t from
the frame's start,

    z = a x + b y + c + t (a' x + b' y + c'),

the deck at the frame's time (a, b, c) and its rate (a', b', c') come out of ONE least-squares
fit with their joint covariance: the plane is not measured twice, and the rates are as well
known as the sweep makes them (the longer the sweep and the wider the deck, the better).

What tells a rate from a slope: a sweep's time runs with one axis of the deck (a grid's
columns along the feeder, x), so the slope along it and the
heave rate, and that slope's rate and the deck's curvature along it, are told apart only by
the time's nonlinearity in x (the columns' angles) and by the filter's own heave rate (radar
Doppler), through the joint covariance. The simulated decks are flat; a cambered or sheered
deck would bias the rate of the slope along the sweep.

The crane's own rotation during the sweep (MRU rates) is removed point by point: each return
is levelled with the attitude at its own time, to first order in t (0.1 s at a few deg/s
moves a point 40 m away by a few centimetres; the second-order term, at 2 deg/s, by 0.4 mm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


MIN_POINTS = 24  # four residuals per coefficient at least
MAX_CONDITION = 1e8  # of the column-scaled normal equations: beyond, the plane alone


@dataclass
class DeckSpin:
    """The deck plane z = a x + b y + c (level frame at the tip) at the frame's time and its
    time derivative, with the joint covariance of (a, b, c, a', b', c')."""

    abc: np.ndarray  # (3,) at the frame's time
    rates: np.ndarray  # (3,) d/dt of (a, b, c): 1/s, 1/s, m/s
    cov: np.ndarray  # (6, 6)
    n_points: int
    span_s: float  # the deck returns' spread in time (first to last)

    @property
    def normal(self) -> np.ndarray:
        """The plane's unit normal (up) at the frame's time."""
        a, b = self.abc[:2]
        return np.array([-a, -b, 1.0]) / math.sqrt(a * a + b * b + 1.0)


def level_at_own_time(points_level: np.ndarray, t_s: np.ndarray, omega_level: np.ndarray) -> np.ndarray:
    """Points levelled with the attitude at the frame's time, moved to where the attitude at
    their own time t_s (from the frame's time) puts them: q + t (w x q), w the crane's angular
    velocity in level axes (the level frame's origin is the tip, which the rotation carries)."""
    wx, wy, wz = (float(v) for v in omega_level)
    q = points_level
    out = np.empty_like(q)
    out[:, 0] = q[:, 0] + t_s * (wy * q[:, 2] - wz * q[:, 1])
    out[:, 1] = q[:, 1] + t_s * (wz * q[:, 0] - wx * q[:, 2])
    out[:, 2] = q[:, 2] + t_s * (wx * q[:, 1] - wy * q[:, 0])
    return out


def spin_plane_in_level(points_level: np.ndarray, t_s: np.ndarray, inflation: float) -> DeckSpin | None:
    """Least squares z = a x + b y + c + t (a' x + b' y + c') through deck points (level frame,
    each at its own time t_s from the frame's time); the covariance s^2 (A^T A)^-1 x inflation
    (one scan's residuals are correlated), about the points' centroid and mean time (where the
    normal equations are well conditioned), mapped to the origin and the frame's time.

    One inflation for the whole matrix: a sweep's time runs with one axis of the deck, so the
    plane and its rates are strongly correlated (the height at the frame's time and the heave
    rate above all), and inflating their blocks apart would make up information about their
    combinations (the height at the returns' mean time, the one well measured). None when the
    returns' times do not separate from their places (MAX_CONDITION), or too few for the six
    coefficients to leave residuals (MIN_POINTS: an exact fit would claim a zero covariance)."""
    t = np.asarray(t_s, dtype=float)
    P = np.ascontiguousarray(points_level.T)  # (3, N): a contiguous row per axis for the products below
    n = P.shape[1]
    if n < MIN_POINTS:
        return None
    c = P.mean(axis=1)
    tm = float(t.mean())
    # rows: slope x, slope y, height, and the same three times (t - tm), about the centroid
    A = np.empty((6, n))
    np.subtract(P[0], c[0], out=A[0])
    np.subtract(P[1], c[1], out=A[1])
    A[2] = 1.0
    np.subtract(t, tm, out=A[5])
    np.multiply(A[5], A[0], out=A[3])
    np.multiply(A[5], A[1], out=A[4])
    zc = P[2] - c[2]
    AtA = A @ A.T
    # Time only separates from place where it does not run in step with it (a grid's columns:
    # the time is a function of x alone, the tangent of the column's angle; a sensor stamping
    # a frame's returns in proportion to x, not at all). Rows scaled to unit length, a grid's
    # frames give condition numbers of the order of 1e3, far below the bound.
    scale = 1.0 / np.sqrt(np.diag(AtA))
    if not np.all(np.isfinite(scale)) or np.linalg.cond(AtA * np.outer(scale, scale)) > MAX_CONDITION:
        return None
    coef = np.linalg.solve(AtA, A @ zc)
    res = zc - coef @ A
    s2 = float(res @ res) / max(n - 6, 1)
    cov_c = s2 * np.linalg.inv(AtA) * inflation
    # z = c_z + a0 + sx (x - cx) + sy (y - cy) + (t - tm) (d0 + dx (x - cx) + dy (y - cy)): its
    # coefficients of x, y, 1, t x, t y, t
    cx, cy = c[0], c[1]
    J = np.array([
        [1.0, 0.0, 0.0, -tm, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0, -tm, 0.0],
        [-cx, -cy, 1.0, tm * cx, tm * cy, -tm],
        [0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, -cx, -cy, 1.0],
    ])
    p = J @ coef
    p[2] += c[2]
    return DeckSpin(p[:3], p[3:], J @ cov_c @ J.T, n, float(t.max() - t.min()))


def deck_point_times(points_sensor: np.ndarray, point_times: np.ndarray, points_used: np.ndarray,
                     inlier_mask: np.ndarray) -> np.ndarray | None:
    """The times of the deck stage's inliers. Its points are the frame's after a finite and
    range crop (the LiDAR deck's preprocessing), in order: every point whose squared range lies
    within those it kept was kept. None when the rows found do not hold its points (another
    preprocessing: no times, the plane alone)."""
    if len(points_used) == len(points_sensor):
        return point_times[inlier_mask]
    r2 = lambda p: (p[:, 0] * p[:, 0] + p[:, 1] * p[:, 1]) + p[:, 2] * p[:, 2]
    r2_used = r2(points_used)
    r2_all = r2(points_sensor)
    rows = np.flatnonzero((r2_all >= r2_used.min()) & (r2_all <= r2_used.max()))  # NaN compares false
    if len(rows) != len(points_used):
        return None
    rows = rows[inlier_mask]
    if not np.array_equal(points_sensor[rows], points_used[inlier_mask]):
        return None
    return point_times[rows]
