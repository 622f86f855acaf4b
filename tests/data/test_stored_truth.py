"""Tables kept on disk (data/stored_truth.py): read back by windows, the same numbers as the whole
arrays in memory; a recording's truth read whole and put there."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.data.frames import HOOK_TRUTH_COLUMNS, Truth
from boomtip.data.stored_truth import StoredTruth, TrackFiles


@pytest.fixture
def grid():
    rng = np.random.default_rng(3)
    t = np.arange(1001) / 200.0
    return t, rng.normal(size=1001), rng.normal(size=(1001, 3))


def _times(t):
    """Inside, on grid points, the two ends, and outside both ends."""
    return [np.array([0.7312, 0.7313, 1.2]), t[[10, 11, 12]], t[[0]], t[[-1]], np.array([t[500]]),
            np.array([-0.3, 0.01]), np.array([4.99, 5.0, 5.2]), np.linspace(-1, 6, 50), t[:1] - 1.0]


def test_tracks_read_back_in_chunks_and_windows(grid):
    t, v1, v3 = grid
    files = TrackFiles()
    for a in range(0, len(t), 137):  # appended in uneven chunks
        files.append("s", v1[a:a + 137])
        files.append("v", v3[a:a + 137])
    assert np.array_equal(files.read("s"), v1) and np.array_equal(files.read("v"), v3)
    assert np.array_equal(files.read("v", 400, 407), v3[400:407]) and files.read("s", 990, 2000).shape == (11,)
    for tq in _times(t):
        assert np.array_equal(files.interp("s", tq, t), np.interp(tq, t, v1))  # clamped at the ends, as np.interp
        expected = np.stack([np.interp(tq, t, v3[:, k]) for k in range(3)], axis=-1)
        assert np.array_equal(files.interp("v", tq, t), expected)
        nan_out = files.interp("s", tq, t, left=np.nan, right=np.nan)
        assert np.array_equal(nan_out, np.interp(tq, t, v1, left=np.nan, right=np.nan), equal_nan=True)


def test_stored_truth_is_the_truth_in_memory(grid):
    t, v1, _ = grid
    files = TrackFiles()
    cols = {"t": t}
    for k, name in enumerate(HOOK_TRUTH_COLUMNS[1:]):
        cols[name] = v1 * (k + 1)
        files.append(name, cols[name])
    stored, memory = StoredTruth(t, files), Truth(cols)
    assert list(stored.columns) == list(HOOK_TRUTH_COLUMNS) and stored.end_s == memory.end_s == 5.0
    assert np.array_equal(stored.t_s, t) and np.array_equal(stored.columns["hook_z"], cols["hook_z"])
    for tq in _times(t):
        for name in ("t", "hook_x", "crane_pitch"):
            assert np.array_equal(stored.at(name, tq), memory.at(name, tq), equal_nan=True)
    with pytest.raises(KeyError):
        stored.columns["D"]


def test_a_recordings_truth_read_whole_is_kept_on_disk_with_the_same_figures(grid):
    t, v1, _ = grid
    cols = {"t": t, "D": v1, "D_dot": 2 * v1, "extra": -v1}  # a file's columns, whatever they are
    stored, memory = StoredTruth.of_columns(cols, tuple(cols)), Truth(cols)
    assert list(stored.columns) == ["t", "D", "D_dot", "extra"] and np.array_equal(stored.columns["extra"], -v1)
    for tq in _times(t):
        assert np.array_equal(stored.at("D_dot", tq), memory.at("D_dot", tq), equal_nan=True)
