"""A folder of point-cloud files (PCD, PLY, KITTI `.bin`) as a frame source.

Times come from a timestamps file (`times.txt` / `timestamps.txt`: one time in seconds per
line, in the files' sorted order) or from the file names: an integer is nanoseconds (as boomtip
names its own frames), a decimal number seconds. The attitude comes from an `mru.csv` beside
the files, or, with `attitude: level` in the installation, the boom-tip frame is taken as level.
Frames are read one at a time as they are iterated: a recording of gigabytes never sits in
memory.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Iterator

import numpy as np

from boomtip.data.frames import MRU_COLUMNS, Frame, FrameSource, MruLog, SourceMeta
from boomtip.data.installation import Installation
from boomtip.data.io.pcd import PcdError, read_pcd
from boomtip.data.io.recording import MRU_BOUNDS, MRU_STEPS, RecordingError, read_csv

SUFFIXES = (".pcd", ".ply", ".bin")
TIMES_FILES = ("times.txt", "timestamps.txt")
MAX_SHARED_STAMPS = 5  # frames sharing the time of the frame before: a few are missing frames, more refuse the folder
FRAME_NUMBER_DIGITS = 10  # an integer name this short is a frame number (as ns it would be under a second)
_NUMBER = re.compile(r"^[-+]?\d+(\.\d*)?([eE][-+]?\d+)?$")


def cloud_files(root: Path) -> list[Path]:
    return sorted(p for p in root.iterdir() if p.suffix.lower() in SUFFIXES and p.is_file())


def times_from_names(files: list[Path]) -> np.ndarray:
    out, integers = [], []
    for p in files:
        stem = p.stem
        if not _NUMBER.match(stem):
            raise RecordingError(f"{p}: the file name is not a time (integer ns or decimal seconds) and the folder "
                                 f"has no {' or '.join(TIMES_FILES)}")
        integers.append(stem.lstrip("+-").isdigit())
        out.append(int(stem) * 1e-9 if integers[-1] else float(stem))
    t = np.array(out, dtype=float)
    # 000000.bin, 000001.bin, ...: frame numbers, not nanoseconds (a sensor frame takes ms); so
    # are names of fewer than 10 digits (boomtip's own nanoseconds have 13)
    counted = len(t) > 1 and np.max(np.diff(np.sort(t))) < 1e-6
    short = max(len(p.stem.lstrip("+-")) for p in files) < FRAME_NUMBER_DIGITS
    if all(integers) and (counted or short):
        listed = ", ".join(p.name for p in files[:2]) + (", ..." if len(files) > 2 else "")
        raise RecordingError(f"{files[0].parent}: the file names count frames ({listed}), they are no times; "
                             f"give their times in a {TIMES_FILES[0]} (one time in seconds per file)")
    return t


def read_cloud(path: Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One file: PCD by our reader, KITTI .bin as float32 x y z intensity, PLY through Open3D."""
    suffix = path.suffix.lower()
    if suffix == ".pcd":
        return read_pcd(path)
    if suffix == ".bin":
        raw = np.fromfile(path, dtype=np.float32)
        if raw.size % 4:
            raise PcdError(f"{path}: {raw.size} floats; a KITTI .bin holds x y z intensity per point (a multiple of 4)")
        pts = raw.reshape(-1, 4)
        return pts[:, :3].astype(np.float64), {"intensity": pts[:, 3].copy()}
    import open3d as o3d

    pc = o3d.io.read_point_cloud(str(path))  # PLY: Open3D's legacy reader (a warning, not an error, on bad files)
    pts = np.asarray(pc.points, dtype=np.float64)
    if len(pts) == 0 and path.stat().st_size > 200:
        raise PcdError(f"{path}: Open3D read no points from this PLY")
    return pts, {}


def check_overlap(log: MruLog, t0_s: float, t1_s: float, where: str) -> None:
    """An attitude log that shares no time with the frames is another clock (a sensor's time
    since boot against the host's UTC, say): every frame would be missing its attitude."""
    if len(log.t_s) and (log.t_s[-1] < t0_s or log.t_s[0] > t1_s):
        raise RecordingError(f"{where}: the attitude spans {log.t_s[0]:.3f} to {log.t_s[-1]:.3f} s, the frames "
                             f"{t0_s:.3f} to {t1_s:.3f} s: no overlap, so the two are on different clocks")


