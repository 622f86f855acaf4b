"""The crane MRU's attitude through a gap in its log: an AR forecast of its own samples before
the gap, with a variance that covers its error, and none past the sigma limit."""

from __future__ import annotations

import math

import numpy as np
import pytest
from boomtip.data.frames import MruLog
from boomtip.fusion.mru_bridge import MruBridge
from boomtip.fusion.wave_predictor import backtest_variance, fit_ar, forecast

DEG = math.pi / 180


def _log(t, gap=(20.0, 25.0), noise_deg=0.0, seed=0):
    """Roll and pitch of two wave components (8 s and 11 s), yaw a slow drift, sampled at 200 Hz
    with a gap; rates their exact derivatives."""
    rng = np.random.default_rng(seed)
    w1, w2 = 2 * np.pi / 8.0, 2 * np.pi / 11.0
    rpy = np.column_stack([1.0 * DEG * np.sin(w1 * t) + 0.3 * DEG * np.sin(w2 * t + 1.0),
                           0.5 * DEG * np.sin(w2 * t + 0.4), 0.01 * DEG * t])
    rate = np.column_stack([1.0 * DEG * w1 * np.cos(w1 * t) + 0.3 * DEG * w2 * np.cos(w2 * t + 1.0),
                            0.5 * DEG * w2 * np.cos(w2 * t + 0.4), np.full_like(t, 0.01 * DEG)])
    rpy = rpy + noise_deg * DEG * rng.standard_normal(rpy.shape)
    keep = (t < gap[0]) | (t > gap[1])
    return MruLog(t[keep], rpy[keep], rate[keep], max_gap_s=0.1), rpy, rate


T = np.arange(0.0, 40.0, 0.005)


def test_a_sum_of_sinusoids_is_predicted_through_5_s_tightly():
    log, rpy, rate = _log(T)
    bridge = MruBridge(log, history_s=20.0, rate_hz=10.0, order=20, max_sigma_rad=0.2 * DEG)
    inside = np.flatnonzero((T > 20.01) & (T < 24.99))[::10]
    err = np.array([bridge.attitude(float(T[i]))[0] - rpy[i] for i in inside])
    rate_err = np.array([bridge.attitude(float(T[i]))[1] - rate[i] for i in inside])
    assert len(inside) == 100
    # AR(20) is exact on two sinusoids: what is left is the 0.1 s mean of the history (it scales an
    # 8 s wave by 1 - 2.6e-4: 0.00026 deg of a 1 deg roll) and the cubic between 10 Hz samples
    assert np.abs(err).max() < 3e-4 * DEG
    assert np.abs(rate_err).max() < 1e-3 * DEG  # linear between samples: 50 times under the MRU rate noise
    # outside the gap: the log's own samples, with no variance
    rpy0, rate0, var0 = bridge.attitude_var(10.0)
    assert np.array_equal(rpy0, log.attitude(10.0)[0]) and not var0.any()


def test_the_variance_covers_a_noisy_forecast_and_grows():
    """The MRU's stated noise (0.02 deg, 0.025 deg/s at 200 Hz) through the chain's own
    complementary filter and rate mean: the forecast is off by a tenth of a degree within
    5 s (AR least squares on noisy samples of a near-deterministic wave), and says so."""
    from boomtip.fusion.attitude_filter import averaged_rates, complementary_attitude

    log, rpy, rate = _log(T, gap=(-1.0, -1.0))
    rng = np.random.default_rng(3)
    keep = (T < 20.0) | (T > 25.0)
    noisy = MruLog(T[keep], (rpy + 0.02 * DEG * rng.standard_normal(rpy.shape))[keep],
                   (rate + 0.025 * DEG * rng.standard_normal(rate.shape))[keep], 0.1)
    filtered, _ = averaged_rates(complementary_attitude(noisy, 1.0), 0.05)
    bridge = MruBridge(filtered, history_s=20.0, rate_hz=10.0, order=20, max_sigma_rad=1.0 * DEG)
    inside = np.flatnonzero((T > 20.01) & (T < 24.99))[::20]
    got = [bridge.attitude_var(float(T[i])) for i in inside]
    err = np.array([g[0][:2] - rpy[i, :2] for g, i in zip(got, inside)])
    sig = np.sqrt(np.array([g[2][:2] for g in got]))
    assert np.all(np.diff(sig[:, 0]) >= -1e-12) and sig[-1, 0] > 10 * sig[0, 0]
    assert np.mean(np.abs(err) <= 3 * sig) > 0.95
    assert 0.3 < np.mean((err / sig) ** 2) < 3.0  # honest per angle
    assert np.sqrt(np.mean(err ** 2)) < 0.15 * DEG


def test_past_the_sigma_limit_there_is_no_attitude():
    log, _, _ = _log(T, noise_deg=0.01, seed=3)
    tight = MruBridge(log, history_s=20.0, rate_hz=10.0, order=20, max_sigma_rad=1e-4 * DEG)
    assert tight.attitude(20.5) is None and tight.attitude(19.0) is not None
    loose = MruBridge(log, history_s=20.0, rate_hz=10.0, order=20, max_sigma_rad=1.0 * DEG)
    assert loose.attitude(20.5) is not None
    # a history too short for the model: no forecast
    short, _, _ = _log(T, gap=(3.0, 8.0))
    assert MruBridge(short, 20.0, 10.0, 20, 1.0 * DEG).attitude(5.0) is None


def test_the_forecast_uses_only_the_samples_before_the_gap():
    log, _, _ = _log(T, noise_deg=0.01, seed=3)
    later = T > 25.0
    changed = MruLog(log.t_s, np.where((log.t_s > 25.0)[:, None], 0.3, log.rpy_rad), log.rpy_rate_radps, 0.1)
    a = MruBridge(log, 20.0, 10.0, 20, DEG).attitude_var(22.0)
    b = MruBridge(changed, 20.0, 10.0, 20, DEG).attitude_var(22.0)
    assert later.any() and all(np.array_equal(x, y) for x, y in zip(a, b))


def test_the_backtest_finds_a_misfit_the_model_variance_misses():
    """An AR(2) fitted to two sinusoids plus noise cannot follow them: its own variance (the
    one-step residual through its impulse response) is below its k-step errors."""
    rng = np.random.default_rng(1)
    t = np.arange(300) * 0.1
    y = np.sin(2 * np.pi * t / 8) + 0.6 * np.sin(2 * np.pi * t / 3.1) + 0.05 * rng.standard_normal(len(t))
    m = fit_ar(y, 2, 0.1)
    _, var_model = forecast(m, y, 30)
    var_back = backtest_variance(m, y, 30)
    assert var_back.shape == (30,) and var_back[0] == pytest.approx(m.sigma ** 2, rel=0.1)
    assert var_back[-1] > 1.3 * var_model[-1]
    # a series too short for the steps: the last backtested value stands for the rest
    v = backtest_variance(m, y[:60], 55)
    assert np.all(np.isfinite(v)) and np.all(v[48:] == v[47]) and v[47] != v[46]  # 60 - 2 - 10 steps hold 10 origins
