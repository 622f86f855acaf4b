"""The hook filter's process model: state layout, RK4 prediction, process noise, and the
hook-position measurement functions.

State (document 002 eq. 4.24, reordered so that the rigid model is a prefix)::

    idx  0 a        1 a'       2 b        3 b'            sway angles (WORLD axes, see data/crane_model.py)
         4 nu       5 nu'      6 nu''                     slew
         7 mu       8 mu'      9 mu''                     luff
        10 l       11 l'      12 l''                      rope length
        13 roll    14 roll'   15 roll''                   vessel roll  (about x)
        16 pitch   17 pitch'  18 pitch''                  vessel pitch (about y)
        19 nu_f    20 nu_f'                               boom deflection (flexible model only)

The rigid model has 19 states (nu_f = 0, i.e. k_f -> inf).  a'', b'' and nu_f'' come from
the closed-form equations of motion of the crane's nominal model
(:func:`boomtip.data.crane_model.pendulum_accelerations_core`, document 002 C.1.1: the filter's
internal model is the crane's model); the joint and vessel accelerations are random walks
driven by white jerk (eq. 4.25).  Prediction: RK4 (4.4) or the explicit midpoint rule (the
filter's default: half the model evaluations, the same estimates to micrometres at 5 ms).
Process noise Q: DWNA blocks for
(a, a'), (b, b'), (nu_f, nu_f') and DWNJ blocks for the kinematic chains, diagonal as in
eqs. 4.29-4.30 (:func:`process_noise`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from boomtip.data.crane_model import pendulum_accelerations_core, rk4_substep

if TYPE_CHECKING:
    from boomtip.fusion.hook_config import ProcessNoiseConfig

__all__ = [
    "STATE_NAMES", "IA", "IAD", "IB", "IBD", "INU", "IMU", "IL", "IROLL", "IPITCH", "IF", "IFD",
    "KIN_CHAINS", "CHAINS", "N_RIGID", "N_FLEXIBLE", "state_size", "HOOK_COLS", "HOOK_IX", "kin_at", "rk4_step", "rk4_float", "rk4_batch", "midpoint_float",
    "midpoint_batch", "process_noise",
    "hook_pos_vel", "hook_pos_vel_batch", "lidar_h_jac", "sway_angles_from_direction",
    "sway_angles_from_directions",
]

STATE_NAMES = [
    "a", "a_dot", "b", "b_dot",
    "nu", "nu_dot", "nu_ddot",
    "mu", "mu_dot", "mu_ddot",
    "l", "l_dot", "l_ddot",
    "roll", "roll_dot", "roll_ddot",
    "pitch", "pitch_dot", "pitch_ddot",
    "nu_f", "nu_f_dot",
]
IA, IAD, IB, IBD = 0, 1, 2, 3
INU, IMU, IL, IROLL, IPITCH = 4, 7, 10, 13, 16
IF, IFD = 19, 20
KIN_CHAINS = (INU, IMU, IL, IROLL, IPITCH)
CHAINS = slice(INU, IF)  # the five kinematic chains' (q, q', q'') in one block
N_RIGID, N_FLEXIBLE = IF, IFD + 1  # the state's size without and with the boom's deflection


def state_size(flexible: bool) -> int:
    return N_FLEXIBLE if flexible else N_RIGID


def kin_at(x, tau):
    """Joint/vessel inputs (15 values) extrapolated by tau with constant acceleration."""
    out = []
    t2 = 0.5 * tau * tau
    for i in KIN_CHAINS:
        q, qd, qdd = x[i], x[i + 1], x[i + 2]
        out += [q + qd * tau + qdd * t2, qd + qdd * tau, qdd]
    return out


def rk4_step(sin, cos, prm, flex, x, h):
    """One RK4 step of the full state; x is a sequence of floats or of equal-shape arrays.

    The kinematic chains are integrated exactly (RK4 is exact for them); the inputs at the
    stage times are their extrapolations, so this equals RK4 on the whole state vector.
    """
    h2 = 0.5 * h
    u0 = x[4:19]
    u1 = kin_at(x, h2)
    u2 = kin_at(x, h)
    f, fd = (x[19], x[20]) if flex else (0.0, 0.0)
    a, ad, b, bd, f, fd = rk4_substep(prm, flex, (x[0], x[1], x[2], x[3], f, fd), h, u0, u1, u2, sin, cos)
    out = [a, ad, b, bd] + list(u2)
    if flex:
        out += [f, fd]
    return out


def rk4_float(prm, flex, x, h):
    """:func:`rk4_step` specialised to a list of floats (same operations, same result,
    without the generic list handling: this runs at 200 Hz in the EKF)."""
    sin, cos, acc = math.sin, math.cos, pendulum_accelerations_core
    (a, ad, b, bd, nu, nud, nudd, mu, mud, mudd, l, ld, ldd,
     r, rd, rdd, p, pd, pdd) = x[:19]
    if flex:
        f, fd = x[19], x[20]
    else:
        f = fd = 0.0
    h2 = 0.5 * h
    t1 = 0.5 * h2 * h2
    t2 = 0.5 * h * h
    # inputs at t + h/2 and t + h (:func:`kin_at`)
    nu1, nud1 = nu + nud * h2 + nudd * t1, nud + nudd * h2
    mu1, mud1 = mu + mud * h2 + mudd * t1, mud + mudd * h2
    l1, ld1 = l + ld * h2 + ldd * t1, ld + ldd * h2
    r1, rd1 = r + rd * h2 + rdd * t1, rd + rdd * h2
    p1, pd1 = p + pd * h2 + pdd * t1, pd + pdd * h2
    nu2, nud2 = nu + nud * h + nudd * t2, nud + nudd * h
    mu2, mud2 = mu + mud * h + mudd * t2, mud + mudd * h
    l2, ld2 = l + ld * h + ldd * t2, ld + ldd * h
    r2, rd2 = r + rd * h + rdd * t2, rd + rdd * h
    p2, pd2 = p + pd * h + pdd * t2, pd + pdd * h
    k1a, k1b, k1f = acc(sin, cos, prm, flex, a, ad, b, bd, nu, nud, nudd, mu, mud, mudd, l, ld, ldd,
                        r, rd, rdd, p, pd, pdd, f, fd)
    a2, ad2, b2, bd2, f2, fd2 = a + h2 * ad, ad + h2 * k1a, b + h2 * bd, bd + h2 * k1b, f + h2 * fd, fd + h2 * k1f
    k2a, k2b, k2f = acc(sin, cos, prm, flex, a2, ad2, b2, bd2, nu1, nud1, nudd, mu1, mud1, mudd, l1, ld1, ldd,
                        r1, rd1, rdd, p1, pd1, pdd, f2, fd2)
    a3, ad3, b3, bd3, f3, fd3 = a + h2 * ad2, ad + h2 * k2a, b + h2 * bd2, bd + h2 * k2b, f + h2 * fd2, fd + h2 * k2f
    k3a, k3b, k3f = acc(sin, cos, prm, flex, a3, ad3, b3, bd3, nu1, nud1, nudd, mu1, mud1, mudd, l1, ld1, ldd,
                        r1, rd1, rdd, p1, pd1, pdd, f3, fd3)
    a4, ad4, b4, bd4, f4, fd4 = a + h * ad3, ad + h * k3a, b + h * bd3, bd + h * k3b, f + h * fd3, fd + h * k3f
    k4a, k4b, k4f = acc(sin, cos, prm, flex, a4, ad4, b4, bd4, nu2, nud2, nudd, mu2, mud2, mudd, l2, ld2, ldd,
                        r2, rd2, rdd, p2, pd2, pdd, f4, fd4)
    h6 = h / 6.0
    out = [
        a + h6 * (ad + 2 * ad2 + 2 * ad3 + ad4),
        ad + h6 * (k1a + 2 * k2a + 2 * k3a + k4a),
        b + h6 * (bd + 2 * bd2 + 2 * bd3 + bd4),
        bd + h6 * (k1b + 2 * k2b + 2 * k3b + k4b),
        nu2, nud2, nudd, mu2, mud2, mudd, l2, ld2, ldd, r2, rd2, rdd, p2, pd2, pdd,
    ]
    if flex:
        out += [f + h6 * (fd + 2 * fd2 + 2 * fd3 + fd4), fd + h6 * (k1f + 2 * k2f + 2 * k3f + k4f)]
    return out


def rk4_batch(prm, flex, X, h):
    """:func:`rk4_step` on arrays, X (n, N) -> (n, N), with the elementwise operations
    grouped into a few 2-D ones (the same operations per element, so the same result)."""
    sin, cos, acc = np.sin, np.cos, pendulum_accelerations_core
    X = np.ascontiguousarray(X)
    n, N = X.shape
    h2 = 0.5 * h
    C = X[4:19].reshape(5, 3, N)  # per chain (q, q', q'')
    q, qd, qdd = C[:, 0], C[:, 1], C[:, 2]
    t1 = 0.5 * h2 * h2
    t2 = 0.5 * h * h
    q1, qd1 = q + qd * h2 + qdd * t1, qd + qdd * h2
    q2, qd2 = q + qd * h + qdd * t2, qd + qdd * h
    u0 = list(X[4:19])
    u1 = [v for i in range(5) for v in (q1[i], qd1[i], qdd[i])]
    u2 = [v for i in range(5) for v in (q2[i], qd2[i], qdd[i])]
    if flex:
        Y, V = X[[IA, IB, IF]], X[[IAD, IBD, IFD]]  # positions (a, b, nu_f), rates
        m = 3
    else:
        Y, V = X[[IA, IB]], X[[IAD, IBD]]
        m = 2

    def k(Yi, Vi, u):
        f, fd = (Yi[2], Vi[2]) if flex else (0.0, 0.0)
        return np.array(acc(sin, cos, prm, flex, Yi[0], Vi[0], Yi[1], Vi[1], *u, f, fd)[:m])

    k1 = k(Y, V, u0)
    Y2, V2 = Y + h2 * V, V + h2 * k1
    k2 = k(Y2, V2, u1)
    Y3, V3 = Y + h2 * V2, V + h2 * k2
    k3 = k(Y3, V3, u1)
    Y4, V4 = Y + h * V3, V + h * k3
    k4 = k(Y4, V4, u2)
    h6 = h / 6.0
    out = np.empty((n, N))
    out[[IA, IB, IF][:m]] = Y + h6 * (V + 2 * V2 + 2 * V3 + V4)
    out[[IAD, IBD, IFD][:m]] = V + h6 * (k1 + 2 * k2 + 2 * k3 + k4)
    Co = out[4:19].reshape(5, 3, N)
    Co[:, 0], Co[:, 1], Co[:, 2] = q2, qd2, qdd
    return out


def midpoint_float(prm, flex, x, h):
    """One explicit midpoint step (second-order Runge-Kutta: the model at t and at t + h/2) of
    the full state, a list of floats; the kinematic chains extrapolated exactly as in
    :func:`rk4_float`. Second order, but at the filter's 5 ms step the pendulum's and the
    deflection's periods (seconds) leave its difference from RK4 at micrometres of the hook's
    estimate (tests/fusion/test_hook_filter.py)."""
    sin, cos, acc = math.sin, math.cos, pendulum_accelerations_core
    (a, ad, b, bd, nu, nud, nudd, mu, mud, mudd, l, ld, ldd,
     r, rd, rdd, p, pd, pdd) = x[:19]
    if flex:
        f, fd = x[19], x[20]
    else:
        f = fd = 0.0
    h2 = 0.5 * h
    t1 = 0.5 * h2 * h2
    t2 = 0.5 * h * h
    k1a, k1b, k1f = acc(sin, cos, prm, flex, a, ad, b, bd, nu, nud, nudd, mu, mud, mudd, l, ld, ldd,
                        r, rd, rdd, p, pd, pdd, f, fd)
    a2, ad2, b2, bd2 = a + h2 * ad, ad + h2 * k1a, b + h2 * bd, bd + h2 * k1b
    f2, fd2 = f + h2 * fd, fd + h2 * k1f
    k2a, k2b, k2f = acc(sin, cos, prm, flex, a2, ad2, b2, bd2,
                        nu + nud * h2 + nudd * t1, nud + nudd * h2, nudd, mu + mud * h2 + mudd * t1, mud + mudd * h2, mudd,
                        l + ld * h2 + ldd * t1, ld + ldd * h2, ldd, r + rd * h2 + rdd * t1, rd + rdd * h2, rdd,
                        p + pd * h2 + pdd * t1, pd + pdd * h2, pdd, f2, fd2)
    out = [a + h * ad2, ad + h * k2a, b + h * bd2, bd + h * k2b,
           nu + nud * h + nudd * t2, nud + nudd * h, nudd, mu + mud * h + mudd * t2, mud + mudd * h, mudd,
           l + ld * h + ldd * t2, ld + ldd * h, ldd, r + rd * h + rdd * t2, rd + rdd * h, rdd,
           p + pd * h + pdd * t2, pd + pdd * h, pdd]
    if flex:
        out += [f + h * fd2, fd + h * k2f]
    return out


def midpoint_batch(prm, flex, X, h):
    """:func:`midpoint_float` on arrays, X (n, N) -> (n, N) (the crane model's core on arrays;
    the UKF's reference for fusion/models/batched_model.py)."""
    sin, cos, acc = np.sin, np.cos, pendulum_accelerations_core
    X = np.ascontiguousarray(X)
    n, N = X.shape
    h2 = 0.5 * h
    C = X[4:19].reshape(5, 3, N)
    q, qd, qdd = C[:, 0], C[:, 1], C[:, 2]
    q1, qd1 = q + qd * h2 + qdd * (0.5 * h2 * h2), qd + qdd * h2
    u1 = [v for i in range(5) for v in (q1[i], qd1[i], qdd[i])]
    m = 3 if flex else 2
    Y, V = (X[[IA, IB, IF]], X[[IAD, IBD, IFD]]) if flex else (X[[IA, IB]], X[[IAD, IBD]])

    def k(Yi, Vi, u):
        f, fd = (Yi[2], Vi[2]) if flex else (0.0, 0.0)
        return np.array(acc(sin, cos, prm, flex, Yi[0], Vi[0], Yi[1], Vi[1], *u, f, fd)[:m])

    k1 = k(Y, V, list(X[4:19]))
    Ym, Vm = Y + h2 * V, V + h2 * k1
    k2 = k(Ym, Vm, u1)
    out = np.empty((n, N))
    out[[IA, IB, IF][:m]] = Y + h * Vm
    out[[IAD, IBD, IFD][:m]] = V + h * k2
    Co = out[4:19].reshape(5, 3, N)
    Co[:, 0], Co[:, 1], Co[:, 2] = q + qd * h + qdd * (0.5 * h * h), qd + qdd * h, qdd
    return out


def _dwna(sigma, dt, full):
    if full:
        return sigma**2 * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
    return np.diag([(0.5 * sigma * dt**2) ** 2, (sigma * dt) ** 2])


def _dwnj(sigma, dt, gamma, full):
    g = np.array([dt**3 / 6, dt**2 / 2, gamma * dt]) * sigma
    return np.outer(g, g) if full else np.diag(g**2)


def process_noise(p: ProcessNoiseConfig, dt: float, n: int) -> np.ndarray:
    """Discrete Q (n, n) for a step dt (eqs. 4.29-4.30)."""
    full = p.full_blocks
    Q = np.zeros((21, 21))
    for i in (IA, IB):
        Q[i:i + 2, i:i + 2] = _dwna(p.sigma_sway_acc_rad_s2, dt, full)
    Q[IF:IF + 2, IF:IF + 2] = _dwna(p.sigma_deflection_acc_rad_s2, dt, full)
    Ts = p.nominal_dt_s
    for i, amax in ((INU, p.slew_acc_max_rad_s2), (IMU, p.luff_acc_max_rad_s2), (IL, p.hoist_acc_max_m_s2)):
        Q[i:i + 3, i:i + 3] = _dwnj(p.joint_jerk_scale * amax / Ts, dt, p.gamma_joint, full)
    for i in (IROLL, IPITCH):
        Q[i:i + 3, i:i + 3] = _dwnj(p.sigma_vessel_jerk_rad_s3, dt, p.gamma_vessel, full)
    return np.ascontiguousarray(Q[:n, :n])


HOOK_COLS = [IA, IAD, IB, IBD, IL, IL + 1]
HOOK_IX = np.ix_(HOOK_COLS, HOOK_COLS)


def hook_pos_vel(x):
    """p_rel, v_rel and their 3 x 6 Jacobians w.r.t. (a, a', b, b', l, l')."""
    a, ad, b, bd, l, ld = x[IA], x[IAD], x[IB], x[IBD], x[IL], x[IL + 1]
    sa, ca, sb, cb = math.sin(a), math.cos(a), math.sin(b), math.cos(b)
    u = (-sa, ca * sb, -ca * cb)
    ea = (-ca, -sa * sb, sa * cb)  # du/da
    eb = (0.0, ca * cb, ca * sb)  # du/db
    u_ab = (0.0, -sa * cb, -sa * sb)  # d2u/da db
    u_bb = (0.0, -ca * sb, ca * cb)  # d2u/db2   (d2u/da2 = -u)
    p = np.array([l * u[0], l * u[1], l * u[2]])
    v = np.array([ld * u[k] + l * (ad * ea[k] + bd * eb[k]) for k in range(3)])
    Hp = np.array([[l * ea[k], 0.0, l * eb[k], 0.0, u[k], 0.0] for k in range(3)])
    Hv = np.array([[ld * ea[k] + l * (-ad * u[k] + bd * u_ab[k]), l * ea[k],
                    ld * eb[k] + l * (ad * u_ab[k] + bd * u_bb[k]), l * eb[k],
                    ad * ea[k] + bd * eb[k], u[k]] for k in range(3)])
    return p, v, Hp, Hv


_HOOK_COLS_A = np.array(HOOK_COLS, np.intp)


def lidar_h_jac(x):
    """h(x) = l u(a, b) and its 3 x 6 Jacobian w.r.t. (a, a', b, b', l, l') (the rows of
    :func:`hook_pos_vel`'s Hp)."""
    a, b, l = float(x[IA]), float(x[IB]), float(x[IL])
    sa, ca, sb, cb = math.sin(a), math.cos(a), math.sin(b), math.cos(b)
    u0, u1, u2 = -sa, ca * sb, -ca * cb
    return (np.array([l * u0, l * u1, l * u2]),
            np.array([[l * -ca, 0.0, l * 0.0, 0.0, u0, 0.0],
                      [l * (-sa * sb), 0.0, l * (ca * cb), 0.0, u1, 0.0],
                      [l * (sa * cb), 0.0, l * (ca * sb), 0.0, u2, 0.0]]))


def hook_pos_vel_batch(X):
    """:func:`hook_pos_vel` for states X (N, n): p, v (N, 3), Hp, Hv (N, 3, 6)."""
    a, ad, b, bd, l, ld = (X[:, i] for i in HOOK_COLS)
    sa, ca, sb, cb = np.sin(a), np.cos(a), np.sin(b), np.cos(b)
    z = np.zeros_like(a)
    u = np.stack([-sa, ca * sb, -ca * cb], 1)
    ea = np.stack([-ca, -sa * sb, sa * cb], 1)
    eb = np.stack([z, ca * cb, ca * sb], 1)
    u_ab = np.stack([z, -sa * cb, -sa * sb], 1)
    u_bb = np.stack([z, -ca * sb, ca * cb], 1)
    a, ad, b, bd, l, ld = (c[:, None] for c in (a, ad, b, bd, l, ld))
    p = l * u
    v = ld * u + l * (ad * ea + bd * eb)
    N = len(X)
    Hp = np.zeros((N, 3, 6))
    Hv = np.empty((N, 3, 6))
    Hp[:, :, 0] = l * ea
    Hp[:, :, 2] = l * eb
    Hp[:, :, 4] = u
    Hv[:, :, 0] = ld * ea + l * (-ad * u + bd * u_ab)
    Hv[:, :, 1] = l * ea
    Hv[:, :, 2] = ld * eb + l * (ad * u_ab + bd * u_bb)
    Hv[:, :, 3] = l * eb
    Hv[:, :, 4] = ad * ea + bd * eb
    Hv[:, :, 5] = u
    return p, v, Hp, Hv


def sway_angles_from_direction(direction, cov) -> tuple[np.ndarray, np.ndarray] | None:
    """The sway angles (a, b) of a rope direction u = (-sin a, cos a sin b, -cos a cos b) (unit,
    tip -> hook, world axes) and their 2x2 covariance J C J^T, J = d(a, b)/du, from the
    direction's 3x3 covariance C (only its part across the rope counts: C is projected on the
    plane normal to u first). None for a NaN or zero direction or a NaN covariance."""
    u = np.asarray(direction, float).reshape(3)
    C = np.asarray(cov, float).reshape(3, 3)
    norm = float(np.linalg.norm(u))
    if not (np.isfinite(norm) and norm > 0 and np.all(np.isfinite(C))):
        return None
    u = u / norm
    a = math.asin(max(-1.0, min(1.0, -u[0])))
    b = math.atan2(u[1], -u[2])
    h2 = u[1] ** 2 + u[2] ** 2
    if h2 < 1e-12:  # the rope horizontal along x: b undefined (never reached by a hanging load)
        return None
    J = np.array([[-1.0 / math.sqrt(h2), 0.0, 0.0], [0.0, -u[2] / h2, u[1] / h2]])  # cos a = sqrt(h2)
    Pn = np.eye(3) - np.outer(u, u)
    return np.array([a, b]), J @ (Pn @ C @ Pn) @ J.T


def sway_angles_from_directions(directions: np.ndarray, covs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sway_angles_from_direction` for K directions (K, 3) and covariances (K, 3, 3) at
    once: (z (K, 2), R (K, 2, 2)), NaN rows where it gives None (a run's rope fits converted
    before its loop instead of one by one at 20 Hz)."""
    U = np.asarray(directions, float).reshape(-1, 3)
    C = np.asarray(covs, float).reshape(-1, 3, 3)
    K = len(U)
    norm = np.linalg.norm(U, axis=1)
    ok = np.isfinite(norm) & (norm > 0) & np.all(np.isfinite(C.reshape(K, 9)), 1)
    u = U / np.where(ok, norm, 1.0)[:, None]
    h2 = u[:, 1] ** 2 + u[:, 2] ** 2
    ok &= h2 >= 1e-12  # the rope horizontal along x: b undefined
    h2 = np.where(ok, h2, 1.0)
    z = np.stack([np.arcsin(np.clip(-u[:, 0], -1.0, 1.0)), np.arctan2(u[:, 1], -u[:, 2])], 1)
    J = np.zeros((K, 2, 3))
    J[:, 0, 0] = -1.0 / np.sqrt(h2)  # cos a = sqrt(h2)
    J[:, 1, 1], J[:, 1, 2] = -u[:, 2] / h2, u[:, 1] / h2
    Pn = np.eye(3) - u[:, :, None] * u[:, None, :]
    JP = J @ Pn
    R = JP @ C @ JP.transpose(0, 2, 1)
    z[~ok], R[~ok] = np.nan, np.nan
    return z, R
