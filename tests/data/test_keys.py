"""Dotted configuration keys (data/keys.py): every leaf key of a model, the nearest valid keys to
a misspelt one, and validation errors that name the file (or the `--set` that supplied the value),
the full dotted key and what was wrong."""

from __future__ import annotations

import pytest
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from boomtip.data.installation import Installation
from boomtip.data.keys import format_validation, leaf_keys, nearest_keys

NONE_CLOSE = "(none close; `boomtip scenarios --keys` lists all)"


class Sensor(BaseModel):
    model_config = ConfigDict(extra="forbid")
    rate_hz: float = Field(10.0, gt=0)
    noise_m: float = 0.0


class Rig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str = "rig"
    lidar: Sensor = Sensor()
    radar: Sensor = Sensor()
    tags: dict = {}
    offsets: list = [1.0, 2.0]


RIG_KEYS = ["name", "lidar.rate_hz", "lidar.noise_m", "radar.rate_hz", "radar.noise_m", "tags", "offsets"]


def _error(data) -> ValidationError:
    with pytest.raises(ValidationError) as exc:
        Rig.model_validate(data)
    return exc.value


# ---------------------------------------------------------------------------------------
# leaf_keys


def test_leaf_keys_are_the_dotted_leaves_in_field_order():
    # an empty dict and a list are leaves (a value is set there, not below)
    assert leaf_keys(Rig()) == RIG_KEYS
    assert leaf_keys(Rig(), "installation") == [f"installation.{k}" for k in RIG_KEYS]
    assert leaf_keys(Rig(), "installation.") == leaf_keys(Rig(), "installation")  # a trailing dot is not doubled


def test_leaf_keys_of_the_installation_name_leaves_only():
    keys = leaf_keys(Installation())
    assert {"lidar.rate_hz", "radar.rate_hz", "lidar.mount.xyz_m", "lidar.mount.rpy_deg"} <= set(keys)
    assert "lidar" not in keys and "lidar.mount" not in keys  # sections are not keys
    assert len(keys) == len(set(keys))


# ---------------------------------------------------------------------------------------
# nearest_keys


def test_nearest_keys_puts_the_closest_first():
    assert nearest_keys("lidar.rate_hzz", RIG_KEYS).split(", ")[0] == "lidar.rate_hz"
    assert nearest_keys("radar.noise", RIG_KEYS).split(", ")[0] == "radar.noise_m"


def test_nearest_keys_lists_at_most_five():
    keys = [f"sensor{i}.rate_hz" for i in range(9)]
    assert len(nearest_keys("sensor.rate_hz", keys).split(", ")) == 5


def test_nearest_keys_falls_back_on_the_same_last_component():
    keys = ["sensors.primary_lidar.noise_m", "sensors.primary_radar.noise_m", "a.b"]
    # too unlike either full key for difflib (ratio 16/38 < 0.5), but the leaf matches
    assert nearest_keys("q.noise_m", keys) == "sensors.primary_lidar.noise_m, sensors.primary_radar.noise_m"


def test_nearest_keys_says_when_nothing_is_close():
    assert nearest_keys("qqqqqq", RIG_KEYS) == NONE_CLOSE
    assert nearest_keys("lidar.rate_hz", []) == NONE_CLOSE


# ---------------------------------------------------------------------------------------
# format_validation


def test_each_error_is_one_line_naming_the_source_and_the_full_key():
    err = _error({"name": 5, "lidar": {"rate_hz": -1}})
    lines = format_validation(err, "rig.yaml", "installation.", keys=leaf_keys(Rig(), "installation")).splitlines()
    assert lines == [
        "rig.yaml: key 'installation.name': Input should be a valid string (got 5)",
        "rig.yaml: key 'installation.lidar.rate_hz': Input should be greater than 0 (got -1)",
    ]


def test_an_unknown_key_gets_the_nearest_valid_ones():
    err = _error({"lidar": {"rate_hzz": 3}})
    msg = format_validation(err, "rig.yaml", "installation.", keys=leaf_keys(Rig(), "installation"))
    head = "rig.yaml: unknown key 'installation.lidar.rate_hzz'; nearest valid keys: "
    assert msg.startswith(head) and "\n" not in msg
    assert msg[len(head):].split(", ")[0] == "installation.lidar.rate_hz"
    # without the list of keys there is nothing to suggest, and the message says where to look
    assert format_validation(err, "rig.yaml") == f"rig.yaml: unknown key 'lidar.rate_hzz'; nearest valid keys: {NONE_CLOSE}"


def test_a_container_value_is_not_echoed():
    err = _error({"lidar": [1, 2]})
    assert format_validation(err, "rig.yaml") == (
        "rig.yaml: key 'lidar': Input should be a valid dictionary or instance of Sensor")


def test_an_error_of_the_whole_document_is_the_root_key():
    assert format_validation(_error(5), "rig.yaml") == (
        "rig.yaml: key '<root>': Input should be a valid dictionary or instance of Rig (got 5)")


def test_a_value_from_set_names_the_set_not_the_file():
    err = _error({"name": "ok", "lidar": {"rate_hz": -1}, "radar": {"rate_hz": 0}})
    msg = format_validation(err, "rig.yaml", overridden={"lidar.rate_hz": "lidar.rate_hz=-1",
                                                          "radar": "radar={rate_hz: 0}"})
    assert msg.splitlines() == [
        "--set lidar.rate_hz=-1: key 'lidar.rate_hz': Input should be greater than 0 (got -1)",
        # a --set of a whole section supplied every key below it
        "--set radar={rate_hz: 0}: key 'radar.rate_hz': Input should be greater than 0 (got 0)",
    ]


def test_a_set_key_that_only_shares_a_prefix_is_not_blamed():
    err = _error({"lidar": {"rate_hz": -1}})
    # `lid` is not a parent of `lidar.rate_hz`: the file supplied the value
    msg = format_validation(err, "rig.yaml", overridden={"lid": "lid=1", "lidar.rate": "lidar.rate=2"})
    assert msg == "rig.yaml: key 'lidar.rate_hz': Input should be greater than 0 (got -1)"
