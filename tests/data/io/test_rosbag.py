"""ROS 1 bags, ROS 2 bags and MCAP: what `simulate --format` writes reads back to the estimates
of the boomtip recording of the same run; topics are guessed by type or chosen; bags from
other software (unnamed topics, zero stamps, a radar's own velocity field) read or are refused
with the topics listed."""

from __future__ import annotations

import csv
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from boomtip.data.io.installation_file import installation_template
from boomtip.data.io.loaders import guess_format, open_source
from boomtip.data.io.recording import RecordingError
from boomtip.data.io.ros_messages import encode_cloud
from boomtip.tools.cli.commands import app

runner = CliRunner()


def _ok(args):
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    return r


@pytest.fixture(scope="module")
def sts(tmp_path_factory):
    root = tmp_path_factory.mktemp("bags")
    _ok(["simulate", "-s", "sts-loaded", "--duration", "2", "--out", str(root / "rec")])
    _ok(["process", str(root / "rec"), "--out", str(root / "rec_out")])
    return root


@pytest.mark.slow
@pytest.mark.parametrize("kind, name", [("mcap", "b_mcap/b_mcap.mcap"), ("ros2", "b_ros2"), ("ros1", "b_ros1/b_ros1.bag")])
def test_each_bag_kind_reads_back_to_the_recordings_estimates(sts, kind, name):
    out = sts / f"b_{kind}"
    _ok(["simulate", "-s", "sts-loaded", "--duration", "2", "--out", str(out), "--format", kind])
    path = sts / name
    assert guess_format(path) == kind
    _ok(["process", str(path), "--out", str(sts / f"p_{kind}")])
    assert (sts / f"p_{kind}" / "estimates.csv").read_bytes() == (sts / "rec_out" / "estimates.csv").read_bytes()
    src = open_source(path)
    assert src.truth is not None and src.meta.provenance is not None and len(src) == 20 + 40
    assert src.meta.installation == open_source(sts / "rec").meta.installation


