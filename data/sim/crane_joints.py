"""Prescribed crane joint motions (slew ``nu``, luff ``mu``, hoist ``l``) for the truth simulation.

Each ``evaluate(t)`` returns :class:`~boomtip.data.crane_model.JointStates` (arrays for an array
``t``, floats for a scalar ``t``: the adaptive integrator calls it per step) and ``breakpoints()``
the times where an acceleration jumps, so the integrators can step exactly onto them.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from pydantic import BaseModel, Field

from boomtip.data.crane_model import DEG, CraneParams, JointStates

__all__ = ["JointLimits", "JointMove", "JointProfile", "CraneJointProfiles", "CoordinatedLinePath"]


class JointLimits(BaseModel):
    """Velocity / acceleration limits of the crane drives.

    Document 002: slew speed about 0.3 rpm = 0.0314 rad/s (3.1.3); acceleration limits
    a_mu = 0.0005 rad/s^2, a_nu = 0.01 rad/s^2, a_l = 0.1125 m/s^2 (4.6.2).  The luffing and
    hoisting speeds are not given there: 1 deg/s and 1 m/s (boomtip defaults).
    """

    slew_rate_max_rad_s: float = 0.3 * 2.0 * math.pi / 60.0
    slew_acc_max_rad_s2: float = 0.01
    luff_rate_max_rad_s: float = 1.0 * DEG
    luff_acc_max_rad_s2: float = 0.0005
    hoist_rate_max_m_s: float = 1.0
    hoist_acc_max_m_s2: float = 0.1125


class JointMove(BaseModel):
    """One acceleration-limited (trapezoidal velocity) move of a joint."""

    t_start_s: float
    target: float  # rad or m
    v_max: float = Field(gt=0)
    a_max: float = Field(gt=0)


def move_timing(delta: float, v_max: float, a_max: float) -> tuple[float, float, float, float]:
    """(t_acc, t_cruise, t_total, v_peak) of a rest-to-rest trapezoidal move of |delta|."""
    d = abs(delta)
    if d <= v_max * v_max / a_max:
        t_a = math.sqrt(d / a_max)
        return t_a, 0.0, 2.0 * t_a, a_max * t_a
    t_a = v_max / a_max
    t_c = (d - v_max * t_a) / v_max
    return t_a, t_c, 2.0 * t_a + t_c, v_max


class JointProfile:
    """Piecewise trapezoidal-velocity trajectory of one joint.

    ``moves`` are executed in order from ``initial``; each starts at ``t_start_s`` (it may
    not start before the previous one has finished).  ``evaluate(t)`` returns
    (value, rate, acceleration), vectorised over ``t``.
    """

    def __init__(self, initial: float, moves: Sequence[JointMove] = ()) -> None:
        self.initial = float(initial)
        self._segments: list[tuple[float, float, float, float, float, float, float]] = []
        value = self.initial
        t_free = -math.inf
        for mv in sorted(moves, key=lambda m: m.t_start_s):
            if mv.t_start_s < t_free - 1e-9:
                raise ValueError(f"move at {mv.t_start_s} s starts before the previous one ends ({t_free} s)")
            delta = mv.target - value
            t_a, t_c, t_tot, v_p = move_timing(delta, mv.v_max, mv.a_max)
            sgn = 1.0 if delta >= 0 else -1.0
            a = v_p / t_a if t_a > 0 else 0.0
            self._segments.append((mv.t_start_s, sgn, abs(delta), a, v_p, t_a, t_c))
            value = mv.target
            t_free = mv.t_start_s + t_tot
        self.final = value
        self.t_end_s = t_free if self._segments else 0.0

    def breakpoints(self) -> list[float]:
        out = []
        for t0, _s, _d, _a, _v, t_a, t_c in self._segments:
            out += [t0, t0 + t_a, t0 + t_a + t_c, t0 + 2 * t_a + t_c]
        return out

    def evaluate(self, t_s):
        if np.ndim(t_s) == 0:
            return self._evaluate_scalar(float(t_s))
        t = np.asarray(t_s, dtype=float)
        q = np.full(t.shape, self.initial)
        qd = np.zeros(t.shape)
        qdd = np.zeros(t.shape)
        for t0, sgn, d, a, v_p, t_a, t_c in self._segments:
            tau = t - t0
            t_tot = 2 * t_a + t_c
            ph1 = (tau >= 0) & (tau < t_a)
            ph2 = (tau >= t_a) & (tau < t_a + t_c)
            ph3 = (tau >= t_a + t_c) & (tau < t_tot)
            done = tau >= t_tot
            s = np.zeros(t.shape)
            sd = np.zeros(t.shape)
            sdd = np.zeros(t.shape)
            s[ph1] = 0.5 * a * tau[ph1] ** 2
            sd[ph1] = a * tau[ph1]
            sdd[ph1] = a
            s[ph2] = 0.5 * a * t_a**2 + v_p * (tau[ph2] - t_a)
            sd[ph2] = v_p
            r3 = t_tot - tau[ph3]
            s[ph3] = d - 0.5 * a * r3**2
            sd[ph3] = a * r3
            sdd[ph3] = -a
            s[done] = d
            q += sgn * s
            qd += sgn * sd
            qdd += sgn * sdd
        return q, qd, qdd

    def _evaluate_scalar(self, t: float) -> tuple[float, float, float]:
        q = self.initial
        qd = 0.0
        qdd = 0.0
        for t0, sgn, d, a, v_p, t_a, t_c in self._segments:
            tau = t - t0
            if tau < 0:
                break
            t_tot = 2 * t_a + t_c
            if tau >= t_tot:
                q += sgn * d
                continue
            if tau < t_a:
                q += sgn * 0.5 * a * tau * tau
                qd += sgn * a * tau
                qdd += sgn * a
            elif tau < t_a + t_c:
                q += sgn * (0.5 * a * t_a * t_a + v_p * (tau - t_a))
                qd += sgn * v_p
            else:
                r3 = t_tot - tau
                q += sgn * (d - 0.5 * a * r3 * r3)
                qd += sgn * a * r3
                qdd -= sgn * a
        return q, qd, qdd


class CraneJointProfiles:
    """Slew, luff and hoist as independent :class:`JointProfile` objects."""

    def __init__(self, slew: JointProfile, luff: JointProfile, hoist: JointProfile) -> None:
        self.slew, self.luff, self.hoist = slew, luff, hoist

    @classmethod
    def from_moves(
        cls,
        nu0_rad: float,
        mu0_rad: float,
        l0_m: float,
        slew_moves: Sequence[tuple[float, float]] = (),
        luff_moves: Sequence[tuple[float, float]] = (),
        hoist_moves: Sequence[tuple[float, float]] = (),
        limits: JointLimits | None = None,
    ) -> "CraneJointProfiles":
        """Moves given as (t_start_s, target) pairs at the drives' limits."""
        lim = limits or JointLimits()
        mk = lambda moves, v, a: [JointMove(t_start_s=t0, target=q, v_max=v, a_max=a) for t0, q in moves]
        return cls(
            JointProfile(nu0_rad, mk(slew_moves, lim.slew_rate_max_rad_s, lim.slew_acc_max_rad_s2)),
            JointProfile(mu0_rad, mk(luff_moves, lim.luff_rate_max_rad_s, lim.luff_acc_max_rad_s2)),
            JointProfile(l0_m, mk(hoist_moves, lim.hoist_rate_max_m_s, lim.hoist_acc_max_m_s2)),
        )

    def breakpoints(self) -> list[float]:
        return sorted(set(self.slew.breakpoints() + self.luff.breakpoints() + self.hoist.breakpoints()))

    def evaluate(self, t_s) -> JointStates:
        return JointStates(*self.slew.evaluate(t_s), *self.luff.evaluate(t_s), *self.hoist.evaluate(t_s))


