"""Pick the frame source for a scenario (ship-to-ship or hook) or a recording folder."""

from __future__ import annotations


from boomtip.data.frames import FrameSource
from boomtip.data.scenario import Scenario


def simulation_for(scenario: Scenario) -> FrameSource:
    if scenario.world.hook.enabled:
        from boomtip.data.sim.hook_world import HookSimulation

        return HookSimulation(scenario)
    from boomtip.data.sim.simulator import Simulation

    return Simulation(scenario)