def test_rerun_opens_the_mcap(sts):
    mcap = sts / "b_mcap" / "b_mcap.mcap"
    if not mcap.exists():
        _ok(["simulate", "-s", "sts-loaded", "--duration", "2", "--out", str(sts / "b_mcap"), "--format", "mcap"])
    r = subprocess.run([sys.executable, "-m", "rerun", "mcap", "convert", str(mcap), "-o", str(sts / "m.rrd")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert (sts / "m.rrd").stat().st_size > 1e6


@pytest.mark.slow
def test_a_hook_run_carries_its_encoders(tmp_path):
    _ok(["simulate", "-s", "hook-2", "--duration", "2", "--out", str(tmp_path / "rec")])
    _ok(["simulate", "-s", "hook-2", "--duration", "2", "--out", str(tmp_path / "bag"), "--format", "mcap"])
    src = open_source(tmp_path / "bag")
    assert src.encoders is not None and not src.meta.installation.radar.enabled
    _ok(["process", str(tmp_path / "rec"), "--out", str(tmp_path / "a")])
    _ok(["process", str(tmp_path / "bag"), "--out", str(tmp_path / "b")])

    def table(p):
        with open(p) as fh:
            rows = list(csv.reader(fh))
        return rows[0], np.array([[float(x) for x in r[2:]] for r in rows[1:]])
    head_a, a = table(tmp_path / "a" / "hook_estimates.csv")
    head_b, b = table(tmp_path / "b" / "hook_estimates.csv")
    # the recording's CSV streams carry 6 significant digits, the bag full doubles
    assert head_a == head_b and a.shape == b.shape and np.max(np.abs(a - b)) < 1e-4


# --- bags from other software ---------------------------------------------------------------
def _foreign_bag(path, clouds: dict[str, str], stamp_zero=False, imu=True, radar_field="doppler", orientation=None):
    """A ROS 2 bag as a driver stack writes it: topics of its own names. orientation: per Imu
    message, its quaternion (x, y, z, w) and orientation_covariance[0] (default: level, 0)."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    rng = np.random.default_rng(0)
    with Writer(path, version=9) as w:
        conns = {t: w.add_connection(t, "sensor_msgs/msg/PointCloud2", typestore=store) for t in clouds}
        imu_conn = w.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=store) if imu else None
        for k in range(10):
            t = 100.0 + 0.1 * k
            sec, nsec = (0, 0) if stamp_zero else (int(t), int(round((t % 1) * 1e9)))
            hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id="s")
            for topic, kind in clouds.items():
                pts = np.column_stack([rng.uniform(-5, 5, 300), rng.uniform(-5, 5, 300), np.full(300, -12.0)])
                fields = {"intensity": np.ones(300, np.float32)} if kind == "lidar" else {radar_field: np.full(300, -0.3, np.float32)}
                spec, data, step = encode_cloud(pts, fields)
                PF = T["sensor_msgs/msg/PointField"]
                msg = T["sensor_msgs/msg/PointCloud2"](header=hdr, height=1, width=300, fields=[PF(name=n, offset=o, datatype=d, count=c) for n, o, d, c in spec],
                                                       is_bigendian=False, point_step=step, row_step=step * 300,
                                                       data=np.frombuffer(data, np.uint8), is_dense=True)
                w.write(conns[topic], int(t * 1e9), store.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))
            if imu:
                Q, V = T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Vector3"]
                (qx, qy, qz, qw), cov0 = orientation[k] if orientation else ((0.0, 0.0, 0.0, 1.0), 0.0)
                cov = np.zeros(9)
                cov[0] = cov0
                m = T["sensor_msgs/msg/Imu"](header=hdr, orientation=Q(x=qx, y=qy, z=qz, w=qw), orientation_covariance=cov,
                                             angular_velocity=V(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=np.zeros(9),
                                             linear_acceleration=V(x=0.0, y=0.0, z=9.81), linear_acceleration_covariance=np.zeros(9))
                w.write(imu_conn, int(t * 1e9), store.serialize_cdr(m, "sensor_msgs/msg/Imu"))


@pytest.fixture
def inst(tmp_path):
    p = tmp_path / "inst.yaml"
    p.write_text(installation_template().replace("attitude: mru", "attitude: mru"))
    from boomtip.data.io.installation_file import load_installation
    return load_installation(p)


def test_two_unnamed_clouds_are_refused_with_the_topics_listed_until_chosen(tmp_path, inst):
    _foreign_bag(tmp_path / "bag", {"/front/points": "lidar", "/rear/points": "lidar"})
    with pytest.raises(RecordingError, match=r"cannot tell which PointCloud2 topic.*/front/points, /rear/points.*--topic"):
        open_source(tmp_path / "bag", installation=inst)
    src = open_source(tmp_path / "bag", installation=inst, topics={"lidar": "/rear/points"})
    frames = list(src)
    assert len(frames) == 10 and {f.sensor for f in frames} == {"lidar"} and not src.meta.installation.radar.enabled
    assert frames[0].t_s == 0.0 and src.meta.t_origin_s == pytest.approx(100.0)  # t from the first stamp
    assert src.mru.attitude(0.5) is not None
    with pytest.raises(RecordingError, match=r"--topic lidar=/nope: .* has no such topic; topics: /front/points"):
        open_source(tmp_path / "bag", installation=inst, topics={"lidar": "/nope"})
    with pytest.raises(RecordingError, match=r"--topic mru=/front/points: a sensor_msgs/msg/PointCloud2, expected sensor_msgs/msg/Imu"):
        open_source(tmp_path / "bag", installation=inst, topics={"mru": "/front/points"})


def test_radar_and_lidar_by_name_a_velocity_field_and_zero_stamps(tmp_path, inst):
    _foreign_bag(tmp_path / "bag", {"/os/lidar_points": "lidar", "/ars548/radar_points": "radar"}, stamp_zero=True)
    src = open_source(tmp_path / "bag", installation=inst)
    frames = list(src)
    radar = [f for f in frames if f.sensor == "radar"]
    assert len(radar) == 10 and np.all(radar[0].fields["range_rate"] == np.float32(-0.3))
    assert frames[0].t_s == 0.0 and src.meta.t_origin_s == pytest.approx(100.0)  # the bag's receive time
    assert any("header stamps are zero" in n for n in src.meta.notes)
    flipped = inst.model_copy(update={"radar": inst.radar.model_copy(update={"velocity_sign": -1})})
    radar = [f for f in open_source(tmp_path / "bag", installation=flipped) if f.sensor == "radar"]
    assert np.all(radar[0].fields["range_rate"] == np.float32(0.3))
    r = runner.invoke(app, ["process", str(tmp_path / "bag"), "--out", str(tmp_path / "o"), "--installation",
                            str(tmp_path / "inst.yaml")])
    assert r.exit_code == 0 and "header stamps are zero" in r.output, r.output


def test_no_attitude_stream_needs_attitude_level(tmp_path, inst):
    _foreign_bag(tmp_path / "bag", {"/points": "lidar"}, imu=False)
    with pytest.raises(RecordingError, match=r"no sensor_msgs/Imu topic.*topics: /points \(PointCloud2\).*attitude: level"):
        open_source(tmp_path / "bag", installation=inst)
    level = inst.model_copy(update={"attitude": "level"})
    assert len(list(open_source(tmp_path / "bag", installation=level))) == 10
    with pytest.raises(RecordingError, match="carries no installation; pass --installation"):
        open_source(tmp_path / "bag")


def test_an_unknown_velocity_field_makes_missing_frames_with_the_reason(tmp_path, inst):
    _foreign_bag(tmp_path / "bag", {"/radar": "radar"}, radar_field="snr_db")
    frames = list(open_source(tmp_path / "bag", installation=inst))
    assert len(frames) == 10 and all(f.error and "no velocity field" in f.error and "radar.velocity_field" in f.error
                                     for f in frames)


# --- what a review fed it -----------------------------------------------------------------
def _write(path, items):
    """A ROS 2 bag from (topic, msgtype, t_s, message or raw bytes) items."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    with Writer(path, version=9) as w:
        conns = {}
        for topic, msgtype, t, msg in items:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=store)
            raw = msg if isinstance(msg, bytes) else store.serialize_cdr(msg, msgtype)
            w.write(conns[topic], int(t * 1e9), raw)
    return store.types


def _header(T, t):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=int(round((t % 1) * 1e9))),
                                    frame_id="s")


