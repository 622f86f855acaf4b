"""The feeder frame's definition from what was known at a time: the levelling calibration's
history and the estimates a live controller would have had (each row in the definition of its
own time), against the whole run's offline definition."""

from __future__ import annotations

import math

import numpy as np
import pytest
from boomtip.fusion.level_calibration import Tilt, correction, tilt_from_normals
from boomtip.data.poses import pose_matrix, pose_vector
from boomtip.fusion.feeder_frame import (
    REC_T,
    RECORD_WIDTH,
    FrameData,
    StateRows,
    causal_estimates,
    estimates_in_feeder_frame,
    feeder_pose_jacobians,
    feeder_poses,
    frame_at,
    frame_history,
    records_in_feeder_frame,
    state_record,
)
from boomtip.fusion.records import Records

SURVEY = math.radians(0.036)


def _data(seed: int = 3, duration_s: float = 60.0) -> FrameData:
    """A deck rolling and pitching about zero seen through a level frame tilted by (0.03, -0.025)
    deg; the own hull's edge 0.03 deg off the heading from 2 s; the centre line 0.5 deg in the
    map, found every 1/6 s from 1 s, with a spread."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1 / 30)
    r = math.radians(1.0) * np.sin(2 * np.pi * t / 10.0)
    p = math.radians(2.5) * np.sin(2 * np.pi * t / 10.0 + 0.7)
    n_true = np.column_stack([np.sin(p) * np.cos(r), -np.sin(r), np.cos(p) * np.cos(r)])
    normals = n_true @ correction(Tilt(math.radians(0.03), math.radians(-0.025), 0.0, 0.0))
    t_hull = np.arange(2.0, 12.0, 1 / 3)
    t_lines = np.arange(1.0, duration_s, 1 / 6)
    return FrameData(t, normals, t_hull, math.radians(0.03) + rng.normal(0, math.radians(0.002), len(t_hull)),
                     t_lines, math.radians(0.5) + rng.normal(0, math.radians(0.05), len(t_lines)),
                     np.array([0.0, 0.0, -40.0, 0.01, -0.02, 0.0]), pose_matrix(0.0, 0.0, -40.0, 0.01, -0.02, 0.0),
                     30.0, SURVEY, math.radians(10.0))


def test_the_survey_stands_until_the_minimum_span_then_the_calibration_from_the_data_so_far():
    d = _data()
    early = frame_at(d, 29.9)
    assert early.tilt is None and np.array_equal(early.C, np.eye(3)) and early.sigmas(SURVEY) == (SURVEY, SURVEY)
    assert np.array_equal(early.T_map_feeder[:3, 3], [0.0, 0.0, 0.0])  # below the tip along the uncorrected vertical
    late = frame_at(d, 45.0)
    n = int(np.searchsorted(d.t_normals_s, 45.0, side="right"))
    ref = tilt_from_normals(d.t_normals_s[:n], d.normals_level[:n], 30.0)
    assert (late.tilt.rx_rad, late.tilt.ry_rad, late.tilt.sigma_rad) == (ref.rx_rad, ref.ry_rad, ref.sigma_rad)
    # 45 s is not a whole number of the 10 s wave: the Hann window leaves 0.004 / 0.007 deg of it,
    # within the calibration's own 1-sigma (0.020 deg)
    err = np.degrees([late.tilt.rx_rad - math.radians(0.03), late.tilt.ry_rad + math.radians(0.025)])
    assert 0.002 < np.abs(err).max() < 0.01 and np.abs(err).max() < 0.5 * math.degrees(late.tilt.sigma_rad)
    assert math.degrees(late.tilt.rz_rad) == pytest.approx(-0.03, abs=2e-3)
    # the origin moves with the corrected vertical: the tilt's lever of 40 m, about 2 cm
    assert 0.01 < np.linalg.norm(late.T_map_feeder[:2, 3]) < 0.04
    assert math.degrees(late.line[0]) == pytest.approx(0.5, abs=0.02) and late.line[1] == np.count_nonzero(d.t_lines_s <= 45.0) > 250


def test_a_definition_knows_nothing_after_its_time():
    d, later = _data(), _data()
    cut = 40.0
    later.normals_level[later.t_normals_s > cut] += 0.01  # everything after the cut changed
    later.hull_yaws_rad[later.t_hull_s > cut] += 0.01
    later.line_yaws_rad[later.t_lines_s > cut] += 0.1
    a, b = frame_at(d, cut), frame_at(later, cut)
    assert a.tilt == b.tilt and a.line == b.line and np.array_equal(a.T_map_feeder, b.T_map_feeder)
    assert frame_at(d, 50.0).tilt != frame_at(later, 50.0).tilt


def test_the_history_ends_at_the_whole_runs_definition():
    d = _data(duration_s=20.0)
    d.min_span_s = 8.0
    t_rows = np.arange(0.5, 20.01, 0.05)  # the last row after the last datum, as in a run
    t_up, frames = frame_history(d, t_rows)
    assert t_up[0] == 0.5 and t_up[-1] == t_rows[-1] and np.allclose(np.diff(t_up[:-1]), 1.0)
    spans = [f.tilt.span_s if f.tilt is not None else 0.0 for f in frames]
    assert [s > 0 for s in spans].index(True) == 8 and np.all(np.diff(spans[8:]) > 0)
    # the own hull's heading as soon as three edges are known (from 2 s, three a second), the
    # survey's tilt with it until the deck normals span 8 s
    heading = [f.tilt is not None for f in frames]
    assert heading.index(True) == 3 and all(heading[3:])  # the update at 3.5 s, after the third edge at 2.67 s
    assert all((f.tilt.rx_rad, f.tilt.ry_rad, f.tilt.sigma_rad) == (0.0, 0.0, SURVEY) for f in frames[3:8])
    assert math.degrees(frames[7].tilt.rz_rad) == pytest.approx(-0.03, abs=2e-3) and frames[7].tilt.rz_sigma_rad < 1e-4
    assert frame_at(d, t_up[7]).tilt is None  # the offline rule: no heading without the tilt
    final, whole = frames[-1], frame_at(d)
    assert final.tilt == whole.tilt and final.line == whole.line and np.array_equal(final.T_map_feeder, whole.T_map_feeder)


def _records(t_rows, xs, Ps, tips, pivots, block_rows: int = 1024) -> Records:
    rec = Records(RECORD_WIDTH, block_rows=block_rows)
    for row in zip(t_rows, xs, Ps, tips, pivots):
        rec.append(state_record(*row, (row[0], 0, 0)))
    return rec


def test_each_online_row_is_in_the_definition_of_its_own_time():
    d = _data()
    rng = np.random.default_rng(1)
    t_rows = np.sort(rng.uniform(0.0, 59.0, 60))
    xs = [np.r_[rng.normal(0, 0.5, 2), -40.0 + rng.normal(0, 0.5), rng.normal(0, 0.02, 3), rng.normal(0, 0.1, 6)] for _ in t_rows]
    Ps = [np.diag(rng.uniform(1e-12, 1e-11, 12)) for _ in t_rows]  # the levelling's sigma shows through
    tips = [rng.normal(0, 0.1, 3) for _ in t_rows]
    pivots = [np.array([0.5, 0.0, -0.3])] * len(t_rows)
    records = _records(t_rows, xs, Ps, tips, pivots, block_rows=16)  # four blocks, three of them stored
    t_up, frames = frame_history(d, t_rows)
    online = causal_estimates(records, d, np.ones(len(t_rows), bool), SURVEY, 1e-4)
    pose, var = online.pose, online.var
    assert np.array_equal(online.t_s, t_rows) and np.array_equal(online.t_updates_s, t_up)
    for k in (0, 17, 33, 59):
        f = frames[int(np.searchsorted(t_up, t_rows[k], side="right")) - 1]
        one = estimates_in_feeder_frame(StateRows(t_rows[k:k + 1], np.array(xs[k:k + 1]), np.array(Ps[k:k + 1]),
                                                  np.array(tips[k:k + 1]), np.array(pivots[k:k + 1])), f, SURVEY, 1e-4)
        assert np.array_equal(pose[k], one[0][0]) and np.array_equal(online.rates[k], one[1][0]) and np.array_equal(var[k], one[2][0])
    # the survey's levelling sigma in roll before the calibration (30 s of normals), the calibration's after
    s_roll = [f.sigmas(SURVEY)[0] for f in frames]
    i = [f.tilt is not None and f.tilt.span_s > 0 for f in frames].index(True)
    assert t_up[i] >= 30.0 > t_up[i - 1] and s_roll[i - 1] == SURVEY and s_roll[i] == frames[i].tilt.sigma_rad
    assert s_roll[-1] < 0.3 * SURVEY
    expected = np.array(s_roll)[np.searchsorted(t_up, t_rows, side="right") - 1] ** 2
    assert np.allclose(var[:, 3], expected, rtol=1e-4) and np.all(var[t_rows < 30.0, 3] >= SURVEY ** 2)


def test_the_feeder_poses_of_many_rows_are_each_rows_transforms_composed_and_their_jacobians_its_derivatives():
    """Row by row: the correction C about the pivot, after the map's pose, after the feeder
    frame's place in the map (4x4s composed); the Jacobian against a one-sided difference."""
    rng = np.random.default_rng(5)
    poses = np.column_stack([rng.normal(0, 20, (40, 3)), rng.normal(0, 0.05, (40, 2)), rng.uniform(-3, 3, 40)])
    pivots = rng.normal(0, 5, (40, 3))
    C, T_mf = correction(Tilt(0.001, -0.0007, 1e-4, 30.0, 0.002)), pose_matrix(1.0, -2.0, 0.3, 0.0, 0.0, 0.4)
    y = feeder_poses(poses, C, pivots, T_mf)
    for row, pivot, got in zip(poses, pivots, y):
        Tc = np.eye(4)
        Tc[:3, :3], Tc[:3, 3] = C, pivot - C @ pivot
        assert got == pytest.approx(pose_vector(Tc @ pose_matrix(*row) @ T_mf), abs=1e-12)
    y0, J = feeder_pose_jacobians(poses, C, pivots, T_mf)
    assert np.array_equal(y0, y) and J.shape == (40, 6, 6)
    step = 1e-5
    for j in range(6):
        moved = poses.copy()
        moved[:, j] += step
        d = feeder_poses(moved, C, pivots, T_mf) - y
        d[:, 3:] = (d[:, 3:] + np.pi) % (2 * np.pi) - np.pi
        assert np.allclose(J[:, :, j], d / step, rtol=0, atol=2e-4)  # the one-sided difference's own error


