"""Rigid-body ship motion: each DOF is a sum of sinusoids, in closed form.

Everything is analytic (no integration), so poses, velocities and accelerations at any
set of times are exact and vectorised. A body's pose in the world is
    p_world = R(t) p_body + o(t),   R = Rz(yaw) Ry(pitch) Rx(roll)
with o(t) = rest position + (surge, sway, heave). Surge/sway/heave are along world axes
(the vessel does not sail), so o's velocity is simply their time derivative.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial.transform import Rotation

from boomtip.data.poses import rpy_matrices
from boomtip.data.sea_spectrum import jonswap
from boomtip.data.sim.world import DOFS, IrregularSea, Motion

G = 9.81


@dataclass(frozen=True)
class SineBank:
    """Sum of sinusoids a_k sin(w_k t + phi_k) per DOF: arrays (6, K) in SI units (m, rad)."""

    amplitude: np.ndarray
    omega: np.ndarray
    phase: np.ndarray

    def eval(self, t_s: np.ndarray, derivative: int = 0) -> np.ndarray:
        """The DOFs (or their n-th time derivative) at times t: (len(t), 6)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        arg = t[:, None, None] * self.omega[None] + self.phase[None] + derivative * np.pi / 2
        return np.sum(self.amplitude[None] * self.omega[None] ** derivative * np.sin(arg), axis=2)

    def at(self, t_s: float) -> np.ndarray:
        """The DOFs at one instant (a frame's pose), (1, 6): `eval([t_s])` in four calls on
        the (6, K) arrays instead of the broadcasts over times; the same values, but for the
        order numpy may add a long sum in (an irregular sea's: within 1e-15)."""
        arg = self.omega * t_s
        arg += self.phase
        np.sin(arg, out=arg)
        arg *= self.amplitude
        return arg.sum(axis=1)[None]


class ShiftedSines:
    """A SineBank at t + c_j for fixed offsets c_j (a sweep's column times), frame after
    frame: sin(w (t + c) + phi) = sin(w t + phi) cos(w c) + cos(w t + phi) sin(w c), so a call
    takes a sine and a cosine per component and one product, not a sine per offset and
    component. The same values as `SineBank.eval(t + c)` to rounding."""

    def __init__(self, bank: SineBank, offsets_s: np.ndarray) -> None:
        self.bank, self.offsets_s = bank, offsets_s
        wc = bank.omega[:, :, None] * np.asarray(offsets_s, dtype=float)  # (6,K,C)
        self._table = np.concatenate([np.cos(wc), np.sin(wc)], axis=1)  # (6,2K,C)

    def eval(self, t_s: float) -> np.ndarray:
        """The DOFs at t_s + each offset: (C, 6)."""
        b = self.bank
        theta = b.omega * t_s + b.phase  # (6,K)
        coef = np.concatenate([b.amplitude * np.sin(theta), b.amplitude * np.cos(theta)], axis=1)  # (6,2K)
        return np.einsum("dk,dkc->cd", coef, self._table)


def sine_bank(motion: Motion, irregular: IrregularSea, seed: int) -> SineBank:
    """Collect the scenario's sinusoids, plus the irregular sea's components, per DOF."""
    amp, om, ph = [], [], []
    for dof in DOFS:
        s = getattr(motion, dof)
        scale = np.pi / 180 if dof in ("roll", "pitch", "yaw") else 1.0
        amp.append([s.amplitude * scale])
        om.append([2 * np.pi / s.period_s])
        ph.append([np.deg2rad(s.phase_deg)])
    amp_a, om_a, ph_a = (np.array(x, dtype=float) for x in (amp, om, ph))
    if irregular.enabled:
        rng = np.random.default_rng(seed)
        wp = 2 * np.pi / irregular.tp_s
        # Random frequencies within each band avoid the exact periodicity of an even grid.
        edges = np.linspace(0.4 * wp, 3.0 * wp, irregular.n_components + 1)
        w = edges[:-1] + rng.random(irregular.n_components) * np.diff(edges)
        a_wave = np.sqrt(2 * jonswap(w, irregular.hs_m, irregular.tp_s, irregular.gamma) * np.diff(edges))
        k = irregular.n_components
        extra_a = np.zeros((6, k))
        for i, dof in enumerate(DOFS):
            gain = irregular.response.get(dof, 0.0)
            scale = np.pi / 180 if dof in ("roll", "pitch", "yaw") else 1.0
            extra_a[i] = gain * scale * a_wave
        extra_p = rng.uniform(0, 2 * np.pi, size=(6, k))  # independent phases per DOF
        amp_a = np.hstack([amp_a, extra_a])
        om_a = np.hstack([om_a, np.broadcast_to(w, (6, k))])
        ph_a = np.hstack([ph_a, extra_p])
    return SineBank(amp_a, om_a, ph_a)


