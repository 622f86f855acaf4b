"""The crane MRU's attitude through a gap in its log, predicted from its own samples before
the gap: roll, pitch and yaw (and their rates, each its own series) by an autoregressive model
fitted to the last `history_s` and run forward (fusion.wave_predictor). A ship's roll and
pitch are narrow-band wave processes, which such a model follows for seconds; a broadband
sea's far less well. Each value carries its variance: the
larger of the model's own (its impulse response) and its k-step errors backtested on the same
history, so a model that fits poorly says so. Only samples before the gap are used: the
prediction is causal, what a live controller would have.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from boomtip.data.frames import MruLog
from scipy.interpolate import CubicHermiteSpline
from scipy.ndimage import uniform_filter1d
from boomtip.fusion.wave_predictor import backtest_variance, fit_ar, forecast
from pydantic import BaseModel, ConfigDict, Field


class MruGapConfig(BaseModel):
    """The feeder estimate through a gap in the crane MRU's log (fusion/feeder_estimator)."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(False, description="predict the crane's attitude through an MRU gap from its own samples before it "
                          "and process the frames with it (off: the chain pauses until the MRU is back). Off by default: "
                          "better than the pause on a regular sea, mixed on an irregular one (fusion/feeder_estimator)")
    history_s: float = Field(20.0, gt=2, description="the MRU samples before the gap the AR model is fitted to")
    rate_hz: float = Field(10.0, gt=0, description="the AR model's sample rate")
    order: int = Field(20, ge=2, le=64, description="the AR model's order")
    max_sigma_deg: float = Field(0.05, gt=0, description="past this 1-sigma of the predicted roll or pitch the chain pauses "
                                 "(0.05 deg moves the deck 45 m below by 4 cm)")


@dataclass(frozen=True)
class GapForecast:
    t_s: np.ndarray  # (K,) the forecast's grid, from the gap's last sample
    values: np.ndarray  # (K, 6) roll, pitch, yaw (unwrapped), their rates
    var: np.ndarray  # (K, 6)
    angles: CubicHermiteSpline  # the angles between the grid's samples, with the rates as their slopes


def forecast_series(t_s: np.ndarray, y: np.ndarray, t_last_s: float, horizon_s: float, history_s: float, rate_hz: float,
                    order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Columns of y (samples at t_s, up to t_last_s) resampled at rate_hz over the last history_s,
    each forecast horizon_s past the series' end: the grid (from the last sample it holds,
    variance 0 there), the values and their variances; None with too short a history."""
    dt = 1.0 / rate_hz
    # each grid sample the mean of the samples about it, not the one nearest it: the AR fit's
    # regressors carry that noise, and noisy regressors bias the fit and let the forecast
    # drift. Centred means, so no lag; the grid ends
    # where the last full one is (a mean cut at the series' end would bend its last samples)
    k = max(1, int(round(dt / float(np.median(np.diff(t_s)))))) | 1 if len(t_s) > 1 else 1  # odd: centred on a sample
    if k > 1:
        y = uniform_filter1d(y, k, axis=0, mode="nearest")
        t_last_s = float(t_s[max(len(t_s) - 1 - k // 2, 0)])
    grid = t_last_s - dt * np.arange(int(history_s * rate_hz))[::-1]
    if grid[0] < t_s[0]:
        grid = grid[grid >= t_s[0]]
    steps = int(math.ceil((horizon_s + (t_s[-1] - t_last_s)) * rate_hz)) + 1
    t_out = t_last_s + dt * np.arange(steps + 1)
    vals, var = np.empty((steps + 1, y.shape[1])), np.empty((steps + 1, y.shape[1]))
    for c in range(y.shape[1]):  # a handful of series
        h = np.interp(grid, t_s, y[:, c])
        model = fit_ar(h, order, dt)
        if model is None:
            return None
        fc, v = forecast(model, h, steps)
        v = np.maximum(v, np.nan_to_num(backtest_variance(model, h, steps), nan=np.inf))
        vals[:, c] = np.r_[h[-1], fc]
        var[:, c] = np.r_[0.0, v]
    return t_out, vals, var


class MruBridge:
    """The log's attitude where it has one; in a gap (longer than the log's max_gap_s) the
    forecast from the samples before it, with its variance, up to where the predicted angle's
    1-sigma passes max_sigma_rad: beyond, no attitude (as the log alone)."""

    def __init__(self, log: MruLog, history_s: float, rate_hz: float, order: int, max_sigma_rad: float,
                 max_horizon_s: float = 60.0) -> None:
        self.log = log
        self.history_s, self.rate_hz, self.order = history_s, rate_hz, order
        self.max_var = max_sigma_rad ** 2
        self.max_horizon_s = max_horizon_s
        self.forecasts: dict[int, GapForecast | None] = {}  # by the gap's first sample after it

    @property
    def max_gap_s(self) -> float:
        return self.log.max_gap_s

    def attitude(self, t_s: float) -> tuple[np.ndarray, np.ndarray] | None:
        got = self.attitude_var(t_s)
        return None if got is None else got[:2]

    def attitude_var(self, t_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(rpy, rpy_rate, variances of the 6) at t_s: variances zero where the log has a sample."""
        att = self.log.attitude(t_s)
        if att is not None:
            return att[0], att[1], np.zeros(6)
        t = self.log.t_s
        if len(t) < 2 or t_s <= t[0]:
            return None
        j = int(t.searchsorted(t_s))  # the first sample after the gap (len(t): the log ended)
        if j not in self.forecasts:
            self.forecasts[j] = self._forecast(j)
        fc = self.forecasts[j]
        if fc is None or t_s > fc.t_s[-1]:
            return None
        var = np.array([np.interp(t_s, fc.t_s, fc.var[:, c]) for c in range(6)])
        if max(var[0], var[1]) > self.max_var:
            return None
        # the angles by a cubic through the values and their rates: linear between the 10 Hz
        # samples would be 0.0006 deg off a 1 deg, 8 s wave (the chord's sag)
        rpy = (fc.angles(t_s) + np.pi) % (2 * np.pi) - np.pi
        rates = np.array([np.interp(t_s, fc.t_s, fc.values[:, c]) for c in range(3, 6)])
        return rpy, rates, var

    def _forecast(self, j: int) -> GapForecast | None:
        t = self.log.t_s
        t_last = float(t[j - 1])
        horizon = min(float(t[j] - t_last) if j < len(t) else math.inf, self.max_horizon_s)
        keep = t >= t_last - self.history_s - 1.0
        keep[j:] = False
        y = np.column_stack([np.unwrap(self.log.rpy_rad[keep], axis=0), self.log.rpy_rate_radps[keep]])
        got = forecast_series(t[keep], y, t_last, horizon, self.history_s, self.rate_hz, self.order)
        if got is None:
            return None
        t_grid, values, var = got
        return GapForecast(t_grid, values, var, CubicHermiteSpline(t_grid, values[:, :3], values[:, 3:], axis=0))