def test_a_long_runs_rows_are_put_in_the_feeder_frame_block_by_block_with_the_same_figures(monkeypatch):
    from boomtip.fusion import feeder_frame

    rng = np.random.default_rng(2)
    xs = [np.r_[rng.normal(0, 0.5, 2), -40.0, rng.normal(0, 0.02, 3), rng.normal(0, 0.1, 6)] for _ in range(50)]
    Ps = [np.diag(rng.uniform(1e-6, 1e-5, 12)) for _ in xs]
    tips, pivots = [rng.normal(0, 0.1, 3) for _ in xs], [rng.normal(0, 1.0, 3) for _ in xs]
    t_rows = np.arange(50) * 0.1
    records = _records(t_rows, xs, Ps, tips, pivots, block_rows=8)
    assert np.array_equal(records.column(REC_T), t_rows)
    frame = frame_at(_data())
    whole = estimates_in_feeder_frame(StateRows(t_rows, np.array(xs), np.array(Ps), np.array(tips), np.array(pivots)),
                                      frame, SURVEY, 1e-4)
    monkeypatch.setattr(feeder_frame, "ROWS_AT_ONCE", 7)  # 8 blocks, the last of one row
    blocks = records_in_feeder_frame(records, np.zeros(50, int), [frame], SURVEY, 1e-4)
    assert all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(whole, blocks))
    # two definitions, changing inside a block: each row in its own
    other = frame_at(_data(), 20.0)
    which = (t_rows >= 2.05).astype(int)
    mixed = records_in_feeder_frame(records, which, [frame, other], SURVEY, 1e-4)
    later = estimates_in_feeder_frame(StateRows(t_rows[21:], np.array(xs[21:]), np.array(Ps[21:]), np.array(tips[21:]),
                                                np.array(pivots[21:])), other, SURVEY, 1e-4)
    for k in range(3):  # pose, rates, variances
        assert np.array_equal(mixed[k][:21], whole[k][:21]) and np.array_equal(mixed[k][21:], later[k])
    assert not np.allclose(later[0], whole[0][21:], rtol=0, atol=1e-12)  # the two definitions differ
