"""Ouster lidar packets decoded with numpy into the frames and points ouster-sdk 1.0 gives,
for the sensor an `OusterMetadata` (`ouster_metadata`) describes.

- `packet_layout`: a lidar packet of the metadata's `udp_profile_lidar` as one numpy
  structured dtype, so a frame's packets decode in a few array operations.
- `FrameBatcher`: packets into frames by frame id with the rules of ouster-sdk's
  FrameBatcher (a frame ends when all its packets are in, or when packets of the next frame
  pile up; late packets are dropped; a new init id restarts the count).
- `xyz_sensor_m`: ouster-sdk's `cartesian` on the table of `xyz_lut`, operation for
  operation in float64, so the points come out as the same floats.
- `index_capture`, `lidar_frames`: a pcap's frame starts from a pass over its packet
  headers, and its frames one at a time.

Images stay staggered (a column is a measurement id, i.e. one firing time), as ouster-sdk's
scan fields are and as its XYZ lookup table expects: `pixel_shift_by_row` only matters for
destaggered images, which nothing here makes.
"""

from __future__ import annotations

import struct
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, NamedTuple

import numpy as np

from boomtip.data.io.ouster_metadata import (LEGACY, PACKET_HEADER_BYTES, PIXEL_LAYOUTS, OusterMetadata,
                                             column_part_bytes, lidar_packet_bytes)
from boomtip.data.io.pcap import FILE_HEADER_BYTES, PcapError, pcap_header, udp_headers, udp_packets

COLUMN_VALID = 0x1  # bit 0 of a column's status
FRAME_ID_MODULUS = 1 << 16  # frame ids are 16-bit and wrap
LEGACY_FRAME_ID_OFFSET = 10  # LEGACY's frame id: in the first column's header
PACKET_HEADER_PREFIX_BYTES = 12  # enough of a packet for its frame id, init id and serial number
# records are read one by one: a large buffer turns their reads into copies (2x faster than
# the default 8 KiB, which a record of one lidar packet outgrows)
READ_BUFFER_BYTES = 1 << 20
DEFAULT_UDP_PORT_LIDAR = 7502  # preferred when metadata without a port leaves a tie
# packets of a later frame held while the current one may still complete (ouster-sdk's cache)
MAX_HELD_PACKETS = 4


@dataclass(frozen=True, eq=False)
class PacketLayout:
    profile: str
    legacy: bool
    packet_bytes: int
    dtype: np.dtype  # one whole lidar packet: dtype["columns"] holds (columns_per_packet,) columns
    range_mask: int
    range_upshift: int
    first_measurement_id_offset: int  # of the first column's measurement id in the packet


def packet_layout(meta: OusterMetadata) -> PacketLayout:
    pixel = PIXEL_LAYOUTS[meta.udp_profile_lidar]
    legacy = meta.udp_profile_lidar == LEGACY
    range_word = "<u2" if pixel.range_bits <= 16 else "<u4"
    pixel_dtype = np.dtype({"names": ["range_word", "reflectivity"], "formats": [range_word, "u1"],
                            "offsets": [0, pixel.reflectivity_byte], "itemsize": pixel.pixel_bytes})
    header_bytes, _, footer_bytes = column_part_bytes(meta)
    column_bytes = header_bytes + meta.pixels_per_column * pixel.pixel_bytes + footer_bytes
    column_dtype = np.dtype({
        "names": ["timestamp_ns", "measurement_id", "status", "pixels"],
        "formats": ["<u8", "<u2", "<u4" if legacy else "<u2", (pixel_dtype, (meta.pixels_per_column,))],
        "offsets": [0, 8, column_bytes - footer_bytes if legacy else 10, header_bytes],
        "itemsize": column_bytes})
    packet_header = 0 if legacy else PACKET_HEADER_BYTES
    packet_bytes = lidar_packet_bytes(meta)
    dtype = np.dtype({"names": ["columns"], "formats": [(column_dtype, (meta.columns_per_packet,))],
                      "offsets": [packet_header], "itemsize": packet_bytes})
    return PacketLayout(meta.udp_profile_lidar, legacy, packet_bytes, dtype, (1 << pixel.range_bits) - 1,
                        pixel.range_upshift, packet_header + 8)


class PacketHeader(NamedTuple):
    frame_id: int
    init_id: int  # 0 in LEGACY packets
    prod_sn: int  # 0 in LEGACY packets


