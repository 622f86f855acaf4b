"""The feeder frame's motion relative to the crane vessel's heading frame, as the feeder
filter models it: pure functions, no state.

State: pose p = (x, y, z, roll, pitch, yaw) of the feeder's map frame in the level frame at
the boom tip (the crane vessel's heading frame moved to the tip), R = Rz(yaw) Ry(pitch)
Rx(roll); the rates of the feeder's motion relative to the crane VESSEL (6); their
accelerations (6); the feeder MRU's offsets (4, below). The tip swings metres over the
vessel's roll and pitch; the crane MRU's rates give that swing's velocity q_dot (the filter's
input), so the position, relative to the
tip, moves by the integral of (rate - q_dot) while the rates and accelerations model only the
feeder's own, smoother, wave motion. The MRU's rates, not its angles, carry the input: an
angle's noise at the tip's 50 m lever is 2 cm a sample, a rate's integrated over a frame a
millimetre. Each
DOF's acceleration is a Singer process (first-order Gauss-Markov with time constant tau):
wave-driven motion is a narrow-band acceleration about zero, and a constant-acceleration
model would let a 50 s outage grow its position error with t^3.

Measurements:
- the deck plane z = a x + b y + c in the level frame: the map frame's z is the deck normal
  and its origin lies on the deck, so (a, b, c) depend on z, roll, pitch (and, weakly, x, y, yaw);
  with the returns' times, the plane and its rate of change together (the deck's spin over the
  sweep), which adds the heave, roll and pitch rates;
- a registration's x, y, yaw, projected on the directions the geometry constrains;
- the velocity of the feeder's point at the radar (radar Doppler, made a velocity in the
  level frame by perception): v + w x (xi - p), w from the Euler rates;
- optionally an MRU on the feeder (document 004's second MRU): the feeder body's attitude in
  its own heading frame and its angular rates. Four constant-ish offsets relate it to the
  map frame (state 18-21): the heading offset between the feeder MRU's heading frame and the
  crane's level frame (004's slowly varying offset, a random walk), and the rotation from the
  feeder body (the MRU's axes) to the map frame: a yaw (the map's x is the crane's heading at
  the first frame, not the feeder's centre line) and a small tilt (the MRU's mounting and bias,
  the deck's camber, the crane side's levelling error).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy.linalg import expm

from boomtip.data.poses import rpy_matrix

N_MOTION = 18  # pose, rates, accelerations
N_STATE = 22  # and the feeder MRU's offsets
POSE, RATE, ACC, OFFSETS = slice(0, 6), slice(6, 12), slice(12, 18), slice(18, 22)
HEADING_OFFSET, BODY_YAW, BODY_TILT = 18, 19, slice(20, 22)
YAW_LEVER_M = 10.0  # yaw is weighed against x and y at this lever when deciding what is observed


@lru_cache(maxsize=256)
def _singer_block(dt_s: float, tau_s: float, rate_tau_s: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
    """Discrete (F, Q per unit spectral density) of [pos, vel, acc] with da = -a/tau dt + dW and
    dv = (a - v/rate_tau) dt, by Van Loan's matrix exponential (exact for any dt; cached because
    frame intervals repeat)."""
    A = np.array([[0.0, 1.0, 0.0], [0.0, -1.0 / rate_tau_s, 1.0], [0.0, 0.0, -1.0 / tau_s]])
    G = np.array([[0.0], [0.0], [1.0]])
    M = np.zeros((6, 6))
    M[:3, :3], M[:3, 3:], M[3:, 3:] = -A, G @ G.T, A.T
    E = expm(M * dt_s)
    F = E[3:, 3:].T
    return F, F @ E[:3, 3:]


def transition(dt_s: float, tau_s: np.ndarray, sigma_acc: np.ndarray, rate_tau_s: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q), 18x18 (the motion states), for each DOF's Singer model (rates damped over
    rate_tau_s); sigma_acc is the steady-state acceleration 1-sigma (spectral density
    2 sigma^2 / tau)."""
    F, Q = np.eye(N_MOTION), np.zeros((N_MOTION, N_MOTION))
    rt = np.full(6, math.inf) if rate_tau_s is None else rate_tau_s
    for i in range(6):
        Fi, Qi = _singer_block(round(float(dt_s), 9), float(tau_s[i]), float(rt[i]))
        idx = [i, 6 + i, 12 + i]
        F[np.ix_(idx, idx)] = Fi
        Q[np.ix_(idx, idx)] = Qi * (2.0 * sigma_acc[i] ** 2 / tau_s[i])
    return F, Q


def rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll)."""
    return rpy_matrix((roll, pitch, yaw))


def omega(pose: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Angular velocity (level axes) of R = Rz(yaw) Ry(pitch) Rx(roll) from the Euler rates."""
    _, p, y = pose[3:6]
    rd, pd, yd = rates[3:6]
    cy, sy, cp, sp = math.cos(y), math.sin(y), math.cos(p), math.sin(p)
    return np.array([-sy * pd + cy * cp * rd, cy * pd + sy * cp * rd, yd - sp * rd])


def euler_rate_matrix(pose: np.ndarray) -> np.ndarray:
    """E with omega = E @ (roll, pitch, yaw rates): omega() as a matrix, for Jacobians."""
    _, p, y = pose[3:6]
    cy, sy, cp, sp = math.cos(y), math.sin(y), math.cos(p), math.sin(p)
    return np.array([[cy * cp, -sy, 0.0], [sy * cp, cy, 0.0], [-sp, 0.0, 1.0]])


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b of two 3-vectors: np.cross's axis handling costs ten times the arithmetic, and
    the filter's models call it at every predict, update and record."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def deck_plane(x: np.ndarray) -> np.ndarray:
    """(a, b, c) of the deck plane z = a x + b y + c in the level frame at the tip."""
    n = rotation(*x[3:6])[:, 2]
    d = -float(n @ x[0:3])
    return np.array([-n[0] / n[2], -n[1] / n[2], -d / n[2]])


def deck_plane_rate(x: np.ndarray, tip_velocity: np.ndarray, dt_s: float = 1e-2) -> np.ndarray:
    """d/dt of deck_plane: the pose moving at the state's rates, its position less the tip's
    velocity (the level frame's origin moves with the tip). By a central difference in time over
    +-dt_s: exact to (rate dt)^2 / 6 (1e-7 of the rate at 3 deg/s), and smooth enough to be
    differenced again for the Jacobian."""
    pose_dot = x[6:12].copy()
    pose_dot[:3] -= tip_velocity
    return (deck_plane(x[:6] + dt_s * pose_dot) - deck_plane(x[:6] - dt_s * pose_dot)) / (2.0 * dt_s)


def deck_spin_jacobian(x: np.ndarray, tip_velocity: np.ndarray) -> np.ndarray:
    """d (deck_plane, deck_plane_rate) / dx (6 x N) over the pose (but its yaw) and the rates
    (but the yaw's): the rate is linear in the rates, with the plane's own pose Jacobian as
    their columns (to (rate dt)^2); differences only for its pose columns. A third of the
    plane evaluations of differencing all ten columns (it runs at every LiDAR frame)."""
    Jp = numeric_jacobian(deck_plane, x, np.arange(6))[:, :6]
    J = np.zeros((6, len(x)))
    J[:3, 0:5] = Jp[:, 0:5]
    J[3:, 6:11] = Jp[:, 0:5]
    J[3:, 0:5] = numeric_jacobian(lambda z: deck_plane_rate(z, tip_velocity), x, np.arange(5))[:, 0:5]
    return J


def point_velocity(x: np.ndarray, xi_level: np.ndarray, tip_velocity: np.ndarray) -> np.ndarray:
    """Velocity relative to the tip (level frame at it) of the feeder's point at xi, m/s;
    tip_velocity: the tip's velocity relative to the vessel (q_dot)."""
    return x[6:9] - tip_velocity + cross3(omega(x[0:6], x[6:12]), xi_level - x[0:3])


def point_velocity_jacobian(x: np.ndarray, xi_level: np.ndarray) -> np.ndarray:
    """d point_velocity / dx (3 x N): analytic in the position, velocity and rates, by
    differences in the three angles only (it runs at every radar frame)."""
    w = omega(x[0:6], x[6:12])
    J = np.zeros((3, len(x)))
    J[:, 6:9] = np.eye(3)
    J[:, 0:3] = -skew(w)
    J[:, 9:12] = -skew(xi_level - x[0:3]) @ euler_rate_matrix(x)
    f = lambda z: cross3(omega(z[0:6], z[6:12]), xi_level - z[0:3])
    J[:, 3:6] = numeric_jacobian(f, x, np.arange(3, 6))[:, 3:6]
    return J


