"""Scenario loading, required keys, `--set` overrides and error messages (data/scenario.py)."""

from __future__ import annotations

from functools import reduce

import pytest
import yaml

from boomtip.data.sim.world import DOFS
from boomtip.tools.config.scenario import (
    Scenario,
    ScenarioError,
    available_scenarios,
    load_scenario,
    parse_override,
    resolve_key,
    scenario_to_yaml,
    valid_keys,
)

BUILTINS = ("sts-empty", "sts-loaded")

# Full keys (as valid_keys() lists them); each is also settable by its short form, without
# the section (`world.feeder.cargo` -> `feeder.cargo`), which resolve_key maps back.
REQUIRED_KEYS = (
    ["seed", "duration_s", "world.feeder.cargo"]
    + [f"world.{ship}.motion.{dof}.{leaf}" for ship in ("crane", "feeder") for dof in DOFS
       for leaf in ("amplitude", "period_s", "phase_deg")]
    + [f"installation.{k}" for k in ("lidar.rate_hz", "lidar.range_noise_m", "lidar.latency_s", "radar.rate_hz",
                                      "radar.latency_s", "mru.rate_hz")]
)

# A value for each required key that differs from both built-ins, to prove the key is wired.
PROBE_VALUES = {
    "seed": 123,
    "duration_s": 7.5,
    "feeder.cargo": True,
    "amplitude": 0.375,
    "period_s": 7.25,
    "phase_deg": 33.0,
    "lidar.rate_hz": 12.5,
    "lidar.range_noise_m": 0.031,
    "lidar.latency_s": 0.042,
    "radar.rate_hz": 16.0,
    "radar.latency_s": 0.017,
    "mru.rate_hz": 150.0,
}


def short(key: str) -> str:
    """The key without its section: `installation.lidar.rate_hz` -> `lidar.rate_hz`."""
    head, _, rest = key.partition(".")
    return rest if head in ("world", "installation", "processing") else key


def get(obj, dotted: str):
    return reduce(getattr, dotted.split("."), obj)


def test_required_dofs_are_the_six_ship_dofs():
    assert tuple(DOFS) == ("surge", "sway", "heave", "roll", "pitch", "yaw")


@pytest.mark.parametrize("name", BUILTINS)
def test_builtins_listed_and_load(name):
    assert name in available_scenarios()
    s = load_scenario(name)
    assert isinstance(s, Scenario)
    assert s.name == name


@pytest.mark.parametrize("key", REQUIRED_KEYS)
def test_required_key_exists_and_is_settable(key):
    assert key in valid_keys(), f"{key} missing from valid_keys()"
    assert resolve_key(short(key)) == key
    for name in BUILTINS:
        get(load_scenario(name), key)  # present in the loaded model
    value = PROBE_VALUES.get(short(key), PROBE_VALUES.get(key.rsplit(".", 1)[-1]))
    text = "true" if value is True else repr(value)
    for written in {key, short(key)}:  # in full and without the section
        s = load_scenario("sts-empty", [f"{written}={text}"])
        assert get(s, key) == value


def test_override_only_changes_its_key():
    base = load_scenario("sts-empty").model_dump()
    s = load_scenario("sts-empty", ["feeder.motion.roll.amplitude=3.5"]).model_dump()
    assert s["world"]["feeder"]["motion"]["roll"]["amplitude"] == 3.5
    s["world"]["feeder"]["motion"]["roll"]["amplitude"] = base["world"]["feeder"]["motion"]["roll"]["amplitude"]
    assert s == base


def test_builtin_sensor_profiles():
    empty, loaded = load_scenario("sts-empty"), load_scenario("sts-loaded")
    # sts-empty is the ideal-sensor verification case.
    assert empty.installation.lidar.range_noise_m == 0 and empty.installation.lidar.range_resolution_m == 0
    assert empty.world.lidar.dropout_probability == 0 and empty.world.lidar.intensity_noise == 0
    assert empty.installation.radar.range_noise_m == 0 and empty.installation.radar.range_rate_noise_mps == 0
    assert empty.installation.radar.detection_probability == 1 and empty.installation.radar.false_alarms_per_scan == 0
    assert empty.world.feeder.cargo is False and loaded.world.feeder.cargo is True
    assert loaded.installation.lidar.range_noise_m > 0


