"""Pick the frame source for a scenario (ship-to-ship or hook) or a recording folder."""

from __future__ import annotations

from pathlib import Path

from data.frames import FrameSource
from data.scenario import Scenario


def simulation_for(scenario: Scenario) -> FrameSource:
    if scenario.hook.enabled:
        from data.hook_world import HookSimulation

        return HookSimulation(scenario)
    from data.simulator import Simulation

    return Simulation(scenario)


def open_recording(path: str | Path) -> FrameSource:
    from data.recording import Recording

    return Recording(path)
