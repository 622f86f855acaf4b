"""The feeder frame's true pose and twist in the crane's heading frame (tools/report/feeder_truth.py),
from a synthetic truth table with both vessels moving in all six DOFs. At the definition time t0
the frame is its definition: the deck point straight below the boom tip (x = y = 0, z = -D) with
the feeder's attitude, yaw relative to the crane's heading. A pure translation of the feeder body
moves x, y, z by exactly that translation in heading axes and leaves the angles alone."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from boomtip.data.frames import TRUTH_COLUMNS, Truth
from boomtip.tools.report.feeder_truth import body_pose_world, feeder_origin_body, feeder_pose_truth, feeder_twist_truth

T = np.arange(201) * 0.05  # 0 to 10 s at 20 Hz
P_TIP_CRANE = np.array([35.0, 4.0, 30.0])
T0 = 2.0  # on the truth's grid: interpolation returns the samples themselves
MOTION = dict(
    crane_x=1.0, crane_y=-2.0, crane_z=0.5 + 0.3 * np.sin(T), crane_roll=0.02 * np.sin(0.7 * T),
    crane_pitch=0.01 * np.cos(0.5 * T), crane_yaw=0.3 + 0.01 * T,
    feeder_x=40.0 + 0.2 * np.sin(0.3 * T), feeder_y=5.0, feeder_z=-3.0 + 0.5 * np.sin(0.9 * T),
    feeder_roll=0.03 * np.sin(0.4 * T), feeder_pitch=0.02, feeder_yaw=1.2 + 0.02 * np.sin(T),
    D=30.0 + 0.5 * np.sin(0.9 * T),
)


def truth(**columns) -> Truth:
    cols = {k: np.zeros(len(T)) for k in TRUTH_COLUMNS}
    cols["t"] = T
    for k, v in {**MOTION, **columns}.items():
        cols[k] = np.broadcast_to(np.asarray(v, dtype=float), T.shape).copy()
    return Truth(cols)


def at(tr: Truth, name: str, t: float) -> float:
    return float(tr.at(name, np.array([t]))[0])


def heading_rotation_T(tr: Truth, t: np.ndarray) -> np.ndarray:
    """World to heading axes: Rz(crane yaw) transposed."""
    return Rotation.from_euler("z", tr.at("crane_yaw", t)[:, None]).as_matrix().transpose(0, 2, 1)


def test_body_pose_world_is_the_zyx_euler_rotation_and_the_position():
    tr = truth()
    R, p = body_pose_world(tr, "feeder", np.array([T0]))
    rpy = [at(tr, f"feeder_{a}", T0) for a in ("roll", "pitch", "yaw")]
    Rz, Ry, Rx = (Rotation.from_euler(ax, a).as_matrix() for ax, a in zip("zyx", rpy[::-1]))
    assert np.allclose(R[0], Rz @ Ry @ Rx, rtol=0, atol=1e-15)
    assert np.array_equal(p[0], [at(tr, f"feeder_{a}", T0) for a in "xyz"])


def test_at_t0_the_pose_is_the_origins_definition():
    tr = truth()
    origin = feeder_origin_body(tr, T0, P_TIP_CRANE)
    (pose,) = feeder_pose_truth(tr, np.array([T0]), origin, P_TIP_CRANE)
    # the deck point straight below the tip, D below it; the frame's axes the feeder body's
    assert pose[:3] == pytest.approx([0.0, 0.0, -at(tr, "D", T0)], abs=1e-12)
    expected_rpy = [at(tr, "feeder_roll", T0), at(tr, "feeder_pitch", T0), at(tr, "feeder_yaw", T0) - at(tr, "crane_yaw", T0)]
    assert pose[3:] == pytest.approx(expected_rpy, abs=1e-14)


def test_the_origin_lies_on_the_feeders_deck_plane_below_the_tip():
    """In world axes the origin is the tip minus D vertically: check it against the tip itself."""
    tr = truth()
    origin = feeder_origin_body(tr, T0, P_TIP_CRANE)
    R_c, p_c = body_pose_world(tr, "crane", np.array([T0]))
    R_f, p_f = body_pose_world(tr, "feeder", np.array([T0]))
    deck_world = R_f[0] @ origin + p_f[0]
    tip_world = R_c[0] @ P_TIP_CRANE + p_c[0]
    assert deck_world == pytest.approx(tip_world - [0.0, 0.0, at(tr, "D", T0)], abs=1e-12)


def test_a_pure_translation_of_the_feeder_moves_xyz_by_exactly_that():
    delta = np.column_stack([0.7 + 0.1 * T, np.full(len(T), -0.4), 0.25 * np.sin(2 * T)])
    base = truth()
    moved = truth(feeder_x=MOTION["feeder_x"] + delta[:, 0], feeder_y=MOTION["feeder_y"] + delta[:, 1],
                  feeder_z=MOTION["feeder_z"] + delta[:, 2])
    origin = feeder_origin_body(base, T0, P_TIP_CRANE)  # the same frame on the feeder for both
    t = T[::7]
    a, b = feeder_pose_truth(base, t, origin, P_TIP_CRANE), feeder_pose_truth(moved, t, origin, P_TIP_CRANE)
    expected = np.einsum("tij,tj->ti", heading_rotation_T(base, t), delta[::7])  # in heading axes
    assert np.allclose(b[:, :3] - a[:, :3], expected, rtol=0, atol=1e-12)
    assert np.array_equal(b[:, 3:], a[:, 3:])
    # with the crane heading along world x, heading and world axes agree: exactly the translation
    base0, moved0 = truth(crane_yaw=0.0), truth(crane_yaw=0.0, feeder_x=MOTION["feeder_x"] + delta[:, 0],
                                                    feeder_y=MOTION["feeder_y"] + delta[:, 1],
                                                    feeder_z=MOTION["feeder_z"] + delta[:, 2])
    origin0 = feeder_origin_body(base0, T0, P_TIP_CRANE)
    d0 = feeder_pose_truth(moved0, t, origin0, P_TIP_CRANE)[:, :3] - feeder_pose_truth(base0, t, origin0, P_TIP_CRANE)[:, :3]
    assert np.allclose(d0, delta[::7], rtol=0, atol=1e-12)


def test_the_crane_heaving_up_moves_the_feeder_frame_down_by_as_much():
    base = truth()
    up = truth(crane_z=MOTION["crane_z"] + 0.8)
    origin = feeder_origin_body(base, T0, P_TIP_CRANE)
    t = T[::9]
    d = feeder_pose_truth(up, t, origin, P_TIP_CRANE) - feeder_pose_truth(base, t, origin, P_TIP_CRANE)
    assert np.allclose(d, [[0.0, 0.0, -0.8, 0.0, 0.0, 0.0]] * len(t), rtol=0, atol=1e-12)


def test_outside_the_truths_span_the_pose_is_nan():
    tr = truth()
    origin = feeder_origin_body(tr, T0, P_TIP_CRANE)
    pose = feeder_pose_truth(tr, np.array([-0.01, 5.0, 10.01]), origin, P_TIP_CRANE)
    assert np.isnan(pose[[0, 2]]).all() and np.isfinite(pose[1]).all()


def test_the_twist_of_a_feeder_drifting_at_constant_velocity():
    """Both vessels still but the feeder moving at v: the twist is v in heading axes and no
    rotation; the pose is linear in time, so the central difference is exact to rounding."""
    v = np.array([0.3, -0.2, 0.05])
    still = dict(crane_z=0.0, crane_roll=0.0, crane_pitch=0.0, crane_yaw=0.4, feeder_roll=0.01, feeder_pitch=0.02,
                 feeder_yaw=1.0, D=30.0)
    tr = truth(**still, feeder_x=40.0 + v[0] * T, feeder_y=5.0 + v[1] * T, feeder_z=-3.0 + v[2] * T)
    origin = feeder_origin_body(tr, T0, P_TIP_CRANE)
    t = np.array([1.0, 3.3, 7.77])
    twist = feeder_twist_truth(tr, t, origin, P_TIP_CRANE)
    v_heading = Rotation.from_euler("z", -0.4).apply(v)
    # rounding: positions of ~50 m carry ~1e-14 m, differenced over 2 ms: ~1e-11 m/s
    assert np.allclose(twist[:, :3], v_heading, rtol=0, atol=1e-10)
    assert np.allclose(twist[:, 3:], 0.0, rtol=0, atol=1e-10)
