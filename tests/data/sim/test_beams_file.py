"""A simulated LiDAR with the beams of a real sensor's metadata file: the elevations are the
file's, each azimuth within half a column of it; a bad beams file is refused with its key."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from boomtip.data.io.beams import BeamsFileError, beam_angles_deg
from boomtip.tools.config.scenario import ScenarioError, load_scenario

OUSTER = Path(__file__).resolve().parents[2] / "data" / "real" / "ouster"
OS1_128 = OUSTER / "OS-1-128_v2.3.0_1024x10_lb_n3.json"
SPINNING = ["lidar.pattern=spinning", "lidar.columns=1024", "duration_s=1"]


def _file_angles(path: Path) -> tuple[np.ndarray, np.ndarray]:
    doc = json.loads(path.read_text())
    doc = doc.get("beam_intrinsics", doc)
    return np.array(doc["beam_altitude_angles"]), np.array(doc["beam_azimuth_angles"])


@pytest.mark.parametrize("name, channels", [("OS-1-128_v2.3.0_1024x10_lb_n3.json", 128), ("OS-1-32-G_v2.1.1_1024x10.json", 32)])
def test_the_simulated_beams_are_the_file_s(name, channels):
    from boomtip.data.sim.sensors import lidar_pattern
    from boomtip.data.sim.world import true_lidar

    s = load_scenario("sts-loaded", SPINNING + [f"lidar.channels={channels}", f"lidar.beams_file={OUSTER / name}"])
    pat = lidar_pattern(true_lidar(s.installation.lidar, s.world))
    alt, az = _file_angles(OUSTER / name)
    d = pat.dirs_sensor.reshape(1024, channels, 3)  # fan by fan
    el_deg = np.degrees(np.arcsin(d[0, :, 2]))
    np.testing.assert_allclose(el_deg, np.sort(alt), atol=0.01)
    # each beam's ray at column c points at column c's azimuth minus the beam's offset (ouster-sdk's sign)
    order = np.argsort(alt, kind="stable")
    column = pat.column.reshape(1024, channels)
    fan_az = np.degrees(np.arctan2(d[:, 0, 1], d[:, 0, 0])) % 360.0
    fired_at = column * 360.0 / 1024
    miss = (fired_at - az[order][None, :] - fan_az[:, None] + 180.0) % 360.0 - 180.0
    assert np.abs(miss).max() <= 0.5 * 360.0 / 1024 + 1e-9
    assert len(np.unique((column[:, 0] - column[:, -1]) % 1024)) == 1  # a fixed shift per beam


def test_a_beams_file_is_read_once_and_must_match_the_channels(tmp_path):
    assert beam_angles_deg(OS1_128, 128)[0][0] == 20.95
    with pytest.raises(BeamsFileError, match="128 beams, expected 64"):
        beam_angles_deg(OS1_128, 64)


@pytest.mark.parametrize("content, expected", [
    (None, "no such file"),
    ("{not json", "not JSON"),
    ('{"beam_intrinsics": {"beam_azimuth_angles": [0]}}', "no beam_altitude_angles"),
    ('{"beam_altitude_angles": [1, "x"], "beam_azimuth_angles": [0, 0]}', "finite angles"),
    ('{"beam_altitude_angles": [1, 2], "beam_azimuth_angles": [0]}', "2 beam_altitude_angles but 1"),
    ('{"beam_altitude_angles": [1, 1], "beam_azimuth_angles": [0, 0]}', "share an elevation"),
    ('{"beam_altitude_angles": [1, 2, 3], "beam_azimuth_angles": [0, 0, 0]}', "3 beams, expected 2"),
])
def test_a_bad_beams_file_is_refused_with_its_key_and_what_was_expected(tmp_path, content, expected):
    path = tmp_path / "beams.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(ScenarioError, match="installation.lidar.beams_file: .*beams.json") as err:
        load_scenario("sts-loaded", SPINNING + ["lidar.channels=2", f"lidar.beams_file={path}"])
    assert expected in str(err.value)
