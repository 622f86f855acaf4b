"""Truth simulation of the crane: the hook pendulum and the boom deflection integrated under
prescribed joint and vessel motion (document 002 5.1.1: the ground truth is driven entirely
deterministically), with the equations of motion of :mod:`boomtip.data.crane_model`.

A real crane deviates from that nominal model (which the hook filter uses), so the truth can
add, each off by default:

* rope stretch: the reeving's axial stiffness EA lengthens the pendulum quasi-statically under
  the hook's weight, ``l_true = l_hoist (1 + m g / EA)`` (and l', l'' by the same factor), while
  the hoist encoder reads the programme's ``l_hoist``;
* wind drag on the block: a horizontal wind ``w`` (world x, y; steady, or with gusts from the
  offshore gust spectrum, :mod:`boomtip.data.sim.wind`) gives
  ``F = 0.5 rho Cd A |w - v_h| (w - v_h)`` with ``v_h`` the hook's horizontal velocity, which
  enters a'' and b'' as a specific force projected on the tangent directions, like gravity.
  Its component along the rope (which would change the tension, hence the boom's drive) is
  left out: for a hook hanging in the wind it is second order in F / (m g).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Iterator, Sequence

import numpy as np

from boomtip.data.crane_model import (
    CraneParams,
    JointStates,
    VesselState,
    crane_accelerations,
    hook_relative_kinematics,
    pendulum_accelerations_core,
    rk4_substep,
    tip_kinematics,
)
from boomtip.data.sim.crane_truth_stream import dop853_chunks, rhs_and_pieces
from boomtip.data.sim.vessel_waves import as_vessel_motion
from boomtip.data.sim.wind import GustyWind

__all__ = ["CraneTruth", "crane_truth_chunks", "simulate_crane"]


@dataclass
class CraneTruth:
    """Recorded truth at ``record_rate_hz``; angles in rad, positions in m, world axes.
    ``l``, ``l_dot``, ``l_ddot`` are the hoist programme's (what the encoder reads)."""

    t: np.ndarray
    nu: np.ndarray
    nu_dot: np.ndarray
    nu_ddot: np.ndarray
    mu: np.ndarray
    mu_dot: np.ndarray
    mu_ddot: np.ndarray
    l: np.ndarray
    l_dot: np.ndarray
    l_ddot: np.ndarray
    l_rope: np.ndarray  # pendulum length: the hoist's l stretched by the hook's weight (= l if rigid)
    nu_f: np.ndarray
    nu_f_dot: np.ndarray
    a: np.ndarray
    b: np.ndarray
    a_dot: np.ndarray
    b_dot: np.ndarray
    roll: np.ndarray
    roll_dot: np.ndarray
    roll_ddot: np.ndarray
    pitch: np.ndarray
    pitch_dot: np.ndarray
    pitch_ddot: np.ndarray
    p_tip_world: np.ndarray
    v_tip_world: np.ndarray
    p_hook_world: np.ndarray
    v_hook_world: np.ndarray
    p_hook_rel_tip: np.ndarray
    v_hook_rel_tip: np.ndarray
    params: CraneParams
    runtime_s: float = 0.0
    method: str = "rk4"
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t)


class _StretchedRope:
    """The joint programme with the hoist's length, rate and acceleration scaled by the
    rope's static stretch (floats or arrays, like the programme)."""

    def __init__(self, joints, factor: float) -> None:
        self.joints, self.factor = joints, factor

    def breakpoints(self) -> list[float]:
        return getattr(self.joints, "breakpoints", lambda: [])()

    def evaluate(self, t_s) -> JointStates:
        nu, nud, nudd, mu, mud, mudd, l, ld, ldd = self.joints.evaluate(t_s)
        s = self.factor
        return JointStates(nu, nud, nudd, mu, mud, mudd, l * s, ld * s, ldd * s)


