"""What the simulator is asked to make (data/sim/run.py): the run's validators (a name is
stripped, a duration is finite, positive and at most a day, the hook scene has a LiDAR and no
radar) and the processing settings a run passes through to its recording: none for a bare
SimulatedRun, exactly the keys a scenario's `processing` section set."""

from __future__ import annotations

import math

import pytest
from pydantic import ValidationError

from boomtip.data.sim.run import MAX_DURATION_S, SimulatedRun
from boomtip.tools.config.scenario import Scenario, load_scenario

HOOK = {"hook": {"enabled": True}}
NO_RADAR = {"radar": {"enabled": False}}


def _errors(**kw) -> list[tuple[tuple, str]]:
    with pytest.raises(ValidationError) as exc:
        SimulatedRun(**kw)
    return [(e["loc"], e["msg"]) for e in exc.value.errors()]


def test_defaults():
    run = SimulatedRun()
    assert (run.name, run.seed, run.duration_s) == ("custom", 0, 60.0)
    assert not run.world.hook.enabled and run.installation.lidar.enabled and run.installation.radar.enabled


@pytest.mark.parametrize("given, kept", [("  sts run \t", "sts run"), ("a", "a"), ("   ", "custom"), ("", "custom")])
def test_the_name_is_stripped_and_a_blank_one_is_custom(given, kept):
    assert SimulatedRun(name=given).name == kept


def test_the_name_is_stripped_on_assignment_too():
    run = SimulatedRun()
    run.name = "  renamed "
    assert run.name == "renamed"


@pytest.mark.parametrize("bad", [math.inf, -math.inf, math.nan, "nan", "1e400"])
def test_a_non_finite_duration_is_refused(bad):
    (loc, _), = _errors(duration_s=bad)
    assert loc == ("duration_s",)


@pytest.mark.parametrize("bad", [0.0, -1.0, MAX_DURATION_S * (1 + 1e-12)])
def test_a_duration_outside_zero_to_a_day_is_refused(bad):
    (loc, _), = _errors(duration_s=bad)
    assert loc == ("duration_s",)


def test_the_duration_bounds_themselves():
    assert MAX_DURATION_S == 86400.0
    assert SimulatedRun(duration_s=MAX_DURATION_S).duration_s == MAX_DURATION_S
    assert SimulatedRun(duration_s=1e-9).duration_s == 1e-9
    run = SimulatedRun()
    with pytest.raises(ValidationError, match="duration_s"):
        run.duration_s = math.nan  # validated on assignment as well
    assert run.duration_s == 60.0


def test_seed_bounds():
    assert SimulatedRun(seed=2**31 - 1).seed == 2**31 - 1
    for bad in (-1, 2**31):
        assert _errors(seed=bad)[0][0] == ("seed",)


def test_the_hook_scene_runs_with_a_lidar_and_no_radar():
    run = SimulatedRun(world=HOOK, installation=NO_RADAR)
    assert run.world.hook.enabled and run.installation.lidar.enabled and not run.installation.radar.enabled


def test_the_hook_scene_refuses_a_radar():
    assert _errors(world=HOOK) == [
        ((), "Value error, the hook chain uses no radar: set installation.radar.enabled: false")]


def test_the_hook_scene_needs_a_lidar():
    # the LiDAR is checked first: that is the error a user without either sees
    for inst in ({"lidar": {"enabled": False}, **NO_RADAR}, {"lidar": {"enabled": False}}):
        assert _errors(world=HOOK, installation=inst) == [
            ((), "Value error, world.hook.enabled needs installation.lidar.enabled")]


def test_without_the_hook_scene_any_sensor_set_is_accepted():
    assert not SimulatedRun(installation={"lidar": {"enabled": False}}).installation.lidar.enabled
    assert not SimulatedRun(installation=NO_RADAR).installation.radar.enabled


def test_assigning_a_radar_installation_to_a_hook_run_is_refused():
    run = SimulatedRun(world=HOOK, installation=NO_RADAR)
    with pytest.raises(ValidationError, match="uses no radar"):
        run.installation = {"radar": {"enabled": True}}


def test_unknown_keys_are_refused():
    assert _errors(nmae="x")[0] == (("nmae",), "Extra inputs are not permitted")


# ---------------------------------------------------------------------------------------
# Processing settings passed through to the recording


def test_a_bare_run_asks_for_no_processing_settings():
    assert SimulatedRun().processing_settings() == {}
    assert SimulatedRun(name="x", seed=3, world=HOOK, installation=NO_RADAR).processing_settings() == {}


def test_a_scenario_passes_the_processing_keys_it_set_and_only_those():
    assert Scenario().processing_settings() == {}
    s = Scenario(processing={"seed": 3, "chain": None, "hook": {"detector": {"max_planes": 2}}})
    # a key set to its default is still set; nothing the scenario left alone appears
    assert s.processing_settings() == {"seed": 3, "chain": None, "hook": {"detector": {"max_planes": 2}}}


def test_built_in_scenarios_pass_their_processing_sections():
    assert load_scenario("sts-empty").processing_settings() == {}
    assert load_scenario("hook-1").processing_settings() == {"chain": "hook"}
    assert load_scenario("sts-empty", ["processing.seed=4"]).processing_settings() == {"seed": 4}