def _cloud(T, t, n=300):
    pts = np.column_stack([np.linspace(-5, 5, n), np.linspace(5, -5, n), np.full(n, -12.0)])
    spec, data, step = encode_cloud(pts, {"intensity": np.ones(n, np.float32)})
    PF = T["sensor_msgs/msg/PointField"]
    return T["sensor_msgs/msg/PointCloud2"](header=_header(T, t), height=1, width=n,
                                            fields=[PF(name=a, offset=o, datatype=d, count=c) for a, o, d, c in spec],
                                            is_bigendian=False, point_step=step, row_step=step * n,
                                            data=np.frombuffer(data, np.uint8), is_dense=True)


def test_a_corrupt_cloud_message_is_a_missing_frame_and_the_run_goes_on(tmp_path, inst):
    from rosbags.typesys import Stores, get_typestore

    T = get_typestore(Stores.ROS2_HUMBLE).types
    store = get_typestore(Stores.ROS2_HUMBLE)
    good = [("/points", "sensor_msgs/msg/PointCloud2", 100 + 0.1 * k, _cloud(T, 100 + 0.1 * k)) for k in range(6)]
    raw = store.serialize_cdr(good[3][3], "sensor_msgs/msg/PointCloud2")
    good[3] = (*good[3][:3], bytes(raw[:40]))  # cut inside the field list
    _write(tmp_path / "bag", good)
    level = inst.model_copy(update={"attitude": "level"})
    frames = list(open_source(tmp_path / "bag", installation=level))
    assert len(frames) == 6 and [f.error is None for f in frames] == [True] * 3 + [False] + [True] * 2
    assert "message 3: cannot be decoded" in frames[3].error and frames[3].t_s == pytest.approx(0.3)


