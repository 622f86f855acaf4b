"""The simulated frame source for a run: the ship-to-ship scene, or the hook scene."""

from __future__ import annotations

from boomtip.data.frames import FrameSource
from boomtip.data.sim.run import SimulatedRun


def simulation_for(run: SimulatedRun) -> FrameSource:
    if run.world.hook.enabled:
        from boomtip.data.sim.hook_world import HookSimulation

        return HookSimulation(run)
    from boomtip.data.sim.simulator import Simulation

    return Simulation(run)
