"""Fuzzing the other readers (hypothesis, fixed seed and budget): the CSV logs, meta.json,
installation files, scenario YAML and --set overrides raise only their own errors."""

from __future__ import annotations

import json
import shutil

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from boomtip.data.frames import MRU_COLUMNS
from boomtip.data.io.installation_file import load_installation
from boomtip.data.io.recording import Recording, RecordingError, read_csv, write_recording
from boomtip.tools.config.scenario import ScenarioError, load_scenario
from boomtip.data.sim.simulator import Simulation

FUZZ = settings(max_examples=150, derandomize=True, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
CELL = st.sampled_from(["0", "1.5", "-3", "nan", "inf", "1e300", "x", "", " ", "0.01", "1e-3", "2,3", "\xff"])
JSONISH = st.recursive(st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=True) | st.text(max_size=8),
                       lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=8), c, max_size=4), max_leaves=12)


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    root = tmp_path_factory.mktemp("fz") / "rec"
    write_recording(Simulation(load_scenario("sts-empty", ["duration_s=0.3"])), root)
    return root


@FUZZ
@given(st.lists(st.lists(CELL, min_size=1, max_size=8), max_size=6), st.booleans())
def test_csv_logs(tmp_path, rows, good_header):
    p = tmp_path / "mru.csv"
    header = ",".join(MRU_COLUMNS) if good_header else "t,roll"
    p.write_text(header + "\n" + "\n".join(",".join(r) for r in rows) + "\n", encoding="utf-8", errors="surrogateescape")
    try:
        read_csv(p, MRU_COLUMNS, bounds={"roll": 1.6})
    except RecordingError:
        pass


@FUZZ
@given(st.sampled_from(["installation", "processing", "duration_s", "format_version", "name", "provenance"]), JSONISH)
def test_meta_json_values(rec, tmp_path, key, value):
    r = tmp_path / "r"
    if not r.exists():
        shutil.copytree(rec, r)
    meta = json.loads((rec / "meta.json").read_text())
    meta[key] = value
    (r / "meta.json").write_text(json.dumps(meta))
    try:
        Recording(r)
    except RecordingError:
        pass


@FUZZ
@given(st.sampled_from(["lidar", "radar", "mru", "crane", "markers", "attitude", "lidar.mount", "crane.geometry"]), JSONISH)
def test_installation_files(tmp_path, key, value):
    p = tmp_path / "i.yaml"
    doc: dict = {}
    node = doc
    *parents, leaf = key.split(".")
    for k in parents:
        node = node.setdefault(k, {})
    node[leaf] = value
    p.write_text(json.dumps(doc))  # JSON is YAML
    try:
        load_installation(p)
    except RecordingError:
        pass


@FUZZ
@given(st.text(max_size=120))
def test_scenario_yaml_text(tmp_path, text):
    p = tmp_path / "s.yaml"
    p.write_text(text, encoding="utf-8", errors="surrogateescape")
    try:
        load_scenario(p)
    except ScenarioError:
        pass


@FUZZ
@given(st.sampled_from(["lidar.rate_hz", "crane.motion.heave.amplitude", "mismatch", "mismatch.wind_mps", "lidar.outages_s",
                        "seed", "duration_s", "processing.fusion.solutions", "nope.key", "lidar", "world", ""]),
       st.sampled_from(["5", "-1", "inf", "nan", "[1,2]", "[[3,1]]", "{}", "{a: 1}", "x", "1e300", "null", "[", "''"]))
@pytest.mark.slow
def test_set_overrides(key, value):
    try:
        load_scenario("sts-empty", [f"{key}={value}"])
    except ScenarioError:
        pass
