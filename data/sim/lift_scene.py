"""The lift's world settings (`world.lift`): the load on the hook, its slings and the programme
that lowers it onto the feeder's deck (data/sim/lift_programme.py)."""

from __future__ import annotations

from pydantic import Field, model_validator

from boomtip.data.installation import StrictModel, require_finite
from boomtip.data.loads import LoadKind, load_mass, load_size


class LiftProgram(StrictModel):
    """The crane's moves: slew and luff the hanging load in over the target, lower it through
    the last metres to a pause, wait, and set it down; the hoist then pays out a little slack."""

    target_deck_m: tuple[float, float] = Field((0.0, 5.0), description="the set-down spot on the feeder's deck, "
                                                "feeder body frame x, y (m)")
    approach_slew_deg: float = Field(2.0, ge=-30, le=30, description="the boom starts this far in slew from the target")
    approach_luff_deg: float = Field(-0.5, ge=-10, le=10, description="and this far in luff")
    start_clearance_m: float = Field(12.0, gt=0, le=100, description="the load's underside above the calm deck at the start")
    pause_clearance_m: float = Field(2.0, ge=0, le=50, description="where the lowering pauses")
    lower_start_s: float = Field(16.0, ge=0, description="when the lowering starts")
    lower_speed_mps: float = Field(0.4, gt=0, le=1.0)
    wait_s: float = Field(8.0, ge=0, description="the pause above the deck")
    land_speed_mps: float = Field(0.2, gt=0, le=1.0)
    slack_m: float = Field(2.0, ge=0, le=10, description="rope paid out below the calm deck: the load lands whatever "
                           "the deck's heave")

    @model_validator(mode="after")
    def _order(self) -> "LiftProgram":
        require_finite(self.target_deck_m, "world.lift.program.target_deck_m")
        if self.pause_clearance_m >= self.start_clearance_m:
            raise ValueError("world.lift.program.pause_clearance_m must be below start_clearance_m")
        return self


class LiftScene(StrictModel):
    """The lift (the crane working over the feeder): enabled, the scene is the hook scene's crane
    vessel, boom, rope and block with a load on slings, beside the moving feeder, both ships in
    their waves."""

    enabled: bool = False
    load: LoadKind = Field("container20", description="container20, container40, blade_section or box")
    load_size_m: tuple[float, float, float] | None = Field(None, description="length, width, height (m); null: the "
                                                            "kind's standard size")
    load_mass_kg: float | None = Field(None, gt=0, description="null: the kind's typical mass")
    sling_height_m: float = Field(3.0, ge=0, le=20, description="the hook above the load's top")
    program: LiftProgram = LiftProgram()

    def size(self) -> tuple[float, float, float]:
        return load_size(self.load, self.load_size_m, "world.lift.load_size_m")

    def mass_kg(self) -> float:
        return load_mass(self.load, self.load_mass_kg)

    @model_validator(mode="after")
    def _has_a_size(self) -> "LiftScene":
        self.size()
        return self
