"""Ouster sensor metadata: what the packet decoder needs to know of a sensor, and the XYZ
lookup table that turns its ranges into points.

- `parse_metadata`: the sensor-metadata JSON, in the flat layout of firmware 2.0-2.3 or the
  nested one (`sensor_info`, `beam_intrinsics`, `lidar_data_format`, ...) of firmware 2.4+
  and 3.x; the flat keys go where ouster-sdk's `convert_legacy_to_nonlegacy` puts them.
  Metadata the decoder cannot follow (a missing key, an unknown UDP profile, per-pixel beam
  angles, packets larger than a UDP datagram) is a `MetadataError`.
- `PIXEL_LAYOUTS`, `lidar_packet_bytes`: the UDP profiles decoded, and the size of a lidar
  packet the metadata describes.
- `xyz_lut`: ouster-sdk's `make_xyz_lut`, operation for operation in float64, so the points
  come out as the same floats.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

RANGE_UNIT_M = 0.001  # ranges are counted in mm
LEGACY = "LEGACY"
PACKET_HEADER_BYTES = 32  # every profile but LEGACY: packet type, frame id, init id, serial number, ...
PACKET_FOOTER_BYTES = 32
COLUMN_HEADER_BYTES = 12  # time stamp (ns), measurement id, status
LEGACY_COLUMN_HEADER_BYTES = 16  # time stamp, measurement id, frame id, encoder count
LEGACY_COLUMN_FOOTER_BYTES = 4  # status, after the pixels
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


def column_part_bytes(meta: OusterMetadata) -> tuple[int, int, int]:
    """A column's header, pixel and footer bytes."""
    legacy = meta.udp_profile_lidar == LEGACY
    return (LEGACY_COLUMN_HEADER_BYTES if legacy else COLUMN_HEADER_BYTES,
            PIXEL_LAYOUTS[meta.udp_profile_lidar].pixel_bytes, LEGACY_COLUMN_FOOTER_BYTES if legacy else 0)


def lidar_packet_bytes(meta: OusterMetadata) -> int:
    header_bytes, pixel_bytes, footer_bytes = column_part_bytes(meta)
    column_bytes = header_bytes + meta.pixels_per_column * pixel_bytes + footer_bytes
    packet_frame = 0 if meta.udp_profile_lidar == LEGACY else PACKET_HEADER_BYTES + PACKET_FOOTER_BYTES
    return packet_frame + meta.columns_per_packet * column_bytes


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
