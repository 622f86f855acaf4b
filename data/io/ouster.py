"""Ouster pcap + sensor-metadata JSON as a frame source, through ouster-sdk.

ouster-sdk does the packet parsing, frame batching and beam geometry (its `XYZLut` from the
metadata's beam angles and lidar-to-sensor transform); this module only maps its frames to
boomtip's: points in the sensor frame (m, zero ranges dropped), `intensity` from the
reflectivity channel, a per-point `t` (s from the frame start) from the column time stamps.
Frame times are the sensor's column clock (PTP-synchronised on a real rig, so an `mru.csv`
beside the pcap shares it); a frame whose column stamps are all zero falls back to the pcap's
capture time and says so. Frames are decoded one at a time as they are iterated.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from boomtip.data.frames import Frame, FrameSource, SourceMeta
from boomtip.data.installation import Installation
from boomtip.data.io.folder import attitude_stream
from boomtip.data.io.recording import RecordingError


def metadata_for(pcap: Path, meta: Path | None = None) -> Path:
    """The sensor-metadata JSON: given, or beside the pcap with the same stem, or the only
    JSON in the pcap's folder whose name starts like the pcap's."""
    if meta is not None:
        if not meta.is_file():
            raise RecordingError(f"{meta}: no such sensor-metadata file")
        return meta
    same = pcap.with_suffix(".json")
    if same.is_file():
        return same
    stem = pcap.stem.split("_")[0]
    near = sorted(p for p in pcap.parent.glob("*.json") if p.name.startswith(stem))
    if len(near) == 1:
        return near[0]
    listed = ", ".join(p.name for p in near) or "none"
    raise RecordingError(f"{pcap}: needs the sensor's metadata JSON ({same.name} beside it, or --meta FILE); "
                         f"candidates found: {listed}")


def _ouster():
    try:
        from ouster.sdk import core, open_source
    except ImportError as exc:  # the [ouster] extra is not installed
        raise RecordingError(f"reading an Ouster pcap needs ouster-sdk (pip install 'boomtip[ouster]'): {exc}") from None
    return core, open_source


class OusterPcapSource(FrameSource):
    def __init__(self, pcap: str | Path, installation: Installation, meta: Path | None = None) -> None:
        self.pcap = Path(pcap)
        if not self.pcap.is_file():
            raise RecordingError(f"{self.pcap}: no such pcap")
        if not installation.lidar.enabled:
            raise RecordingError(f"installation.lidar.enabled is false, but {self.pcap} holds LiDAR frames")
        self.meta_json = metadata_for(self.pcap, meta)
        self.meta: SourceMeta | None = None
        self._said_capture, self._use_capture, self._capture_to_sensor_s = False, False, 0.0
        core, _ = _ouster()
        src = self._open()
        try:
            self.info = src.sensor_info[0]
            # the index is a C++ pass over the packet headers: the frame count and capture times
            # without decoding a frame
            index = np.asarray(src.individual_index[0], dtype=np.float64)
        finally:
            src.close()
        self.period_s = 1.0 / float(self.info.format.fps or installation.lidar.rate_hz)
        self._xyz = core.XYZLut(self.info)
        self._capture_s = index[:, 0] * 1e-6 if len(index) else np.zeros(0)
        if len(self._capture_s) == 0:
            raise RecordingError(f"{self.pcap}: no LiDAR frame for the sensor in {self.meta_json.name}")
        first = next(iter(self._frames(limit=1)))
        if first.error is not None:
            raise RecordingError(f"{first.error}; is {self.meta_json.name} this capture's metadata?")
        self.t_start_s = first.t_s
        self._capture_to_sensor_s = 0.0 if self._use_capture else self.t_start_s - float(self._capture_s[0])
        installation = installation.model_copy(update={"radar": installation.radar.model_copy(update={"enabled": False})})
        duration = float(self._capture_s[-1] - self._capture_s[0]) + self.period_s
        self.meta = SourceMeta(installation=installation, duration_s=duration, name=self.pcap.stem,
                               t_start_s=self.t_start_s)
        if self._use_capture:
            self._said_capture = True
            self.meta.notes.append(f"{self.pcap.name}: the first frame has no column time stamps; every frame is "
                                   "timed by the pcap's capture clock")
        self.mru = attitude_stream(self.pcap.parent, installation, self.t_start_s, self.t_start_s + duration)
        self.truth = None

    def _open(self):
        _, open_source = _ouster()
        try:
            return open_source(str(self.pcap), meta=[str(self.meta_json)], sensor_idx=0, index=True)
        except Exception as exc:  # ouster-sdk wraps every parse failure in its own exception types
            raise RecordingError(f"{self.pcap} with {self.meta_json.name}: ouster-sdk cannot read it: {exc}") from None

    def __len__(self) -> int:
        return len(self._capture_s)

    def __iter__(self) -> Iterator[Frame]:
        return self._frames()

    def _frames(self, limit: int | None = None) -> Iterator[Frame]:
        core, _ = _ouster()
        src = self._open()
        i = 0
        try:
            it = iter(src)
            while limit is None or i < limit:
                try:
                    frame_set = next(it)
                except StopIteration:
                    return
                except Exception as exc:  # a truncated or corrupt packet stream: the run keeps what it read
                    yield Frame("lidar", i, self._time_of(i, None), np.zeros((0, 3)), {}, path=str(self.pcap),
                                error=f"{self.pcap}: frame {i}: ouster-sdk stopped reading: {exc}")
                    return
                for scan in frame_set.valid_frames():
                    yield self._frame(core, scan, i)
                    i += 1
        finally:
            src.close()

    def _time_of(self, i: int, column_ns: np.ndarray | None) -> float:
        """The sensor's column clock; a frame without column stamps (or every frame, when the
        first has none) takes the pcap's capture time, shifted onto the column clock."""
        if not self._use_capture and column_ns is not None and np.any(column_ns > 0):
            return float(column_ns[column_ns > 0].min()) * 1e-9
        if self.meta is None and i == 0:
            self._use_capture = True  # decided on the first frame, so the whole run keeps one clock
        if self.meta is not None and not self._said_capture:
            self._said_capture = True
            self.meta.notes.append(f"{self.pcap.name}: frames without column time stamps are timed by the pcap's "
                                   "capture clock")
        k = min(i, len(self._capture_s) - 1)
        return float(self._capture_s[k]) + (i - k) * self.period_s + self._capture_to_sensor_s

    def _frame(self, core, scan, i: int) -> Frame:
        column_ns = np.asarray(scan.timestamp, dtype=np.int64)
        t_s = self._time_of(i, column_ns)
        rng = scan.field(core.ChanField.RANGE)
        keep = np.flatnonzero(rng.ravel() > 0)  # no return: range 0
        # take() on indices, not a boolean mask: numpy's masked gather of (N, 3) rows is 4x slower
        points = self._xyz(rng).reshape(-1, 3).take(keep, axis=0)
        refl = scan.field(core.ChanField.REFLECTIVITY) if scan.has_field(core.ChanField.REFLECTIVITY) else np.zeros_like(rng)
        col_t = np.where(column_ns > 0, column_ns * 1e-9 - t_s, 0.0).astype(np.float32)
        t_point = np.broadcast_to(col_t[None, :], rng.shape).reshape(-1).take(keep)
        fields = {"intensity": refl.reshape(-1).take(keep).astype(np.float32), "t": t_point}
        valid_cols = int(np.count_nonzero(np.asarray(scan.status) & 1))
        if not scan.complete(self.info.format.column_window):
            # a capture cut mid-frame, lost packets, or metadata of another lidar mode
            return Frame("lidar", i, t_s, np.zeros((0, 3)), {}, path=str(self.pcap),
                         error=f"{self.pcap}: frame {i}: incomplete, {valid_cols} of {self.info.format.columns_per_frame} "
                               "columns (lost packets, a cut capture, or metadata of another lidar mode)")
        return Frame("lidar", i, t_s, points, fields, path=str(self.pcap))
