"""Loaders: a folder of clouds with an installation file reads like the boomtip recording it
came from; times from names or a timestamps file; a level installation without an attitude
stream; KITTI .bin; a selection of frames; clear errors for the formats not read."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from boomtip.data.io.installation_file import installation_template, load_installation
from boomtip.data.io.loaders import guess_format, open_source
from boomtip.data.io.pcd import write_pcd
from boomtip.data.io.recording import RecordingError
from boomtip.tools.cli.commands import app

runner = CliRunner()


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    root = tmp_path_factory.mktemp("loaders")
    assert runner.invoke(app, ["simulate", "-s", "sts-loaded", "--duration", "2", "--out", str(root / "rec")]).exit_code == 0
    return root / "rec"


def _deck_rows(path):
    with open(path) as fh:
        return [(r["t"], r["value"], r["status"]) for r in csv.DictReader(fh) if r["method"] == "deck_lidar"]


@pytest.mark.slow
def test_a_folder_of_pcds_reads_like_its_recording(rec, tmp_path):
    clouds = tmp_path / "clouds"
    clouds.mkdir()
    for p in (rec / "lidar").iterdir():
        shutil.copy(p, clouds / p.name)
    shutil.copy(rec / "mru.csv", clouds / "mru.csv")
    inst = tmp_path / "inst.yaml"
    # the defaults are the recording's LiDAR and mount; its survey has the waterline too
    inst.write_text(installation_template().replace("waterline_z_m: null", "waterline_z_m: 0.0"))
    assert guess_format(clouds) == "folder" and guess_format(rec) == "boomtip"
    r = runner.invoke(app, ["process", str(clouds), "--installation", str(inst), "--out", str(tmp_path / "f")])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["process", str(rec), "--out", str(tmp_path / "b")])
    assert r.exit_code == 0, r.output
    assert _deck_rows(tmp_path / "f" / "measurements.csv") == _deck_rows(tmp_path / "b" / "measurements.csv")
    # without truth, the report says what was estimated
    report = (tmp_path / "f" / "report.md").read_text()
    assert "no truth" in report and "| deck_lidar | 20 | 100.0 % |" in report and (tmp_path / "f" / "plots" / "estimates.png").is_file()
    # without an installation file the folder is refused, naming what is missing
    r = runner.invoke(app, ["process", str(clouds), "--out", str(tmp_path / "g")])
    assert r.exit_code == 2 and "--installation" in r.output


def _ground(n=4000, height=12.0, seed=0):
    rng = np.random.default_rng(seed)
    # sensor looking down (the default mount): boresight x is down, so the ground is x = height
    yz = rng.uniform(-8, 8, (n, 2))
    return np.column_stack([np.full(n, height) + rng.normal(0, 0.01, n), yz])


def test_level_attitude_and_times_from_names_or_a_file(tmp_path):
    folder = tmp_path / "ground"
    folder.mkdir()
    for k in range(5):
        write_pcd(folder / f"{1.5 + 0.1 * k:.1f}.pcd", _ground(seed=k), {"intensity": np.ones(4000, np.float32)})
    inst = tmp_path / "level.yaml"
    inst.write_text("attitude: level\nradar: {enabled: false}\nlidar: {rate_hz: 10}\ncrane: {geometry: {boom_tip_m: [0, 0, 0]}}\n")
    src = open_source(folder, installation=load_installation(inst))
    frames = list(src)
    np.testing.assert_allclose([f.t_s for f in frames], [0.0, 0.1, 0.2, 0.3, 0.4], atol=1e-12)  # from the first stamp
    assert src.meta.t_origin_s == 1.5
    r = runner.invoke(app, ["process", str(folder), "--installation", str(inst), "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    assert "attitude: level" in r.output
    vals = [float(v) for _, v, s in _deck_rows(tmp_path / "o" / "measurements.csv") if s == "ok"]
    assert len(vals) == 5 and np.allclose(vals, 12.5, atol=0.01)  # 12 m below the sensor, 0.5 m below the tip
    (folder / "times.txt").write_text("\n".join(str(10 + k) for k in range(5)) + "\n")
    timed = open_source(folder, installation=load_installation(inst))
    assert [f.t_s for f in timed] == [0, 1, 2, 3, 4] and timed.meta.t_origin_s == 10
    (folder / "times.txt").write_text("1\n2\n")
    with pytest.raises(RecordingError, match="2 times for 5 cloud files"):
        open_source(folder, installation=load_installation(inst))
    (folder / "times.txt").unlink()
    (folder / "frame_a.pcd").write_bytes((folder / "1.5.pcd").read_bytes())
    with pytest.raises(RecordingError, match="frame_a.pcd: the file name is not a time"):
        open_source(folder, installation=load_installation(inst))
    inst.write_text("radar: {enabled: false}\n")
    (folder / "frame_a.pcd").unlink()
    with pytest.raises(RecordingError, match="attitude: level"):
        open_source(folder, installation=load_installation(inst))


def test_kitti_bin_and_a_selection_of_frames(tmp_path):
    folder = tmp_path / "kitti"
    folder.mkdir()
    for k in range(6):  # KITTI names count frames; their times are in times.txt
        pts = np.column_stack([_ground(seed=k), np.full(4000, 0.3)]).astype(np.float32)
        pts.tofile(folder / f"{k:06d}.bin")
    inst = tmp_path / "i.yaml"
    inst.write_text("attitude: level\nradar: {enabled: false}\n")
    with pytest.raises(RecordingError, match="count frames"):
        open_source(folder, installation=load_installation(inst))
    (folder / "times.txt").write_text("\n".join(f"{0.1 * k:.1f}" for k in range(6)) + "\n")
    frames = list(open_source(folder, installation=load_installation(inst), start_s=0.1, duration_s=0.35, every=2))
    assert [round(f.t_s, 3) for f in frames] == [0.1, 0.3]
    assert frames[0].fields["intensity"][0] == pytest.approx(0.3) and frames[0].points_sensor.shape == (4000, 3)
    single = tmp_path / "one"  # one KITTI file alone: 549 is a frame's number, not 549 ns
    single.mkdir()
    (folder / "000003.bin").rename(single / "00549.bin")
    with pytest.raises(RecordingError, match=r"count frames \(00549.bin\)"):
        open_source(single, installation=load_installation(inst))
    (single / "0000000033333.bin").write_bytes((single / "00549.bin").read_bytes())  # boomtip's own: 13 digits of ns
    (single / "00549.bin").unlink()
    one = open_source(single, installation=load_installation(inst))
    assert list(one)[0].t_s == 0.0 and one.meta.t_origin_s == pytest.approx(33333e-9)
    (folder / "000003.bin").write_bytes((single / "0000000033333.bin").read_bytes())
    (folder / "000006.bin").write_bytes(b"\x00" * 10)
    (folder / "times.txt").write_text("\n".join(f"{0.1 * k:.1f}" for k in range(7)) + "\n")
    bad = list(open_source(folder, installation=load_installation(inst)))[-1]
    assert bad.error is not None and "multiple of 4" in bad.error


def test_unknown_keys_in_an_installation_file_name_the_key(tmp_path):
    p = tmp_path / "i.yaml"
    p.write_text("lidar: {rate_hzz: 10}\n")
    with pytest.raises(RecordingError, match=r"lidar.rate_hzz.*lidar.rate_hz"):
        load_installation(p)


@pytest.mark.parametrize("name, fmt", [("x.pcap", "ouster"), ("x.bag", "ros1"), ("x.mcap", "mcap"), ("x.db3", "ros2")])
def test_formats_are_guessed_from_the_path_and_garbage_is_refused_by_name(tmp_path, name, fmt):
    (tmp_path / name).write_bytes(b"garbage")
    (tmp_path / "x.json").write_text("{}")
    assert guess_format(tmp_path / name) == fmt
    inst = tmp_path / "inst.yaml"
    inst.write_text(installation_template())
    r = runner.invoke(app, ["process", str(tmp_path / name), "--installation", str(inst), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and name in r.output and "Traceback" not in r.output, r.output


def test_absolute_time_stamps_start_the_outputs_at_the_first_frame(tmp_path):
    folder = tmp_path / "epoch"
    folder.mkdir()
    t0_ns = 1_700_000_000_000_000_000  # a ROS export: nanoseconds since 1970
    for k in range(10):
        write_pcd(folder / f"{t0_ns + k * 100_000_000}.pcd", _ground(seed=k), {"intensity": np.ones(4000, np.float32)})
    inst = tmp_path / "level.yaml"
    inst.write_text("attitude: level\nradar: {enabled: false}\ncrane: {geometry: {boom_tip_m: [0, 0, 0]}}\n")
    r = runner.invoke(app, ["process", str(folder), "--installation", str(inst), "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    with open(tmp_path / "o" / "estimates.csv") as fh:
        rows = [row for row in csv.DictReader(fh) if row["solution"] == "fused"]
    assert len(rows) >= 90 and float(rows[0]["t"]) == 0.0 and float(rows[-1]["D"]) == pytest.approx(12.5, abs=0.01)
    settings = json.loads((tmp_path / "o" / "settings.json").read_text())
    assert settings["source"]["t_origin_s"] == 1.7e9 and settings["source"]["t_start_s"] == 0.0
    assert "t = 0 s is 2023-11-14T22:13:20.000Z" in (tmp_path / "o" / "report.md").read_text()


@pytest.mark.parametrize("start, duration, every", [(float("nan"), None, 1), (0.0, float("nan"), 1), (float("inf"), None, 1),
                                                    (0.0, float("inf"), 1), (-1.0, None, 1), (0.0, 0.0, 1), (0.0, None, 0)])
def test_a_selection_that_is_not_a_finite_part_is_refused(start, duration, every):
    from boomtip.data.io.loaders import Selection
    from boomtip.data.io.recording import RecordingError

    class Source:
        meta = type("M", (), {"t_start_s": 0.0})()
        duration_s = 10.0

    with pytest.raises(RecordingError, match="expected a finite start >= 0, a finite duration > 0 and every >= 1"):
        Selection(Source(), start, duration, every)


def test_frames_sharing_a_time_stamp_are_missing_and_many_refuse_the_folder(tmp_path):
    folder = tmp_path / "f"
    folder.mkdir()
    for k in range(12):
        write_pcd(folder / f"{k:02d}.pcd", _ground(n=200, seed=k), {})
    inst = tmp_path / "level.yaml"
    inst.write_text("attitude: level\nradar: {enabled: false}\n")
    times = [0.1 * k for k in range(12)]
    times[5] = times[4]
    (folder / "times.txt").write_text("\n".join(f"{t:.1f}" for t in times) + "\n")
    src = open_source(folder, installation=load_installation(inst))
    frames = list(src)
    assert [f.error is None for f in frames].count(False) == 1 and "shares its time stamp 0.400000 s with 04.pcd" in frames[5].error
    assert any("1 frame(s) share their time stamp" in n for n in src.meta.notes)
    (folder / "times.txt").write_text("0\n" * 12)  # a times.txt of zeros
    with pytest.raises(RecordingError, match="11 of 12 frames share their time stamp"):
        open_source(folder, installation=load_installation(inst))


def test_integer_names_shorter_than_ten_digits_count_frames(tmp_path):
    folder = tmp_path / "f"
    folder.mkdir()
    for k in range(3):  # 100 ms apart as nanoseconds, but 9 digits: frame numbers of a sparse export
        write_pcd(folder / f"{(k + 1) * 100_000_000}.pcd", _ground(n=200, seed=k), {})
    inst = tmp_path / "level.yaml"
    inst.write_text("attitude: level\nradar: {enabled: false}\n")
    with pytest.raises(RecordingError, match="count frames"):
        open_source(folder, installation=load_installation(inst))


@pytest.mark.parametrize("items, message", [(["lidar=/a", "lidar=/b"], "the lidar is already --topic lidar=/a"),
                                            (["lidar=/a", "radar=/a"], "/a is already the lidar"),
                                            (["lidar"], "expected ROLE=NAME")])
def test_a_topic_given_twice_or_for_two_roles_is_refused(items, message):
    from boomtip.data.io.loaders import parse_topics

    with pytest.raises(RecordingError, match=message):
        parse_topics(items)
    assert parse_topics(["mru=none", "feeder_mru=none", "lidar=/os/points"]) == {"mru": "none", "feeder_mru": "none",
                                                                               "lidar": "/os/points"}