def _accelerations_with_drag(k_drag_per_m: float, wind_x, wind_y, gusts: GustyWind | None = None):
    """:func:`pendulum_accelerations_core` plus the wind drag on the hook, same signature and
    elementwise like it (floats in the RK4 loop, arrays elsewhere). ``k_drag_per_m`` is
    0.5 rho Cd A / m (1/m): the drag's specific force per squared relative air speed. With
    ``gusts`` the wind is theirs at the keyword ``t`` (s), and ``accel.time_varying`` is true."""

    def accel(sin, cos, prm, flexible, a, ad, b, bd, nu, nud, nudd, mu, mud, mudd, l, ld, ldd,
              roll, rolld, rolldd, pitch, pitchd, pitchdd, f, fd, t=0.0):
        add, bdd, fdd = pendulum_accelerations_core(sin, cos, prm, flexible, a, ad, b, bd, nu, nud, nudd,
                                                    mu, mud, mudd, l, ld, ldd, roll, rolld, rolldd,
                                                    pitch, pitchd, pitchdd, f, fd)
        _, _, L, bb, h, cx, cy, cz = prm[:8]
        # boom-tip velocity in vessel axes (as in the core), then its horizontal world part
        sn, cn, smu, cmu = sin(nu), cos(nu), sin(mu), cos(mu)
        th, thd = nu + f, nud + fd
        st, ct = sin(th), cos(th)
        Lc = L * cmu
        qx, qy, qz = cx + bb * cn + Lc * ct, cy + bb * sn + Lc * st, cz + h + L * smu
        k1, k2, bnd = -L * smu * mud, Lc * thd, bb * nud
        qdx = -bnd * sn + k1 * ct - k2 * st
        qdy = bnd * cn + k1 * st + k2 * ct
        qdz = Lc * mud
        sr, cr, sp, cp = sin(roll), cos(roll), sin(pitch), cos(pitch)
        wx, wy, wz = rolld, cr * pitchd, -sr * pitchd
        vvx = qdx + wy * qz - wz * qy
        vvy = qdy + wz * qx - wx * qz
        vvz = qdz + wx * qy - wy * qx
        v_tip_x = cp * vvx + sp * sr * vvy + sp * cr * vvz
        v_tip_y = cr * vvy - sr * vvz
        # the air's horizontal velocity relative to the hook, w - (v_tip + l' u + l (a' e_a + cos a b' e_b))
        sa, ca, sb, cb = sin(a), cos(a), sin(b), cos(b)
        wind_x, wind_y = steady if gusts is None else gusts(t)
        rx = wind_x - (v_tip_x - ld * sa - l * ad * ca)
        ry = wind_y - (v_tip_y + ld * ca * sb + l * (ca * bd * cb - ad * sa * sb))
        k = k_drag_per_m * (rx * rx + ry * ry) ** 0.5
        fx, fy = k * rx, k * ry
        # projected on e_a = (-cos a, -sin a sin b, sin a cos b) and e_b = (0, cos b, sin b)
        return add - (fx * ca + fy * sa * sb) / l, bdd + fy * cb / (l * ca), fdd

    steady = (wind_x, wind_y)
    accel.time_varying = gusts is not None
    return accel


def _inputs_at(joints, vessel, t: float) -> tuple:
    return tuple(float(v) for v in (*joints.evaluate(t), *vessel.evaluate(t)))


