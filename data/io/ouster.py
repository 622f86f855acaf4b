"""Ouster pcap + sensor-metadata JSON as a frame source, decoded by boomtip itself.

`ouster_metadata` reads the sensor's metadata and builds ouster-sdk's XYZ lookup table from
its beam angles, beam origin and lidar-to-sensor transform; `ouster_packets` reads the
capture (libpcap, IPv4 fragments, UDP), batches the lidar packets into frames by frame id and
computes the points with that table, float for float; this module maps those frames to
boomtip's: points in the sensor frame (m, zero ranges dropped), `intensity` from the
reflectivity channel, a per-point `t` (s from the frame start) from the column time stamps.
Frame times are the sensor's column clock (PTP-synchronised on a real rig, so an `mru.csv`
beside the pcap shares it); a frame whose column stamps are all zero falls back to the pcap's
capture time and says so. Frames are decoded one at a time as they are iterated; the frame
count and capture times come from a pass over the packet headers.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterator

import numpy as np

from boomtip.data.frames import Frame, FrameSource, SourceMeta
from boomtip.data.installation import Installation
from boomtip.data.io.folder import attitude_stream
from boomtip.data.io.ouster_metadata import MetadataError, OusterMetadata, parse_metadata, xyz_lut
from boomtip.data.io.ouster_packets import (COLUMN_VALID, CaptureIndex, LidarScan, index_capture, lidar_frames,
                                            packet_layout, xyz_sensor_m)
from boomtip.data.io.pcap import PcapError
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


class OusterPcapSource(FrameSource):
    def __init__(self, pcap: str | Path, installation: Installation, meta: Path | None = None, strict: bool = False) -> None:
        self.pcap = Path(pcap)
        if not self.pcap.is_file():
            raise RecordingError(f"{self.pcap}: no such pcap")
        if not installation.lidar.enabled:
            raise RecordingError(f"installation.lidar.enabled is false, but {self.pcap} holds LiDAR frames")
        self.meta_json = metadata_for(self.pcap, meta)
        self.meta: SourceMeta | None = None
        self._said_capture, self._use_capture, self._capture_to_sensor_s = False, False, 0.0
        self.sensor = self._read_metadata()
        self._layout = packet_layout(self.sensor)
        index = self._index()
        self._port = index.udp_port_lidar
        self.period_s = 1.0 / float(self.sensor.fps or installation.lidar.rate_hz)
        self._direction_m, self._offset_m = xyz_lut(self.sensor)
        self._scratch_m = np.empty_like(self._direction_m)
        self._capture_s = index.frame_capture_time_s
        if len(self._capture_s) == 0:
            raise RecordingError(f"{self.pcap}: no LiDAR frame for the sensor in {self.meta_json.name}: "
                                 f"{self._what_was_seen(index)}")
        first = next(iter(self._frames(limit=1)))
        if first.error is not None:
            raise RecordingError(f"{first.error}; is {self.meta_json.name} this capture's metadata?")
        self.t_start_s = first.t_s
        self._capture_to_sensor_s = 0.0 if self._use_capture else self.t_start_s - float(self._capture_s[0])
        installation = installation.model_copy(update={"radar": installation.radar.model_copy(update={"enabled": False})})
        duration = float(self._capture_s[-1] - self._capture_s[0]) + self.period_s
        self.meta = SourceMeta(installation=installation, duration_s=duration, name=self.pcap.stem,
                               t_start_s=self.t_start_s)
        if index.read_error is not None:
            self.meta.notes.append(f"{self.pcap.name}: {index.read_error}; the frames before it are read")
        if self._use_capture:
            self._said_capture = True
            self.meta.notes.append(f"{self.pcap.name}: the first frame has no column time stamps; every frame is "
                                   "timed by the pcap's capture clock")
        self.mru = attitude_stream(self.pcap.parent, installation, self.t_start_s, self.t_start_s + duration, self.meta.notes,
                                   strict)
        self.truth = None

    def _read_metadata(self) -> OusterMetadata:
        try:
            doc = json.loads(self.meta_json.read_bytes())
        except OSError as exc:
            raise RecordingError(f"{self.meta_json}: cannot read it: {exc.strerror or exc}") from None
        except ValueError as exc:  # JSONDecodeError, or bytes that are no text
            raise RecordingError(f"{self.pcap} with {self.meta_json.name}: the metadata is not JSON ({exc}); "
                                 "expected the sensor-metadata JSON the sensor or ouster-sdk wrote") from None
        try:
            return parse_metadata(doc)
        except MetadataError as exc:
            raise RecordingError(f"{self.pcap} with {self.meta_json.name}: not Ouster sensor metadata: {exc}") from None

    def _index(self) -> CaptureIndex:
        try:
            return index_capture(self.pcap, self.sensor, self._layout)
        except PcapError as exc:
            raise RecordingError(f"{self.pcap}: not a readable pcap: {exc}") from None
        except OSError as exc:
            raise RecordingError(f"{self.pcap}: cannot read it: {exc.strerror or exc}") from None

    def _what_was_seen(self, index: CaptureIndex) -> str:
        """What the capture holds against what the metadata expects, for a capture with no frame."""
        port = "any port" if self.sensor.udp_port_lidar is None else f"port {self.sensor.udp_port_lidar}"
        expected = f"expected {self._layout.packet_bytes}-byte {self._layout.profile} packets on {port}"
        seen = "; ".join(f"port {p}: " + ", ".join(f"{n} x {size} bytes" for size, n in sizes.most_common(3))
                         for p, sizes in sorted(index.packet_sizes.items())) or "no UDP packets"
        cut = f"; the capture stops early: {index.read_error}" if index.read_error else ""
        return f"{expected}, the capture holds {seen}{cut}"

    @property
    def info(self):
        """ouster-sdk's SensorInfo of the same metadata, for comparisons against ouster-sdk
        (`bench io`); needs ouster-sdk, which reading the pcap does not."""
        try:
            from ouster.sdk import core
        except ImportError as exc:
            raise RecordingError(f"comparing with ouster-sdk needs it installed: {exc}") from None
        return core.SensorInfo(self.meta_json.read_text())

    def __len__(self) -> int:
        return len(self._capture_s)

    def __iter__(self) -> Iterator[Frame]:
        return self._frames()

    def _frames(self, limit: int | None = None) -> Iterator[Frame]:
        scans = lidar_frames(self.pcap, self.sensor, self._layout, self._port)
        i = 0
        try:
            while limit is None or i < limit:
                try:
                    scan = next(scans)
                except StopIteration:
                    return
                except PcapError:
                    return  # a cut or corrupt record between frames: the index pass noted it
                except OSError as exc:  # the file went away or the disk failed mid-run: the run keeps what it read
                    yield Frame("lidar", i, self._time_of(i, None), np.zeros((0, 3)), {}, path=str(self.pcap),
                                error=f"{self.pcap}: frame {i}: cannot read on: {exc.strerror or exc}")
                    return
                yield self._frame(scan, i)
                i += 1
        finally:
            scans.close()

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

    def _frame(self, scan: LidarScan, i: int) -> Frame:
        column_ns = scan.column_timestamp_ns.astype(np.int64)
        t_s = self._time_of(i, column_ns)
        if not scan.complete:
            # a capture cut mid-frame, lost packets, or metadata of another lidar mode
            valid_cols = int(np.count_nonzero(scan.column_status & COLUMN_VALID))
            why = scan.read_error or "lost packets, a cut capture, or metadata of another lidar mode"
            dropped = "".join(f"; {n} packets dropped: {reason}" for reason, n in scan.dropped.items())
            return Frame("lidar", i, t_s, np.zeros((0, 3)), {}, path=str(self.pcap),
                         error=f"{self.pcap}: frame {i}: incomplete, {valid_cols} of {self.sensor.columns_per_frame} "
                               f"columns ({why}{dropped})")
        rng = scan.range_mm.ravel()
        keep = np.flatnonzero(rng)  # no return: range 0
        points = xyz_sensor_m(rng, keep, self._direction_m, self._offset_m, self._scratch_m)
        col_t = np.where(column_ns > 0, column_ns * 1e-9 - t_s, 0.0).astype(np.float32)
        t_point = np.broadcast_to(col_t[None, :], scan.range_mm.shape).reshape(-1).take(keep)
        fields = {"intensity": scan.reflectivity.ravel().take(keep).astype(np.float32), "t": t_point}
        return Frame("lidar", i, t_s, points, fields, path=str(self.pcap))