def attitude_stream(root: Path, installation: Installation, t0_s: float, t1_s: float, notes: list[str] | None = None,
                    strict: bool = False) -> MruLog:
    """The MRU log of a recording without one of its own: an `mru.csv` beside the clouds (its bad
    samples dropped into `notes`, or refused when `strict`), or, with `attitude: level` in the
    installation, a level boom-tip frame over [t0, t1]."""
    path = root / "mru.csv"
    if path.is_file():
        log = MruLog.from_columns(read_csv(path, MRU_COLUMNS, bounds=MRU_BOUNDS, steps=MRU_STEPS, strict=strict, notes=notes))
        check_overlap(log, t0_s, t1_s, str(path))
        return log
    if installation.attitude != "level":
        raise RecordingError(f"{root}: no mru.csv; give one, or set `attitude: level` in the installation "
                             "file if the boom-tip frame is level (no attitude stream)")
    return MruLog.level(t0_s, t1_s)


class FolderSource(FrameSource):
    def __init__(self, root: str | Path, installation: Installation, sensor: str = "lidar", strict: bool = False) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise RecordingError(f"{self.root}: no such folder")
        self.files = cloud_files(self.root)
        if not self.files:
            raise RecordingError(f"{self.root}: no {', '.join(SUFFIXES)} files")
        times_file = next((self.root / n for n in TIMES_FILES if (self.root / n).is_file()), None)
        self.t_s = self._times_file(times_file) if times_file else times_from_names(self.files)
        order = np.argsort(self.t_s, kind="stable")
        self.files, self.t_s = [self.files[i] for i in order], self.t_s[order]
        self.sensor = sensor
        if not getattr(installation, sensor).enabled:
            raise RecordingError(f"installation.{sensor}.enabled is false, but {self.root} holds {sensor} frames")
        other = "radar" if sensor == "lidar" else "lidar"
        installation = installation.model_copy(update={other: getattr(installation, other).model_copy(update={"enabled": False})})
        duration = float(self.t_s[-1] - self.t_s[0]) + 1.0 / getattr(installation, sensor).rate_hz
        self.meta = SourceMeta(installation=installation, duration_s=duration, name=self.root.name,
                               t_start_s=float(self.t_s[0]))
        self.mru = attitude_stream(self.root, installation, float(self.t_s[0]), float(self.t_s[-1]), self.meta.notes, strict)
        self.truth = None
        # a frame sharing the time of the one before has no time of its own: a missing frame; many
        # such (a times.txt of zeros) are no recording's times at all
        self.shared = np.concatenate([[False], np.diff(self.t_s) == 0])
        shared = int(self.shared.sum())
        if shared > MAX_SHARED_STAMPS:
            raise RecordingError(f"{self.root}: {shared} of {len(self.files)} frames share their time stamp with the frame "
                                 f"before (first {self.files[int(np.argmax(self.shared))].name}); give each frame its own "
                                 f"time (file names or {TIMES_FILES[0]})")
        if shared:
            self.meta.notes.append(f"{self.root.name}: {shared} frame(s) share their time stamp with the frame before; "
                                   "each is a missing frame")

    def _times_file(self, path: Path) -> np.ndarray:
        rows = [ln.strip() for ln in path.read_text(encoding="utf-8", errors="replace").splitlines() if ln.strip()]
        if len(rows) != len(self.files):
            raise RecordingError(f"{path}: {len(rows)} times for {len(self.files)} cloud files; expected one per file")
        try:
            t = np.array([float(r.split()[0]) for r in rows])
        except ValueError:
            bad = next(i for i, r in enumerate(rows) if not _NUMBER.match(r.split()[0]))
            raise RecordingError(f"{path}: line {bad + 1}: {rows[bad]!r} is not a time in seconds") from None
        if not np.all(np.isfinite(t)):
            raise RecordingError(f"{path}: a time is not finite")
        return t

    def __len__(self) -> int:
        return len(self.files)

    def __iter__(self) -> Iterator[Frame]:
        for i, (path, t) in enumerate(zip(self.files, self.t_s)):
            if self.shared[i]:
                yield Frame(self.sensor, i, float(t), np.zeros((0, 3)), {}, path=str(path),
                            error=f"{path}: shares its time stamp {t:.6f} s with {self.files[i - 1].name}")
                continue
            try:
                points, fields = read_cloud(path)
            except PcdError as exc:
                yield Frame(self.sensor, i, float(t), np.zeros((0, 3)), {}, path=str(path), error=str(exc))
                continue
            yield Frame(self.sensor, i, float(t), points, fields, path=str(path))