class CoordinatedLinePath:
    """Joint trajectories that keep the hanging hook on a straight line at constant height.

    The (static-equilibrium, hanging straight down) hook position moves in the vessel frame
    from ``p_start_vessel_m`` to ``p_end_vessel_m`` (same z) along a quintic
    (minimum-jerk) time law between ``t_start_s`` and ``t_end_s``.  Inverse kinematics of the
    rigid crane gives nu, mu, l and their first two derivatives in closed form.
    """

    def __init__(
        self,
        params: CraneParams,
        p_start_vessel_m: Sequence[float],
        p_end_vessel_m: Sequence[float],
        t_start_s: float,
        t_end_s: float,
    ) -> None:
        self.p0 = np.asarray(p_start_vessel_m, float)
        self.p1 = np.asarray(p_end_vessel_m, float)
        self._p0 = [float(v) for v in self.p0]
        self._dp = [float(v) for v in self.p1 - self.p0]
        if abs(self.p0[2] - self.p1[2]) > 1e-9:
            raise ValueError("the path must be at constant height")
        self.prm = params
        self.t0, self.t1 = float(t_start_s), float(t_end_s)
        for p in (self.p0, self.p1):  # the farthest points of a segment are its ends
            if np.hypot(p[0] - params.c[0], p[1] - params.c[1]) >= params.b + params.L:
                raise ValueError("path outside the crane's reach")

    def breakpoints(self) -> list[float]:
        return [self.t0, self.t1]

    def evaluate(self, t_s) -> JointStates:
        scalar = np.ndim(t_s) == 0
        if scalar:  # plain-float path (called per step by the adaptive integrator)
            return self._evaluate_scalar(float(t_s))
        t = np.atleast_1d(np.asarray(t_s, float))
        T = self.t1 - self.t0
        tau = np.clip((t - self.t0) / T, 0.0, 1.0)
        inside = (t > self.t0) & (t < self.t1)
        s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        sd = np.where(inside, (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / T, 0.0)
        sdd = np.where(inside, (60 * tau - 180 * tau**2 + 120 * tau**3) / T**2, 0.0)
        return self._ik(s, sd, sdd, np.sqrt, np.arctan2, np.arccos, np.sin, np.cos)

    def _evaluate_scalar(self, t: float) -> JointStates:
        T = self.t1 - self.t0
        tau = min(max((t - self.t0) / T, 0.0), 1.0)
        s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        if self.t0 < t < self.t1:
            sd = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / T
            sdd = (60 * tau - 180 * tau**2 + 120 * tau**3) / T**2
        else:
            sd = sdd = 0.0
        return self._ik(s, sd, sdd, math.sqrt, math.atan2, math.acos, math.sin, math.cos)

    def _ik(self, s, sd, sdd, sqrt, atan2, acos, sin, cos) -> JointStates:
        P = self.prm
        cx, cy, cz = P.c
        dp = self._dp
        # horizontal vector from crane base to the target (vessel frame) and derivatives
        dx = self._p0[0] + dp[0] * s - cx
        dy = self._p0[1] + dp[1] * s - cy
        dxd, dyd = dp[0] * sd, dp[1] * sd
        dxdd, dydd = dp[0] * sdd, dp[1] * sdd
        rho2 = dx * dx + dy * dy
        rho = sqrt(rho2)
        nu = atan2(dy, dx)
        cross = dx * dyd - dy * dxd
        nu_d = cross / rho2
        nu_dd = (dx * dydd - dy * dxdd) / rho2 - 2 * cross * (dx * dxd + dy * dyd) / rho2**2
        dot = dx * dxd + dy * dyd
        rho_d = dot / rho
        rho_dd = (dxd**2 + dyd**2 + dx * dxdd + dy * dydd) / rho - dot**2 / rho**3
        w = (rho - P.b) / P.L
        w_d, w_dd = rho_d / P.L, rho_dd / P.L
        sq = sqrt(1 - w * w)
        mu = acos(w)
        mu_d = -w_d / sq
        mu_dd = -w_dd / sq - w * w_d**2 / sq**3
        z_tip = cz + P.h + P.L * sin(mu)
        l = z_tip - self._p0[2]
        l_d = P.L * cos(mu) * mu_d
        l_dd = P.L * (cos(mu) * mu_dd - sin(mu) * mu_d**2)
        return JointStates(nu, nu_d, nu_dd, mu, mu_d, mu_dd, l, l_d, l_dd)
