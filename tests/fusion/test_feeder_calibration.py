"""The levelling calibration from deck normals and the MRU's complementary filter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from boomtip.data.frames import MruLog
from boomtip.fusion.attitude_filter import averaged_rates, complementary_attitude
from boomtip.fusion.level_calibration import Tilt, correction, tilt_from_normals, with_heading


def _normals(tilt_x: float, tilt_y: float, t: np.ndarray) -> np.ndarray:
    # a deck rolling 1 deg and pitching 2.5 deg about zero, seen through a frame tilted by (tilt_x, tilt_y)
    r = math.radians(1.0) * np.sin(2 * np.pi * t / 10.0)
    p = math.radians(2.5) * np.sin(2 * np.pi * t / 10.0 + 0.7)
    n_true = np.column_stack([np.sin(p) * np.cos(r), -np.sin(r), np.cos(p) * np.cos(r)])
    C = correction(Tilt(tilt_x, tilt_y, 0.0, 0.0))
    return n_true @ C  # tilted = C^T true


def test_tilt_recovered_to_a_thousandth_of_a_degree_in_60_s():
    t = np.arange(0.0, 60.0, 0.1)
    tx, ty = math.radians(0.03), math.radians(-0.025)
    tilt = tilt_from_normals(t, _normals(tx, ty, t), min_span_s=30.0)
    assert math.degrees(tilt.rx_rad) == pytest.approx(0.03, abs=1e-3)
    assert math.degrees(tilt.ry_rad) == pytest.approx(-0.025, abs=1e-3)
    n_corr = _normals(tx, ty, t) @ correction(tilt).T
    assert abs(math.degrees(np.mean(n_corr[:, 0]))) < 0.01


def test_a_gap_in_the_normals_does_not_bias_the_tilt():
    """A 50 s outage in a 110 s run: one Hann window across the gap weighs the waves unevenly
    (0.1 deg wrong here); the stretch before it alone gives the tilt, the 10 s after too short."""
    t = np.r_[np.arange(0.0, 50.0, 0.1), np.arange(100.0, 110.0, 0.1)]
    tx, ty = math.radians(0.03), math.radians(-0.025)
    n = _normals(tx, ty, t)
    tilt = tilt_from_normals(t, n, min_span_s=30.0)
    assert math.degrees(tilt.rx_rad) == pytest.approx(0.03, abs=2e-3)
    assert math.degrees(tilt.ry_rad) == pytest.approx(-0.025, abs=2e-3)
    assert tilt.span_s == pytest.approx(49.9)
    one_window = tilt_from_normals(t, n, min_span_s=30.0, max_gap_s=np.inf)
    assert abs(math.degrees(one_window.ry_rad) + 0.025) > 0.02  # what the split avoids
    # two long stretches both count
    t2 = np.r_[np.arange(0.0, 40.0, 0.1), np.arange(90.0, 130.0, 0.1)]
    both = tilt_from_normals(t2, _normals(tx, ty, t2), min_span_s=30.0)
    assert both.span_s == pytest.approx(79.8) and math.degrees(both.rx_rad) == pytest.approx(0.03, abs=2e-3)


def test_no_tilt_before_the_minimum_span():
    t = np.arange(0.0, 20.0, 0.1)
    assert tilt_from_normals(t, _normals(0.001, 0.0, t), min_span_s=30.0) is None


def test_complementary_filter_cuts_angle_noise_keeps_bias_and_motion():
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 60.0, 0.005)
    true = np.column_stack([0.02 * np.sin(0.63 * t), 0.035 * np.sin(0.63 * t + 0.8), np.zeros_like(t)])
    rate = np.column_stack([0.02 * 0.63 * np.cos(0.63 * t), 0.035 * 0.63 * np.cos(0.63 * t + 0.8), np.zeros_like(t)])
    bias = np.array([math.radians(0.01), math.radians(-0.015), 0.0])
    log = MruLog(t, true + bias + rng.normal(0, math.radians(0.02), true.shape),
                 rate + rng.normal(0, math.radians(0.025), rate.shape))
    out = complementary_attitude(log, 1.0)
    err = out.rpy_rad[2000:, :2] - true[2000:, :2]
    assert np.degrees(err.std(axis=0)).max() < 0.004  # from 0.02 deg
    assert np.degrees(err.mean(axis=0)) == pytest.approx(np.degrees(bias[:2]), abs=2e-3)


def test_the_filtered_angles_sigma_is_what_the_filter_leaves():
    """The stated 0.02 deg and 0.025 deg/s at 200 Hz through a 1 s filter: 0.0016 deg, as the
    filter leaves it on 20 minutes of noise alone (within a few per cent)."""
    from boomtip.fusion.attitude_filter import complementary_angle_sigma

    rng = np.random.default_rng(11)
    t = np.arange(0.0, 1200.0, 0.005)
    log = MruLog(t, rng.normal(0, math.radians(0.02), (len(t), 3)), rng.normal(0, math.radians(0.025), (len(t), 3)))
    out = complementary_attitude(log, 1.0)
    measured = np.degrees(out.rpy_rad[2000:, :2].std(axis=0))
    predicted = math.degrees(complementary_angle_sigma(math.radians(0.02), math.radians(0.025), 1.0, 0.005))
    assert predicted == pytest.approx(0.0016, abs=5e-5)
    assert measured == pytest.approx([predicted, predicted], rel=0.06)
    assert complementary_angle_sigma(0.1, 0.2, 0.0, 0.005) == 0.1  # no filter: the stated noise


def test_complementary_filter_starts_without_the_first_samples_noise():
    """Started at the first sample, the first second carried its noise (e^(-t / tau)); started
    from the backward pass it is filtered from the first sample on."""
    errs = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        t = np.arange(0.0, 20.0, 0.005)
        true = np.column_stack([0.02 * np.sin(0.63 * t + seed), np.zeros_like(t), np.zeros_like(t)])
        rate = np.column_stack([0.02 * 0.63 * np.cos(0.63 * t + seed), np.zeros_like(t), np.zeros_like(t)])
        log = MruLog(t, true + rng.normal(0, math.radians(0.02), true.shape), rate + rng.normal(0, math.radians(0.025), rate.shape))
        out = complementary_attitude(log, 1.0)
        errs.append(out.rpy_rad[:20, 0] - true[:20, 0])  # the first 0.1 s
    assert np.degrees(np.sqrt(np.mean(np.square(errs)))) < 0.005  # a single sample's: 0.02 deg


def test_rotation_about_the_vertical_from_the_own_hulls_edge():
    rng = np.random.default_rng(6)
    tilt = Tilt(math.radians(0.03), math.radians(-0.02), 1e-5, 60.0)
    hull = math.radians(0.03) + rng.normal(0, math.radians(0.002), 40)
    assert with_heading(tilt, hull[:2]) is tilt  # too few edges: not calibrated
    cal = with_heading(tilt, hull)
    assert math.degrees(cal.rz_rad) == pytest.approx(-0.03, abs=0.0015)
    assert math.degrees(cal.rz_sigma_rad) == pytest.approx(0.002 * 1.25 / math.sqrt(40), rel=0.4)
    x_hull = np.array([math.cos(hull[0]), math.sin(hull[0]), 0.0])  # the edge as the level frame sees it
    x_corr = correction(cal) @ x_hull
    assert abs(math.degrees(math.atan2(x_corr[1], x_corr[0]))) < 0.004  # along the heading again
    assert (cal.rx_rad, cal.ry_rad) == (tilt.rx_rad, tilt.ry_rad)


def test_complementary_filter_restarts_at_a_gap():
    t = np.r_[np.arange(0.0, 5.0, 0.005), np.arange(10.0, 15.0, 0.005)]
    rpy = np.zeros((len(t), 3))
    rpy[t >= 10.0, 0] = 0.05  # the vessel rolled during the gap
    out = complementary_attitude(MruLog(t, rpy, np.zeros_like(rpy)), 1.0)
    assert out.rpy_rad[t >= 10.0, 0][0] == pytest.approx(0.05, abs=1e-9)


def test_averaged_rates_cut_the_noise_and_keep_the_wave():
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 30.0, 0.005)
    true = np.column_stack([0.0138 * np.cos(0.63 * t), 0.022 * np.cos(0.63 * t + 0.8), np.zeros_like(t)])
    noisy = true + rng.normal(0, math.radians(0.025), true.shape)
    gap = (t > 10.0) & (t < 10.5)  # a gap restarts the mean: nothing averaged across it
    log = MruLog(t[~gap], np.zeros((int((~gap).sum()), 3)), noisy[~gap], max_gap_s=0.1)
    out, n = averaged_rates(log, 0.05)
    assert n == 21
    err = out.rpy_rate_radps - true[~gap]
    assert np.std(err[:, :2]) == pytest.approx(math.radians(0.025) / math.sqrt(21), rel=0.1)
    assert abs(np.mean(err[:, :2])) < 1e-5  # no lag: the window is centred
    assert averaged_rates(log, 0.0)[1] == 1


def test_a_mean_tilt_beyond_the_survey_is_the_feeders_list_not_the_mount():
    """A feeder listing 0.5 deg averages to 0.5 deg, which the deck cannot tell from a mount
    error; the survey (0.036 deg 1-sigma here) says the mount is not that far off."""
    from boomtip.fusion.level_calibration import within_the_survey

    t = np.arange(0.0, 60.0, 0.1)
    prior = math.radians(math.hypot(0.03, 0.02))
    mount = tilt_from_normals(t, _normals(math.radians(0.04), math.radians(-0.035), t), min_span_s=30.0)
    kept, why = within_the_survey(mount, prior)
    assert kept is mount and why is None
    listing = tilt_from_normals(t, _normals(math.radians(0.5), 0.0, t), min_span_s=30.0)
    kept, why = within_the_survey(listing, prior)
    assert "list or trim" in why and "0.500 deg" in why
    assert (kept.rx_rad, kept.ry_rad, kept.sigma_rad, kept.span_s) == (0.0, 0.0, prior, listing.span_s)  # the survey's
    assert with_heading(kept, np.full(5, 0.01)).rz_rad == pytest.approx(-0.01)  # the hull's heading still applies
    assert within_the_survey(None, prior) == (None, None)
    inside = Tilt(4.0 * prior * 0.99, 0.0, 0.0, 60.0)  # just inside 4 sigma is still the mount's
    assert within_the_survey(inside, prior) == (inside, None)
    outside = Tilt(0.0, -4.0 * prior * 1.01, 0.0, 60.0)
    assert within_the_survey(outside, prior)[0].ry_rad == 0.0