def test_joints_are_read_by_name_in_every_message_and_bounded(tmp_path, inst):
    from rosbags.typesys import Stores, get_typestore

    T = get_typestore(Stores.ROS2_HUMBLE).types
    JS = T["sensor_msgs/msg/JointState"]
    items = [("/points", "sensor_msgs/msg/PointCloud2", 100.0, _cloud(T, 100.0))]
    for k in range(10):  # two publishers on one topic, each with its own joints and order
        t = 100 + 0.05 * k
        items.append(("/joint_states", "sensor_msgs/msg/JointState", t,
                      JS(header=_header(T, t), name=["gripper", "hoist"], position=np.array([9.0, 30.0]),
                         velocity=np.zeros(0), effort=np.zeros(0))))
        items.append(("/joint_states", "sensor_msgs/msg/JointState", t + 0.01,
                      JS(header=_header(T, t + 0.01), name=["hoist", "luff", "slew"], position=np.array([30.0, 0.7, 0.1]),
                         velocity=np.zeros(0), effort=np.zeros(0))))
    _write(tmp_path / "bag", items)
    level = inst.model_copy(update={"attitude": "level"})
    enc = open_source(tmp_path / "bag", installation=level).encoders
    assert len(enc["t"]) == 10 and np.all(enc["hoist"] == 30.0) and np.all(enc["luff"] == 0.7) and np.all(enc["slew"] == 0.1)
    items[2] = (*items[2][:3], JS(header=_header(T, 100.01), name=["hoist", "luff", "slew"], position=np.array([30.0, 45.0, 0.1]),
                                  velocity=np.zeros(0), effort=np.zeros(0)))  # luff in degrees
    _write(tmp_path / "bag2", items)
    src = open_source(tmp_path / "bag2", installation=level)
    assert len(src.encoders["t"]) == 9 and np.all(src.encoders["luff"] == 0.7)
    assert any("/joint_states: dropped 1 of 10 samples (messages stamped 100.010 s): first column 'luff' is 45.0 "
               "(expected |luff| <= 1.5708)" in n for n in src.meta.notes), src.meta.notes
    with pytest.raises(RecordingError, match=r"/joint_states: message stamped 100.010 s: column 'luff' is 45.0"):
        open_source(tmp_path / "bag2", installation=level, strict=True)


NO_ORIENTATION = [((0.0, 0.0, 0.0, 0.0), 0.0)] * 5 + [((0.0, 0.0, 0.0, 1.0), -1.0)] * 5  # both REP 145 forms


def test_an_imu_without_orientation_is_not_an_attitude_and_says_so(tmp_path, inst):
    _foreign_bag(tmp_path / "bag", {"/points": "lidar"}, orientation=NO_ORIENTATION)
    with pytest.raises(RecordingError, match=r"/imu/data: its Imu messages carry no orientation .*REP 145.*attitude: level"):
        open_source(tmp_path / "bag", installation=inst)
    level = inst.model_copy(update={"attitude": "level"})
    src = open_source(tmp_path / "bag", installation=level)
    assert len(list(src)) == 10 and src.mru.attitude(0.5)[0].tolist() == [0.0, 0.0, 0.0]
    assert any("/imu/data: its Imu messages carry no orientation" in n and "taken as level" in n for n in src.meta.notes)


