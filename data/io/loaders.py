"""One loader per format behind one interface, found by a registry (kiss-icp's `datasets/`
model): a guess from the path, `--format` to force one, and a selection of the frames
(`--start`, `--duration`, `--every`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Callable, Iterator

from boomtip.data.frames import Frame, FrameSource
from boomtip.data.installation import Installation
from boomtip.data.io.recording import RecordingError


def _boomtip(path: Path, installation: Installation | None) -> FrameSource:
    from boomtip.data.io.recording import Recording

    rec = Recording(path)
    if installation is not None:  # the user's survey replaces the recording's own
        rec.meta.installation = installation
    return rec


def _folder(path: Path, installation: Installation | None) -> FrameSource:
    from boomtip.data.io.folder import FolderSource

    if installation is None:
        raise RecordingError(f"{path}: a folder of clouds carries no installation; pass --installation FILE.yaml "
                             "(`boomtip installation --template` prints one)")
    return FolderSource(path, installation)


LOADERS: dict[str, Callable[[Path, Installation | None], FrameSource]] = {"boomtip": _boomtip, "folder": _folder}
PLANNED = {".pcap": "ouster", ".bag": "ros1", ".mcap": "mcap", ".db3": "ros2"}


def guess_format(path: Path) -> str:
    if (path / "meta.json").is_file():
        return "boomtip"
    if path.is_dir():
        from boomtip.data.io.folder import cloud_files

        if cloud_files(path):
            return "folder"
        raise RecordingError(f"{path}: neither a boomtip recording (meta.json) nor a folder of .pcd/.ply/.bin files")
    if path.suffix.lower() in PLANNED:
        raise RecordingError(f"{path}: the {PLANNED[path.suffix.lower()]} loader is not built yet; formats read: "
                             f"{', '.join(LOADERS)}")
    if not path.exists():
        raise RecordingError(f"{path}: no such recording")
    raise RecordingError(f"{path}: a single file; put it in a folder (the folder loader reads .pcd/.ply/.bin)")


def open_source(path: str | Path, format: str | None = None, installation: Installation | None = None,
                start_s: float | None = None, duration_s: float | None = None, every: int = 1) -> FrameSource:
    path = Path(path)
    kind = format or guess_format(path)
    if kind not in LOADERS:
        raise RecordingError(f"--format {kind!r}: expected one of {', '.join(LOADERS)}")
    source = LOADERS[kind](path, installation)
    if start_s is not None or duration_s is not None or every != 1:
        source = Selection(source, start_s or 0.0, duration_s, every)
    return source


class Selection(FrameSource):
    """A part of a source: frames from `start_s` for `duration_s`, every `every`-th of each
    sensor (like kiss-icp's --jump and --n-scans); the streams pass through."""

    def __init__(self, source: FrameSource, start_s: float, duration_s: float | None, every: int) -> None:
        if every < 1 or start_s < 0 or (duration_s is not None and duration_s <= 0):
            raise RecordingError(f"--start {start_s}, --duration {duration_s}, --every {every}: expected start >= 0, "
                                 "duration > 0 and every >= 1")
        t0 = source.meta.t_start_s
        self.source, self.every = source, every
        self.start_s = t0 + start_s  # --start counts from the source's first time stamp
        self.end_s = self.start_s + duration_s if duration_s is not None else float("inf")
        src_end = t0 + source.duration_s
        self.meta = replace(source.meta, t_start_s=self.start_s, duration_s=max(min(self.end_s, src_end) - self.start_s, 0.0))
        self.mru, self.truth, self.encoders = source.mru, source.truth, source.encoders
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
                break
            k = seen[frame.sensor]
            seen[frame.sensor] += 1
            if k % self.every == 0:
                yield frame