def numeric_jacobian(h, x: np.ndarray, columns: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """dh/dx over the given state columns (central differences; the rest are zero)."""
    y0 = h(x)
    J = np.zeros((len(y0), len(x)))
    for j in columns:
        e = np.zeros_like(x)
        e[j] = step
        J[:, j] = (h(x + e) - h(x - e)) / (2 * step)
    return J


def well_observed(info_xy_yaw: np.ndarray, max_sigma_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Which combinations of (x, y, yaw) a registration constrains: A (k,3) and their variances
    (k,), from the eigen-directions of the information with yaw weighed at YAW_LEVER_M; a
    direction known worse than max_sigma_m is dropped (document 003's bad-pose rejection,
    done with the geometry instead of a pose-consistency test)."""
    S = np.diag([1.0, 1.0, 1.0 / YAW_LEVER_M])  # (x, y, yaw) = S (x, y, yaw * L)
    info_scaled = S @ info_xy_yaw @ S
    w, U = np.linalg.eigh(0.5 * (info_scaled + info_scaled.T))
    keep = w > 1.0 / (max_sigma_m * max_sigma_m)
    return U[:, keep].T @ np.linalg.inv(S), 1.0 / w[keep]


def body_to_map(x: np.ndarray) -> np.ndarray:
    """R_body_map: the feeder MRU's axes to the map frame, from the offsets (yaw, then tilt)."""
    a, b = x[BODY_TILT]
    return rotation(float(a), float(b), float(x[BODY_YAW]))


def feeder_mru_rotation(x: np.ndarray) -> np.ndarray:
    """What the feeder MRU's angles describe: its body in its own heading frame,
    Rz(-heading offset) R_level_map R_body_map^T."""
    psi = float(x[HEADING_OFFSET])
    c, s = math.cos(psi), math.sin(psi)
    Rz_T = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return Rz_T @ rotation(*x[3:6]) @ body_to_map(x).T


def euler_rpy(R: np.ndarray) -> np.ndarray:
    """roll, pitch, yaw of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    return np.array([math.atan2(R[2, 1], R[2, 2]), -math.asin(max(-1.0, min(1.0, float(R[2, 0])))), math.atan2(R[1, 0], R[0, 0])])


def feeder_mru_measurement(x: np.ndarray) -> np.ndarray:
    """The feeder MRU's roll, pitch, yaw (rad) and angular velocity in its heading frame
    (rad/s), from the state: the map's angular velocity (level axes) turned by the offset."""
    psi = float(x[HEADING_OFFSET])
    c, s = math.cos(psi), math.sin(psi)
    w = omega(x[0:6], x[6:12])
    return np.concatenate([euler_rpy(feeder_mru_rotation(x)), [c * w[0] + s * w[1], -s * w[0] + c * w[1], w[2]]])


def condition_on(pose_reg: np.ndarray, info6: np.ndarray, z_roll_pitch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The registration's (x, y, yaw) given z, roll and pitch known from elsewhere (the deck):
    an ICP that tilts a little wrong shifts sideways to make up for it (by the tilt times the
    structure's height); the Gaussian conditional undoes that: mean - L11^-1 L12 (known - its
    own). Returns (x, y, yaw) and their information L11."""
    a, b = [0, 1, 5], [2, 3, 4]
    L11, L12 = info6[np.ix_(a, a)], info6[np.ix_(a, b)]
    d = np.asarray(z_roll_pitch, dtype=float) - pose_reg[b]
    return pose_reg[a] - np.linalg.pinv(L11) @ (L12 @ d), L11


def yaw_only(info_xy_yaw: np.ndarray) -> np.ndarray:
    """The information of (x, y, yaw) kept for the yaw alone, x and y left free: the yaw's
    Schur complement, as a 3x3 with zero information in x and y."""
    L = info_xy_yaw[:2, :2]
    s = info_xy_yaw[2, 2] - info_xy_yaw[2, :2] @ np.linalg.pinv(L) @ info_xy_yaw[:2, 2]
    return np.diag([0.0, 0.0, max(float(s), 0.0)])


def attitude_pose_cov(p_level_m: np.ndarray, angle_var_rad2: float) -> np.ndarray:
    """(6, 6): the covariance a levelling error (about the level x and y axes, variance
    angle_var each) puts on a pose whose origin is p_level (from the tip, where the level frame
    turns): the origin moves by d x p (sideways by its depth times d, vertically by its
    horizontal offset times d), the roll and pitch by d."""
    x, y, z = p_level_m
    J = np.array([[0.0, z], [-z, 0.0], [y, -x], [1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    return angle_var_rad2 * (J @ J.T)