def test_topic_none_reads_no_topic_for_a_role(tmp_path, inst):
    _foreign_bag(tmp_path / "bag", {"/points": "lidar"})
    level = inst.model_copy(update={"attitude": "level"})
    src = open_source(tmp_path / "bag", installation=level, topics={"mru": "none"})
    assert src.mru.attitude(0.5)[0].tolist() == [0.0, 0.0, 0.0] and "mru" not in src.role_topic
    with pytest.raises(RecordingError, match="no sensor_msgs/Imu topic"):
        open_source(tmp_path / "bag", installation=inst, topics={"mru": "none"})
    with pytest.raises(RecordingError, match="no sensor_msgs/PointCloud2 topic"):
        open_source(tmp_path / "bag", installation=level, topics={"lidar": "none"})


def test_imu_messages_without_orientation_among_good_ones_are_dropped_and_counted(tmp_path, inst):
    level_q = ((0.0, 0.0, 0.0, 1.0), 0.0)
    orientation = [level_q] * 10
    orientation[3] = ((0.0, 0.0, 0.0, 0.0), 0.0)
    orientation[6] = ((0.0, 0.0, 0.3, 0.5), 0.0)  # not a unit quaternion
    _foreign_bag(tmp_path / "bag", {"/points": "lidar"}, orientation=orientation)
    src = open_source(tmp_path / "bag", installation=inst)
    assert len(src.mru.t_s) == 8
    assert any("/imu/data: dropped 2 of 10 samples (messages stamped 100.300 s, stamped 100.600 s): first no orientation"
               in n for n in src.meta.notes), src.meta.notes
    with pytest.raises(RecordingError, match=r"/imu/data: message stamped 100.300 s: no orientation \(REP 145\)"):
        open_source(tmp_path / "bag", installation=inst, strict=True)


