"""The installation model refuses what no rig has: non-finite quantities, mount angles beyond a
turn; the world model likewise (a NaN amplitude would run a whole simulation on NaN)."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from boomtip.data.installation import Installation, Mount
from boomtip.tools.config.scenario import ScenarioError, load_scenario


@pytest.mark.parametrize("rpy, ok", [((90.0, 90.0, 0.0), True), ((-360.0, 360.0, 0.0), True), ((900.0, 0.0, 0.0), False),
                                     ((0.0, -361.0, 0.0), False)])
def test_mount_angles_are_degrees_within_a_turn(rpy, ok):
    if ok:
        assert Mount(rpy_deg=rpy).rpy_deg == rpy
    else:
        with pytest.raises(ValidationError, match="within \\+-360"):
            Mount(rpy_deg=rpy)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), "nan", "-inf"])
def test_no_installation_quantity_is_infinite_or_nan(value):
    with pytest.raises(ValidationError, match="finite number"):
        Installation.model_validate({"lidar": {"rate_hz": value}})


@pytest.mark.parametrize("key", ["world.crane.motion.heave.amplitude", "duration_s"])
def test_a_world_quantity_that_is_nan_is_refused_with_its_key(key):
    with pytest.raises(ScenarioError, match=f"key '{key}': Input should be a finite number"):
        load_scenario("sts-loaded", [f"{key}=nan"])


def test_a_beam_wider_than_the_scans_spacing_is_refused_with_its_key():
    """The footprint model casts only the rays beside a depth edge: a footprint narrower than
    the spacing between rays (0.5 deg, 8.7 mrad, on the default grid; an OS1-128's 6.1 mrad)."""
    assert Installation.model_validate({"lidar": {"beam_divergence_mrad": 8.0}}).lidar.beam_divergence_mrad == 8.0
    with pytest.raises(ValidationError, match="beam_divergence_mrad"):
        Installation.model_validate({"lidar": {"beam_divergence_mrad": 9.0}})
    with pytest.raises(ScenarioError, match="beam_divergence_mrad"):
        load_scenario("sts-loaded", ["lidar.pattern=spinning", "lidar.channels=128", "lidar.beam_divergence_mrad=6.5"])


def test_a_load_model_without_dimensions_is_refused_naming_the_key():
    with pytest.raises(ValidationError, match=r"installation\.lift\.load_model\.size_m"):
        Installation.model_validate({"lift": {"load_model": {"kind": "box"}}})
    with pytest.raises(ValidationError, match="three positive lengths"):
        Installation.model_validate({"lift": {"load_model": {"kind": "box", "size_m": [2.0, 0.0, 1.0]}}})


def test_a_load_models_size_and_mass_default_to_its_kinds():
    model = Installation.model_validate({"lift": {"load_model": {"kind": "container40"}}}).lift.load_model
    assert model.dimensions() == (12.192, 2.438, 2.591) and model.mass() == 28000.0
    assert Installation().lift.load_model is None  # not known unless the installation says
