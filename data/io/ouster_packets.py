"""Ouster lidar packets decoded with numpy into the frames and points ouster-sdk 1.0 gives.

- `parse_metadata`: the sensor-metadata JSON, in the flat layout of firmware 2.0-2.3 or the
  nested one (`sensor_info`, `beam_intrinsics`, `lidar_data_format`, ...) of firmware 2.4+
  and 3.x; the flat keys go where ouster-sdk's `convert_legacy_to_nonlegacy` puts them.
- `packet_layout`: a lidar packet of the metadata's `udp_profile_lidar` as one numpy
  structured dtype, so a frame's packets decode in a few array operations.
- `FrameBatcher`: packets into frames by frame id with the rules of ouster-sdk's
  FrameBatcher (a frame ends when all its packets are in, or when packets of the next frame
  pile up; late packets are dropped; a new init id restarts the count).
- `xyz_lut`, `xyz_sensor_m`: ouster-sdk's `make_xyz_lut` and `cartesian`, operation for
  operation in float64, so the points come out as the same floats.
- `index_capture`, `lidar_frames`: a pcap's frame starts from a pass over its packet
  headers, and its frames one at a time.

Images stay staggered (a column is a measurement id, i.e. one firing time), as ouster-sdk's
scan fields are and as its XYZ lookup table expects: `pixel_shift_by_row` only matters for
destaggered images, which nothing here makes.
"""

from __future__ import annotations

import re
import struct
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, NamedTuple

import numpy as np

from boomtip.data.io.pcap import FILE_HEADER_BYTES, PcapError, pcap_header, udp_headers, udp_packets

RANGE_UNIT_M = 0.001  # ranges are counted in mm
COLUMN_VALID = 0x1  # bit 0 of a column's status
FRAME_ID_MODULUS = 1 << 16  # frame ids are 16-bit and wrap
LEGACY = "LEGACY"
PACKET_HEADER_BYTES = 32  # every profile but LEGACY: packet type, frame id, init id, serial number, ...
PACKET_FOOTER_BYTES = 32
COLUMN_HEADER_BYTES = 12  # time stamp (ns), measurement id, status
LEGACY_COLUMN_HEADER_BYTES = 16  # time stamp, measurement id, frame id, encoder count
LEGACY_COLUMN_FOOTER_BYTES = 4  # status, after the pixels
LEGACY_FRAME_ID_OFFSET = 10  # LEGACY's frame id: in the first column's header
PACKET_HEADER_PREFIX_BYTES = 12  # enough of a packet for its frame id, init id and serial number
# records are read one by one: a large buffer turns their reads into copies (2x faster than
# the default 8 KiB, which a record of one lidar packet outgrows)
READ_BUFFER_BYTES = 1 << 20
DEFAULT_UDP_PORT_LIDAR = 7502  # preferred when metadata without a port leaves a tie
# packets of a later frame held while the current one may still complete (ouster-sdk's cache)
MAX_HELD_PACKETS = 4
# ouster-sdk's beam-origin offsets for metadata that does not give one, by product line
DEFAULT_BEAM_ORIGIN_MM = {"OS-0-": 27.67, "OS-1-": 15.806, "OS-2-": 13.762}
GEN1_BEAM_ORIGIN_MM = 12.163
NESTED_SECTIONS = ("sensor_info", "beam_intrinsics", "lidar_intrinsics", "config_params", "lidar_data_format")
# where ouster-sdk moves the flat layout's keys (lidar_data_format is the flat data_format)
FLAT_KEYS = {"config_params": ("udp_port_lidar", "udp_port_imu", "lidar_mode"),
             "beam_intrinsics": ("lidar_origin_to_beam_origin_mm", "beam_altitude_angles", "beam_azimuth_angles",
                                 "beam_to_lidar_transform"),
             "lidar_intrinsics": ("lidar_to_sensor_transform",),
             "sensor_info": ("prod_line", "prod_sn", "initialization_id")}
MAX_UDP_PAYLOAD_BYTES = 65_507  # over IPv4
MAX_COLUMNS_PER_FRAME = 1 << 16  # a column's measurement id is 16-bit
LIDAR_MODE = re.compile(r"^(\d+)x(\d+)$")  # columns x frames per second, e.g. 1024x10


class MetadataError(ValueError):
    """Sensor metadata that lacks something the decoder needs, or asks for what it cannot do."""