def _rk4_chunked(prm, flex, joints, vessel, y0, duration_s, dt_s, rec_every, accel, chunk_steps=20000):
    """Fixed-step RK4 with the prescribed inputs precomputed (vectorised) on the half-step grid.

    Steps containing a joint-acceleration breakpoint (trapezoid corners) are split there,
    with one-sided input limits, so the discontinuous inputs keep RK4's order.
    """
    n_steps = int(round(duration_s / dt_s))
    n_rec = n_steps // rec_every + 1
    out = np.empty((n_rec, 6))
    a, ad, b, bd, f, fd = (float(v) for v in y0)
    out[0] = (a, ad, b, bd, f, fd)
    rec_i = 1
    sin, cos = math.sin, math.cos
    core = accel
    h = dt_s
    h2 = 0.5 * h
    h6 = h / 6.0
    bps = getattr(joints, "breakpoints", lambda: [])()
    special: dict[int, list[float]] = {}
    for bp in bps:
        k = int(math.ceil(bp / h - 1e-9)) - 1  # step k covers (k h, (k+1) h]
        if 0 <= k < n_steps:
            special.setdefault(k, []).append(bp)
    eps = 1e-9
    step = 0
    while step < n_steps:
        n = min(chunk_steps, n_steps - step)
        tg = (step + np.arange(2 * n + 1) * 0.5) * h
        J = joints.evaluate(tg)
        V = vessel.evaluate(tg)
        U = list(zip(*(np.asarray(c, float).tolist() for c in (*J, *V))))
        for k in range(n):
            if step + k in special:
                t0 = (step + k) * h
                t1 = t0 + h
                y = (a, ad, b, bd, f, fd)
                edges = [t0] + sorted(special[step + k]) + [t1]
                for ta, tb in zip(edges[:-1], edges[1:]):
                    if tb - ta <= eps:
                        continue
                    y = rk4_substep(prm, flex, y, tb - ta, _inputs_at(joints, vessel, ta + eps if ta > t0 else ta),
                                    _inputs_at(joints, vessel, 0.5 * (ta + tb)), _inputs_at(joints, vessel, tb - eps),
                                    accel=accel)
                a, ad, b, bd, f, fd = y
            else:
                u0, u1, u2 = U[2 * k], U[2 * k + 1], U[2 * k + 2]
                k1a, k1b, k1f = core(sin, cos, prm, flex, a, ad, b, bd, *u0, f, fd)
                a2, ad2, b2, bd2, f2, fd2 = (a + h2 * ad, ad + h2 * k1a, b + h2 * bd, bd + h2 * k1b,
                                             f + h2 * fd, fd + h2 * k1f)
                k2a, k2b, k2f = core(sin, cos, prm, flex, a2, ad2, b2, bd2, *u1, f2, fd2)
                a3, ad3, b3, bd3, f3, fd3 = (a + h2 * ad2, ad + h2 * k2a, b + h2 * bd2, bd + h2 * k2b,
                                             f + h2 * fd2, fd + h2 * k2f)
                k3a, k3b, k3f = core(sin, cos, prm, flex, a3, ad3, b3, bd3, *u1, f3, fd3)
                a4, ad4, b4, bd4, f4, fd4 = (a + h * ad3, ad + h * k3a, b + h * bd3, bd + h * k3b,
                                             f + h * fd3, fd + h * k3f)
                k4a, k4b, k4f = core(sin, cos, prm, flex, a4, ad4, b4, bd4, *u2, f4, fd4)
                a += h6 * (ad + 2 * ad2 + 2 * ad3 + ad4)
                b += h6 * (bd + 2 * bd2 + 2 * bd3 + bd4)
                f += h6 * (fd + 2 * fd2 + 2 * fd3 + fd4)
                ad += h6 * (k1a + 2 * k2a + 2 * k3a + k4a)
                bd += h6 * (k1b + 2 * k2b + 2 * k3b + k4b)
                fd += h6 * (k1f + 2 * k2f + 2 * k3f + k4f)
            if (step + k + 1) % rec_every == 0:
                out[rec_i] = (a, ad, b, bd, f, fd)
                rec_i += 1
        step += n
    return out[:rec_i]


def _dop853(prm, flex, joints, vessel, y0, duration_s, t_rec, rtol, accel):
    """scipy DOP853 integrated piecewise between the inputs' breakpoints (acceleration steps)."""
    from scipy.integrate import solve_ivp

    rhs, pieces = rhs_and_pieces(prm, flex, joints, vessel, duration_s, accel)
    out = np.empty((len(t_rec), 6))
    y = np.asarray(y0, float)
    for t0, t1 in pieces:
        sel = (t_rec >= t0) & (t_rec <= t1)
        sol = solve_ivp(rhs, (t0, t1), y, method="DOP853", rtol=rtol, atol=rtol * 1e-3, dense_output=True)
        if not sol.success:
            raise RuntimeError(sol.message)
        if np.any(sel):
            out[sel] = sol.sol(t_rec[sel]).T
        y = sol.y[:, -1]
    return out


