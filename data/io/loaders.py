"""One loader per format behind one interface, found by a registry (kiss-icp's `datasets/`
model): a guess from the path, `--format` to force one, and a selection of the frames
(`--start`, `--duration`, `--every`)."""

from __future__ import annotations

import math

from dataclasses import replace
from pathlib import Path
from typing import Callable, Iterator

from boomtip.data.frames import Frame, FrameSource, MruLog, Truth
from boomtip.data.installation import Installation
from boomtip.data.io.recording import RecordingError


def _boomtip(path: Path, installation: Installation | None, options: dict) -> FrameSource:
    from boomtip.data.io.recording import Recording

    rec = Recording(path, options.get("strict", False))
    if installation is not None:  # the user's survey replaces the recording's own
        rec.meta.installation = installation
    return rec


def _needs(path: Path, installation: Installation | None, what: str) -> Installation:
    if installation is None:
        raise RecordingError(f"{path}: {what} carries no installation; pass --installation FILE.yaml "
                             "(`boomtip installation --template` prints one)")
    return installation


def _folder(path: Path, installation: Installation | None, options: dict) -> FrameSource:
    from boomtip.data.io.folder import FolderSource

    return FolderSource(path, _needs(path, installation, "a folder of clouds"), strict=options.get("strict", False))


def _ouster(path: Path, installation: Installation | None, options: dict) -> FrameSource:
    from boomtip.data.io.ouster import OusterPcapSource

    return OusterPcapSource(path, _needs(path, installation, "an Ouster pcap"), options.get("meta"), options.get("strict", False))


def _ros(path: Path, installation: Installation | None, options: dict) -> FrameSource:
    from boomtip.data.io.rosbag import RosBagSource

    return RosBagSource(path, installation, options.get("topics"), options.get("strict", False))


# ROS 1 bags, ROS 2 bags and MCAP files share one reader (rosbags); the names say what the user has.
LOADERS: dict[str, Callable[[Path, Installation | None, dict], FrameSource]] = {
    "boomtip": _boomtip, "folder": _folder, "ouster": _ouster, "ros1": _ros, "ros2": _ros, "mcap": _ros}
SUFFIXES = {".pcap": "ouster", ".bag": "ros1", ".mcap": "mcap", ".db3": "ros2"}


def guess_format(path: Path) -> str:
    if (path / "meta.json").is_file():
        return "boomtip"
    if path.is_dir():
        from boomtip.data.io.folder import cloud_files

        if (path / "metadata.yaml").is_file():
            return "ros2"
        if cloud_files(path):
            return "folder"
        inner = [p for p in path.iterdir() if p.suffix.lower() in SUFFIXES]
        if len(inner) == 1:
            return SUFFIXES[inner[0].suffix.lower()]
        raise RecordingError(f"{path}: neither a boomtip recording (meta.json), a ROS 2 bag (metadata.yaml), a folder "
                             "of .pcd/.ply/.bin files, nor a folder holding one .bag, .mcap or .pcap")
    if not path.exists():
        raise RecordingError(f"{path}: no such recording")
    if path.suffix.lower() in SUFFIXES:
        return SUFFIXES[path.suffix.lower()]
    raise RecordingError(f"{path}: a single {path.suffix or 'extensionless'} file; formats read: a boomtip recording, "
                         "a folder of .pcd/.ply/.bin, an Ouster .pcap, a ROS .bag, a ROS 2 bag folder, an .mcap")


def _inner_file(path: Path, kind: str) -> Path:
    """A folder holding just one bag/pcap (as `simulate --format ros1` writes) reads as that file."""
    if path.is_dir() and kind in ("ros1", "ouster", "mcap") and not (path / "metadata.yaml").is_file():
        inner = [p for p in path.iterdir() if SUFFIXES.get(p.suffix.lower()) == kind]
        if len(inner) == 1:
            return inner[0]
    return path


def parse_topics(items: list[str] | None) -> dict[str, str]:
    topics: dict[str, str] = {}
    for item in items or []:
        role, sep, name = item.partition("=")
        role, name = role.strip(), name.strip()
        if not sep or not role or not name:
            raise RecordingError(f"--topic {item!r}: expected ROLE=NAME, e.g. --topic lidar=/os_cloud_node/points")
        if role in topics:
            raise RecordingError(f"--topic {item!r}: the {role} is already --topic {role}={topics[role]}; give each role once")
        other = next((r for r, n in topics.items() if n == name and name.lower() != "none"), None)
        if other is not None:
            raise RecordingError(f"--topic {item!r}: {name} is already the {other}; one topic fills one role")
        topics[role] = name
    return topics