def test_a_bad_meta_is_named_and_an_imu_on_another_clock_is_refused(tmp_path, inst):
    from rosbags.typesys import Stores, get_typestore

    T = get_typestore(Stores.ROS2_HUMBLE).types
    meta = '{"installation": {"attitude": "sideways"}}'
    _write(tmp_path / "bag", [("/points", "sensor_msgs/msg/PointCloud2", 100.0, _cloud(T, 100.0)),
                              ("/boomtip/meta", "std_msgs/msg/String", 100.0, T["std_msgs/msg/String"](data=meta))])
    with pytest.raises(RecordingError, match=r"/boomtip/meta: key 'installation.attitude'"):
        open_source(tmp_path / "bag")
    Q, V = T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Vector3"]
    imu = [("/imu", "sensor_msgs/msg/Imu", 1.0 + 0.1 * k, T["sensor_msgs/msg/Imu"](
        header=_header(T, 1.0 + 0.1 * k), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.zeros(9),
        angular_velocity=V(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=np.zeros(9),
        linear_acceleration=V(x=0.0, y=0.0, z=0.0), linear_acceleration_covariance=np.zeros(9))) for k in range(5)]
    _write(tmp_path / "bag3", [("/points", "sensor_msgs/msg/PointCloud2", 100.0, _cloud(T, 100.0)), *imu])
    with pytest.raises(RecordingError, match=r"/imu: the attitude spans 1.000 to 1.400 s, the frames 100.000 .*different clocks"):
        open_source(tmp_path / "bag3", installation=inst)


def test_multi_valued_coordinates_are_a_missing_frame():
    from boomtip.data.io.ros_messages import CloudError, decode_cloud

    with pytest.raises(CloudError, match=r"field 'x' is float32\[2\]: expected one float"):
        decode_cloud([("x", 0, 7, 2), ("y", 8, 7, 1), ("z", 12, 7, 1)], b"\0" * 16, 1, 1, 16, 16)
    with pytest.raises(CloudError, match=r"field 'x' is int16: expected one float"):
        decode_cloud([("x", 0, 3, 1), ("y", 2, 3, 1), ("z", 4, 3, 1)], b"\0" * 6, 1, 1, 6, 6)


def test_a_feeder_mru_goes_into_the_bag_and_reads_back_beside_the_cranes(tmp_path):
    """Two Imu topics: the one named for the feeder is its MRU, the other the crane's."""
    s = ["--set", "world.feeder.mru.enabled=true"]
    _ok(["simulate", "-s", "sts-loaded", "--duration", "1", "--out", str(tmp_path / "rec"), *s])
    _ok(["simulate", "-s", "sts-loaded", "--duration", "1", "--out", str(tmp_path / "bag"), "--format", "mcap", *s])
    rec, bag = open_source(tmp_path / "rec"), open_source(tmp_path / "bag")
    assert bag.feeder_mru is not None and rec.feeder_mru is not None
    np.testing.assert_allclose(bag.feeder_mru.rpy_rad, rec.feeder_mru.rpy_rad, atol=1e-9)
    np.testing.assert_allclose(bag.mru.rpy_rad, rec.mru.rpy_rad, atol=1e-9)
    assert not np.allclose(bag.mru.rpy_rad, bag.feeder_mru.rpy_rad, atol=1e-3)


def test_clouds_come_in_stamp_order_and_a_late_or_repeated_one_is_a_missing_frame():
    from boomtip.data.frames import Frame
    from boomtip.data.io.rosbag import in_stamp_order

    def f(sensor, t):
        return Frame(sensor, 0, t, np.ones((4, 3)), {}, path=f"{sensor}@{t}")

    received = [f("lidar", 0.0), f("radar", 0.05), f("lidar", 0.2), f("lidar", 0.1),  # 0.1 a little late: put in place
                f("lidar", 0.3), f("lidar", 0.3),  # a repeated stamp
                f("lidar", 0.9), f("lidar", 1.5), f("lidar", 0.35)]  # 0.35 comes after 1.5: late beyond the window
    out = list(in_stamp_order(iter(received), window_s=0.5))
    lidar = [(x.t_s, x.error is None) for x in out if x.sensor == "lidar"]
    assert lidar == [(0.0, True), (0.1, True), (0.2, True), (0.3, True), (0.3, False), (0.9, True), (0.35, False),
                     (1.5, True)]  # the late one goes at once, as a missing frame
    assert "repeats the stamp 0.300000 s of the previous lidar frame" in out[[x.path for x in out].index("lidar@0.3", 4)].error
    late = next(x for x in out if x.path == "lidar@0.35")
    assert "stamped 0.550 s before a lidar frame already given" in late.error and len(late.points_sensor) == 0


def test_a_sensor_lagging_the_other_keeps_every_frame():
    """A radar whose messages all arrive 0.6 s after their stamps (its latency): none is lost."""
    from boomtip.data.frames import Frame
    from boomtip.data.io.rosbag import in_stamp_order

    arrivals = sorted([(0.1 * k, Frame("lidar", k, 0.1 * k, np.ones((4, 3)), {})) for k in range(50)] +
                      [(0.1 * k + 0.6, Frame("radar", k, 0.1 * k, np.ones((4, 3)), {})) for k in range(50)],
                      key=lambda a: a[0])
    out = list(in_stamp_order(iter(f for _, f in arrivals), window_s=0.5))
    assert len(out) == 100 and all(f.error is None for f in out)
    assert [f.t_s for f in out if f.sensor == "radar"] == [0.1 * k for k in range(50)]


def test_an_unnamed_cloud_beside_a_named_radar_is_the_lidar(tmp_path, inst):
    _foreign_bag(tmp_path / "bag", {"/os/points": "lidar", "/ti_mmwave/radar_scan_pcl": "radar"})
    src = open_source(tmp_path / "bag", installation=inst)
    assert src.role_topic["lidar"] == "/os/points" and src.role_topic["radar"] == "/ti_mmwave/radar_scan_pcl"
    assert {f.sensor for f in src} == {"lidar", "radar"}
