"""The levelling calibration from deck normals and the MRU's complementary filter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from boomtip.data.frames import MruLog
from boomtip.fusion.attitude_filter import complementary_attitude
from boomtip.fusion.level_calibration import correction, tilt_from_normals


def _normals(tilt_x: float, tilt_y: float, t: np.ndarray) -> np.ndarray:
    # a deck rolling 1 deg and pitching 2.5 deg about zero, seen through a frame tilted by (tilt_x, tilt_y)
    r = math.radians(1.0) * np.sin(2 * np.pi * t / 10.0)
    p = math.radians(2.5) * np.sin(2 * np.pi * t / 10.0 + 0.7)
    n_true = np.column_stack([np.sin(p) * np.cos(r), -np.sin(r), np.cos(p) * np.cos(r)])
    C = correction(type("T", (), {"rx_rad": tilt_x, "ry_rad": tilt_y})())
    return n_true @ C  # tilted = C^T true


def test_tilt_recovered_to_a_thousandth_of_a_degree_in_60_s():
    t = np.arange(0.0, 60.0, 0.1)
    tx, ty = math.radians(0.03), math.radians(-0.025)
    tilt = tilt_from_normals(t, _normals(tx, ty, t), min_span_s=30.0)
    assert math.degrees(tilt.rx_rad) == pytest.approx(0.03, abs=1e-3)
    assert math.degrees(tilt.ry_rad) == pytest.approx(-0.025, abs=1e-3)
    n_corr = _normals(tx, ty, t) @ correction(tilt).T
    assert abs(math.degrees(np.mean(n_corr[:, 0]))) < 0.01


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


def test_complementary_filter_restarts_at_a_gap():
    t = np.r_[np.arange(0.0, 5.0, 0.005), np.arange(10.0, 15.0, 0.005)]
    rpy = np.zeros((len(t), 3))
    rpy[t >= 10.0, 0] = 0.05  # the vessel rolled during the gap
    out = complementary_attitude(MruLog(t, rpy, np.zeros_like(rpy)), 1.0)
    assert out.rpy_rad[t >= 10.0, 0][0] == pytest.approx(0.05, abs=1e-9)
