"""The simulated frame source for a run: the ship-to-ship scene, the hook scene or the lift."""

from __future__ import annotations

from boomtip.data.frames import FrameSource
from boomtip.data.sim.run import SimulatedRun


def simulation_for(run: SimulatedRun) -> FrameSource:
    if run.world.lift.enabled:
        from boomtip.data.sim.lift_world import LiftSimulation

        return LiftSimulation(run)
    if run.world.hook.enabled:
        from boomtip.data.sim.hook_world import HookSimulation

        return HookSimulation(run)
    from boomtip.data.sim.simulator import Simulation

    return Simulation(run)