# ---------------------------------------------------------------------------------------
# Errors


@pytest.mark.parametrize(
    "bad, nearest",
    [
        ("lidar.rate_hzz=5", "lidar.rate_hz"),
        ("feedr.cargo=true", "feeder.cargo"),
        ("lidar.range_noise=0.1", "lidar.range_noise_m"),
        ("crane.motion.heave.amplitud=1", "crane.motion.heave.amplitude"),
    ],
)
def test_unknown_set_key_lists_nearest_keys(bad, nearest):
    with pytest.raises(ScenarioError) as exc:
        load_scenario("sts-empty", [bad])
    msg = str(exc.value)
    assert bad.split("=")[0] in msg
    assert "nearest" in msg and nearest in msg


def test_set_below_a_scalar_is_refused():
    with pytest.raises(ScenarioError, match="lidar.rate_hz"):
        load_scenario("sts-empty", ["lidar.rate_hz.sub=1"])


def test_set_without_equals_is_refused():
    with pytest.raises(ScenarioError, match="dotted.key=value"):
        load_scenario("sts-empty", ["lidar.rate_hz"])


@pytest.mark.parametrize("key", ["lidar.rate_hz", "radar.rate_hz", "mru.rate_hz"])
@pytest.mark.parametrize("value", ["-5", "0"])
def test_non_positive_rate_names_the_key(key, value):
    with pytest.raises(ScenarioError) as exc:
        load_scenario("sts-empty", [f"{key}={value}"])
    assert f"'installation.{key}'" in str(exc.value)  # the full key the short one resolved to


@pytest.mark.parametrize("key", ["lidar.fov_h_deg", "radar.fov_az_deg"])
def test_fov_over_360_names_the_key(key):
    with pytest.raises(ScenarioError) as exc:
        load_scenario("sts-empty", [f"{key}=400"])
    assert f"'installation.{key}'" in str(exc.value)
    load_scenario("sts-empty", [f"{key}=360"])  # the bound itself is allowed


def test_negative_noise_and_bad_probability_name_the_key():
    for text, key in [("lidar.range_noise_m=-0.1", "lidar.range_noise_m"),
                      ("lidar.dropout_probability=1.0", "lidar.dropout_probability"),
                      ("radar.detection_probability=1.5", "radar.detection_probability"),
                      ("crane.motion.roll.period_s=0", "crane.motion.roll.period_s")]:
        with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
            load_scenario("sts-empty", [text])


def test_min_range_above_max_range_is_an_error():
    with pytest.raises(ScenarioError, match="min_range_m"):
        load_scenario("sts-empty", ["lidar.min_range_m=400"])


def test_wrong_type_names_the_key_and_the_value():
    with pytest.raises(ScenarioError) as exc:
        load_scenario("sts-empty", ["lidar.rate_hz=fast"])
    assert "'installation.lidar.rate_hz'" in str(exc.value) and "fast" in str(exc.value)


def test_unknown_scenario_name_errors():
    with pytest.raises(ScenarioError) as exc:
        load_scenario("sts-nonexistent")
    msg = str(exc.value)
    assert "sts-nonexistent" in msg
    assert all(b in msg for b in BUILTINS)  # lists what exists


# ---------------------------------------------------------------------------------------
# Files


def test_yaml_file_path_works(tmp_path):
    path = tmp_path / "my-case.yaml"
    path.write_text(yaml.safe_dump({
        "seed": 5,
        "duration_s": 2.0,
        "feeder": {"cargo": True, "motion": {"heave": {"amplitude": 1.25, "period_s": 8.0, "phase_deg": 10}}},
        "lidar": {"rate_hz": 5, "dropout_probability": 0.1},  # the layout before sections: split leaf by leaf
    }))
    for arg in (path, str(path)):
        s = load_scenario(arg)
        assert s.name == "my-case"  # defaults to the file stem
        assert s.seed == 5 and s.duration_s == 2.0 and s.world.feeder.cargo is True
        assert s.world.feeder.motion.heave.amplitude == 1.25 and s.world.feeder.motion.heave.period_s == 8.0
        assert s.installation.lidar.rate_hz == 5.0 and s.world.lidar.dropout_probability == 0.1
        assert s.installation.radar.rate_hz == Scenario().installation.radar.rate_hz  # unspecified keys take defaults
    s = load_scenario(path, ["lidar.rate_hz=20", "name=renamed"])
    assert s.installation.lidar.rate_hz == 20.0 and s.name == "renamed"


