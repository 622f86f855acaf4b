"""ROS 1 bags, ROS 2 bags (sqlite3 or MCAP storage) and bare MCAP files as a frame source,
through rosbags (no ROS install).

Roles and their message types: `lidar` and `radar` are sensor_msgs/PointCloud2, `mru` is
sensor_msgs/Imu (orientation and body rates), `feeder_mru` too (an MRU on the feeder: guessed
only from an Imu topic whose name says "feeder"), `encoders` is sensor_msgs/JointState (joints
`slew`, `luff`, `hoist`), and boomtip's own bags add `truth` (std_msgs/Float64MultiArray, one
row per message, columns in the layout's label) and `meta` (std_msgs/String, the recording's
meta.json). Topics come from `--topic ROLE=NAME` or are guessed by message type; when two
topics could fill a role, the error lists them. The streams (Imu, JointState, truth) are
read in one pass up front, they are small; clouds are decoded one at a time as iterated.
Frame times are the header stamps; a bag whose stamps are zero falls back to the bag's
receive time, and the report says so.
"""

from __future__ import annotations

import heapq
import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Iterator

import numpy as np

from boomtip.data.frames import HOOK_TRUTH_COLUMNS, LIFT_TRUTH_COLUMNS, MRU_COLUMNS, TRUTH_COLUMNS, Frame, FrameSource, MruLog, SourceMeta, Truth
from boomtip.data.installation import Installation
from pydantic import ValidationError

from boomtip.data.io.folder import check_overlap
from boomtip.data.io.recording import ENCODER_BOUNDS, MRU_BOUNDS, MRU_STEPS, RecordingError
from boomtip.data.io.samples import drop_bad_samples
from boomtip.data.keys import format_validation, leaf_keys
from boomtip.data.io.ros_messages import RADAR_VELOCITY_FIELDS, CloudError, cloud_to_frame, decode_cloud, mru_from_imu

ROLES = {"lidar": "sensor_msgs/msg/PointCloud2", "radar": "sensor_msgs/msg/PointCloud2", "mru": "sensor_msgs/msg/Imu",
         "feeder_mru": "sensor_msgs/msg/Imu", "encoders": "sensor_msgs/msg/JointState", "truth": "std_msgs/msg/Float64MultiArray", "meta": "std_msgs/msg/String"}
JOINTS = ("slew", "luff", "hoist")
QUATERNION_NORM_TOLERANCE = 1e-2  # drivers round their quaternions; renormalised
REORDER_WINDOW_S = 0.5  # how late a bag's cloud message may arrive and still be put in its place
NO_TOPIC = "none"  # --topic ROLE=none: no topic fills that role, none is guessed for it


def _stamp_s(header) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def _cloud_fields(msg) -> list[tuple[str, int, int, int]]:
    return [(f.name, int(f.offset), int(f.datatype), int(f.count)) for f in msg.fields]


