"""Recordings on disk (data/recording.py, data/pcd.py) and `boomtip simulate` (tools/cli.py)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from boomtip.data.frames import MRU_COLUMNS, TRUTH_COLUMNS
from boomtip.data.io.pcd import PcdError, read_pcd, write_pcd
from boomtip.data.io.recording import FORMAT_VERSION, Recording, RecordingError, frame_file_name, write_recording
from boomtip.tools.config.scenario import load_scenario
from boomtip.data.sim.simulator import Simulation
from boomtip.tools.cli.commands import app


@pytest.fixture(scope="module")
def scenario():
    return load_scenario("sts-loaded", ["duration_s=1"])


@pytest.fixture(scope="module")
def sim(scenario):
    return Simulation(scenario)


@pytest.fixture(scope="module")
def frames(sim):
    return list(sim)


@pytest.fixture(scope="module")
def rec_dir(tmp_path_factory, scenario):
    out = tmp_path_factory.mktemp("rec") / "sts-loaded"
    write_recording(Simulation(scenario), out)  # a fresh source: writing must not depend on state
    return out


@pytest.fixture
def rec_copy(rec_dir, tmp_path):
    """A private copy to damage."""
    dst = tmp_path / "copy"
    shutil.copytree(rec_dir, dst)
    return dst


# ---------------------------------------------------------------------------------------
# Round trip


def test_layout(rec_dir, scenario):
    assert (rec_dir / "meta.json").is_file() and (rec_dir / "mru.csv").is_file() and (rec_dir / "truth.csv").is_file()
    n_lidar = len(list((rec_dir / "lidar").glob("*.pcd")))
    n_radar = len(list((rec_dir / "radar").glob("*.pcd")))
    assert n_lidar == round(scenario.duration_s * scenario.installation.lidar.rate_hz) == 10
    assert n_radar == round(scenario.duration_s * scenario.installation.radar.rate_hz) == 20
    assert frame_file_name(0.1) == "0000100000000.pcd"
    assert (rec_dir / "lidar" / "0000100000000.pcd").is_file()
    # nothing left behind from the atomic write
    assert not [p for p in rec_dir.parent.iterdir() if p.name.startswith(".")]
    assert not list(rec_dir.rglob(".*"))


def test_every_frame_round_trips(rec_dir, frames):
    rec = Recording(rec_dir)
    back = list(rec)
    assert len(rec) == len(back) == len(frames)
    for a, b in zip(frames, back):
        assert (b.sensor, b.index) == (a.sensor, a.index)
        assert b.t_s == pytest.approx(a.t_s, abs=1e-9)
        assert b.error is None and b.path and b.path.endswith(frame_file_name(a.t_s))
        assert b.points_sensor.shape == a.points_sensor.shape and b.points_sensor.dtype == np.float64
        # float32 on disk: exactly the float32 rounding of the simulated points
        np.testing.assert_array_equal(b.points_sensor, a.points_sensor.astype(np.float32).astype(np.float64))
        np.testing.assert_allclose(b.points_sensor, a.points_sensor, rtol=1e-6, atol=1e-5)
        assert list(b.fields) == list(a.fields)
        for k in a.fields:
            assert b.fields[k].dtype == a.fields[k].dtype, k
            np.testing.assert_array_equal(b.fields[k], a.fields[k], err_msg=k)
    # the loaded scenario has radar false alarms and LiDAR noise: the comparison is not trivial
    assert any((f.fields["label"] == 0).any() for f in frames if f.sensor == "radar")


def test_mru_log_round_trips(rec_dir, sim):
    rec = Recording(rec_dir)
    np.testing.assert_allclose(rec.mru.t_s, sim.mru.t_s, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(rec.mru.rpy_rad, sim.mru.rpy_rad, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(rec.mru.rpy_rate_radps, sim.mru.rpy_rate_radps, rtol=1e-9, atol=1e-12)
    assert rec.mru.max_gap_s == sim.mru.max_gap_s
    assert rec.mru.t_s[-1] >= sim.scenario.duration_s  # covers the whole run
    header = (rec_dir / "mru.csv").read_text().splitlines()[0].split(",")
    assert tuple(header) == MRU_COLUMNS


def test_truth_round_trips(rec_dir, sim):
    rec = Recording(rec_dir)
    assert rec.truth is not None
    assert set(rec.truth.columns) == set(TRUTH_COLUMNS)
    for k in TRUTH_COLUMNS:
        np.testing.assert_allclose(rec.truth.columns[k], sim.truth.columns[k], rtol=1e-9, atol=1e-12, err_msg=k)


def test_meta_json(rec_dir, sim, scenario):
    meta = json.loads((rec_dir / "meta.json").read_text())
    assert meta["format_version"] == FORMAT_VERSION
    # processing's part: the installation; the world only as provenance
    assert meta["installation"] == scenario.installation.model_dump(mode="json")
    assert meta["provenance"]["scenario"] == scenario.model_dump(mode="json")
    assert meta["frames"] == {"lidar": 10, "radar": 20}
    rec = Recording(rec_dir)
    assert rec.meta.installation == scenario.installation
    assert rec.meta.provenance == scenario.model_dump(mode="json")
    np.testing.assert_array_equal(rec.meta.T_crane_boomtip, sim.meta.T_crane_boomtip)
    np.testing.assert_allclose(rec.meta.T_crane_boomtip[:3, 3], scenario.installation.crane.geometry.boom_tip_m)
    for s in ("lidar", "radar"):
        T = rec.meta.T_boomtip_sensor[s]
        np.testing.assert_array_equal(T, sim.meta.T_boomtip_sensor[s])
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)


def test_D_recomputed_from_truth_poses_and_meta_equals_truth_D(rec_dir):
    """Only the files: truth.csv poses + the tip and the deck plane give back D."""
    from boomtip.tools.config.scenario import scenario_from_dict
    from boomtip.data.sim.scene import feeder_deck_plane_body

    meta = json.loads((rec_dir / "meta.json").read_text())
    lines = (rec_dir / "truth.csv").read_text().splitlines()
    names = lines[0].split(",")
    tab = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])
    c = {n: tab[:, i] for i, n in enumerate(names)}
    R_c = Rotation.from_euler("xyz", np.column_stack([c["crane_roll"], c["crane_pitch"], c["crane_yaw"]]))
    p_c = np.column_stack([c["crane_x"], c["crane_y"], c["crane_z"]])
    R_f = Rotation.from_euler("xyz", np.column_stack([c["feeder_roll"], c["feeder_pitch"], c["feeder_yaw"]]))
    p_f = np.column_stack([c["feeder_x"], c["feeder_y"], c["feeder_z"]])
    tip = R_c.apply(np.asarray(meta["installation"]["crane"]["geometry"]["boom_tip_m"])) + p_c
    plane = feeder_deck_plane_body(scenario_from_dict(meta["provenance"]["scenario"]))
    n = R_f.apply(plane[:3])
    d = plane[3] - np.einsum("ij,ij->i", n, p_f)
    D = (np.einsum("ij,ij->i", n, tip) + d) / n[:, 2]
    np.testing.assert_allclose(D, c["D"], atol=1e-6)
    assert np.ptp(c["D"]) > 0.1  # both ships move
    # and D_dot is its time derivative
    t = c["t"]
    np.testing.assert_allclose(np.gradient(D, t)[1:-1], c["D_dot"][1:-1], atol=2e-4)


def test_write_refuses_non_empty_out_without_force(rec_copy, scenario):
    sentinel = rec_copy / "keep.txt"
    sentinel.write_text("mine")
    short = load_scenario("sts-empty", ["duration_s=0.2"])
    short_sim = Simulation(short)
    with pytest.raises(RecordingError, match="--force"):
        write_recording(short_sim, rec_copy)
    assert sentinel.read_text() == "mine"  # untouched
    assert not [p for p in rec_copy.parent.iterdir() if ".partial" in p.name]
    # an empty folder is fine, and --force replaces a non-empty one
    empty = rec_copy.parent / "empty"
    empty.mkdir()
    write_recording(short_sim, empty)
    write_recording(short_sim, rec_copy, force=True)
    assert not sentinel.exists()
    assert len(Recording(rec_copy)) == 2 + 4
    assert Recording(rec_copy).meta.provenance == short.model_dump(mode="json")


# ---------------------------------------------------------------------------------------
# Damaged recordings


def _frame_files(root, sensor):
    return sorted((root / sensor).glob("*.pcd"))


@pytest.mark.parametrize(
    "damage",
    ["garbage", "ascii_garbage", "truncated_data", "truncated_header", "empty_file"],
)
def test_corrupt_pcd_yields_frame_with_error_and_others_read(rec_copy, frames, damage):
    victim = _frame_files(rec_copy, "lidar")[3]
    raw = victim.read_bytes()
    bad = {
        "garbage": bytes(range(256)) * 4 + b"\x00\xff\xfe",
        "ascii_garbage": b"hello world\nthis is not a point cloud\n",
        "truncated_data": raw[: len(raw) - 1000],
        "truncated_header": raw[:40],
        "empty_file": b"",
    }[damage]
    victim.write_bytes(bad)
    back = list(Recording(rec_copy))
    assert len(back) == len(frames)
    broken = [f for f in back if f.error]
    assert len(broken) == 1
    f = broken[0]
    assert victim.name in f.error and f.path == str(victim)
    assert (f.sensor, f.index) == ("lidar", 3) and f.t_s == pytest.approx(0.3)
    assert len(f) == 0
    if damage == "truncated_data":
        assert "truncated" in f.error
    for a, b in zip(frames, back):
        if b is f:
            continue
        assert b.error is None
        np.testing.assert_array_equal(b.points_sensor, a.points_sensor.astype(np.float32))


def test_read_pcd_errors_name_the_file(tmp_path):
    p = tmp_path / "bad.pcd"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    with pytest.raises(PcdError, match="bad.pcd"):
        read_pcd(p)
    with pytest.raises(PcdError, match="missing.pcd"):
        read_pcd(tmp_path / "missing.pcd")


def test_empty_pcd_round_trips(tmp_path):
    p = tmp_path / "empty.pcd"
    fields = {"range": np.zeros(0, np.float32), "label": np.zeros(0, np.int32)}
    write_pcd(p, np.zeros((0, 3)), fields)
    pts, back = read_pcd(p)
    assert pts.shape == (0, 3) and pts.dtype == np.float64
    assert list(back) == list(fields)
    assert all(back[k].dtype == fields[k].dtype and back[k].shape == (0,) for k in fields)


def test_pcd_round_trips_dtypes(tmp_path):
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(17, 3)) * 50
    fields = {"a": rng.random(17).astype(np.float32), "b": rng.random(17), "c": np.arange(17, dtype=np.int16),
              "d": np.arange(17, dtype=np.uint8), "e": -np.arange(17, dtype=np.int64)}
    write_pcd(tmp_path / "x.pcd", pts, fields)
    p, f = read_pcd(tmp_path / "x.pcd")
    np.testing.assert_array_equal(p, pts.astype(np.float32))
    for k in fields:
        assert f[k].dtype == fields[k].dtype
        np.testing.assert_array_equal(f[k], fields[k])


def test_empty_frame_in_a_recording_reads_as_an_empty_frame(rec_copy, frames):
    victim = _frame_files(rec_copy, "radar")[5]
    write_pcd(victim, np.zeros((0, 3)), {k: np.zeros(0, v.dtype) for k, v in frames[0 if frames[0].sensor == "radar" else 1].fields.items()})
    back = list(Recording(rec_copy))
    f = next(b for b in back if b.path == str(victim))
    assert f.error is None and len(f) == 0 and f.sensor == "radar" and f.index == 5
    assert all(b.error is None for b in back)


def test_mru_out_of_order_names_the_line(rec_copy):
    path = rec_copy / "mru.csv"
    lines = path.read_text().splitlines()
    lines[3], lines[4] = lines[4], lines[3]  # rows t=0.010 and t=0.015 swapped
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError) as exc:
        Recording(rec_copy, strict=True)
    msg = str(exc.value)
    assert "mru.csv" in msg and "line 5" in msg and "is not after the previous sample" in msg
    kept = Recording(rec_copy)  # by default the late sample is dropped and said
    assert np.all(np.diff(kept.mru.t_s) > 0) and any("dropped 1 of" in n for n in kept.meta.notes)


def test_mru_duplicate_timestamp_is_out_of_order(rec_copy):
    path = rec_copy / "mru.csv"
    lines = path.read_text().splitlines()
    lines[10] = lines[9]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError, match=r"mru\.csv: line 11"):
        Recording(rec_copy, strict=True)


@pytest.mark.parametrize(
    "edit, expect",
    [
        (lambda ls: ls.__setitem__(6, ls[6] + ",1"), "line 7"),
        (lambda ls: ls.__setitem__(8, ls[8].replace(",", ",x", 1)), "line 9"),
        (lambda ls: ls.__setitem__(0, ls[0].replace("pitch_rate", "pr")), "pitch_rate"),
    ],
)
def test_bad_mru_csv_errors_name_file_and_line(rec_copy, edit, expect):
    path = rec_copy / "mru.csv"
    lines = path.read_text().splitlines()
    edit(lines)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError) as exc:
        Recording(rec_copy)
    assert "mru.csv" in str(exc.value) and expect in str(exc.value)


def test_bad_meta_errors(rec_copy):
    meta_path = rec_copy / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["format_version"] = 99
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(RecordingError, match="format_version"):
        Recording(rec_copy)
    meta["format_version"] = FORMAT_VERSION
    meta["installation"]["lidar"]["mount"]["rpy_deg"] = [90, 90]
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(RecordingError, match="installation.lidar.mount.rpy_deg"):
        Recording(rec_copy)
    meta_path.write_text("{not json")
    with pytest.raises(RecordingError, match="meta.json"):
        Recording(rec_copy)
    meta_path.unlink()
    with pytest.raises(RecordingError, match="meta.json"):
        Recording(rec_copy)


def test_missing_recording_folder(tmp_path):
    with pytest.raises(RecordingError, match="nope"):
        Recording(tmp_path / "nope")


# ---------------------------------------------------------------------------------------
# CLI


@pytest.fixture(scope="module")
def runner():
    return CliRunner()


def test_cli_simulate_writes_a_recording(runner, tmp_path):
    out = tmp_path / "run"
    res = runner.invoke(app, ["simulate", "-s", "sts-empty", "--out", str(out), "--duration", "0.2",
                              "--set", "lidar.rate_hz=20", "--seed", "4"])
    assert res.exit_code == 0, res.output
    rec = Recording(out)
    assert rec.meta.duration_s == 0.2 and rec.meta.provenance["seed"] == 4
    assert rec.meta.installation.lidar.rate_hz == 20
    frames = list(rec)
    assert sum(f.sensor == "lidar" for f in frames) == 4 and sum(f.sensor == "radar" for f in frames) == 4
    assert all(f.error is None and len(f) > 0 for f in frames)
    assert "wrote" in res.output


def test_cli_refuses_non_empty_out_without_force(runner, tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    args = ["simulate", "-s", "sts-empty", "--out", str(out), "--duration", "0.1"]
    res = runner.invoke(app, args)
    assert res.exit_code == 2
    assert "--force" in res.output and "Traceback" not in res.output
    assert (out / "keep.txt").read_text() == "mine"
    res = runner.invoke(app, args + ["--force"])
    assert res.exit_code == 0, res.output
    assert not (out / "keep.txt").exists() and (out / "meta.json").is_file()


def test_cli_unknown_set_key_prints_nearest_keys(runner, tmp_path):
    out = tmp_path / "run"
    res = runner.invoke(app, ["simulate", "-s", "sts-empty", "--out", str(out), "--duration", "0.1",
                              "--set", "lidar.rate_hzz=5"])
    assert res.exit_code == 2
    assert "lidar.rate_hzz" in res.output and "lidar.rate_hz," in res.output
    assert not out.exists()


def test_cli_unknown_scenario(runner, tmp_path):
    res = runner.invoke(app, ["simulate", "-s", "no-such-scenario", "--out", str(tmp_path / "r")])
    assert res.exit_code == 2
    assert "no-such-scenario" in res.output and "sts-empty" in res.output


def test_cli_scenarios_keys(runner):
    res = runner.invoke(app, ["scenarios", "--keys"])
    assert res.exit_code == 0
    keys = res.stdout.split()
    assert "installation.lidar.rate_hz" in keys and "world.feeder.motion.heave.amplitude" in keys
    assert "world.mismatch.rope_ea_n" in keys and "processing.fusion.jerk_psd" in keys


# ---------------------------------------------------------------------------------------
# MRU log (data/frames.py MruLog)


def test_mru_log_is_the_crane_attitude_plus_its_noise_bias_and_lag(sim, scenario):
    tr, mru, mm = sim.truth, sim.mru, scenario.world.mismatch
    sigma = np.deg2rad(scenario.installation.mru.angle_noise_deg)
    assert sigma > 0 and mm.mru_lag_s > 0 and np.any(mm.mru_bias_deg)
    inside = mru.t_s >= mm.mru_lag_s  # where the truth covers the lagged time
    truth_rpy = np.column_stack([tr.at(f"crane_{a}", mru.t_s[inside] - mm.mru_lag_s) for a in ("roll", "pitch", "yaw")])
    err = mru.rpy_rad[inside] - truth_rpy
    assert np.std(err, axis=0) == pytest.approx(np.full(3, sigma), rel=0.15)
    np.testing.assert_allclose(np.mean(err, axis=0), np.deg2rad(mm.mru_bias_deg), atol=4 * sigma / np.sqrt(len(err)))
    np.testing.assert_allclose(np.diff(mru.t_s), 1 / scenario.installation.mru.rate_hz, atol=1e-12)


def test_mru_attitude_interpolates_and_refuses_gaps_and_outside():
    from boomtip.data.frames import MruLog
    t = np.array([0.0, 0.01, 0.02, 0.5, 0.51])
    rpy = np.array([[0, 0, 0], [0.01, -0.02, 3.13], [0.02, -0.04, -3.13], [0.0, 0.0, 0.0], [0.0, 0.0, 0.1]])
    log = MruLog(t, rpy, rpy * 10, max_gap_s=0.1)
    a, r = log.attitude(0.005)
    np.testing.assert_allclose(a, [0.005, -0.01, 1.565])
    np.testing.assert_allclose(r, [0.05, -0.1, 15.65])
    a, _ = log.attitude(0.01)
    np.testing.assert_allclose(a, rpy[1])
    a, _ = log.attitude(0.015)  # yaw crosses +-pi: interpolate the short way round
    assert abs(abs(a[2]) - np.pi) < 1e-9
    assert log.attitude(0.3) is None  # inside a 0.48 s gap
    assert log.attitude(-0.01) is None and log.attitude(0.6) is None
    a, _ = log.attitude(0.505)
    np.testing.assert_allclose(a, [0, 0, 0.05])


# ---------------------------------------------------------------------------------------
# An MRU on the feeder


@pytest.fixture(scope="module")
def feeder_mru_rec(tmp_path_factory):
    s = load_scenario("sts-loaded", ["duration_s=0.5", "world.feeder.mru.enabled=true", "world.feeder.mru.outages_s=[[0.2,0.3]]"])
    out = tmp_path_factory.mktemp("rec") / "feeder-mru"
    sim = Simulation(s)
    write_recording(Simulation(s), out)
    return sim, out


def test_feeder_mru_is_off_by_default(rec_dir, sim):
    assert sim.feeder_mru is None and not (rec_dir / "feeder_mru.csv").exists()
    assert Recording(rec_dir).feeder_mru is None


def test_feeder_mru_round_trips_with_its_gap(feeder_mru_rec):
    sim, out = feeder_mru_rec
    rec = Recording(out)
    np.testing.assert_allclose(rec.feeder_mru.t_s, sim.feeder_mru.t_s, atol=1e-12)
    np.testing.assert_allclose(rec.feeder_mru.rpy_rad, sim.feeder_mru.rpy_rad, atol=1e-12)
    np.testing.assert_allclose(rec.feeder_mru.rpy_rate_radps, sim.feeder_mru.rpy_rate_radps, atol=1e-12)
    assert rec.feeder_mru.attitude(0.25) is None and rec.feeder_mru.attitude(0.15) is not None  # the outage is a gap
    # the feeder's attitude, not the crane's: its yaw carries the heading references' offset
    yaw_bias = np.degrees(np.nanmean(sim.feeder_mru.rpy_rad[:, 2] - sim.truth.at("feeder_yaw", sim.feeder_mru.t_s - 0.002)))
    assert yaw_bias == pytest.approx(0.5, abs=0.01)



def test_a_selection_of_frames_keeps_the_feeder_mru(feeder_mru_rec):
    from boomtip.data.io.loaders import open_source

    part = open_source(feeder_mru_rec[1], start_s=0.1, duration_s=0.3, every=2)
    assert part.feeder_mru is not None  # --start / --duration / --every used to drop it, silently
    np.testing.assert_array_equal(part.feeder_mru.t_s, Recording(feeder_mru_rec[1]).feeder_mru.t_s)

def test_a_bad_feeder_mru_csv_names_the_file_and_line(feeder_mru_rec, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(feeder_mru_rec[1], dst)
    path = dst / "feeder_mru.csv"
    lines = path.read_text().splitlines()
    lines[5] = ",".join(["nan" if i == 1 else v for i, v in enumerate(lines[5].split(","))])
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError) as exc:
        Recording(dst, strict=True)
    assert "feeder_mru.csv" in str(exc.value) and "line 6" in str(exc.value)
    assert any("feeder_mru.csv: dropped 1 of" in n for n in Recording(dst).meta.notes)