def test_yaml_round_trip(tmp_path):
    s = load_scenario("sts-loaded", ["feeder.irregular.enabled=true"])
    path = tmp_path / "dump.yaml"
    path.write_text(scenario_to_yaml(s))
    assert load_scenario(path) == s


def test_unknown_key_in_yaml_file_names_it_and_the_nearest(tmp_path):
    path = tmp_path / "typo.yaml"
    path.write_text("lidar:\n  rate_hzz: 10\n")
    with pytest.raises(ScenarioError) as exc:
        load_scenario(path)
    msg = str(exc.value)
    assert str(path) in msg and "lidar.rate_hzz" in msg and "lidar.rate_hz" in msg


def test_invalid_yaml_file_errors(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("lidar: [unclosed\n")
    with pytest.raises(ScenarioError, match="bad.yaml"):
        load_scenario(bad)
    notmap = tmp_path / "list.yaml"
    notmap.write_text("- 1\n- 2\n")
    with pytest.raises(ScenarioError, match="mapping"):
        load_scenario(notmap)


# ---------------------------------------------------------------------------------------
# Override value parsing


@pytest.mark.parametrize(
    "text, key, value",
    [
        ("lidar.rate_hz=20", "lidar.rate_hz", 20),
        ("lidar.rate_hz=2.5e+1", "lidar.rate_hz", 25.0),
        ("feeder.cargo=true", "feeder.cargo", True),
        ("feeder.cargo=false", "feeder.cargo", False),
        ("crane.geometry.boom_tip_m=[1, 2.5, 3]", "crane.geometry.boom_tip_m", [1, 2.5, 3]),
        ("description=a b = c", "description", "a b = c"),
        (" lidar.pattern = spinning", "lidar.pattern", "spinning"),
    ],
)
def test_parse_override_values_are_yaml(text, key, value):
    assert parse_override(text) == (key, value)


def test_overrides_apply_yaml_values():
    s = load_scenario("sts-empty", [
        "crane.geometry.boom_tip_m=[12, -38.5, 50]",
        "feeder.cargo=true",
        "lidar.enabled=false",
        "lidar.motion_during_sweep=true",
        "feeder.irregular.response={heave: 0.7}",
        "feeder.irregular.response.roll=0.2",
    ])
    assert s.installation.crane.geometry.boom_tip_m == (12.0, -38.5, 50.0)
    assert s.world.feeder.cargo is True and s.installation.lidar.enabled is False and s.world.lidar.motion_during_sweep is True
    assert s.world.feeder.irregular.response == {"heave": 0.7, "roll": 0.2}


def test_exponent_without_sign_still_loads_as_a_number():
    # PyYAML (YAML 1.1) reads "2.5e1" as a string; the typed model must still coerce it.
    assert load_scenario("sts-empty", ["lidar.rate_hz=2.5e1"]).installation.lidar.rate_hz == 25.0
    assert load_scenario("sts-empty", ["lidar.range_noise_m=2e-2"]).installation.lidar.range_noise_m == 0.02


def test_short_key_in_two_sections_is_refused_with_both():
    with pytest.raises(ScenarioError) as exc:
        load_scenario("sts-empty", ["lidar={}"])
    assert "more than one section" in str(exc.value)
    assert "world.lidar" in str(exc.value) and "installation.lidar" in str(exc.value)


def test_empty_mismatch_resets_it_to_none():
    s = load_scenario("sts-loaded")
    assert s.world.mismatch != type(s.world.mismatch)()  # the built-in carries one
    for text in ("mismatch={}", "world.mismatch={}"):
        assert load_scenario("sts-loaded", [text]).world.mismatch == type(s.world.mismatch)()


def test_later_override_wins():
    s = load_scenario("sts-empty", ["lidar.rate_hz=5", "lidar.rate_hz=15"])
    assert s.installation.lidar.rate_hz == 15.0


def test_list_of_wrong_length_is_an_error():
    with pytest.raises(ScenarioError, match="boom_tip_m"):
        load_scenario("sts-empty", ["crane.geometry.boom_tip_m=[1, 2]"])
