"""The crane's nominal model: an offshore crane with a flexible boom and a hook on a rope.

Shared by the truth simulation (data/sim/crane_truth.py) and the hook filter's process model
(fusion/models): pure functions of the state and the joint/vessel inputs.

Model (document 002, chapter 4, re-derived in our conventions)
---------------------------------------------------------------
Frames (right-handed, z up, SI units, radians):

* world (inertial) frame ``w``: origin at the vessel's fixed centre of rotation, z up.
* vessel frame ``v``: body-fixed at the same origin; x forward (bow), y to port, z up.
  Attitude ``R_world_vessel = Rz(yaw) Ry(pitch) Rx(roll)
  = Rotation.from_euler("xyz", [roll, pitch, yaw])`` with yaw = 0 (document 002 3.1.4:
  fixed heading, no surge/sway/heave).
* crane frame: origin at the crane base ``c`` (vessel coordinates), slewed by ``nu`` about
  the vessel z axis; the boom points along its x axis.

Boom tip in the crane frame (document 002 eq. 4.18, the flexible version of 4.11)::

    p_tip_crane = [b + L cos(mu) cos(nu_f),  L cos(mu) sin(nu_f),  h + L sin(mu)]

so that, in vessel coordinates,
``p_tip_vessel = c + b e(nu) + L cos(mu) e(nu + nu_f) + (h + L sin(mu)) e_z`` with
``e(x) = [cos x, sin x, 0]``: the deflection ``nu_f`` is a rotation of the boom about a
vertical axis through the mast-boom joint (offset ``b`` from the slewing axis), i.e. a
deflection "in the slewing direction".  ``p_tip_world = R_world_vessel p_tip_vessel``
(eqs. 4.15-4.17).

Hook (lower block + load) is a point mass ``m`` on a massless rigid rope of prescribed
length ``l(t)`` hanging from the boom tip.  Its position relative to the tip is
(document 002 eq. 4.1)::

    r = l u(a, b),   u = [-sin a,  cos a sin b,  -cos a cos b]

**Our choice of frame: the sway angles (a, b) are defined with respect to the WORLD axes**
(not the slewed crane frame as in document 002).  Then ``r`` is directly the quantity a
world-aligned perception reports (``p_hook_world - p_tip_world``), the filter's LiDAR model
is ``h(x) = l u(a, b)`` and the pendulum equations contain no frame-rotation terms: every
effect of slewing, luffing, boom deflection and vessel motion enters the pendulum only
through the inertial acceleration of the suspension point.  The singularity of this
parameterisation (b = +-90 deg: the rope horizontal along world y) is never reached.

Equations of motion (closed form, REFERENCE.md "A simpler route ...").  With the
orthonormal basis ``u``, ``e_a = du/da = [-cos a, -sin a sin b, sin a cos b]`` and
``e_b = (du/db)/cos a = [0, cos b, sin b]``, the hook's Newton equation
``m (a_tip + r'') = m g_vec - T u`` (``g_vec = [0, 0, -g]``, rope tension ``T``) projected on
``e_a``, ``e_b`` and ``u`` gives::

    l a'' + 2 l' a' + l sin a cos a b'^2           = (g_vec - a_tip) . e_a
    l cos a b'' + 2 l' cos a b' - 2 l sin a a' b'   = (g_vec - a_tip) . e_b
    T = m [ (g_vec - a_tip) . u - l'' + l a'^2 + l cos^2 a b'^2 ]

The boom's generalised coordinate ``nu_f`` (point mass ``m_b`` at the tip, torsion spring
``k_f``, Rayleigh damping ``c_f``, eqs. 4.18-4.22) obeys the Lagrange equation::

    m_b (a_tip - g_vec) . J + k_f nu_f + c_f nu_f' = T u . J,      J = d p_tip_world / d nu_f

with ``a_tip = a_tip0 + J nu_f''`` (``a_tip0``: everything but ``nu_f''``): slew
acceleration, centripetal/Coriolis terms, luffing, vessel motion and the rope tension's
component along ``J`` drive the boom.  Substituting ``T`` gives ``nu_f''`` explicitly::

    nu_f'' (m_b J.J + m (J.u)^2) = T0 (J.u) - m_b (a_tip0 - g_vec) . J - k_f nu_f - c_f nu_f'

(``T0``: tension with ``nu_f'' = 0``), then ``a''`` and ``b''`` follow.  This is the same
system as document 002's Lagrangian model (appendix A), whose mass matrix is inverted
numerically there.  The rigid model is the flexible one with ``k_f -> inf`` (``nu_f`` = 0).

Joint motions (slew ``nu``, luff ``mu``, hoist ``l``) and vessel roll/pitch are inputs: the
truth simulation prescribes them (document 002 5.1.1), the filter estimates them.  Only the
hook and boom states are integrated (:func:`rk4_substep`).  The truth may add effects this
model leaves out (rope stretch, wind drag: data/sim/crane_truth.py).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial.transform import Rotation

__all__ = [
    "DEG",
    "CraneParams",
    "JointStates",
    "VesselState",
    "pendulum_accelerations_core",
    "crane_accelerations",
    "rk4_substep",
    "vessel_rotation",
    "tip_kinematics",
    "hook_relative_kinematics",
]

DEG = math.pi / 180.0


# --------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------
class CraneParams(BaseModel):
    """Crane, boom and hook parameters (document 002 Table 4.1)."""

    model_config = ConfigDict(frozen=True)

    m: float = Field(1e6, gt=0, description="hook + load mass [kg]")
    m_b: float = Field(2e6, gt=0, description="boom inertia as a point mass at the tip [kg]")
    L: float = Field(150.0, gt=0, description="boom length [m]")
    b: float = Field(10.0, description="mast-boom joint offset from the slewing axis [m]")
    h: float = Field(40.0, description="mast height (boom foot above the crane base) [m]")
    c: tuple[float, float, float] = Field(
        (50.0, -20.0, 10.0), description="crane base in the vessel frame, from the centre of rotation [m]"
    )
    k_f: float = Field(2e11, gt=0, description="boom torsion spring (slewing direction) [N m/rad]")
    c_f: float = Field(2e9, ge=0, description="boom torsion damping [J s/rad]")
    g: float = Field(9.81, gt=0, description="gravitational acceleration [m/s^2]")
    flexible: bool = Field(True, description="flexible boom (nu_f state) or rigid boom")
    sway_damping_per_s: float = Field(
        0.0, ge=0, description="linear damping on a', b' [1/s]; 0 in the document's model (tests only)"
    )

    def as_tuple(self) -> tuple[float, ...]:
        cx, cy, cz = self.c
        return (self.m, self.m_b, self.L, self.b, self.h, cx, cy, cz, self.k_f, self.c_f, self.g,
                self.sway_damping_per_s)



# --------------------------------------------------------------------------------------
# Inputs: joint and vessel motion
# --------------------------------------------------------------------------------------
class JointStates(NamedTuple):
    """Prescribed crane joint trajectories: angles in rad, rope length in m."""

    nu: np.ndarray
    nu_dot: np.ndarray
    nu_ddot: np.ndarray
    mu: np.ndarray
    mu_dot: np.ndarray
    mu_ddot: np.ndarray
    l: np.ndarray
    l_dot: np.ndarray
    l_ddot: np.ndarray


class VesselState(NamedTuple):
    """Vessel roll/pitch (rad) and their first two time derivatives."""

    roll: np.ndarray
    roll_dot: np.ndarray
    roll_ddot: np.ndarray
    pitch: np.ndarray
    pitch_dot: np.ndarray
    pitch_ddot: np.ndarray


# --------------------------------------------------------------------------------------
# Dynamics (one implementation for python floats, numpy arrays and complex arrays)
# --------------------------------------------------------------------------------------
def pendulum_accelerations_core(sin, cos, prm, flexible,
                                a, ad, b, bd,
                                nu, nud, nudd, mu, mud, mudd, l, ld, ldd,
                                roll, rolld, rolldd, pitch, pitchd, pitchdd,
                                f, fd):
    """(a'', b'', nu_f'') from the state and the inputs; ``prm`` is ``CraneParams.as_tuple()``.

    Works elementwise on floats (pass math.sin/cos) or arrays (np.sin/cos, also complex for
    complex-step differentiation), and on the hook filter's tracer (fusion/models/autodiff.py:
    straight-line code, no branch on a value).  See the module docstring for the derivation.
    """
    m, mb, L, bb, h, cx, cy, cz, kf, cf, g, zeta = prm
    sa = sin(a)
    ca = cos(a)
    sb = sin(b)
    cb = cos(b)
    sr = sin(roll)
    cr = cos(roll)
    sp = sin(pitch)
    cp = cos(pitch)
    # body angular velocity / acceleration of R = Ry(pitch) Rx(roll)
    wx = rolld
    wy = cr * pitchd
    wz = -sr * pitchd
    alx = rolldd
    aly = cr * pitchdd - sr * rolld * pitchd
    alz = -sr * pitchdd - cr * rolld * pitchd
    # crane geometry (vessel frame)
    smu = sin(mu)
    cmu = cos(mu)
    sn = sin(nu)
    cn = cos(nu)
    th = nu + f
    thd = nud + fd
    st = sin(th)
    ct = cos(th)
    Lc = L * cmu
    qx = cx + bb * cn + Lc * ct
    qy = cy + bb * sn + Lc * st
    qz = cz + h + L * smu
    k1 = -L * smu * mud
    k2 = Lc * thd
    bnd = bb * nud
    qdx = -bnd * sn + k1 * ct - k2 * st
    qdy = bnd * cn + k1 * st + k2 * ct
    qdz = Lc * mud
    k3 = -L * (cmu * mud * mud + smu * mudd) - Lc * thd * thd
    k4 = -2.0 * L * smu * mud * thd + Lc * nudd
    bn2 = bnd * nud
    bndd = bb * nudd
    qddx = -bndd * sn - bn2 * cn + k3 * ct - k4 * st
    qddy = bndd * cn - bn2 * sn + k3 * st + k4 * ct
    qddz = L * (cmu * mudd - smu * mud * mud)
    # acceleration in vessel axes: q'' + w x (2 q' + w x q) + alpha x q
    wqx = wy * qz - wz * qy
    wqy = wz * qx - wx * qz
    wqz = wx * qy - wy * qx
    tx = 2.0 * qdx + wqx
    ty = 2.0 * qdy + wqy
    tz = 2.0 * qdz + wqz
    avx = qddx + (wy * tz - wz * ty) + (aly * qz - alz * qy)
    avy = qddy + (wz * tx - wx * tz) + (alz * qx - alx * qz)
    avz = qddz + (wx * ty - wy * tx) + (alx * qy - aly * qx)
    # to world axes
    R01 = sp * sr
    R02 = sp * cr
    R21 = cp * sr
    R22 = cp * cr
    a0x = cp * avx + R01 * avy + R02 * avz
    a0y = cr * avy - sr * avz
    a0z = -sp * avx + R21 * avy + R22 * avz
    ux = -sa
    uy = ca * sb
    uz = -ca * cb
    if flexible:
        jvx = -Lc * st
        jvy = Lc * ct
        Jx = cp * jvx + R01 * jvy
        Jy = cr * jvy
        Jz = -sp * jvx + R21 * jvy
        T0 = m * (g * ca * cb - (a0x * ux + a0y * uy + a0z * uz) - ldd + l * (ad * ad + ca * ca * bd * bd))
        Ju = Jx * ux + Jy * uy + Jz * uz
        num = T0 * Ju - mb * (a0x * Jx + a0y * Jy + a0z * Jz + g * Jz) - kf * f - cf * fd
        fdd = num / (mb * (Jx * Jx + Jy * Jy + Jz * Jz) + m * Ju * Ju)
        atx = a0x + Jx * fdd
        aty = a0y + Jy * fdd
        atz = a0z + Jz * fdd
    else:
        fdd = 0.0 * a
        atx, aty, atz = a0x, a0y, a0z
    # (g_vec - a_tip) . e_a and . e_b
    Ga = atx * ca + aty * sa * sb - atz * sa * cb - g * sa * cb
    Gb = -(aty * cb + atz * sb) - g * sb
    add = (Ga - 2.0 * ld * ad) / l - sa * ca * bd * bd - zeta * ad
    bdd = Gb / (l * ca) - 2.0 * ld * bd / l + 2.0 * (sa / ca) * ad * bd - zeta * bd
    return add, bdd, fdd


def crane_accelerations(params: CraneParams, a, a_dot, b, b_dot, joints: JointStates, vessel: VesselState,
                        nu_f=0.0, nu_f_dot=0.0, flexible: bool | None = None):
    """Vectorised (numpy) (a'', b'', nu_f'') for arrays of states and inputs."""
    flex = params.flexible if flexible is None else flexible
    j, v = joints, vessel
    return pendulum_accelerations_core(np.sin, np.cos, params.as_tuple(), flex, a, a_dot, b, b_dot,
                                       j.nu, j.nu_dot, j.nu_ddot, j.mu, j.mu_dot, j.mu_ddot,
                                       j.l, j.l_dot, j.l_ddot,
                                       v.roll, v.roll_dot, v.roll_ddot, v.pitch, v.pitch_dot, v.pitch_ddot,
                                       nu_f, nu_f_dot)


def rk4_substep(prm, flex, y, h, u0, u1, u2, sin=math.sin, cos=math.cos, accel=None):
    """One RK4 step of (a, a', b, b', nu_f, nu_f') with the inputs u0, u1, u2 (15 values each,
    as in :func:`pendulum_accelerations_core`) at the start, middle and end.

    sin/cos are parameters so the filter runs it on arrays with the very same operations;
    ``accel`` (same signature as the core, default the core) lets the truth add what the
    nominal model leaves out.
    """
    acc = pendulum_accelerations_core if accel is None else accel
    a, ad, b, bd, f, fd = y
    h2 = 0.5 * h
    k1a, k1b, k1f = acc(sin, cos, prm, flex, a, ad, b, bd, *u0, f, fd)
    a2, ad2, b2, bd2, f2, fd2 = a + h2 * ad, ad + h2 * k1a, b + h2 * bd, bd + h2 * k1b, f + h2 * fd, fd + h2 * k1f
    k2a, k2b, k2f = acc(sin, cos, prm, flex, a2, ad2, b2, bd2, *u1, f2, fd2)
    a3, ad3, b3, bd3, f3, fd3 = a + h2 * ad2, ad + h2 * k2a, b + h2 * bd2, bd + h2 * k2b, f + h2 * fd2, fd + h2 * k2f
    k3a, k3b, k3f = acc(sin, cos, prm, flex, a3, ad3, b3, bd3, *u1, f3, fd3)
    a4, ad4, b4, bd4, f4, fd4 = a + h * ad3, ad + h * k3a, b + h * bd3, bd + h * k3b, f + h * fd3, fd + h * k3f
    k4a, k4b, k4f = acc(sin, cos, prm, flex, a4, ad4, b4, bd4, *u2, f4, fd4)
    h6 = h / 6.0
    return (a + h6 * (ad + 2 * ad2 + 2 * ad3 + ad4), ad + h6 * (k1a + 2 * k2a + 2 * k3a + k4a),
            b + h6 * (bd + 2 * bd2 + 2 * bd3 + bd4), bd + h6 * (k1b + 2 * k2b + 2 * k3b + k4b),
            f + h6 * (fd + 2 * fd2 + 2 * fd3 + fd4), fd + h6 * (k1f + 2 * k2f + 2 * k3f + k4f))


# --------------------------------------------------------------------------------------
# Kinematics (vectorised)
# --------------------------------------------------------------------------------------
def vessel_rotation(roll_rad, pitch_rad, yaw_rad=0.0) -> np.ndarray:
    """R_world_vessel = Rz(yaw) Ry(pitch) Rx(roll), shape (..., 3, 3)."""
    roll = np.asarray(roll_rad, float)
    shp = roll.shape
    eul = np.stack(np.broadcast_arrays(roll, np.asarray(pitch_rad, float), np.asarray(yaw_rad, float)), -1)
    return Rotation.from_euler("xyz", eul.reshape(-1, 3)).as_matrix().reshape(shp + (3, 3))


def tip_kinematics(params: CraneParams, joints: JointStates, vessel: VesselState, nu_f=0.0, nu_f_dot=0.0,
                   nu_f_ddot=0.0):
    """Boom-tip position, velocity and acceleration in the world frame, each (N, 3)."""
    P = params
    j, v = joints, vessel
    nu, nud, nudd = (np.atleast_1d(np.asarray(x, float)) for x in (j.nu, j.nu_dot, j.nu_ddot))
    mu, mud, mudd = (np.atleast_1d(np.asarray(x, float)) for x in (j.mu, j.mu_dot, j.mu_ddot))
    f, fd, fdd = np.broadcast_arrays(*(np.atleast_1d(np.asarray(x, float)) for x in (nu_f, nu_f_dot, nu_f_ddot)))
    f, fd, fdd = (np.broadcast_to(x, nu.shape) for x in (f, fd, fdd))
    cx, cy, cz = P.c
    th, thd, thdd = nu + f, nud + fd, nudd + fdd
    e = lambda x: np.stack([np.cos(x), np.sin(x), np.zeros_like(x)], -1)
    ep = lambda x: np.stack([-np.sin(x), np.cos(x), np.zeros_like(x)], -1)
    ez = np.array([0.0, 0.0, 1.0])
    Lc = (P.L * np.cos(mu))[:, None]
    Ls = (P.L * np.sin(mu))[:, None]
    q = np.array([cx, cy, cz]) + P.b * e(nu) + Lc * e(th) + (P.h + Ls) * ez
    qd = (P.b * nud[:, None] * ep(nu) - Ls * mud[:, None] * e(th) + Lc * thd[:, None] * ep(th)
          + Lc * mud[:, None] * ez)
    qdd = (P.b * (nudd[:, None] * ep(nu) - (nud**2)[:, None] * e(nu))
           - (Lc * (mud**2)[:, None] + Ls * mudd[:, None]) * e(th)
           - 2 * Ls * (mud * thd)[:, None] * ep(th)
           + Lc * (thdd[:, None] * ep(th) - (thd**2)[:, None] * e(th))
           + (Lc * mudd[:, None] - Ls * (mud**2)[:, None]) * ez)
    roll, rolld, rolldd = (np.broadcast_to(np.asarray(x, float), nu.shape) for x in (v.roll, v.roll_dot, v.roll_ddot))
    pitch, pitchd, pitchdd = (np.broadcast_to(np.asarray(x, float), nu.shape) for x in (v.pitch, v.pitch_dot, v.pitch_ddot))
    sr, cr = np.sin(roll), np.cos(roll)
    w = np.stack([rolld, cr * pitchd, -sr * pitchd], -1)
    al = np.stack([rolldd, cr * pitchdd - sr * rolld * pitchd, -sr * pitchdd - cr * rolld * pitchd], -1)
    R = vessel_rotation(roll, pitch)
    vel_v = qd + np.cross(w, q)
    acc_v = qdd + np.cross(w, 2 * qd + np.cross(w, q)) + np.cross(al, q)
    rot = lambda x: np.einsum("nij,nj->ni", R, x)
    return rot(q), rot(vel_v), rot(acc_v)


def hook_relative_kinematics(l, l_dot, a, a_dot, b, b_dot):
    """Hook position and velocity relative to the boom tip, world axes, each (N, 3)."""
    l, l_dot, a, a_dot, b, b_dot = (np.asarray(x, float) for x in (l, l_dot, a, a_dot, b, b_dot))
    sa, ca, sb, cb = np.sin(a), np.cos(a), np.sin(b), np.cos(b)
    u = np.stack([-sa, ca * sb, -ca * cb], -1)
    ea = np.stack([-ca, -sa * sb, sa * cb], -1)
    eb = np.stack([np.zeros_like(b), cb, sb], -1)
    r = l[..., None] * u
    rd = l_dot[..., None] * u + l[..., None] * (a_dot[..., None] * ea + (ca * b_dot)[..., None] * eb)
    return r, rd

