"""Filter tuning from the scenario: sea state and sensor noise, never from the truth."""

from __future__ import annotations

import numpy as np

from boomtip.data.sim.motion import jonswap
from boomtip.data.scenario import IrregularSea, Scenario


def relative_heave_components(s: Scenario) -> list[tuple[float, float]]:
    """(amplitude m, period s) of every motion component that moves D.

    Heave enters directly; roll and pitch enter through their lever arm: the horizontal
    distance from the rotation centre to the boom tip (crane) or to the deck point below it
    (feeder). Irregular seas add their spectrum's components scaled by the DOF response.
    """
    tip = np.asarray(s.crane.geometry.boom_tip_m)
    feeder_pos = np.asarray(s.feeder.geometry.position_m)
    levers = {
        "crane": {"heave": 1.0, "roll": abs(tip[1]), "pitch": abs(tip[0])},
        "feeder": {"heave": 1.0, "roll": abs(tip[1] - feeder_pos[1]) + 1.0, "pitch": abs(tip[0] - feeder_pos[0]) + 1.0},
    }
    out: list[tuple[float, float]] = []
    for name, vessel in (("crane", s.crane), ("feeder", s.feeder)):
        for dof, lever in levers[name].items():
            sine = getattr(vessel.motion, dof)
            scale = np.deg2rad(1.0) * lever if dof != "heave" else 1.0
            if sine.amplitude:
                out.append((abs(sine.amplitude) * scale, sine.period_s))
        out += _irregular_components(vessel.irregular, levers[name])
    return out


def _irregular_components(irr: IrregularSea, levers: dict[str, float]) -> list[tuple[float, float]]:
    if not irr.enabled:
        return []
    wp = 2 * np.pi / irr.tp_s
    edges = np.linspace(0.4 * wp, 3.0 * wp, 33)
    w = (edges[:-1] + edges[1:]) / 2
    a = np.sqrt(2 * jonswap(w, irr.hs_m, irr.tp_s, irr.gamma) * np.diff(edges))
    out = []
    for dof, lever in levers.items():
        gain = irr.response.get(dof, 0.0) * (np.deg2rad(1.0) * lever if dof != "heave" else 1.0)
        out += [(float(gain * ak), float(2 * np.pi / wk)) for ak, wk in zip(a, w) if gain * ak > 0]
    return out
