"""A recording's frame files as arrays: the order a sorted list of (time, sensor, path) had."""

from pathlib import Path

import numpy as np

from boomtip.data.io.frame_files import FRAME_SENSORS, FrameFiles


def test_frames_come_in_time_then_sensor_then_name_order_with_their_paths():
    items = [(200, "radar", "0000000200"), (100, "lidar", "100"), (200, "lidar", "0000000200"),
             (100, "lidar", "0100"), (50, "radar", "50"), (100, "lidar", "100 "), (100, "lidar", "１００")]
    root = Path("/rec")
    files = FrameFiles(root, np.array([t for t, _, _ in items], dtype=np.int64),
                       np.array([FRAME_SENSORS.index(s) for _, s, _ in items], dtype=np.int8), [f"{n}.pcd" for _, _, n in items])
    expected = sorted((t, s, root / s / f"{n}.pcd") for t, s, n in items)
    assert len(files) == 7 and list(files) == expected
    assert list(files) == expected  # again


def test_no_frames():
    files = FrameFiles(Path("/rec"), np.zeros(0, np.int64), np.zeros(0, np.int8), [])
    assert len(files) == 0 and list(files) == []