class RosBagSource(FrameSource):
    def __init__(self, path: str | Path, installation: Installation | None, topics: dict[str, str] | None = None,
                 strict: bool = False) -> None:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        self.strict = strict
        self._stream_notes: list[str] = []
        self._no_orientation: dict[str, str] = {}  # role -> its Imu topic, whose messages carry no orientation
        if not self.path.exists():
            raise RecordingError(f"{self.path}: no such bag")
        self._typestore = get_typestore(Stores.ROS2_HUMBLE)  # for ROS 2 bags that do not carry their definitions
        try:
            with AnyReader([self.path], default_typestore=self._typestore) as reader:
                self.topics = {c.topic: c.msgtype for c in reader.connections}
                counts = {c.topic: c.msgcount for c in reader.connections}
                self.role_topic = self._roles(topics or {})
                # a cloud topic that never carried a message (a writer's unused connection) is no sensor
                self.role_topic = {r: t for r, t in self.role_topic.items()
                                   if r not in ("lidar", "radar") or counts[t] > 0 or r in (topics or {})}
                self._bag_span_s = (reader.start_time * 1e-9, reader.end_time * 1e-9)
                streams, skipped = self._read_streams(reader)
        except RecordingError:
            raise
        except KeyError as exc:  # a channel whose schema encoding rosbags does not know (json, protobuf)
            raise RecordingError(f"{self.path}: a channel's schema encoding {exc} is not a ROS message definition; "
                                 "boomtip reads ROS 1 / ROS 2 (ros2msg, cdr) channels only") from None
        except Exception as exc:  # rosbags raises its own error types for every unreadable bag
            hint = {".bag": " (`rosbag reindex` may repair an unindexed ROS 1 bag)",
                    ".mcap": " (`mcap recover` may repair a truncated MCAP)"}.get(self.path.suffix.lower(), "")
            raise RecordingError(f"{self.path}: not a readable ROS bag or MCAP file: {type(exc).__name__}: {exc}{hint}") from None
        self._len = sum(counts[self.role_topic[r]] for r in ("lidar", "radar") if r in self.role_topic)
        own = streams.get("meta")
        notes = [f"{self.path.name}: {topic}: {n} message(s) could not be decoded and were skipped"
                 for topic, n in skipped.items()] + self._stream_notes
        if installation is None and own is None:
            raise RecordingError(f"{self.path}: the bag carries no installation; pass --installation FILE.yaml "
                                 "(`boomtip installation --template` prints one)")
        if installation is None:
            try:
                installation = Installation.model_validate(own["installation"])
            except ValidationError as exc:
                raise RecordingError(format_validation(exc, f"{self.path}: {self.role_topic['meta']}", "installation.",
                                                       keys=leaf_keys(Installation(), "installation"))) from None
        installation = self._enable_roles(installation)
        self.velocity_field = installation.radar.velocity_field
        self.velocity_sign = float(installation.radar.velocity_sign)
        self._stamp_clock = self._first_stamps()
        if not self._stamp_clock:
            notes.append(f"{self.path.name}: the cloud header stamps are zero; frames are timed by the bag's receive time")
        t0, t1 = self._span
        if "mru" in self._no_orientation and installation.attitude != "level":
            raise RecordingError(
                f"{self.path}: {self._no_orientation['mru']}: its Imu messages carry no orientation (an all-zero "
                "quaternion or orientation_covariance[0] = -1: a gyro-only Imu, REP 145); boomtip needs the boom tip's "
                "roll and pitch: name an Imu topic with orientation (--topic mru=NAME), or, for a boom tip that "
                "stays level, set `attitude: level` in the installation")
        for role, topic in self._no_orientation.items():
            notes.append(f"{self.path.name}: {topic}: its Imu messages carry no orientation (REP 145): not used as "
                         f"the {role}" + ("; the boom tip is taken as level (attitude: level)" if role == "mru" else ""))
        if "mru" in streams:
            self.mru = streams["mru"]
            check_overlap(self.mru, t0, t1, f"{self.path}: {self.role_topic['mru']}")
        elif installation.attitude == "level":
            self.mru = MruLog.level(t0, t1)
        else:
            raise RecordingError(f"{self.path}: no sensor_msgs/Imu topic for the attitude (topics: {self._listing()}); "
                                 "pass --topic mru=NAME, or set `attitude: level` in the installation file")
        self.feeder_mru = streams.get("feeder_mru")
        if self.feeder_mru is not None:
            check_overlap(self.feeder_mru, t0, t1, f"{self.path}: {self.role_topic['feeder_mru']}")
        self.encoders = streams.get("encoders")
        self.truth = streams.get("truth")
        processing = own.get("processing") if own else None
        processing = processing if isinstance(processing, dict) else {}
        prov = own.get("provenance") if own else None
        prov = prov.get("scenario") if isinstance(prov, dict) else None
        self.meta = SourceMeta(installation=installation, duration_s=max(t1 - t0, 0.0), processing=processing,
                               name=(own or {}).get("name", self.path.stem), provenance=prov, t_start_s=t0, notes=notes)

    # -- topics ------------------------------------------------------------------------------
    def _listing(self) -> str:
        return ", ".join(f"{t} ({m.split('/')[-1]})" for t, m in sorted(self.topics.items())) or "none"

    def _roles(self, given: dict[str, str]) -> dict[str, str]:
        roles: dict[str, str] = {}
        unused = {role for role, topic in given.items() if topic.strip().lower() == NO_TOPIC}
        for role, topic in given.items():
            if role not in ROLES:
                raise RecordingError(f"--topic {role}={topic}: unknown role; expected one of {', '.join(ROLES)}")
            if role in unused:
                continue
            if topic not in self.topics:
                raise RecordingError(f"--topic {role}={topic}: {self.path} has no such topic; topics: {self._listing()}")
            if self.topics[topic] != ROLES[role]:
                raise RecordingError(f"--topic {role}={topic}: a {self.topics[topic]}, expected {ROLES[role]}")
            roles[role] = topic
        for role, msgtype in ROLES.items():
            if role in roles or role in unused or role in ("lidar", "radar"):
                continue
            cands = [t for t, m in self.topics.items() if m == msgtype and t not in roles.values()]
            if role in ("mru", "feeder_mru"):  # the feeder's says so in its name; the crane's is the other
                cands = [t for t in cands if ("feeder" in t.lower()) == (role == "feeder_mru")]
            if role in ("truth", "meta"):
                cands = [t for t in cands if t.startswith("/boomtip/")]
            if len(cands) > 1:
                raise RecordingError(f"{self.path}: {len(cands)} {msgtype} topics could be the {role}: {', '.join(cands)}; "
                                     f"choose one with --topic {role}=NAME")
            if cands:
                roles[role] = cands[0]
        clouds = [t for t, m in self.topics.items() if m == ROLES["lidar"] and t not in roles.values()]
        free = [r for r in ("lidar", "radar") if r not in roles and r not in unused]
        if free and clouds:
            named = {r: [t for t in clouds if r in t.lower()] for r in free}
            for r in free:
                if len(named[r]) == 1:
                    roles[r] = named[r][0]
            left = [t for t in clouds if t not in roles.values()]
            free = [r for r in free if r not in roles]
            if len(left) == 1 and "lidar" in free and "lidar" not in unused:
                roles["lidar"] = left[0]  # one cloud topic whose name says nothing (beside a named radar): a LiDAR
            elif len(left) > 1 and free == ["lidar", "radar"]:
                raise RecordingError(f"{self.path}: cannot tell which PointCloud2 topic is the {' or '.join(free)}: "
                                     f"{', '.join(left)}; choose with --topic lidar=NAME --topic radar=NAME")
            # other cloud topics (a second LiDAR, a camera's depth cloud) are left unread
        if "lidar" not in roles and "radar" not in roles:
            raise RecordingError(f"{self.path}: no sensor_msgs/PointCloud2 topic; topics: {self._listing()}")
        return roles

    def _enable_roles(self, inst: Installation) -> Installation:
        for sensor in ("lidar", "radar"):
            spec = getattr(inst, sensor)
            if sensor not in self.role_topic and spec.enabled:
                inst = inst.model_copy(update={sensor: spec.model_copy(update={"enabled": False})})
            elif sensor in self.role_topic and not spec.enabled:
                raise RecordingError(f"installation.{sensor}.enabled is false, but {self.path} has {sensor} frames on "
                                     f"{self.role_topic[sensor]}")
        return inst

    # -- streams -----------------------------------------------------------------------------
    def _read_streams(self, reader) -> tuple[dict, dict[str, int]]:
        """The small streams by role, and how many messages of each topic could not be decoded."""
        wanted = {self.role_topic[r]: r for r in ("mru", "feeder_mru", "encoders", "truth", "meta") if r in self.role_topic}
        if not wanted:
            return {}, {}
        rows: dict[str, list] = {r: [] for r in wanted.values()}
        conns = [c for c in reader.connections if c.topic in wanted]
        bad: dict[str, int] = {}
        for conn, t_ns, raw in reader.messages(connections=conns):
            role = wanted[conn.topic]
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception:  # one corrupt message of a stream: skipped and counted, the stream stays
                bad[conn.topic] = bad.get(conn.topic, 0) + 1
                continue
            if role == "meta":
                rows[role].append(msg.data)
            elif role == "truth":
                rows[role].append((msg.layout.dim[0].label if msg.layout.dim else "", np.asarray(msg.data, float)))
            elif role in ("mru", "feeder_mru"):
                q, w = msg.orientation, msg.angular_velocity
                cov0 = float(msg.orientation_covariance[0]) if len(msg.orientation_covariance) else 0.0
                rows[role].append((_stamp_s(msg.header) or t_ns * 1e-9, q.x, q.y, q.z, q.w, w.x, w.y, w.z, cov0))
            else:
                rows[role].append((_stamp_s(msg.header) or t_ns * 1e-9, list(msg.name), np.asarray(msg.position, float)))
        out: dict = {}
        for topic, role in wanted.items():
            if rows[role]:
                stream = getattr(self, f"_{role}")(rows[role], topic)
                if stream is None:  # an Imu without orientation
                    self._no_orientation[role] = topic
                else:
                    out[role] = stream
        return out, bad

    def _meta(self, rows: list[str], topic: str) -> dict:
        try:
            meta = json.loads(rows[0])
        except json.JSONDecodeError as exc:
            raise RecordingError(f"{self.path}: {topic}: not the JSON of a boomtip meta: {exc}") from None
        if not isinstance(meta, dict) or not isinstance(meta.get("installation"), dict):
            raise RecordingError(f"{self.path}: {topic}: expected a JSON object with an 'installation'")
        return meta

    def _feeder_mru(self, rows: list[tuple], topic: str) -> MruLog | None:
        return self._mru(rows, topic)

    def _screened(self, table: np.ndarray, names: list[str], topic: str, bounds: dict[str, float],
                  steps: dict[str, float] | None = None, why: dict[int, str] | None = None) -> np.ndarray:
        """A stream's good rows in time order: messages out of order are sorted (a bag interleaves
        publishers), a repeated stamp, a bad value or a glitch is dropped and counted (refused
        with --strict); see data/io/samples.py."""
        order = np.argsort(table[:, 0], kind="stable")
        position = np.empty_like(order)
        position[order] = np.arange(len(order))  # a message's row once sorted
        why = {int(position[k]): w for k, w in (why or {}).items()}
        return drop_bad_samples(table[order], names, f"{self.path}: {topic}", "message",
                                lambda k: f"stamped {table[order[k], 0]:.3f} s", self.strict,
                                self._stream_notes, "t", bounds, steps, why)

    def _mru(self, rows: list[tuple], topic: str) -> MruLog | None:
        """Roll, pitch, yaw and their rates from Imu messages; None when no message carries an
        orientation (REP 145: an all-zero quaternion, or orientation_covariance[0] = -1)."""
        a = np.array(rows, dtype=float)
        quat, no_orientation = a[:, 1:5], (a[:, 8] == -1.0) | np.all(a[:, 1:5] == 0.0, axis=1)
        if no_orientation.all():
            return None
        norm = np.linalg.norm(quat, axis=1)
        unit = np.isfinite(norm) & (np.abs(norm - 1.0) < QUATERNION_NORM_TOLERANCE)
        why = {int(k): "no orientation (REP 145)" if no_orientation[k] else
               f"orientation quaternion of norm {float(norm[k])!r} (expected 1)"
               for k in np.flatnonzero(no_orientation | ~unit)}
        quat = np.where(unit[:, None], quat / np.where(unit, norm, 1.0)[:, None], [0.0, 0.0, 0.0, 1.0])
        rpy, rates = mru_from_imu(quat, a[:, 5:8])
        table = np.column_stack([a[:, 0], rpy, rates])
        good = self._screened(table, list(MRU_COLUMNS), topic, MRU_BOUNDS, MRU_STEPS, why)
        return MruLog.from_columns({n: good[:, j] for j, n in enumerate(MRU_COLUMNS)})

    def _encoders(self, rows: list[tuple], topic: str) -> dict[str, np.ndarray]:
        """Joint positions by name in every message (several publishers may share the topic,
        each with its own joints); messages without the three joints are skipped."""
        t, pos = [], []
        for stamp, names, position in rows:
            if all(j in names for j in JOINTS):
                idx = [names.index(j) for j in JOINTS]
                if len(position) > max(idx):
                    t.append(stamp)
                    pos.append(position[idx])
        if not t:
            seen = sorted({n for r in rows for n in r[1]})
            raise RecordingError(f"{self.path}: {topic}: no message gives positions for the joints "
                                 f"{', '.join(JOINTS)} (joints seen: {', '.join(seen) or 'none'})")
        good = self._screened(np.column_stack([np.array(t, float), np.array(pos, float)]), ["t", *JOINTS], topic,
                              ENCODER_BOUNDS)
        if len(good) < 2:
            raise RecordingError(f"{self.path}: {topic}: {len(good)} usable encoder messages; at least 2 needed")
        return {"t": good[:, 0], **{j: good[:, i + 1] for i, j in enumerate(JOINTS)}}

    def _truth(self, rows: list[tuple], topic: str) -> Truth:
        names = tuple(rows[0][0].split(","))
        if names not in (TRUTH_COLUMNS, HOOK_TRUTH_COLUMNS, LIFT_TRUTH_COLUMNS):
            raise RecordingError(f"{self.path}: {topic}: truth columns {names[:4]}...: not boomtip's truth table")
        table = np.array([r[1] for r in rows if len(r[1]) == len(names)])
        if len(table) < 2:
            raise RecordingError(f"{self.path}: {topic}: fewer than 2 rows of {len(names)} truth columns")
        return Truth({k: table[:, i] for i, k in enumerate(names)})

    # -- frames ------------------------------------------------------------------------------
    def _cloud_messages(self, limit: int | None = None) -> Iterator[tuple[str, int, object]]:
        """(sensor, receive time ns, message); the message is the exception when it could not
        be decoded, so one corrupt message is one missing frame."""
        from rosbags.highlevel import AnyReader

        topic_role = {self.role_topic[r]: r for r in ("lidar", "radar") if r in self.role_topic}
        with AnyReader([self.path], default_typestore=self._typestore) as reader:
            conns = [c for c in reader.connections if c.topic in topic_role]
            for k, (conn, t_ns, raw) in enumerate(reader.messages(connections=conns)):
                if limit is not None and k >= limit:
                    return
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                    _stamp_s(msg.header), msg.data, msg.fields  # a schema of that name but other fields
                except Exception as exc:
                    msg = exc
                yield topic_role[conn.topic], t_ns, msg

    def _first_stamps(self) -> bool:
        """Whether the clouds carry header stamps: frames are then timed by them, else by the
        bag's receive time. The span starts at the first cloud (streams recorded before it
        do not count) and ends at the bag's end, on the clouds' clock."""
        try:
            first = [(t_ns, _stamp_s(msg.header)) for _, t_ns, msg in self._cloud_messages(limit=8)
                     if not isinstance(msg, Exception)]
        except Exception as exc:
            raise RecordingError(f"{self.path}: the cloud topics cannot be read: {type(exc).__name__}: {exc}") from None
        stamped = bool(first) and all(s > 0 for _, s in first)
        shift = (first[0][1] - first[0][0] * 1e-9) if stamped else 0.0
        start = (first[0][1] if stamped else first[0][0] * 1e-9) if first else self._bag_span_s[0]
        self._span = (start, max(start, self._bag_span_s[1] + shift))
        self._shift_s = shift
        return stamped

    def __len__(self) -> int:
        return self._len

    def __iter__(self) -> Iterator[Frame]:
        return in_stamp_order(self._frames_as_received())

    def _frames_as_received(self) -> Iterator[Frame]:
        index = {"lidar": 0, "radar": 0}
        for sensor, t_ns, msg in self._cloud_messages():
            i = index[sensor]
            index[sensor] += 1
            where = f"{self.path}: {self.role_topic[sensor]} message {i}"
            if isinstance(msg, Exception):
                yield Frame(sensor, i, t_ns * 1e-9 + self._shift_s, np.zeros((0, 3)), {}, path=where,
                            error=f"{where}: cannot be decoded as a PointCloud2: {type(msg).__name__}: {msg}")
                continue
            t_s = _stamp_s(msg.header) if self._stamp_clock else t_ns * 1e-9
            try:
                cloud = decode_cloud(_cloud_fields(msg), msg.data, int(msg.height), int(msg.width), int(msg.point_step),
                                     int(msg.row_step), bool(msg.is_bigendian))
                points, fields = cloud_to_frame(cloud, sensor, self.velocity_field, self.velocity_sign, t_s)
            except CloudError as exc:
                yield Frame(sensor, i, t_s, np.zeros((0, 3)), {}, path=where, error=f"{where}: {exc}")
                continue
            if sensor == "radar" and "range_rate" not in fields:
                yield Frame(sensor, i, t_s, np.zeros((0, 3)), {}, path=where,
                            error=f"{where}: no velocity field (tried {', '.join(RADAR_VELOCITY_FIELDS)}); set "
                                  "radar.velocity_field in the installation")
                continue
            yield Frame(sensor, i, t_s, points, fields, path=where)


