"""Prescribed vessel roll and pitch for the truth simulation: regular or summed sinusoids,
a static vessel, or user callables.  Each ``evaluate(t)`` returns
:class:`~boomtip.data.crane_model.VesselState` (arrays for an array ``t``, floats for a scalar).
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np
from pydantic import BaseModel, Field

from boomtip.data.crane_model import DEG, VesselState

__all__ = ["WaveComponent", "VesselWaves", "StaticVessel", "CallableVesselMotion", "as_vessel_motion"]


class WaveComponent(BaseModel):
    amplitude_deg: float
    period_s: float = Field(gt=0)
    phase_deg: float = 0.0


def _sines(comps: Sequence[WaveComponent], t):
    if np.ndim(t) == 0:
        q = qd = qdd = 0.0
        for c in comps:
            A, w, ph = c.amplitude_deg * DEG, 2 * math.pi / c.period_s, c.phase_deg * DEG
            s, co = math.sin(w * t + ph), math.cos(w * t + ph)
            q += A * s
            qd += A * w * co
            qdd -= A * w * w * s
        return q, qd, qdd
    t = np.asarray(t, float)
    q, qd, qdd = np.zeros(t.shape), np.zeros(t.shape), np.zeros(t.shape)
    for c in comps:
        A, w, ph = c.amplitude_deg * DEG, 2 * np.pi / c.period_s, c.phase_deg * DEG
        s, co = np.sin(w * t + ph), np.cos(w * t + ph)
        q += A * s
        qd += A * w * co
        qdd -= A * w * w * s
    return q, qd, qdd


class VesselWaves(BaseModel):
    """Vessel roll and pitch as sums of sinusoids about the fixed centre of rotation."""

    roll: list[WaveComponent] = Field(default_factory=list)
    pitch: list[WaveComponent] = Field(default_factory=list)

    @classmethod
    def regular(cls, amplitude_deg: float, period_s: float, roll_phase_deg: float = 90.0,
                pitch_phase_deg: float = 0.0) -> "VesselWaves":
        return cls(
            roll=[WaveComponent(amplitude_deg=amplitude_deg, period_s=period_s, phase_deg=roll_phase_deg)],
            pitch=[WaveComponent(amplitude_deg=amplitude_deg, period_s=period_s, phase_deg=pitch_phase_deg)],
        )

    def evaluate(self, t_s) -> VesselState:
        return VesselState(*_sines(self.roll, t_s), *_sines(self.pitch, t_s))


class StaticVessel:
    def evaluate(self, t_s) -> VesselState:
        if np.ndim(t_s) == 0:
            return VesselState(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        z = np.zeros(np.shape(t_s))
        return VesselState(z, z, z, z, z, z)


class CallableVesselMotion:
    """Vessel motion from user callables ``fn(t) -> (angle, rate, acceleration)`` in rad.

    Each callable must accept a float or an array of times.
    """

    def __init__(self, roll_fn: Callable | None = None, pitch_fn: Callable | None = None) -> None:
        zero = lambda t: (0.0, 0.0, 0.0) if np.ndim(t) == 0 else (np.zeros(np.shape(t)),) * 3
        self.roll_fn = roll_fn or zero
        self.pitch_fn = pitch_fn or zero

    def evaluate(self, t_s) -> VesselState:
        r = self.roll_fn(t_s)
        p = self.pitch_fn(t_s)
        if np.ndim(t_s) != 0:
            shp = np.shape(t_s)
            r = tuple(np.broadcast_to(np.asarray(v, float), shp) for v in r)
            p = tuple(np.broadcast_to(np.asarray(v, float), shp) for v in p)
        return VesselState(*r, *p)


def as_vessel_motion(vessel_motion) -> object:
    if vessel_motion is None:
        return StaticVessel()
    if isinstance(vessel_motion, (list, tuple)) and len(vessel_motion) == 2 and all(
        callable(f) or f is None for f in vessel_motion
    ):
        return CallableVesselMotion(*vessel_motion)
    if not hasattr(vessel_motion, "evaluate"):
        raise TypeError("vessel_motion must have evaluate(t) or be a (roll_fn, pitch_fn) pair")
    return vessel_motion
