"""A run's processing settings from the command line (--processing FILE, --set processing.KEY=V),
and settings.json: the record a run is repeated from."""

from __future__ import annotations

import json
import re
import subprocess

import pytest
from typer.testing import CliRunner

from boomtip.data.io.installation_file import load_installation
from boomtip.data.io.recording import RecordingError
from boomtip.tools.cli import app
from boomtip.tools.config.scenario import ScenarioError
from boomtip.data.keys import settings_dump
from boomtip.tools.config.processing import Processing
from boomtip.tools.config.settings import boomtip_commit, processing_settings

runner = CliRunner()


def test_the_file_then_set_win_over_the_sources_own(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("processing:\n  seed: 5\n  feeder: {enabled: false}\n")
    p = processing_settings({"seed": 2, "heave": {"max_deck_age_s": 0.3}}, f, ["processing.seed=7", "heave.deck_prior_tol_m=0.4"])
    assert p.seed == 7 and not p.feeder.enabled and p.heave.max_deck_age_s == 0.3 and p.heave.deck_prior_tol_m == 0.4
    f.write_text("feeder: {enabled: false}\n")  # without its section
    assert not processing_settings({}, f).feeder.enabled


@pytest.mark.parametrize("over, message", [(["processing.sead=1"], "unknown scenario key 'processing.sead'"),
                                           (["lidar.rate_hz=5"], "is not a processing setting"),
                                           (["processing.seed=-1"], "processing.seed"),
                                           (["processing.seed"], "expected dotted.key=value")])
def test_a_bad_setting_is_refused_with_its_key(over, message):
    with pytest.raises(ScenarioError, match=message):
        processing_settings({}, None, over)


def test_a_bad_processing_file_is_refused_with_the_file(tmp_path):
    f = tmp_path / "p.yaml"
    for text, message in (("", "empty"), ("- 1\n", "mapping"), ("lidar: {rate_hz: 5}\n", "unknown key 'processing.lidar'"),
                          ("heave: [\n", "not a YAML"), ("seed: -3\n", "processing.seed")):
        f.write_text(text)
        with pytest.raises(ScenarioError, match=re.escape(str(f)) + ".*" + message):
            processing_settings({}, f)
    with pytest.raises(ScenarioError, match="no such processing file"):
        processing_settings({}, tmp_path / "missing.yaml")


def test_an_installation_file_is_not_empty_and_holds_no_processing(tmp_path):
    f = tmp_path / "rig.yaml"
    f.write_text("")
    with pytest.raises(RecordingError, match="empty; expected installation keys"):
        load_installation(f)
    f.write_text("attitude: level\nprocessing: {seed: 1}\n")
    with pytest.raises(RecordingError, match="--processing FILE.yaml"):
        load_installation(f)


def test_a_setting_without_limit_survives_the_json_record():
    p = processing_settings({}, None, ["processing.heave.deck_lidar.preprocess.max_range_m=inf"])
    record = json.loads(json.dumps(settings_dump(p, exclude_unset=True), allow_nan=False))
    assert record == {"heave": {"deck_lidar": {"preprocess": {"max_range_m": "inf"}}}}
    again = Processing.model_validate(record)
    assert again == p and again.model_fields_set == p.model_fields_set


def test_only_what_was_set_is_set_after_the_round_trip():
    """A setting left unset follows the installation (the markers' height, the Doppler band):
    the record must not mark every default as given."""
    p = processing_settings({}, None, ["processing.seed=4"])
    again = Processing.model_validate(settings_dump(p, exclude_unset=True))
    assert settings_dump(again, exclude_unset=True) == {"seed": 4}
    assert "reflectors" not in again.heave.model_fields_set


def test_the_commit_is_only_boomtips_own(tmp_path):
    """A checkout's commit, marked when it has local changes; none for code inside another
    repository (a virtualenv's site-packages in someone's project)."""
    repo = tmp_path / "repo"
    (repo / "site-packages" / "boomtip").mkdir(parents=True)
    (repo / "a.txt").write_text("a")
    git = ["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t"]
    for args in (["init", "-q"], ["add", "a.txt"], ["commit", "-q", "-m", "a"]):
        subprocess.run([*git, *args], check=True, capture_output=True)
    head = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    assert boomtip_commit(repo) == head
    (repo / "a.txt").write_text("b")
    assert boomtip_commit(repo) == head + "+local changes"
    assert boomtip_commit(repo / "site-packages") is None
    assert boomtip_commit(tmp_path) is None


def test_the_version_is_printed():
    r = runner.invoke(app, ["--version"])
    assert r.exit_code == 0 and r.output.startswith("boomtip ")


@pytest.mark.slow
def test_a_run_is_repeated_from_its_settings_json(tmp_path):
    """`process --set` applied, recorded in settings.json, and the same run again from that file
    alone (as --installation and --processing) writes the same estimates."""
    rec = tmp_path / "rec"
    assert runner.invoke(app, ["simulate", "-s", "sts-empty", "--duration", "3", "--out", str(rec)]).exit_code == 0
    a = tmp_path / "a"
    r = runner.invoke(app, ["process", str(rec), "--out", str(a), "--set", "processing.feeder.enabled=false",
                            "--set", "processing.seed=3"])
    assert r.exit_code == 0, r.output
    settings = json.loads((a / "settings.json").read_text())
    assert settings["processing"]["seed"] == 3 and settings["processing"]["feeder"]["enabled"] is False
    assert settings["command"]["name"] == "process" and settings["input"]["bytes"] > 0
    assert settings["command"]["params"]["set"] == ["processing.feeder.enabled=false", "processing.seed=3"]
    assert settings["boomtip"]["version"] and settings["source"]["t_start_s"] == 0.0
    assert not (a / "feeder_estimates.csv").exists()
    b = tmp_path / "b"
    r = runner.invoke(app, ["process", str(rec), "--out", str(b), "--installation", str(a / "settings.json"),
                            "--processing", str(a / "settings.json")])
    assert r.exit_code == 0, r.output
    assert (a / "estimates.csv").read_bytes() == (b / "estimates.csv").read_bytes()