def _setup(params, joints, vessel_motion, initial_state, rope_ea_n, wind_mps, drag_area_m2, drag_coefficient,
           air_density_kgpm3, gust_seed=None):
    """The integration's inputs: the stretched rope's programme, the accelerations (with the
    drag), the vessel, the parameters as a tuple, the flexibility and the initial state."""
    if rope_ea_n is not None and not rope_ea_n > 0:
        raise ValueError("rope_ea_n must be positive (or None for a rigid rope)")
    if not drag_area_m2 >= 0:
        raise ValueError("drag_area_m2 must be >= 0")
    rope = joints if rope_ea_n is None else _StretchedRope(joints, 1.0 + params.m * params.g / rope_ea_n)
    accel = pendulum_accelerations_core
    if drag_area_m2 > 0:
        k_drag = 0.5 * air_density_kgpm3 * drag_coefficient * drag_area_m2 / params.m
        gusts = None if gust_seed is None else GustyWind.draw((float(wind_mps[0]), float(wind_mps[1])), gust_seed)
        accel = _accelerations_with_drag(k_drag, float(wind_mps[0]), float(wind_mps[1]), gusts)
    vessel = as_vessel_motion(vessel_motion)
    flex = bool(params.flexible)
    y0 = np.array(initial_state, float)
    if not flex:
        y0[4:] = 0.0
    return rope, accel, vessel, params.as_tuple(), flex, y0


def _truth_from_states(params, joints, rope, vessel, t_rec, Y, runtime_s, method) -> CraneTruth:
    """The recorded truth from the integrated states Y (m, 6) at the times t_rec: elementwise in
    the samples, so a chunk of records gives the same numbers as the whole run."""
    a, ad, b, bd, f, fd = Y.T
    J = joints.evaluate(t_rec)
    V = vessel.evaluate(t_rec)
    J = JointStates(*(np.broadcast_to(np.asarray(x, float), t_rec.shape).copy() for x in J))
    V = VesselState(*(np.broadcast_to(np.asarray(x, float), t_rec.shape).copy() for x in V))
    Jt = J if rope is joints else JointStates(*(np.broadcast_to(np.asarray(x, float), t_rec.shape).copy()
                                                for x in rope.evaluate(t_rec)))
    # the drag leaves nu_f'' unchanged (module docstring): the nominal model gives it
    _, _, fdd = crane_accelerations(params, a, ad, b, bd, Jt, V, f, fd)
    p_tip, v_tip, _ = tip_kinematics(params, Jt, V, f, fd, fdd)
    r, rd = hook_relative_kinematics(Jt.l, Jt.l_dot, a, ad, b, bd)
    return CraneTruth(
        t=t_rec, nu=J.nu, nu_dot=J.nu_dot, nu_ddot=J.nu_ddot, mu=J.mu, mu_dot=J.mu_dot, mu_ddot=J.mu_ddot,
        l=J.l, l_dot=J.l_dot, l_ddot=J.l_ddot, l_rope=Jt.l, nu_f=f, nu_f_dot=fd, a=a, b=b, a_dot=ad, b_dot=bd,
        roll=V.roll, roll_dot=V.roll_dot, roll_ddot=V.roll_ddot,
        pitch=V.pitch, pitch_dot=V.pitch_dot, pitch_ddot=V.pitch_ddot,
        p_tip_world=p_tip, v_tip_world=v_tip, p_hook_world=p_tip + r, v_hook_world=v_tip + rd,
        p_hook_rel_tip=r, v_hook_rel_tip=rd, params=params, runtime_s=runtime_s, method=method,
    )


