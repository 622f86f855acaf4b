"""PointCloud2 and Imu contents <-> boomtip arrays, as pure functions."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.data.io.ros_messages import (CloudError, cloud_to_frame, decode_cloud, encode_cloud, imu_from_mru,
                                          mru_from_imu)


def _padded_cloud(big_endian=False):
    """PointXYZI as pcl_ros writes it: x y z, 4 pad bytes, intensity, 12 pad bytes (32-byte
    points), two rows of 3 with 8 bytes of row padding."""
    order = ">" if big_endian else "<"
    dt = np.dtype({"names": ["x", "y", "z", "intensity"], "formats": [order + "f4"] * 4, "offsets": [0, 4, 8, 16],
                   "itemsize": 32})
    pts = np.zeros(6, dtype=dt)
    pts["x"], pts["y"], pts["z"], pts["intensity"] = np.arange(6), 10 + np.arange(6), -5.0, 0.5 * np.arange(6)
    pts["x"][4] = np.nan  # an organised cloud's no-return
    rows = pts.tobytes()
    data = rows[:96] + b"\0" * 8 + rows[96:] + b"\0" * 8
    fields = [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("_", 12, 7, 1), ("intensity", 16, 7, 1)]
    return fields, data, pts


@pytest.mark.parametrize("big_endian", [False, True])
def test_padded_rows_and_points_decode_in_either_byte_order(big_endian):
    fields, data, pts = _padded_cloud(big_endian)
    cloud = decode_cloud(fields, data, height=2, width=3, point_step=32, row_step=104, big_endian=big_endian)
    assert cloud.dtype.names == ("x", "y", "z", "intensity") and len(cloud) == 6
    xyz, f = cloud_to_frame(cloud, "lidar")
    assert xyz.shape == (5, 3) and xyz.dtype == np.float64  # the NaN point is dropped
    np.testing.assert_array_equal(xyz[:, 1], [10, 11, 12, 13, 15])
    np.testing.assert_array_equal(f["intensity"], [0, 0.5, 1, 1.5, 2.5])


def test_malformed_clouds_raise_the_readers_error():
    fields, data, _ = _padded_cloud()
    with pytest.raises(CloudError, match="truncated"):
        decode_cloud(fields, data[:50], 2, 3, 32, 104)
    with pytest.raises(CloudError, match="overruns point_step"):
        decode_cloud([("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 30, 7, 1)], data, 2, 3, 32, 104)
    with pytest.raises(CloudError, match="no x, y, z"):
        decode_cloud([("a", 0, 7, 1)], data, 2, 3, 32, 104)
    with pytest.raises(CloudError, match="inconsistent"):
        decode_cloud(fields, data, 2, 3, 32, 10)


def test_encode_then_decode_is_exact_for_boomtips_fields():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3)).astype(np.float32).astype(np.float64)
    fields = {"intensity": rng.random(50).astype(np.float32), "t": rng.random(50).astype(np.float32),
              "label": rng.integers(0, 9, 50).astype(np.int32)}
    spec, data, step = encode_cloud(pts, fields)
    cloud = decode_cloud(spec, data, 1, 50, step, step * 50)
    xyz, f = cloud_to_frame(cloud, "lidar")
    np.testing.assert_array_equal(xyz, pts)
    for k in fields:
        np.testing.assert_array_equal(f[k], fields[k])
        assert f[k].dtype == fields[k].dtype


def test_radar_velocity_fields_map_to_range_rate_with_their_sign():
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("doppler", "<f4")])
    cloud = np.zeros(3, dtype=dt)
    cloud["x"], cloud["y"], cloud["z"], cloud["doppler"] = [10, 0, 0], [0, 20, 0], [0, 0, -30], [0.5, -1.0, 2.0]
    _, f = cloud_to_frame(cloud, "radar")
    np.testing.assert_array_equal(f["range_rate"], [0.5, -1.0, 2.0])
    np.testing.assert_allclose(f["range"], [10, 20, 30])
    np.testing.assert_allclose(f["azimuth"], [0, np.pi / 2, 0], atol=1e-7)
    np.testing.assert_allclose(f["elevation"], [0, 0, -np.pi / 2], atol=1e-7)
    _, f = cloud_to_frame(cloud, "radar", velocity_field="doppler", velocity_sign=-1)
    np.testing.assert_array_equal(f["range_rate"], [-0.5, 1.0, -2.0])
    with pytest.raises(CloudError, match="'v_radial' not in"):
        cloud_to_frame(cloud, "radar", velocity_field="v_radial")


def test_lidar_time_fields_become_seconds_from_the_stamp():
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("t", "<u4")])
    cloud = np.zeros(2, dtype=dt)
    cloud["x"], cloud["t"] = 1.0, [0, 50_000_000]  # Ouster's driver: uint32 ns from the stamp
    np.testing.assert_allclose(cloud_to_frame(cloud, "lidar")[1]["t"], [0, 0.05])
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("timestamp", "<f8")])
    cloud = np.zeros(2, dtype=dt)
    cloud["x"], cloud["timestamp"] = 1.0, [1.7e9 + 0.25, 1.7e9 + 0.3]  # absolute seconds (Hesai)
    np.testing.assert_allclose(cloud_to_frame(cloud, "lidar", stamp_s=1.7e9 + 0.25)[1]["t"], [0, 0.05], atol=1e-6)


def test_imu_and_mru_conventions_round_trip():
    rng = np.random.default_rng(1)
    rpy = rng.uniform([-0.3, -0.3, -3.0], [0.3, 0.3, 3.0], (200, 3))
    rates = rng.normal(scale=0.1, size=(200, 3))
    quat, omega = imu_from_mru(rpy, rates)
    np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, atol=1e-12)
    back_rpy, back_rates = mru_from_imu(quat, omega)
    np.testing.assert_allclose(back_rpy, rpy, atol=1e-12)
    np.testing.assert_allclose(back_rates, rates, atol=1e-12)
    # pure yaw rate about a level frame is a body z rate; a pure roll rate is a body x rate
    _, w = imu_from_mru(np.zeros((1, 3)), np.array([[0.0, 0.0, 0.2]]))
    np.testing.assert_allclose(w, [[0, 0, 0.2]])
    _, w = imu_from_mru(np.array([[0.0, 0.4, 0.0]]), np.array([[0.1, 0.0, 0.0]]))
    np.testing.assert_allclose(w, [[0.1, 0, 0]])


def test_float_nanosecond_time_fields_and_implausible_ones():
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("timestamp", "<f8")])
    cloud = np.zeros(2, dtype=dt)
    cloud["x"], cloud["timestamp"] = 1.0, [1.7e18 + 2.5e8, 1.7e18 + 3.0e8]  # Livox: absolute ns as doubles
    np.testing.assert_allclose(cloud_to_frame(cloud, "lidar", stamp_s=1.7e9 + 0.25)[1]["t"], [0, 0.05], atol=1e-6)
    cloud["timestamp"] = [5e3, 6e3]  # neither an offset in s nor a stamp: left out rather than trusted
    assert "t" not in cloud_to_frame(cloud, "lidar")[1]
