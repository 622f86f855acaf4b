"""The crane programmes of document 002 section 5.2 (scenarios hook-1 .. hook-4): joint
motions, vessel motion and duration for :func:`~boomtip.data.sim.crane_truth.simulate_crane`.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

from boomtip.data.crane_model import DEG, CraneParams
from boomtip.data.sim.crane_joints import CoordinatedLinePath, CraneJointProfiles, JointLimits
from boomtip.data.sim.vessel_waves import StaticVessel, VesselWaves

__all__ = ["ScenarioSpec", "scenario_hook_1", "scenario_hook_2", "scenario_hook_3", "scenario_hook_4",
           "HOOK_SCENARIOS"]


class ScenarioSpec(NamedTuple):
    joints: object
    vessel: object
    duration_s: float


DECK_HEIGHT_M = 10.0  # deck level in the vessel frame (crane base height c_z); not given in 002


def _tip_height(params: CraneParams, mu: float) -> float:
    return params.c[2] + params.h + params.L * math.sin(mu)


def scenario_hook_1(params: CraneParams | None = None, limits: JointLimits | None = None) -> ScenarioSpec:
    """Nominal ship-to-ship transfer (002 5.2.1), static vessel, 700 s.

    Hook at rest at deck level (slew 90 deg, luff 30 deg, rope 115 m); hoist to 60 m
    (t = 10 s), simultaneous slew to 0 deg and luff to 60 deg (t = 80 s; slewing finishes
    first), then lower to 175 m (t = 250 s) and hang until 700 s.
    """
    P = params or CraneParams()
    mu0 = 30 * DEG
    l0 = _tip_height(P, mu0) - DECK_HEIGHT_M
    joints = CraneJointProfiles.from_moves(
        90 * DEG, mu0, l0,
        slew_moves=[(100.0, 0.0)], luff_moves=[(100.0, 60 * DEG)],
        hoist_moves=[(10.0, 40.0), (250.0, 175.0)], limits=limits,
    )
    return ScenarioSpec(joints, StaticVessel(), 700.0)


def scenario_hook_2(params: CraneParams | None = None, limits: JointLimits | None = None) -> ScenarioSpec:
    """Scenario 1's crane motion with pitch and roll of 1 deg, 8 s period (002 5.2.2).

    The document gives no phases: pitch phase 0 deg, roll phase 90 deg (ours).
    """
    s1 = scenario_hook_1(params, limits)
    return ScenarioSpec(s1.joints, VesselWaves.regular(1.0, 8.0), 700.0)


def scenario_hook_3(params: CraneParams | None = None) -> ScenarioSpec:
    """Coordinated straight-line path (002 5.2.3), 650 s, waves 1 deg / 8 s.

    The hanging hook moves at 50 m above the centre of rotation along the vessel's y axis
    at x = 120 m, from y = -60 m (starboard) to y = +60 m (port), with a minimum-jerk
    time law from t = 10 s to t = 640 s (coordinates ours; the document gives a figure).
    """
    P = params or CraneParams()
    path = CoordinatedLinePath(P, (120.0, -60.0, 50.0), (120.0, 60.0, 50.0), 10.0, 640.0)
    return ScenarioSpec(path, VesselWaves.regular(1.0, 8.0), 650.0)


def scenario_hook_4(params: CraneParams | None = None, limits: JointLimits | None = None) -> ScenarioSpec:
    """Stress test (002 5.2.4), 100 s: from rope 200 m, slew 0, luff 15 deg, all drives at
    full speed (from t = 5 s) to slew 110 deg, luff 20 deg, rope 180 m; waves 2 deg / 8 s."""
    joints = CraneJointProfiles.from_moves(
        0.0, 15 * DEG, 200.0,
        slew_moves=[(5.0, 110 * DEG)], luff_moves=[(5.0, 20 * DEG)], hoist_moves=[(5.0, 180.0)],
        limits=limits,
    )
    return ScenarioSpec(joints, VesselWaves.regular(2.0, 8.0), 100.0)


HOOK_SCENARIOS: dict[str, Callable[..., ScenarioSpec]] = {
    "hook-1": scenario_hook_1,
    "hook-2": scenario_hook_2,
    "hook-3": scenario_hook_3,
    "hook-4": scenario_hook_4,
}