def in_stamp_order(frames: Iterator[Frame], window_s: float = REORDER_WINDOW_S) -> Iterator[Frame]:
    """Each sensor's frames in time-stamp order: a bag holds messages in the order they were
    received, and a publisher (or a network) delivers some late. A frame waits until a frame of
    its sensor `window_s` newer has arrived; one of its sensor arriving later than that, or
    repeating its sensor's previous stamp, becomes a missing frame with that reason (a filter
    cannot go back in time). Sensors are not reordered against each other: one that lags the
    other as a whole (its latency) keeps every frame, and the fusion places it in time."""
    heaps: dict[str, list[tuple[float, int, Frame]]] = {}
    last_out: dict[str, float] = {}
    for order, frame in enumerate(frames):
        heap, last = heaps.setdefault(frame.sensor, []), last_out.get(frame.sensor, -math.inf)
        if frame.t_s < last:
            yield frame if frame.error else _missing(frame, f"stamped {last - frame.t_s:.3f} s before a {frame.sensor} "
                                                            f"frame already given (it arrived more than {window_s:g} s late)")
            continue
        heapq.heappush(heap, (frame.t_s, order, frame))
        while heap and heap[0][0] <= frame.t_s - window_s:
            yield from _emit(heapq.heappop(heap)[2], last_out)
    rest = sorted(item for heap in heaps.values() for item in heap)
    for _, _, frame in rest:
        yield from _emit(frame, last_out)


def _emit(frame: Frame, last_out: dict[str, float]) -> Iterator[Frame]:
    if frame.error is None and last_out.get(frame.sensor) == frame.t_s:
        yield _missing(frame, f"repeats the stamp {frame.t_s:.6f} s of the previous {frame.sensor} frame")
        return
    last_out[frame.sensor] = max(last_out.get(frame.sensor, -math.inf), frame.t_s)
    yield frame


def _missing(frame: Frame, why: str) -> Frame:
    return replace(frame, points_sensor=frame.points_sensor[:0], fields={}, error=f"{frame.path}: {why}")