def euler_rates_to_omega_world(rpy: np.ndarray, rpy_dot: np.ndarray) -> np.ndarray:
    """Angular velocity in world axes for R = Rz(yaw) Ry(pitch) Rx(roll).

    w = yaw_dot e_z + pitch_dot Rz e_y + roll_dot Rz Ry e_x.
    """
    r, p, y = rpy.T
    rd, pd, yd = rpy_dot.T
    cy, sy, cp, sp = np.cos(y), np.sin(y), np.cos(p), np.sin(p)
    wx = -sy * pd + cy * cp * rd
    wy = cy * pd + sy * cp * rd
    wz = yd - sp * rd
    return np.stack([wx, wy, wz], axis=-1)


@dataclass(frozen=True)
class BodyStates:
    """Poses and twists of one body at a set of times (world frame, world axes)."""

    t_s: np.ndarray
    position_m: np.ndarray  # (T,3) body origin
    rpy_rad: np.ndarray  # (T,3) roll, pitch, yaw
    velocity_mps: np.ndarray  # (T,3) body origin velocity
    omega_radps: np.ndarray  # (T,3) angular velocity
    rpy_rate_radps: np.ndarray  # (T,3) Euler angle rates

    @property
    def rotation(self) -> Rotation:
        return Rotation.from_euler("xyz", self.rpy_rad)

    @cached_property
    def R(self) -> np.ndarray:
        """Rotation matrices (T,3,3), R = Rz(yaw) Ry(pitch) Rx(roll): written out because a
        scipy Rotation per frame costs more than the maths for a few matrices."""
        return rpy_matrices(self.rpy_rad)

    def matrices(self) -> np.ndarray:
        """4x4 T_world_body per time: (T,4,4)."""
        T = np.tile(np.eye(4), (len(self.t_s), 1, 1))
        T[:, :3, :3] = self.R
        T[:, :3, 3] = self.position_m
        return T

    def point_velocity(self, p_world: np.ndarray, index: np.ndarray | int) -> np.ndarray:
        """Velocity of body-fixed points at world positions p (N,3) at state index/indices."""
        return self.velocity_mps[index] + np.cross(self.omega_radps[index], p_world - self.position_m[index])


class ShipMotion:
    """Closed-form 6-DOF motion of one vessel about its rest position."""

    def __init__(self, motion: Motion, irregular: IrregularSea, rest_position_m, seed: int) -> None:
        self.bank = sine_bank(motion, irregular, seed)
        self.rest_position_m = np.asarray(rest_position_m, dtype=float)

    def states(self, t_s) -> BodyStates:
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        q = self.bank.eval(t)
        qd = self.bank.eval(t, 1)
        rpy, rpy_dot = q[:, 3:], qd[:, 3:]
        return BodyStates(
            t_s=t,
            position_m=self.rest_position_m + q[:, :3],
            rpy_rad=rpy,
            velocity_mps=qd[:, :3],
            omega_radps=euler_rates_to_omega_world(rpy, rpy_dot),
            rpy_rate_radps=rpy_dot,
        )