_HEADER = struct.Struct("<HHQ")  # packet type, frame id, then init id (24 bits) and serial number (40 bits)
_LEGACY_FRAME_ID = struct.Struct("<H")


def packet_header(layout: PacketLayout, payload) -> PacketHeader:
    """From a packet's first `PACKET_HEADER_PREFIX_BYTES`."""
    if layout.legacy:
        return PacketHeader(_LEGACY_FRAME_ID.unpack_from(payload, LEGACY_FRAME_ID_OFFSET)[0], 0, 0)
    _, frame_id, ids = _HEADER.unpack_from(payload)
    return PacketHeader(frame_id, ids & 0xFFFFFF, (ids >> 24) & 0xFF_FFFF_FFFF)


def same_sensor(meta: OusterMetadata, header: PacketHeader) -> bool:
    """ouster-sdk's packet check: the init id and serial number, where both sides know them."""
    return not ((meta.init_id and header.init_id and header.init_id != meta.init_id)
                or (meta.prod_sn and header.prod_sn and header.prod_sn != meta.prod_sn))


def frame_id_difference(current: int, other: int) -> int:
    """other - current on the wrapping 16-bit frame counter, in [-32768, 32767]."""
    return (other - current + FRAME_ID_MODULUS // 2) % FRAME_ID_MODULUS - FRAME_ID_MODULUS // 2


def lidar_packets_per_frame(meta: OusterMetadata) -> int:
    """The packets that carry the column window (ouster-sdk's DataFormat::lidar_packets_per_frame)."""
    first, last = meta.column_window
    first_packet, last_packet = first // meta.columns_per_packet, last // meta.columns_per_packet
    if first <= last:
        return last_packet - first_packet + 1
    packets = -(-meta.columns_per_frame // meta.columns_per_packet)
    return packets if first_packet == last_packet else packets - first_packet + 1 + last_packet


def column_window_complete(column_status: np.ndarray, column_window: tuple[int, int]) -> bool:
    valid = (column_status & COLUMN_VALID) != 0
    first, last = column_window
    if first <= last:
        return bool(valid[first: last + 1].all())
    return bool(valid[: last + 1].all() and valid[first:].all())


def decode_packets(layout: PacketLayout, columns_per_frame: int, packets: bytes
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A frame's packets (concatenated) to its staggered range (mm, uint32) and reflectivity
    (uint8) images, (pixels, columns), and its per-column time stamps (ns) and status. Only
    valid columns (status bit 0) within the frame are written; the rest stay 0."""
    columns = np.frombuffer(packets, layout.dtype)["columns"]  # (packets, columns_per_packet)
    measurement_id, status = columns["measurement_id"], columns["status"]
    packet_i, column_i = np.nonzero(((status & COLUMN_VALID) != 0) & (measurement_id < columns_per_frame))
    column = measurement_id[packet_i, column_i]
    pixels = columns["pixels"]  # (packets, columns_per_packet, pixels_per_column)
    h = pixels.shape[-1]
    # whole columns scattered as rows, then one transposing copy: 6x faster than scattering
    # columns into the (pixels, columns) image
    range_by_column = np.zeros((columns_per_frame, h), np.uint32)
    # field by field: numpy gathers a structured dtype element by element, 15x slower
    range_by_column[column] = pixels["range_word"][packet_i, column_i] & layout.range_mask
    if layout.range_upshift:
        range_by_column <<= layout.range_upshift
    reflectivity_by_column = np.zeros((columns_per_frame, h), np.uint8)
    reflectivity_by_column[column] = pixels["reflectivity"][packet_i, column_i]
    timestamp_ns = np.zeros(columns_per_frame, np.uint64)
    timestamp_ns[column] = columns["timestamp_ns"][packet_i, column_i]
    column_status = np.zeros(columns_per_frame, np.uint32)
    column_status[column] = status[packet_i, column_i]
    range_mm, reflectivity = np.ascontiguousarray(range_by_column.T), np.ascontiguousarray(reflectivity_by_column.T)
    return range_mm, reflectivity, timestamp_ns, column_status


@dataclass(eq=False)
class LidarScan:
    frame_id: int
    capture_time_s: float  # the pcap's time of its first packet
    range_mm: np.ndarray  # (pixels, columns) uint32, staggered; 0: no return
    reflectivity: np.ndarray  # (pixels, columns) uint8, staggered
    column_timestamp_ns: np.ndarray  # (columns,) uint64; 0 for a column not received
    column_status: np.ndarray  # (columns,) uint32; bit 0: valid
    complete: bool  # every column of the column window valid
    packets: int
    dropped: dict[str, int] = field(default_factory=dict)  # packets dropped while it was batched, by reason
    read_error: str | None = None  # why the capture could not be read past this frame


class FrameBatcher:
    """Lidar packets into frames by frame id, by ouster-sdk's FrameBatcher's rules: a frame is
    released once all of its packets are in; packets of a later frame are held meanwhile, and
    once `MAX_HELD_PACKETS` of them wait the frame is released as it is; packets of a
    released frame are dropped; a changed init id (the sensor restarted) releases the frame."""

    def __init__(self, meta: OusterMetadata, layout: PacketLayout) -> None:
        self.meta, self.layout = meta, layout
        self.expected_packets = lidar_packets_per_frame(meta)
        self._last_init_id = meta.init_id
        self._finished_id: int | None = None
        self._frame_id: int | None = None
        self._capture_time_s = 0.0
        self._payloads: list = []
        self._packet_ids: set[int] = set()
        self._held: list[tuple[int, object, float]] = []
        self._dropped: Counter = Counter()

    def drop(self, reason: str) -> None:
        """Count a packet dropped before batching (wrong size, another sensor's)."""
        self._dropped[reason] += 1

    def add(self, header: PacketHeader, payload, capture_time_s: float) -> list[LidarScan]:
        """Batch one lidar packet; the frames it releases (usually none, or one)."""
        done: list[LidarScan] = []
        if not self.layout.legacy and header.init_id != self._last_init_id:
            self._last_init_id = header.init_id  # its frame ids start over
            if self._frame_id is not None:
                done.append(self._release())
            self._finished_id, self._held = None, []
        self._batch(header.frame_id, payload, capture_time_s, done)
        return done

    def finish(self, read_error: str | None = None) -> list[LidarScan]:
        """The frame in progress at the end of the capture (packets held for a later frame
        are dropped, as ouster-sdk does)."""
        if self._frame_id is None:
            return []
        scan = self._release()
        scan.read_error = read_error
        return [scan]

    def _batch(self, frame_id: int, payload, capture_time_s: float, done: list[LidarScan]) -> None:
        if self._finished_id is not None and frame_id_difference(self._finished_id, frame_id) <= 0:
            self._dropped["late, of a finished frame"] += 1
            return
        if self._frame_id is None:
            self._frame_id, self._capture_time_s, self._finished_id = frame_id, capture_time_s, None
        ahead = frame_id_difference(self._frame_id, frame_id)
        if ahead < 0:
            self._dropped["late, of an earlier frame"] += 1
        elif ahead > 0:
            self._held.append((frame_id, payload, capture_time_s))
            if len(self._held) >= MAX_HELD_PACKETS:
                done.append(self._release())
                self._replay(done)
        else:
            self._payloads.append(payload)
            first_column = struct.unpack_from("<H", payload, self.layout.first_measurement_id_offset)[0]
            packet_id = first_column // self.meta.columns_per_packet
            if packet_id < self.meta.columns_per_frame // self.meta.columns_per_packet:
                self._packet_ids.add(packet_id)
            if len(self._payloads) >= self.expected_packets and len(self._packet_ids) == self.expected_packets:
                done.append(self._release())
                self._replay(done)

    def _replay(self, done: list[LidarScan]) -> None:
        held, self._held = self._held, []
        held.sort(key=lambda p: frame_id_difference(self._finished_id, p[0]))  # the nearest frame first
        for frame_id, payload, capture_time_s in held:
            self._batch(frame_id, payload, capture_time_s, done)

    def _release(self) -> LidarScan:
        arrays = decode_packets(self.layout, self.meta.columns_per_frame, b"".join(self._payloads))
        scan = LidarScan(self._frame_id, self._capture_time_s, *arrays,
                         complete=column_window_complete(arrays[3], self.meta.column_window),
                         packets=len(self._payloads), dropped=dict(self._dropped))
        self._finished_id, self._frame_id = self._frame_id, None
        self._payloads, self._packet_ids, self._dropped = [], set(), Counter()
        return scan


def xyz_sensor_m(range_mm: np.ndarray, pixels: np.ndarray, direction_m: np.ndarray, offset_m: np.ndarray,
                 scratch_m: np.ndarray | None = None) -> np.ndarray:
    """Points (N, 3) in the sensor frame (m) of the given pixels (indices into the flattened
    staggered image) from the ranges (mm) and the lookup table; pass pixels with a return
    (nonzero range): ouster-sdk gives 0, 0, 0 for a zero range, this the beam origin.
    `scratch_m`, a (3, pixels) float64 buffer kept from frame to frame, lets the whole image be
    computed in place and then gathered, axis by axis on contiguous rows: 1.3x faster than
    gathering the table, and no fresh megabytes per frame."""
    points = np.empty((len(pixels), 3))
    if scratch_m is None:
        ranges = range_mm.take(pixels).astype(np.float64)
        for axis in range(3):
            component = direction_m[axis].take(pixels)
            component *= ranges
            component += offset_m[axis].take(pixels)
            points[:, axis] = component
        return points
    ranges = range_mm.astype(np.float64)
    for axis in range(3):
        np.multiply(ranges, direction_m[axis], out=scratch_m[axis])
        scratch_m[axis] += offset_m[axis]
        points[:, axis] = scratch_m[axis].take(pixels)
    return points


class CaptureIndex(NamedTuple):
    udp_port_lidar: int | None  # the metadata's, else the port with the most lidar-sized packets
    frame_capture_time_s: np.ndarray  # the pcap's time of each frame's first packet
    packet_sizes: dict[int, Counter]  # by destination port: payload sizes seen, to say why nothing matched
    read_error: str | None  # a cut or corrupt record that ended the pass


def index_capture(path: Path, meta: OusterMetadata, layout: PacketLayout) -> CaptureIndex:
    """The frame starts (a packet with a frame id after the previous one's, as ouster-sdk's
    index counts them), from a pass that reads only each packet's headers."""
    sizes: dict[int, Counter] = defaultdict(Counter)
    starts: dict[int, list[float]] = defaultdict(list)
    previous_frame_id: dict[int, int] = {}
    read_error = None
    with open(path, "rb", buffering=READ_BUFFER_BYTES) as fh:
        header = pcap_header(fh.read(FILE_HEADER_BYTES))
        try:
            for udp in udp_headers(fh, header, PACKET_HEADER_PREFIX_BYTES):
                port = udp.destination_port
                sizes[port][udp.payload_bytes] += 1
                if udp.payload_bytes != layout.packet_bytes or meta.udp_port_lidar not in (None, port):
                    continue
                packet = packet_header(layout, udp.payload_prefix)
                if not same_sensor(meta, packet):
                    continue
                before = previous_frame_id.get(port)
                if before is None or frame_id_difference(before, packet.frame_id) > 0:
                    starts[port].append(udp.capture_time_s)
                    previous_frame_id[port] = packet.frame_id
        except PcapError as exc:
            read_error = str(exc)
    port = meta.udp_port_lidar
    if port is None and starts:
        port = max(starts, key=lambda p: (sizes[p][layout.packet_bytes], p == DEFAULT_UDP_PORT_LIDAR, -p))
    return CaptureIndex(port, np.asarray(starts.get(port, []), dtype=np.float64), dict(sizes), read_error)


def lidar_frames(path: Path, meta: OusterMetadata, layout: PacketLayout, udp_port_lidar: int) -> Iterator[LidarScan]:
    """The capture's lidar frames, one at a time. A cut or corrupt record ends the frame in
    progress with its `read_error`; with no frame in progress the `PcapError` is raised."""
    batcher = FrameBatcher(meta, layout)
    wrong_size = f"not {layout.packet_bytes} bytes"
    with open(path, "rb", buffering=READ_BUFFER_BYTES) as fh:
        header = pcap_header(fh.read(FILE_HEADER_BYTES))
        try:
            for packet in udp_packets(fh, header):
                if packet.destination_port != udp_port_lidar:
                    continue
                if len(packet.payload) != layout.packet_bytes:
                    batcher.drop(wrong_size)
                    continue
                lidar_header = packet_header(layout, packet.payload)
                if not same_sensor(meta, lidar_header):
                    batcher.drop("another sensor's init id or serial number")
                    continue
                yield from batcher.add(lidar_header, packet.payload, packet.capture_time_s)
        except PcapError as exc:
            scans = batcher.finish(str(exc))
            if not scans:
                raise
            yield from scans
            return
    yield from batcher.finish()
