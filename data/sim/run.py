"""What the simulator is asked to make: a world, the installation it deviates from, a seed and a
duration. A scenario (tools.config.scenario) adds the processing settings the run asks for; the
simulator passes them through to its recording untouched and never reads them."""

from __future__ import annotations

import math

from pydantic import Field, field_validator, model_validator

from boomtip.data.installation import Installation, StrictModel
from boomtip.data.sim.randomize import randomized_world
from boomtip.data.sim.world import World

__all__ = ["SimulatedRun"]

MAX_DURATION_S = 86400.0  # a day: longer runs are a typo, not a study


class SimulatedRun(StrictModel):
    """A simulated run: the world (simulation only) and the installation (what processing may know)."""

    name: str = "custom"
    description: str = ""
    seed: int = Field(0, ge=0, le=2**31 - 1)
    duration_s: float = Field(60.0, gt=0, le=MAX_DURATION_S)
    world: World = World()
    installation: Installation = Installation()

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        return v.strip() or "custom"

    @field_validator("duration_s")
    @classmethod
    def _finite_duration(cls, v: float) -> float:
        if not math.isfinite(v):
            raise ValueError("must be finite")
        return v

    @model_validator(mode="after")
    def _hook_needs_a_lidar(self) -> "SimulatedRun":
        if self.world.hook.enabled and not self.installation.lidar.enabled:
            raise ValueError("world.hook.enabled needs installation.lidar.enabled")
        if self.world.hook.enabled and self.installation.radar.enabled:
            raise ValueError("the hook chain uses no radar: set installation.radar.enabled: false")
        if self.world.lift.enabled:
            if self.world.hook.enabled:
                raise ValueError("world.lift.enabled is a scene of its own (the hook scene's crane over the feeder): "
                                 "set world.hook.enabled: false")
            if not self.installation.lidar.enabled:
                raise ValueError("world.lift.enabled needs installation.lidar.enabled")
        return self

    @model_validator(mode="after")
    def _draw_the_world(self) -> "SimulatedRun":
        """A randomized world's mismatch drawn once, here, so every consumer of the run (the
        scene, the simulator, the truth) sees the same world. Drawing again gives the same
        draws (the seed's), so re-validating a run changes nothing."""
        world = randomized_world(self.world, self.installation, self.seed)
        if world is not self.world:
            object.__setattr__(self, "world", world)  # not an assignment: that would validate this model again
        return self

    def processing_settings(self) -> dict:
        """The processing settings the run asks for, as raw keys for the recording's meta.json:
        none here (a scenario has them)."""
        return {}