def open_source(path: str | Path, format: str | None = None, installation: Installation | None = None,
                start_s: float | None = None, duration_s: float | None = None, every: int = 1,
                topics: dict[str, str] | None = None, meta: Path | None = None, strict: bool = False) -> FrameSource:
    """The frame source for a path (`format`, else guessed from it). strict: a bad sample in a
    stream refuses the source; else it is dropped and counted in the source's notes."""
    path = Path(path)
    kind = format or guess_format(path)
    if kind not in LOADERS:
        raise RecordingError(f"--format {kind!r}: expected one of {', '.join(LOADERS)}")
    if topics and LOADERS[kind] is not _ros:
        raise RecordingError(f"--topic: the {kind} loader has no topics (only ros1, ros2, mcap)")
    source = Rebased(LOADERS[kind](_inner_file(path, kind), installation, {"topics": topics or {}, "meta": meta,
                                                                            "strict": strict}))
    if start_s is not None or duration_s is not None or every != 1:
        source = Selection(source, start_s or 0.0, duration_s, every)
    return source


class Rebased(FrameSource):
    """A source on one time base: t = 0 at its first stamp, whatever its clock (a folder's file
    names, an Ouster sensor's clock, a bag's epoch seconds); the clock's value there is kept as
    `meta.t_origin_s`. The frames and every stream are shifted alike; a source already starting
    at 0 passes unchanged."""

    def __new__(cls, source: FrameSource):
        if source.meta.t_start_s == 0.0:
            return source
        return super().__new__(cls)

    def __init__(self, source: FrameSource) -> None:
        t0 = self.origin_s = source.meta.t_start_s
        self.source = source
        self.meta = replace(source.meta, t_start_s=0.0, t_origin_s=source.meta.t_origin_s + t0)
        self.mru = _shifted_log(source.mru, t0)
        self.feeder_mru = _shifted_log(source.feeder_mru, t0)
        self.encoders = None if source.encoders is None else {**source.encoders, "t": source.encoders["t"] - t0}
        self.truth = None if source.truth is None else Truth({**source.truth.columns, "t": source.truth.t_s - t0})

    def __len__(self) -> int:
        return len(self.source)

    def __getattr__(self, name: str):  # what a loader says of itself (a bag's topics) passes through
        if name == "source":  # not set yet: no recursion
            raise AttributeError(name)
        return getattr(self.source, name)

    def __iter__(self) -> Iterator[Frame]:
        for frame in self.source:
            yield replace(frame, t_s=frame.t_s - self.origin_s)


def _shifted_log(log: MruLog | None, t0_s: float) -> MruLog | None:
    return None if log is None else replace(log, t_s=log.t_s - t0_s)


class Selection(FrameSource):
    """A part of a source: frames from `start_s` for `duration_s`, every `every`-th of each
    sensor (like kiss-icp's --jump and --n-scans); the streams pass through."""

    def __init__(self, source: FrameSource, start_s: float, duration_s: float | None, every: int) -> None:
        # `not (x >= 0)`: NaN compares false, so a NaN start or duration is refused too
        if every < 1 or not (0 <= start_s < math.inf) or (duration_s is not None and not (0 < duration_s < math.inf)):
            raise RecordingError(f"--start {start_s}, --duration {duration_s}, --every {every}: expected a finite "
                                 "start >= 0, a finite duration > 0 and every >= 1")
        t0 = source.meta.t_start_s
        self.source, self.every = source, every
        self.start_s = t0 + start_s  # --start counts from the source's first time stamp
        self.end_s = self.start_s + duration_s if duration_s is not None else float("inf")
        src_end = t0 + source.duration_s
        self.meta = replace(source.meta, t_start_s=self.start_s, duration_s=max(min(self.end_s, src_end) - self.start_s, 0.0))
        self.mru, self.truth, self.encoders = source.mru, source.truth, source.encoders
        self.feeder_mru = source.feeder_mru
        share = self.meta.duration_s / max(source.duration_s, 1e-9)
        self._len = max(1, int(len(source) * share) // every)

    def __len__(self) -> int:
        return self._len

    def __iter__(self) -> Iterator[Frame]:
        seen = {"lidar": 0, "radar": 0}
        for frame in self.source:
            if frame.t_s < self.start_s:
                continue
            if frame.t_s >= self.end_s:
                if frame.t_s >= self.end_s + 1.0:  # a bag's frames come in receive order: a lagging one may follow
                    break
                continue
            k = seen[frame.sensor]
            seen[frame.sensor] += 1
            if k % self.every == 0:
                yield frame