@dataclass(frozen=True)
class PixelLayout:
    pixel_bytes: int
    range_bits: int
    range_upshift: int  # low-bandwidth profiles drop the range's low bits: mm = raw << upshift
    reflectivity_byte: int


# the first return of each profile (ouster-sdk's parsing.cpp field tables)
PIXEL_LAYOUTS = {
    LEGACY: PixelLayout(12, 20, 0, 4),
    "RNG19_RFL8_SIG16_NIR16": PixelLayout(12, 19, 0, 4),
    "RNG15_RFL8_NIR8": PixelLayout(4, 15, 3, 2),
    "RNG19_RFL8_SIG16_NIR16_DUAL": PixelLayout(16, 19, 0, 3),
    "RNG15_RFL8_NIR8_DUAL": PixelLayout(8, 15, 3, 2),
}


@dataclass(frozen=True, eq=False)
class OusterMetadata:
    prod_line: str
    prod_sn: int  # 0: unknown, not checked
    init_id: int  # 0: unknown, not checked
    udp_port_lidar: int | None  # None: not in the metadata, found from the capture
    udp_profile_lidar: str
    columns_per_frame: int
    pixels_per_column: int
    columns_per_packet: int
    column_window: tuple[int, int]  # first and last column the sensor sends, inclusive; may wrap
    fps: float | None
    beam_altitude_deg: np.ndarray  # (pixels_per_column,)
    beam_azimuth_deg: np.ndarray  # (pixels_per_column,)
    beam_to_lidar_transform_mm: np.ndarray  # (4, 4), translation in mm
    lidar_to_sensor_transform_mm: np.ndarray  # (4, 4), translation in mm


def _nested(doc: dict) -> tuple[dict, dict]:
    """The nested layout, and each section's name as the user's file spells it (for errors)."""
    if any(isinstance(doc.get(s), dict) for s in NESTED_SECTIONS):
        return doc, {s: s for s in NESTED_SECTIONS}
    nested: dict = {s: {} for s in NESTED_SECTIONS}
    for section, keys in FLAT_KEYS.items():
        nested[section].update({k: doc[k] for k in keys if k in doc})
    if isinstance(doc.get("data_format"), dict):
        nested["lidar_data_format"] = doc["data_format"]
    names = {s: "the top level" for s in NESTED_SECTIONS}
    names["lidar_data_format"] = "data_format"
    return nested, names


def parse_metadata(doc: dict) -> OusterMetadata:
    """The decoder's view of an Ouster sensor-metadata JSON (already loaded)."""
    if not isinstance(doc, dict):
        raise MetadataError(f"a JSON {type(doc).__name__}, expected an object")
    try:
        meta = _parse_metadata(*_nested(doc))
    except MetadataError:
        raise
    except (TypeError, ValueError, AttributeError, IndexError, KeyError) as exc:  # a value of an unexpected kind
        raise MetadataError(f"unexpected contents ({type(exc).__name__}: {exc})") from None
    if lidar_packet_bytes(meta) > MAX_UDP_PAYLOAD_BYTES:
        raise MetadataError(f"{meta.columns_per_packet} columns of {meta.pixels_per_column} pixels a packet: more "
                            "than a UDP datagram holds")
    return meta


