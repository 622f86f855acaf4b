"""The Ouster metadata parser and XYZ lookup table (`data/io/ouster_metadata.py`): the flat and
nested metadata layouts read alike, errors say what is missing or not decoded, a malformed
value of any kind is a metadata error; the lookup table's points, and against ouster-sdk (a
test-only reference, skipped without it) for both metadata layouts and any transform."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from boomtip.data.io.ouster_metadata import MetadataError, parse_metadata, xyz_lut
from boomtip.data.io.ouster_packets import xyz_sensor_m

REAL = Path(__file__).resolve().parents[1] / "real" / "ouster"
CAPTURES = ("OS-1-128_v2.3.0_1024x10_lb_n3", "OS-2-128-U1_v2.3.0_1024x10", "OS-1-32-G_v2.1.1_1024x10")


# --- Ouster metadata ------------------------------------------------------------------------

def shipped_metadata(name: str) -> dict:
    return json.loads((REAL / f"{name}.json").read_text())


def nested(flat: dict) -> dict:
    """The shipped flat (firmware 2.x) metadata rewritten in the nested layout of firmware 2.4+."""
    move = {"sensor_info": ("prod_line", "prod_sn", "prod_pn", "initialization_id", "build_rev", "build_date", "image_rev",
                            "status"),
            "config_params": ("udp_port_lidar", "udp_port_imu", "lidar_mode"),
            "beam_intrinsics": ("beam_altitude_angles", "beam_azimuth_angles", "lidar_origin_to_beam_origin_mm"),
            "lidar_intrinsics": ("lidar_to_sensor_transform",), "imu_intrinsics": ("imu_to_sensor_transform",)}
    out = {section: {k: flat[k] for k in keys if k in flat} for section, keys in move.items()}
    out["lidar_data_format"] = flat["data_format"]
    out["calibration_status"] = {}
    return out


@pytest.mark.parametrize("name", CAPTURES)
def test_flat_and_nested_metadata_read_alike(name):
    flat = shipped_metadata(name)
    a, b = parse_metadata(flat), parse_metadata(nested(flat))
    for key, value in vars(a).items():
        np.testing.assert_array_equal(getattr(b, key), value, err_msg=key)
    assert a.udp_profile_lidar == flat["data_format"].get("udp_profile_lidar", "LEGACY")
    assert a.udp_port_lidar == flat.get("udp_port_lidar") and a.column_window == (0, 1023) and a.fps == 10.0
    assert a.beam_to_lidar_transform_mm[0, 3] == flat["lidar_origin_to_beam_origin_mm"]


def test_metadata_errors_say_what_is_missing_or_not_decoded():
    flat = shipped_metadata(CAPTURES[0])
    cases = [({k: v for k, v in flat.items() if k != "beam_altitude_angles"}, "no beam_altitude_angles in the top level"),
             ({**flat, "beam_azimuth_angles": [0.0] * 64}, "beam_azimuth_angles in the top level: 64 values, expected 128"),
             ({**flat, "data_format": {**flat["data_format"], "udp_profile_lidar": "RNG99"}}, "udp_profile_lidar RNG99: not decoded"),
             ({**flat, "data_format": {**flat["data_format"], "column_window": [0, 4096]}}, r"column_window in data_format: \[0, 4096\]"),
             ({**flat, "udp_port_lidar": 0}, "the sensor's lidar stream was off"),
             ({k: v for k, v in flat.items() if k != "lidar_to_sensor_transform"}, "no lidar_to_sensor_transform"),
             ({k: v for k, v in flat.items() if k not in ("data_format", "lidar_mode")}, "no data_format"),
             ([1, 2], "a JSON list, expected an object")]
    for doc, message in cases:
        with pytest.raises(MetadataError, match=message):
            parse_metadata(doc)
    nested_doc = nested(flat)
    del nested_doc["lidar_data_format"]["pixels_per_column"]
    with pytest.raises(MetadataError, match="no pixels_per_column in lidar_data_format"):
        parse_metadata(nested_doc)


def test_any_malformed_value_is_a_metadata_error():
    """Every key of both layouts set to values of the wrong kind: a MetadataError or a reading,
    never another exception."""
    flat = shipped_metadata(CAPTURES[0])
    for doc in (flat, nested(flat)):
        for key in doc:
            for bad in ("x", "", [], {}, None, -1, 10**9, [[1, 2], [3]], True):
                try:
                    parse_metadata({**doc, key: bad})
                except MetadataError:
                    pass
    for section in ("lidar_data_format", "beam_intrinsics"):
        for key in nested(flat)[section]:
            for bad in ("x", [], None, -5, 10**9, [1, "y"]):
                try:
                    parse_metadata({**nested(flat), section: {**nested(flat)[section], key: bad}})
                except MetadataError:
                    pass


# --- the XYZ lookup table ------------------------------------------------------------------

def test_xyz_of_the_lookup_table_is_range_times_direction_plus_offset():
    meta = parse_metadata(shipped_metadata(CAPTURES[2]))
    direction_m, offset_m = xyz_lut(meta)
    assert direction_m.shape == offset_m.shape == (3, 32 * 1024)
    np.testing.assert_allclose(np.linalg.norm(direction_m, axis=0), 1e-3, rtol=1e-12)  # unit vectors, per mm
    range_mm = np.zeros(32 * 1024, np.uint32)
    range_mm[[0, 5, 1024 * 31 + 1023]] = [1000, 250_000, 3]
    pixels = np.flatnonzero(range_mm)
    expected = range_mm[pixels, None] * direction_m.T[pixels] + offset_m.T[pixels]
    scratch = np.empty_like(direction_m)
    for got in (xyz_sensor_m(range_mm, pixels, direction_m, offset_m),
                xyz_sensor_m(range_mm, pixels, direction_m, offset_m, scratch)):
        np.testing.assert_array_equal(got, expected)
    # pixel 0 (beam 0 at 12.75 deg up, column 0 at the encoder's zero) looks back along the
    # sensor's -x: the lidar frame's +x, turned 180 deg about z by lidar_to_sensor_transform
    assert expected[0, 0] < -0.97 and abs(expected[0, 1]) < 0.08 and expected[0, 2] > 0.2


# --- against ouster-sdk (a test-only reference) -------------------------------------------------

# ouster-sdk's XYZLut is float64 too (XYZLutT<double>) and xyz_lut repeats its operations in its
# order, so the points come out equal to the bit here; the tolerance leaves room for a libm or
# a compiler that rounds cos/sin or a product's sum in another last bit (one float64 unit of a
# 200 m point is 3e-14 m)
POINT_TOLERANCE_M = 1e-9


@pytest.mark.parametrize("name", CAPTURES)
def test_the_lookup_table_is_ouster_sdks_for_both_metadata_layouts_and_any_transform(name):
    core = pytest.importorskip("ouster.sdk").core
    flat = shipped_metadata(name)
    rotation, _ = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))
    lidar_to_sensor = np.eye(4)
    lidar_to_sensor[:3, :3], lidar_to_sensor[:3, 3] = rotation, [12.5, -3.25, 40.0]
    general = {**flat, "lidar_to_sensor_transform": lidar_to_sensor.ravel().tolist(),
               "beam_to_lidar_transform": [1, 0, 0, 15.1, 0, 1, 0, 0, 0, 0, 1, 4.2, 0, 0, 0, 1]}
    for doc, exact in [(flat, True), (nested(flat), True), (general, False)]:
        lut = core.XYZLut(core.SensorInfo(json.dumps(doc)))
        direction_m, offset_m = xyz_lut(parse_metadata(doc))
        if exact:  # the shipped transforms (a turn about z, exact in any order of sums): the same bits
            np.testing.assert_array_equal(direction_m.T, lut.direction)
            np.testing.assert_array_equal(offset_m.T, lut.offset)
        range_mm = np.random.default_rng(2).integers(0, 2**19, (lut.h, lut.w)).astype(np.uint32)
        pixels = np.flatnonzero(range_mm)
        points = xyz_sensor_m(range_mm.ravel(), pixels, direction_m, offset_m)
        np.testing.assert_allclose(points, lut(range_mm).reshape(-1, 3)[pixels], rtol=0, atol=POINT_TOLERANCE_M)