def crane_truth_chunks(
    params: CraneParams,
    joints,
    vessel_motion=None,
    duration_s: float = 100.0,
    record_rate_hz: float = 200.0,
    *,
    chunk_s: float = 10.0,
    initial_state: Sequence[float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    rtol: float = 1e-9,
    rope_ea_n: float | None = None,
    wind_mps: tuple[float, float] = (0.0, 0.0),
    drag_area_m2: float = 0.0,
    drag_coefficient: float = 1.2,
    air_density_kgpm3: float = 1.225,
    gust_seed: int | None = None,
) -> Iterator[CraneTruth]:
    """:func:`simulate_crane` (DOP853) a chunk of ``chunk_s`` seconds of records at a time, in
    order: the same numbers, with a memory that does not grow with ``duration_s`` (a 700 s run's
    whole truth is 46 MB, and its derivation several times that)."""
    rope, accel, vessel, prm, flex, y0 = _setup(params, joints, vessel_motion, initial_state, rope_ea_n, wind_mps,
                                                drag_area_m2, drag_coefficient, air_density_kgpm3, gust_seed)
    n_rec = int(round(duration_s * record_rate_hz)) + 1
    t_rec = np.arange(n_rec) / record_rate_hz
    chunk_n = max(1, int(round(chunk_s * record_rate_hz)))
    for first, Y in dop853_chunks(prm, flex, rope, vessel, y0, duration_s, t_rec, rtol, accel, chunk_n):
        yield _truth_from_states(params, joints, rope, vessel, t_rec[first:first + len(Y)], Y, 0.0, "dop853")


def simulate_crane(
    params: CraneParams,
    joints,
    vessel_motion=None,
    duration_s: float = 100.0,
    dt_s: float = 1e-3,
    record_rate_hz: float = 200.0,
    *,
    method: str = "dop853",
    initial_state: Sequence[float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    rtol: float = 1e-9,
    rope_ea_n: float | None = None,
    wind_mps: tuple[float, float] = (0.0, 0.0),
    drag_area_m2: float = 0.0,
    drag_coefficient: float = 1.2,
    air_density_kgpm3: float = 1.225,
    gust_seed: int | None = None,
) -> CraneTruth:
    """Integrate the hook pendulum and (if ``params.flexible``) the boom deflection.

    ``joints``: object with ``evaluate(t) -> JointStates`` (e.g. the programmes of
    data/sim/crane_joints.py).  ``vessel_motion``: object with ``evaluate(t) -> VesselState``
    (data/sim/vessel_waves.py), a ``(roll_fn, pitch_fn)`` pair of callables, or None for a
    static vessel.
    ``initial_state`` = (a, a_dot, b, b_dot, nu_f, nu_f_dot).
    ``method``: "dop853" (default; scipy's adaptive 8th-order solver with ``rtol``,
    integrated piecewise between the joints' acceleration breakpoints, dense output at the
    record times) or "rk4" (fixed step ``dt_s``, plain-float arithmetic).  dop853 is several times
    faster than rk4 at 1 kHz; the two agree to < 1e-5 m.

    Beyond the nominal model (module docstring): ``rope_ea_n``, the reeving's axial stiffness
    EA in N (None: rigid rope); ``wind_mps``, a steady wind (world x, y) acting on the block's
    drag area ``drag_area_m2`` (0: no drag) with ``drag_coefficient`` and ``air_density_kgpm3``.
    ``gust_seed``: gusts on the steady wind (:mod:`boomtip.data.sim.wind`, drawn with this seed;
    None: steady; dop853 only).
    The truth's ``l`` is the hoist programme's (the encoder's), ``l_rope`` the stretched length.
    """
    rope, accel, vessel, prm, flex, y0 = _setup(params, joints, vessel_motion, initial_state, rope_ea_n, wind_mps,
                                                drag_area_m2, drag_coefficient, air_density_kgpm3, gust_seed)
    if method == "rk4" and getattr(accel, "time_varying", False):
        raise ValueError("simulate_crane: gusts (gust_seed) need method='dop853'; rk4 takes a steady wind")
    rec_every = int(round(1.0 / (record_rate_hz * dt_s)))
    if method == "rk4" and abs(rec_every * dt_s * record_rate_hz - 1.0) > 1e-9:
        raise ValueError("dt_s must divide the record period")
    n_rec = int(round(duration_s * record_rate_hz)) + 1
    t_rec = np.arange(n_rec) / record_rate_hz
    t_start = time.perf_counter()
    if method == "rk4":
        Y = _rk4_chunked(prm, flex, rope, vessel, y0, duration_s, dt_s, rec_every, accel)
        t_rec = t_rec[: len(Y)]
    elif method == "dop853":
        Y = _dop853(prm, flex, rope, vessel, y0, duration_s, t_rec, rtol, accel)
    else:
        raise ValueError(f"unknown method {method!r}")
    runtime = time.perf_counter() - t_start
    return _truth_from_states(params, joints, rope, vessel, t_rec, Y, runtime, method)