def _parse_metadata(nested: dict, names: dict) -> OusterMetadata:
    def get(section: str, key: str, default=None, required: bool = False):
        value = nested.get(section, {}).get(key) if isinstance(nested.get(section), dict) else None
        if value is None and required:
            raise MetadataError(f"no {key} in {names[section]}")
        return default if value is None else value

    def numbers(section: str, key: str, count: int | None = None, required: bool = True) -> np.ndarray | None:
        value = get(section, key, required=required)
        if value is None:
            return None
        try:
            array = np.asarray(value, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise MetadataError(f"{key} in {names[section]}: expected numbers") from None
        if count is not None and array.size != count:
            raise MetadataError(f"{key} in {names[section]}: {array.size} values, expected {count}")
        return array

    def integer(section: str, key: str, default=None, required: bool = False) -> int | None:
        value = get(section, key, required=required)
        if value is None or value == "":  # firmware 2.x writes "" for a serial number it does not know
            return default
        try:
            return int(value)
        except (TypeError, ValueError):
            raise MetadataError(f"{key} in {names[section]}: {value!r}, expected an integer") from None

    prod_line = str(get("sensor_info", "prod_line", ""))
    mode = LIDAR_MODE.match(str(get("config_params", "lidar_mode", "")))
    altitude_deg = numbers("beam_intrinsics", "beam_altitude_angles")
    fmt = "lidar_data_format"
    if nested.get(fmt):
        w, h = integer(fmt, "columns_per_frame", required=True), integer(fmt, "pixels_per_column", required=True)
    elif mode:  # metadata older than firmware 2.0 has no data format: the mode and the beams tell it
        w, h = int(mode.group(1)), altitude_deg.size
    else:
        raise MetadataError(f"no {names[fmt]} (or lidar_mode) to tell the columns and pixels of a frame")
    cpp = integer(fmt, "columns_per_packet", 16)
    if min(w, h, cpp) <= 0 or w > MAX_COLUMNS_PER_FRAME:
        raise MetadataError(f"{names[fmt]}: {w} columns of {h} pixels, {cpp} per packet; expected positive counts, "
                            f"at most {MAX_COLUMNS_PER_FRAME} columns")
    window = get(fmt, "column_window", [0, w - 1])
    try:
        window = (int(window[0]), int(window[1])) if len(window) == 2 else None
    except (TypeError, ValueError, KeyError):
        window = None
    if window is None or not all(0 <= c < w for c in window):
        raise MetadataError(f"column_window in {names[fmt]}: {get(fmt, 'column_window')!r}, expected two columns "
                            f"in [0, {w - 1}]")
    profile = str(get(fmt, "udp_profile_lidar", LEGACY))
    if profile not in PIXEL_LAYOUTS:
        raise MetadataError(f"udp_profile_lidar {profile}: not decoded (decoded: {', '.join(PIXEL_LAYOUTS)})")
    if str(get(fmt, "header_type", "STANDARD")) != "STANDARD":
        raise MetadataError(f"header_type {get(fmt, 'header_type')} in {names[fmt]}: only STANDARD packet headers "
                            "are decoded")
    if altitude_deg.size == w * h != h:
        raise MetadataError("per-pixel beam angles (a DF sensor): not decoded")
    if altitude_deg.size != h:
        raise MetadataError(f"beam_altitude_angles in {names['beam_intrinsics']}: {altitude_deg.size} values, "
                            f"expected {h}")
    azimuth_deg = numbers("beam_intrinsics", "beam_azimuth_angles", h)
    origin = numbers("beam_intrinsics", "lidar_origin_to_beam_origin_mm", 1, required=False)
    if origin is None:
        origin_mm = next((mm for line, mm in DEFAULT_BEAM_ORIGIN_MM.items() if prod_line.startswith(line)),
                         GEN1_BEAM_ORIGIN_MM)
    else:
        origin_mm = float(origin[0])
    beam_to_lidar = numbers("beam_intrinsics", "beam_to_lidar_transform", 16, required=False)
    if beam_to_lidar is None:  # a beam origin on the x axis at the given distance, as ouster-sdk builds it
        beam_to_lidar = np.eye(4)
        beam_to_lidar[0, 3] = origin_mm
    lidar_to_sensor = numbers("lidar_intrinsics", "lidar_to_sensor_transform", 16)
    port = integer("config_params", "udp_port_lidar")
    if port == 0:
        raise MetadataError("udp_port_lidar is 0: the sensor's lidar stream was off")
    fps = float(get(fmt, "fps", 0)) or (float(mode.group(2)) if mode else None)
    return OusterMetadata(
        prod_line=prod_line, prod_sn=integer("sensor_info", "prod_sn", 0),
        init_id=integer("sensor_info", "initialization_id", 0), udp_port_lidar=port, udp_profile_lidar=profile,
        columns_per_frame=w, pixels_per_column=h, columns_per_packet=cpp, column_window=window, fps=fps,
        beam_altitude_deg=altitude_deg, beam_azimuth_deg=azimuth_deg,
        beam_to_lidar_transform_mm=beam_to_lidar.reshape(4, 4), lidar_to_sensor_transform_mm=lidar_to_sensor.reshape(4, 4))


@dataclass(frozen=True, eq=False)
class PacketLayout:
    profile: str
    legacy: bool
    packet_bytes: int
    dtype: np.dtype  # one whole lidar packet: dtype["columns"] holds (columns_per_packet,) columns
    range_mask: int
    range_upshift: int
    first_measurement_id_offset: int  # of the first column's measurement id in the packet


def _column_bytes(meta: OusterMetadata) -> tuple[int, int, int]:
    """A column's header, pixel and footer bytes."""
    legacy = meta.udp_profile_lidar == LEGACY
    return (LEGACY_COLUMN_HEADER_BYTES if legacy else COLUMN_HEADER_BYTES,
            PIXEL_LAYOUTS[meta.udp_profile_lidar].pixel_bytes, LEGACY_COLUMN_FOOTER_BYTES if legacy else 0)


def lidar_packet_bytes(meta: OusterMetadata) -> int:
    header_bytes, pixel_bytes, footer_bytes = _column_bytes(meta)
    column_bytes = header_bytes + meta.pixels_per_column * pixel_bytes + footer_bytes
    packet_frame = 0 if meta.udp_profile_lidar == LEGACY else PACKET_HEADER_BYTES + PACKET_FOOTER_BYTES
    return packet_frame + meta.columns_per_packet * column_bytes


def packet_layout(meta: OusterMetadata) -> PacketLayout:
    pixel = PIXEL_LAYOUTS[meta.udp_profile_lidar]
    legacy = meta.udp_profile_lidar == LEGACY
    range_word = "<u2" if pixel.range_bits <= 16 else "<u4"
    pixel_dtype = np.dtype({"names": ["range_word", "reflectivity"], "formats": [range_word, "u1"],
                            "offsets": [0, pixel.reflectivity_byte], "itemsize": pixel.pixel_bytes})
    header_bytes, _, footer_bytes = _column_bytes(meta)
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


def xyz_lut(meta: OusterMetadata) -> tuple[np.ndarray, np.ndarray]:
    """ouster-sdk's XYZ lookup table (make_xyz_lut, without extrinsics), in the same float64
    operations: for each pixel of the staggered image, row-major, the direction (m per mm of
    range) and offset (m) of its point range_mm * direction + offset in the sensor frame. Both
    (3, pixels): x, y and z rows, so a frame's pixels are gathered from contiguous rows."""
    h, w = meta.pixels_per_column, meta.columns_per_frame
    b2l, l2s = meta.beam_to_lidar_transform_mm, meta.lidar_to_sensor_transform_mm
    beam_origin_mm = b2l[0, 3]
    if b2l[2, 3] != 0:  # a beam origin off the rotation plane: its distance from the axis
        beam_origin_mm = np.sqrt(b2l[0, 3] ** 2 + b2l[2, 3] ** 2)
    # column 0 fires at encoder angle 2 pi, and the encoder counts down as the head turns
    encoder_rad = (2.0 * np.pi - np.arange(w, dtype=np.float64) * (np.pi * 2.0 / w))[None, :]
    azimuth_rad = (-meta.beam_azimuth_deg * np.pi / 180.0)[:, None]
    altitude_rad = (meta.beam_altitude_deg * np.pi / 180.0)[:, None]
    cos_altitude = np.cos(altitude_rad)
    direction = [np.cos(encoder_rad + azimuth_rad) * cos_altitude, np.sin(encoder_rad + azimuth_rad) * cos_altitude,
                 np.broadcast_to(np.sin(altitude_rad), (h, w))]
    offset = [np.cos(encoder_rad) * b2l[0, 3] - direction[0] * beam_origin_mm,
              np.sin(encoder_rad) * b2l[0, 3] - direction[1] * beam_origin_mm,
              -direction[2] * beam_origin_mm + b2l[2, 3]]
    # rows times the rotation's transpose, summed left to right as Eigen does; then mm -> m
    direction_m = np.empty((3, h * w))
    offset_m = np.empty((3, h * w))
    for axis in range(3):
        d = direction[0] * l2s[axis, 0] + direction[1] * l2s[axis, 1] + direction[2] * l2s[axis, 2]
        o = offset[0] * l2s[axis, 0] + offset[1] * l2s[axis, 1] + offset[2] * l2s[axis, 2] + l2s[axis, 3]
        direction_m[axis] = (d * RANGE_UNIT_M).ravel()
        offset_m[axis] = (o * RANGE_UNIT_M).ravel()
    return direction_m, offset_m


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
