"""Write a frame source as a ROS bag, through rosbags: an MCAP (a ROS 2 bag folder whose
`.mcap` file also opens alone, in rerun's viewer or Foxglove), a ROS 2 sqlite3 bag, or a ROS 1
bag. Topics: /boomtip/lidar and /boomtip/radar (PointCloud2, sensor frames `lidar`, `radar`),
/boomtip/mru (Imu: orientation and body rates), /boomtip/encoders (JointState: slew, luff,
hoist), /boomtip/truth (Float64MultiArray, one truth row per message, the columns in the
layout's label) and /boomtip/meta (String: the meta.json a boomtip recording carries)."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from boomtip.data.frames import FrameSource
from boomtip.data.io.output_folder import output_folder
from boomtip.data.io.recording import json_text, meta_to_json
from boomtip.data.io.ros_messages import encode_cloud, imu_from_mru

KINDS = ("mcap", "ros2", "ros1")
TOPICS = {"lidar": "/boomtip/lidar", "radar": "/boomtip/radar", "mru": "/boomtip/mru", "feeder_mru": "/boomtip/feeder_mru",
          "encoders": "/boomtip/encoders", "truth": "/boomtip/truth", "meta": "/boomtip/meta"}
MSGTYPES = {"lidar": "sensor_msgs/msg/PointCloud2", "radar": "sensor_msgs/msg/PointCloud2", "mru": "sensor_msgs/msg/Imu",
            "feeder_mru": "sensor_msgs/msg/Imu", "encoders": "sensor_msgs/msg/JointState", "truth": "std_msgs/msg/Float64MultiArray", "meta": "std_msgs/msg/String"}


class _Messages:
    """Builds the messages of one typestore (ROS 1 headers carry a `seq`)."""

    def __init__(self, typestore, ros1: bool) -> None:
        self.T, self.ros1 = typestore.types, ros1
        self.serialize = typestore.serialize_ros1 if ros1 else typestore.serialize_cdr

    def header(self, t_s: float, frame_id: str):
        ns = int(round(t_s * 1e9))
        stamp = self.T["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        if self.ros1:
            return self.T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame_id)
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def cloud(self, t_s: float, sensor: str, points: np.ndarray, fields: dict[str, np.ndarray]):
        spec, data, step = encode_cloud(points, fields)
        PF = self.T["sensor_msgs/msg/PointField"]
        return self.T["sensor_msgs/msg/PointCloud2"](
            header=self.header(t_s, sensor), height=1, width=len(points),
            fields=[PF(name=n, offset=o, datatype=d, count=c) for n, o, d, c in spec],
            is_bigendian=False, point_step=step, row_step=step * len(points),
            data=np.frombuffer(data, dtype=np.uint8), is_dense=bool(np.isfinite(points).all()))

    def imu(self, t_s: float, quat: np.ndarray, omega: np.ndarray):
        Q, V = self.T["geometry_msgs/msg/Quaternion"], self.T["geometry_msgs/msg/Vector3"]
        unknown = np.zeros(9)
        unknown[0] = -1.0  # REP 145: no estimate of the linear acceleration
        return self.T["sensor_msgs/msg/Imu"](
            header=self.header(t_s, "crane"), orientation=Q(x=quat[0], y=quat[1], z=quat[2], w=quat[3]),
            orientation_covariance=np.zeros(9), angular_velocity=V(x=omega[0], y=omega[1], z=omega[2]),
            angular_velocity_covariance=np.zeros(9), linear_acceleration=V(x=0.0, y=0.0, z=0.0),
            linear_acceleration_covariance=unknown)

    def joints(self, t_s: float, position: np.ndarray):
        return self.T["sensor_msgs/msg/JointState"](header=self.header(t_s, "crane"), name=["slew", "luff", "hoist"],
                                                    position=position, velocity=np.zeros(0), effort=np.zeros(0))

    def row(self, label: str, values: np.ndarray):
        L, D = self.T["std_msgs/msg/MultiArrayLayout"], self.T["std_msgs/msg/MultiArrayDimension"]
        return self.T["std_msgs/msg/Float64MultiArray"](
            layout=L(dim=[D(label=label, size=len(values), stride=len(values))], data_offset=0), data=values)

    def text(self, s: str):
        return self.T["std_msgs/msg/String"](data=s)


def write_bag(source: FrameSource, out: Path, kind: str = "mcap", force: bool = False,
              progress: Callable[[int], None] | None = None, inputs: tuple[Path | None, ...] = ()) -> dict:
    """Every frame, stream and the truth of a source into OUT, atomically: a ROS 2 bag folder
    (mcap or sqlite3 storage) or a folder holding OUT.bag (ROS 1)."""
    from rosbags.typesys import Stores, get_typestore

    if kind not in KINDS:
        raise ValueError(f"bag kind {kind!r}: expected one of {', '.join(KINDS)}")
    ros1 = kind == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    msgs = _Messages(store, ros1)
    counts = {"lidar": 0, "radar": 0}
    with output_folder(out, force, inputs) as staging:
        stem = out.stem if out.suffix.lower() in (".mcap", ".bag", ".db3") else out.name  # --out x.mcap: x.mcap/x.mcap
        bag_path = staging / (f"{stem}.bag" if ros1 else stem)
        if ros1:
            from rosbags.rosbag1 import Writer
            writer = Writer(bag_path)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer
            writer = Writer(bag_path, version=9,
                            storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3)
        with writer:
            inst = source.meta.installation
            present = {"lidar": inst.lidar.enabled, "radar": inst.radar.enabled, "encoders": source.encoders is not None,
                       "truth": source.truth is not None, "feeder_mru": source.feeder_mru is not None}
            conn = {r: writer.add_connection(TOPICS[r], MSGTYPES[r], typestore=store) for r in TOPICS
                    if present.get(r, True)}

            def put(role: str, t_s: float, msg) -> None:
                writer.write(conn[role], int(round(t_s * 1e9)), msgs.serialize(msg, MSGTYPES[role]))

            t0 = source.meta.t_start_s
            # The streams go in first: a reader sorts by time anyway, and a bag's streams are
            # small beside its clouds.
            for role, m in (("mru", source.mru), ("feeder_mru", source.feeder_mru)):
                if m is None:
                    continue
                quat, omega = imu_from_mru(m.rpy_rad, m.rpy_rate_radps)
                for k in range(len(m.t_s)):
                    put(role, float(m.t_s[k]), msgs.imu(float(m.t_s[k]), quat[k], omega[k]))
            if source.encoders is not None:
                e = source.encoders
                pos = np.column_stack([e["slew"], e["luff"], e["hoist"]])
                for k in range(len(e["t"])):
                    put("encoders", float(e["t"][k]), msgs.joints(float(e["t"][k]), pos[k]))
            if source.truth is not None:
                cols = list(source.truth.columns)
                table = np.column_stack([source.truth.columns[c] for c in cols])
                label = ",".join(cols)
                for k in range(len(table)):
                    put("truth", float(table[k, 0]), msgs.row(label, table[k]))
            for frame in source:
                put(frame.sensor, frame.t_s, msgs.cloud(frame.t_s, frame.sensor, frame.points_sensor, frame.fields))
                counts[frame.sensor] += 1
                if progress:
                    progress(1)
            meta = meta_to_json(source.meta, counts)
            put("meta", t0, msgs.text(json_text(meta)))
        if not ros1:  # the ROS 2 writer made a folder of its own: its files become OUT's
            for p in bag_path.iterdir():
                p.rename(staging / p.name)
            bag_path.rmdir()
    return meta
