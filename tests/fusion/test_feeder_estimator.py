"""The feeder estimator's steps one at a time (fusion/feeder_estimator.py), on hand-made MRU logs
and deck planes: the levelling's attitude and its noise, through a gap in the MRU's log and
after it; where the filter starts; which radar frames register and how the radar's offsets
are learnt before they are used; and what the end says when nothing was seen."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from boomtip.data.frames import AttitudeNoise, MruLog
from boomtip.data.installation import Installation, MruSpec
from boomtip.data.poses import inverse, pose_matrix
from boomtip.fusion.attitude_filter import averaged_rates, complementary_angle_sigma, complementary_attitude
from boomtip.fusion.feeder_frame import REC_P, REC_T, StateRows
from boomtip.fusion.feeder_estimator import (
    RADAR_DECK_OFFSET_MIN_FRAMES,
    REGISTRATION_YAW_LEVER_M,
    DeckMeasurement,
    FeederEstimator,
    FeederEstimatorConfig,
    RadarOffset,
    RadarOffsetConfig,
)
from boomtip.fusion.models.relative_motion import attitude_pose_cov, deck_plane
from boomtip.fusion.mru_bridge import MruBridge, MruGapConfig

GAP = (20.0, 22.0)  # the MRU's log has no sample in here
WAVE_RAD_S = 2 * math.pi / 8.0
# the stated MRU of a kit (the defaults state no noise at all: every sigma would be 0)
INSTALLATION = Installation(mru=MruSpec(angle_noise_deg=0.02, rate_noise_degps=0.025))
LEVER_M = float(np.linalg.norm(INSTALLATION.T_crane_boomtip()[:3, 3]))
RADAR = RadarOffsetConfig(enabled=True, after_s=0.5, learn_every=4, offset_frames=400, min_offset_frames=3, max_sigma_m=0.3)
TIP = np.array([10.0, -40.0, 52.0])
TIP_V = np.array([0.01, -0.02, 0.03])
LIDAR = np.array([0.0, 0.0, -0.5])


def wave_log(t0: float = 0.0, t1: float = 30.0, gap: tuple[float, float] | None = GAP, seed: int = 0) -> MruLog:
    """200 Hz of an 8 s roll and pitch wave (and a slow yaw), 0.02 deg of angle noise."""
    t = t0 + np.arange(int(round((t1 - t0) * 200)) + 1) / 200.0
    if gap is not None:
        t = t[(t < gap[0]) | (t > gap[1])]
    w = WAVE_RAD_S
    rpy = np.column_stack([0.02 * np.sin(w * t), 0.015 * np.cos(w * t + 0.3), 0.3 + 0.001 * np.sin(0.5 * w * t)])
    rates = np.column_stack([0.02 * w * np.cos(w * t), -0.015 * w * np.sin(w * t + 0.3), 0.0005 * w * np.cos(0.5 * w * t)])
    rpy += np.random.default_rng(seed).normal(0.0, math.radians(0.02), rpy.shape)
    return MruLog(t, rpy, rates)


def estimator(log: MruLog | None = None, radar: RadarOffsetConfig = RADAR, feeder_mru: MruLog | None = None,
              **cfg) -> FeederEstimator:
    return FeederEstimator(wave_log() if log is None else log, INSTALLATION, FeederEstimatorConfig(**cfg), radar, feeder_mru)


def bridged(max_sigma_deg: float = 0.05) -> FeederEstimator:
    return estimator(mru_gap=MruGapConfig(enabled=True, max_sigma_deg=max_sigma_deg))


def deck(abc=(0.01, -0.02, -45.0), rates=None) -> DeckMeasurement:
    a, b, _ = abc
    n = np.array([-a, -b, 1.0]) / math.sqrt(a * a + b * b + 1.0)
    cov = np.diag([1e-6, 1e-6, 1e-4]) if rates is None else np.diag([1e-6, 1e-6, 1e-4, 1e-4, 1e-4, 1e-2])
    return DeckMeasurement(np.array(abc), cov, n, None if rates is None else np.asarray(rates, dtype=float))


def started(est: FeederEstimator, t_s: float = 19.0) -> FeederEstimator:
    """The filter started at a deck at t_s (a LiDAR frame with the MRU's own attitude) and its row recorded."""
    att = est.attitude(t_s, "lidar")
    assert att is not None and att.forecast_var is None
    assert est.lidar_deck(t_s, TIP, TIP_V, LIDAR, att.noise, deck())
    est.record(t_s, "lidar", TIP_V, LIDAR, (0, 0))
    return est


# -- the attitude ------------------------------------------------------------------------------

def test_the_attitude_is_the_filtered_mrus_with_the_nominal_noise():
    """The MRU's angles through the complementary filter and its rates averaged (attitude_filter),
    the noise the installation states, filtered so: the same numbers as those steps by hand."""
    log = wave_log()
    est = estimator(log)
    filtered, n = averaged_rates(complementary_attitude(log, 1.0), 0.05)
    assert est.rates_averaged_over == n == 21  # +-0.05 s of 200 Hz samples
    angle = complementary_angle_sigma(math.radians(0.02), math.radians(0.025), 1.0, 1.0 / 200.0)
    assert est.noise == AttitudeNoise.of_installation(INSTALLATION, angle, n)
    for t in (3.0, 12.345, 19.99):
        att = est.attitude(t, "lidar")
        rpy, rate = filtered.attitude(t)
        assert np.array_equal(att.rpy_rad, rpy) and np.array_equal(att.rpy_rate_radps, rate)
        assert att.noise == est.noise and att.forecast_var is None and (t, "lidar") not in est.forecast_frames
    # the filtered angles are not the raw ones (else nothing above would have been tested)
    assert not np.array_equal(est.attitude(3.0, "lidar").rpy_rad, log.attitude(3.0)[0])


def test_raw_angles_and_rates_when_the_filters_are_off():
    log = wave_log()
    est = estimator(log, mru_tau_s=0.0, mru_rate_half_window_s=0.0)
    att = est.attitude(7.2, "radar")
    assert np.array_equal(att.rpy_rad, log.attitude(7.2)[0]) and np.array_equal(att.rpy_rate_radps, log.attitude(7.2)[1])
    assert est.rates_averaged_over == 1
    assert est.noise == AttitudeNoise.of_installation(INSTALLATION, math.radians(0.02), 1)


def test_without_the_bridge_a_gap_in_the_log_has_no_attitude():
    est = estimator()
    assert not isinstance(est.mru, MruBridge)
    assert est.attitude(21.0, "lidar") is None and not est.forecast_frames
    assert est.attitude(31.0, "lidar") is None  # past the log's end


def test_through_a_gap_the_forecast_with_its_inflated_noise():
    est = bridged()
    assert isinstance(est.mru, MruBridge)
    for t in (20.5, 21.5):
        att = est.attitude(t, "lidar")
        rpy, rate, var = est.mru.attitude_var(t)
        assert var.any() and est.forecast_frames[(t, "lidar")] == max(var[0], var[1])
        assert np.array_equal(att.rpy_rad, rpy) and np.array_equal(att.rpy_rate_radps, rate)
        assert np.array_equal(att.forecast_var, var)
        assert att.noise == est.noise.with_forecast(var, LEVER_M)
        assert att.noise.angle_rad == math.sqrt(est.noise.angle_rad ** 2 + max(var[0], var[1]))
        assert est.gap_angle_var == max(var[0], var[1])
        # the forecast follows the wave: within 4 sigma of its own error and the filtered angles' noise
        truth = np.array([0.02 * math.sin(WAVE_RAD_S * t), 0.015 * math.cos(WAVE_RAD_S * t + 0.3)])
        assert np.all(np.abs(att.rpy_rad[:2] - truth) < 4 * np.hypot(np.sqrt(var[:2]), est.noise.angle_rad))
    late = est.attitude(21.5, "lidar")
    assert est.attitude(20.5, "lidar").noise.angle_rad < late.noise.angle_rad  # the forecast's error grows


def test_beyond_max_sigma_there_is_no_attitude():
    probe = bridged()
    near, far = (max(probe.attitude(t, "lidar").forecast_var[:2]) for t in (20.3, 21.9))
    limit_deg = math.degrees((near * far) ** 0.25)  # the two sigmas' geometric mean
    assert math.degrees(math.sqrt(near)) < limit_deg < math.degrees(math.sqrt(far))
    est = bridged(limit_deg)
    assert est.attitude(20.3, "lidar").forecast_var is not None
    assert est.attitude(21.9, "lidar") is None and (21.9, "lidar") not in est.forecast_frames


# -- where the filter starts -------------------------------------------------------------------

def test_nothing_happens_before_the_first_deck():
    est = estimator()
    att = est.attitude(5.0, "lidar")
    assert est.lidar_deck(5.0, TIP, TIP_V, LIDAR, att.noise, None) is False
    assert not est.started and est.t_definition is None and est.T_level_map0 is None
    assert len(est.records) == 0 and est.normals == []


def test_the_first_deck_defines_the_map_frame_and_is_fused():
    est = estimator()
    d = deck()
    att = est.attitude(5.0, "lidar")
    assert est.lidar_deck(5.0, TIP, TIP_V, LIDAR, att.noise, d) is True
    n = d.normal
    pose = np.array([0.0, 0.0, -45.0, -math.asin(n[1]), math.atan2(n[0], n[2]), 0.0])
    assert est.started and est.t_definition == 5.0
    assert np.array_equal(est.T_level_map0, pose_matrix(*pose))
    first = StateRows.of(est.records.read(0, 1))
    assert np.array_equal(first.x[0, :6], pose)  # the start's own row, before the deck's update
    P0 = first.P[0]
    assert np.array_equal(np.diag(P0)[:6], [1e-8, 1e-8, 1e-4, 1e-6, 1e-6, 1e-10])
    assert est.filter.updates.counts["deck_lidar"]["accepted"] == 1
    assert est.normals == [(5.0, n)] and len(est.records) == 1
    assert np.array_equal(first.tips[0], TIP_V) and np.array_equal(first.pivots[0], LIDAR)
    # the map frame's z = 0 plane is the deck: the start's plane is the measured one (to round-off
    # of 45 m: 1e-13), and the update leaves it there
    assert np.allclose(deck_plane(est.x_start), d.abc, rtol=0, atol=1e-13) and np.array_equal(est.x_start[:12], first.x[0])
    assert np.allclose(est.deck_plane(), d.abc, rtol=0, atol=1e-13)
    assert np.array_equal(est.deck_plane(), deck_plane(est.filter.x))
    assert np.array_equal(est.map_pose(), inverse(pose_matrix(*est.filter.x[:6])))


def test_after_the_first_deck_a_frame_without_one_is_a_prediction():
    est = started(estimator())
    reference = copy.deepcopy(est.filter)
    att = est.attitude(19.1, "lidar")
    assert est.lidar_deck(19.1, TIP + 0.01, TIP_V, LIDAR, att.noise, None) is False
    reference.predict(19.1, TIP_V, att.noise.tip_velocity_mps, TIP + 0.01)
    assert np.array_equal(est.filter.x, reference.x) and np.array_equal(est.filter.P, reference.P)
    assert len(est.normals) == 1 and est.filter.t_s == 19.1
    # a deck with its spin is one measurement of plane and rates
    att = est.attitude(19.2, "lidar")
    assert est.lidar_deck(19.2, TIP, TIP_V, LIDAR, att.noise, deck(rates=(0.0, 0.0, 0.0))) is True
    assert est.filter.updates.counts["deck_spin_lidar"]["accepted"] == 1 and est.normals[-1][0] == 19.2


def test_registration_sigma_and_position_sigma_read_the_filter():
    est = started(estimator())
    s = est.filter.pose_sigma()
    assert est.registration_sigma_m() == float(np.hypot(s[0], s[1])) + REGISTRATION_YAW_LEVER_M * float(s[5])
    assert est.position_sigma_x_m() == float(s[0])


# -- through an MRU gap and after it -----------------------------------------------------------

def test_rows_recorded_in_a_gap_carry_the_forecasts_covariance_on_top():
    est = started(bridged())
    last_P = lambda: est.records.last[REC_P].reshape(12, 12)
    assert np.array_equal(last_P(), est.filter.P[:12, :12])  # before the gap: the filter's own
    att = est.attitude(20.5, "radar")
    est.predict(20.5, TIP, TIP_V, att.noise)
    P = est.filter.P.copy()
    est.record(20.5, "radar", TIP_V, LIDAR, (0, 0))
    expected = P[:12, :12].copy()
    expected[:6, :6] += attitude_pose_cov(est.filter.x[:3], max(att.forecast_var[:2]))
    assert np.array_equal(last_P(), expected)
    assert np.array_equal(est.filter.P, P)  # the filter's own covariance is not touched
    assert not np.array_equal(last_P(), P[:12, :12])


def test_a_filter_started_in_a_gap_has_its_first_row_carry_the_forecast():
    est = bridged()
    att = est.attitude(20.5, "lidar")
    assert att.forecast_var is not None
    assert est.lidar_deck(20.5, TIP, TIP_V, LIDAR, att.noise, deck())
    first = StateRows.of(est.records.read(0, 1))
    row = first.P[0]
    start_P = np.diag([1e-8, 1e-8, 1e-4, 1e-6, 1e-6, 1e-10])
    expected = start_P + attitude_pose_cov(first.x[0, :3], max(att.forecast_var[:2]))
    assert np.array_equal(row[:6, :6], expected)


def test_a_frame_fused_after_later_attitudes_keeps_its_own_forecasts_covariance():
    est = bridged()
    # the chain's order through the warm-up: each frame's attitude when it arrives ...
    held = est.attitude(20.5, "lidar")
    assert held.forecast_var is not None
    est.attitude(22.3, "lidar")  # the MRU back: the warm-up ends at this frame
    # ... and all of them fused now, the first (in the gap) first
    est.lidar_deck(20.5, TIP, TIP_V, LIDAR, held.noise, deck())
    start_P = np.diag([1e-8, 1e-8, 1e-4, 1e-6, 1e-6, 1e-10])
    first = StateRows.of(est.records.read(0, 1))
    expected = start_P + attitude_pose_cov(first.x[0, :3], max(held.forecast_var[:2]))
    assert np.array_equal(first.P[0][:6, :6], expected)


def test_the_first_lidar_frame_after_a_gap_widens_the_pose_once_and_lets_the_tips_place_go():
    est = started(bridged())
    att = est.attitude(21.0, "lidar")
    gap_var = max(att.forecast_var[:2])
    est.lidar_deck(21.0, TIP, TIP_V, LIDAR, att.noise, None)  # predicted, with the tip's place
    est.record(21.0, "lidar", TIP_V, LIDAR, (0, 0))
    assert est.filter.tip_position is not None
    P = est.filter.P.copy()
    att = est.attitude(22.3, "lidar")  # the MRU is back
    assert att.forecast_var is None and att.noise == est.noise and (22.3, "lidar") not in est.forecast_frames
    expected = P.copy()
    expected[:6, :6] += attitude_pose_cov(est.filter.x[:3], gap_var)
    assert np.array_equal(est.filter.P, expected)
    assert est.filter.tip_position is None and est.gap_angle_var is None
    # the next step is predicted with the tip's velocity, not the jump of its place
    reference = copy.deepcopy(est.filter)
    est.lidar_deck(22.3, TIP + [0.18, 0.0, -0.085], TIP_V, LIDAR, att.noise, None)
    reference.predict(22.3, TIP_V, att.noise.tip_velocity_mps, None)
    assert np.array_equal(est.filter.x[:3], reference.x[:3])
    # once: the next frames leave the covariance and the tip's place alone
    P = est.filter.P.copy()
    est.attitude(22.4, "lidar")
    assert np.array_equal(est.filter.P, P) and est.filter.tip_position is not None


def test_a_radar_frame_after_a_gap_lets_the_tip_go_and_leaves_the_widening_to_the_lidar():
    est = started(bridged())
    att = est.attitude(21.0, "radar")
    gap_var = max(att.forecast_var[:2])
    est.predict(21.0, TIP, TIP_V, att.noise)
    P = est.filter.P.copy()
    est.attitude(22.3, "radar")
    assert est.filter.tip_position is None and np.array_equal(est.filter.P, P) and est.gap_angle_var == gap_var
    est.predict(22.3, TIP, TIP_V, est.noise)
    P = est.filter.P.copy()
    est.attitude(22.35, "lidar")
    expected = P.copy()
    expected[:6, :6] += attitude_pose_cov(est.filter.x[:3], gap_var)
    assert np.array_equal(est.filter.P, expected)
    assert est.filter.tip_position is not None  # let go once, at the radar frame


# -- registrations -----------------------------------------------------------------------------

def _registration(est: FeederEstimator, d_xy_yaw=(0.02, -0.015, math.radians(0.02))) -> tuple[np.ndarray, np.ndarray]:
    """A registration's pose off the state's by d (x, y, yaw), z, roll and pitch the state's, and
    its information (1 mm, 0.001 deg)."""
    pose = est.filter.x[:6].copy()
    pose[[0, 1, 5]] += d_xy_yaw
    return pose, np.diag([1e6, 1e6, 1e6, 1e10, 1e10, 1e10])


@pytest.mark.parametrize("young", [True, False])
def test_a_young_models_registration_moves_only_the_yaw(young):
    est = started(estimator())
    est.predict(21.0, TIP, TIP_V, est.noise)  # 2 s on: the yaw and x, y are free enough to move
    before = est.filter.x.copy()
    pose, info = _registration(est)
    est.update_registration(21.0, pose, info, young, est.noise)
    after = est.filter.x
    assert est.last_registration_t == 21.0 and est.filter.updates.counts["registration"]["accepted"] == 1
    assert 0.0 < after[5] - before[5] < math.radians(0.02)
    if young:
        assert np.array_equal(after[:5], before[:5])
    else:
        assert 0.0 < after[0] - before[0] < 0.02 and -0.015 < after[1] - before[1] < 0.0


def test_which_radar_frames_register():
    est = started(estimator())
    assert est.radar_registration_wanted(19.0) is None  # no LiDAR registration yet, no offset
    pose, info = _registration(est, (0.0, 0.0, 0.0))
    est.update_registration(19.0, pose, info, False, est.noise)
    wanted = []
    for k in range(9):  # radar frames while the LiDAR registers: every 4th teaches the offset
        t = 19.0 + 0.05 * (k + 1)
        wanted.append(est.radar_registration_wanted(t))
        if wanted[-1]:
            est.radar_registration(wanted[-1], est.filter.x[[0, 1, 5]] + [0.05, -0.03, 0.001], np.eye(3))
        est.predict(t, TIP, TIP_V, est.noise)
        est.record(t, "radar", TIP_V, LIDAR, (0, 0))
    assert wanted == ["learn", None, None, None, "learn", None, None, None, "learn"]
    assert est.radar_offset.n == 3 == RADAR.min_offset_frames
    assert est.radar_registration_wanted(19.5) is None  # 0.5 s is not yet "out for after_s": the 9th frame learns nothing
    assert est.radar_registration_wanted(19.5 + 1e-9) == "update"
    short = started(estimator(radar=RadarOffsetConfig(True, 0.5, 4, 400, 4, 0.3)))
    short.update_registration(19.0, *_registration(short, (0.0, 0.0, 0.0)), False, short.noise)
    short.radar_registration("learn", short.filter.x[[0, 1, 5]], np.eye(3))
    assert short.radar_registration_wanted(25.0) is None  # out long enough, but the offset is not known
    off = started(estimator(radar=RadarOffsetConfig(False, 0.5, 4, 400, 3, 0.3)))
    assert off.radar_registration_wanted(19.0) is None and off.radar_registration_wanted(25.0) is None


def test_a_radar_registration_teaches_the_offset_then_updates_less_it():
    est = started(estimator())
    x_before = est.filter.x.copy()
    d = np.array([0.05, -0.03, 0.001])
    est.radar_registration("learn", est.filter.x[[0, 1, 5]] + d, np.eye(3))
    assert np.array_equal(est.filter.x, x_before)  # learning updates nothing
    assert np.allclose(est.radar_offset.mean, d, rtol=0, atol=1e-15) and est.radar_offset.n == 1
    calls = []
    real = est.filter.update_registration
    est.filter.update_registration = lambda *a, **k: calls.append((a, k)) or real(*a, **k)
    z = est.filter.x[[0, 1, 5]] + d
    info = np.diag([1e4, 1e4, 1e7])
    est.radar_registration("update", z, info)
    (args, kwargs), = calls
    assert np.array_equal(args[0], z - est.radar_offset.mean) and args[1] is info
    assert np.array_equal(args[2], est.radar_offset.covariance())
    assert kwargs == {"kind": "radar_registration", "max_sigma_m": RADAR.max_sigma_m}
    assert est.filter.updates.counts["radar_registration"]["accepted"] == 1


def test_the_radar_offset_is_a_capped_running_mean_with_the_yaw_wrapped():
    off = RadarOffset(frames=2)
    off.add([math.pi - 0.01, 0.0, math.pi - 0.01], np.array([0.0, 0.0, -math.pi + 0.01]))
    assert off.mean[2] == pytest.approx(-0.02, abs=1e-15)  # across +-pi, not 2 pi - 0.02
    off = RadarOffset(frames=2)
    for v in (1.0, 2.0, 4.0):
        off.add([v, 0.0, 0.0], np.zeros(3))
    # weights 1, 1/2, then 1/2 (capped): 1 -> 1.5 -> 2.75; the mean square 1 -> 2.5 -> 9.25
    assert off.mean[0] == 2.75 and off.mean_square[0] == 9.25
    assert off.covariance()[0, 0] == (9.25 - 2.75 ** 2) / 2 and off.covariance()[1, 1] == 0.0


# -- the radar's deck and Doppler ----------------------------------------------------------------

def test_the_radar_decks_offset_is_learnt_while_the_lidar_sees_the_deck_and_applied_after():
    est = started(estimator())  # the LiDAR's last deck at 19.0
    x, P = est.filter.x.copy(), est.filter.P.copy()
    a, b, c = deck_plane(est.filter.x)
    off = np.array([2e-4, -1e-4, 0.05])  # the radar's plane: tilted and 5 cm off the LiDAR's
    radar = deck((a + off[0], b + off[1], c + off[2]))
    x0, y0 = est.filter.x[0], est.filter.x[1]
    for k in range(RADAR_DECK_OFFSET_MIN_FRAMES):
        est.update_radar(19.0 + 0.5 * k / RADAR_DECK_OFFSET_MIN_FRAMES, None, None, LIDAR, radar, est.noise)
    assert np.array_equal(est.filter.x, x) and np.array_equal(est.filter.P, P)  # learnt, not used
    assert "deck_radar" not in est.filter.updates.counts
    assert est.radar_deck_offset_n == RADAR_DECK_OFFSET_MIN_FRAMES
    diff = radar.abc - [a, b, c]
    assert np.array_equal(est.radar_deck_offset, [diff[0], diff[1], diff[2] + diff[0] * x0 + diff[1] * y0])
    assert est.radar_deck_offset == pytest.approx(off, abs=1e-12)  # the map's origin is below the tip: x0, y0 ~ 0
    seen = []
    real = est.filter.update_deck
    est.filter.update_deck = lambda kind, abc, cov: seen.append((kind, abc)) or real(kind, abc, cov)
    est.update_radar(19.0 + 0.5 + 1e-6, None, None, LIDAR, radar, est.noise)  # the LiDAR out for radar_deck_after_s
    (kind, abc), = seen
    assert kind == "deck_radar" and np.allclose(abc, [a, b, c], rtol=0, atol=1e-12)  # the offset taken off
    assert est.filter.updates.counts["deck_radar"]["accepted"] == 1


def test_the_radar_deck_is_used_as_it_is_before_the_offset_has_enough_frames():
    est = started(estimator())
    radar = deck((0.0102, -0.0201, -44.95))
    for k in range(RADAR_DECK_OFFSET_MIN_FRAMES - 1):
        est.update_radar(19.0 + 0.01 * k, None, None, LIDAR, radar, est.noise)
    seen = []
    est.filter.update_deck = lambda kind, abc, cov: seen.append(abc)
    est.update_radar(20.0, None, None, LIDAR, radar, est.noise)
    assert len(seen) == 1 and np.array_equal(seen[0], radar.abc)


def test_the_radar_doppler_carries_the_tips_velocity_noise():
    est = started(estimator())
    seen = []
    est.filter.update_point_velocity = lambda v, cov, xi: seen.append((v, cov, xi))
    v, cov, xi = np.array([0.1, 0.0, -0.2]), np.eye(3) * 1e-4, np.array([0.3, 0.0, -0.5])
    est.update_radar(19.05, v, cov, xi, None, est.noise)
    (v1, cov1, xi1), = seen
    assert v1 is v and xi1 is xi and np.array_equal(cov1, cov + np.eye(3) * est.noise.tip_velocity_mps ** 2)


# -- the feeder's MRU ----------------------------------------------------------------------------

def test_the_feeder_mru_is_taken_at_each_frames_time_and_its_gaps_counted():
    feeder = wave_log(0.0, 19.5, gap=None, seed=1)
    est = started(estimator(feeder_mru=feeder))
    assert est.filter.feeder_mru_started and est.filter.updates.counts["feeder_mru"]["accepted"] >= 1
    n = sum(est.filter.updates.counts["feeder_mru"].values())
    est.predict(19.4, TIP, TIP_V, est.noise)
    assert sum(est.filter.updates.counts["feeder_mru"].values()) == n + 1 and est.feeder_mru_gaps == 0
    est.predict(19.6, TIP, TIP_V, est.noise)  # past the feeder MRU's log
    assert sum(est.filter.updates.counts["feeder_mru"].values()) == n + 1 and est.feeder_mru_gaps == 1
    assert estimator(feeder_mru=feeder, use_feeder_mru=False).feeder_mru is None


# -- at the end ----------------------------------------------------------------------------------

def test_finish_without_any_deck_says_so_and_has_no_rows():
    est = estimator()
    att = est.attitude(5.0, "lidar")
    est.lidar_deck(5.0, TIP, TIP_V, LIDAR, att.noise, None)
    res = est.finish([], [])
    assert res.notes == ["feeder: no LiDAR deck plane in this run: no estimate"]
    assert res.t_s.shape == (0,) and res.pose.shape == (0, 6) and res.rates.shape == (0, 6) and res.var.shape == (0, 12)
    assert math.isnan(res.t_definition_s) and res.centre_line is None and res.online is None
    assert res.T_map_feeder is None and res.feeder_mru is None


def test_finish_without_any_deck_but_with_edges_found_says_so_too():
    est = estimator()
    att = est.attitude(5.0, "lidar")
    est.lidar_deck(5.0, TIP, TIP_V, LIDAR, att.noise, None)
    res = est.finish([(0.01, 3)], [0.002, 0.003])  # a centre line and hull edges, and never a deck
    assert res.notes == ["feeder: no LiDAR deck plane in this run: no estimate"] and res.t_s.shape == (0,)
    d = est._frame_data([(0.01, 3)], [0.002, 0.003])
    assert np.all(np.isinf(d.t_hull_s)) and np.all(np.isinf(d.t_lines_s))  # known only at the end


def test_finish_keeps_one_row_per_time():
    est = started(estimator())  # two rows at 19.0: the start's and the frame's
    for t in (19.1, 19.2):
        att = est.attitude(t, "lidar")
        est.lidar_deck(t, TIP, TIP_V, LIDAR, att.noise, deck())
        est.record(t, "lidar", TIP_V, LIDAR, (0, 0))
    assert est.records.column(REC_T).tolist() == [19.0, 19.0, 19.1, 19.2]
    res = est.finish([], [])
    assert res.t_s.tolist() == [19.0, 19.1, 19.2] and res.pose.shape == (3, 6) and res.var.shape == (3, 12)
    assert res.t_definition_s == 19.0 and np.all(np.isfinite(res.pose))
    assert any("under 30 s of deck planes" in n for n in res.notes)


def test_each_update_s_innovation_is_kept_per_kind_and_an_overconfident_kind_is_said():
    from boomtip.fusion.consistency import consistency_block, flagged_notes

    from boomtip.fusion.feeder_filter import FeederFilter

    f = FeederFilter()
    f.start(0.0, np.zeros(6), np.eye(6) * 1e-4, np.zeros(3))
    H = np.zeros((1, len(f.x)))
    H[0, 2] = 1.0  # z alone
    S = float((H @ f.P @ H.T)[0, 0]) + 1e-4
    y = 2.0 * np.sqrt(S)  # an innovation of 2 sigma: NIS 4
    assert f._update("probe", np.array([y]), np.zeros(1), H, np.array([[1e-4]]))
    assert [a.tolist() for a in f.updates.innovations.arrays("probe")] == [[0.0], [pytest.approx(4.0)], [1.0], [1.0]]
    for k in range(1, 60):  # a second of innovations at 4 sigma: far beyond what the covariance says
        f.predict(k / 60, np.zeros(3), 0.0)
        H2 = H.copy()
        f._update("probe", np.array([4.0 * np.sqrt(float((H2 @ f.P @ H2.T)[0, 0]) + 1e-4)]), np.zeros(1), H2,
                  np.array([[1e-4]]))
    block = consistency_block(f.updates.innovations)
    assert block["probe"]["flagged"] and block["probe"]["nis_per_dof"] > 10
    assert flagged_notes(block, "feeder")[0].startswith("feeder: the probe updates' innovations are ")

