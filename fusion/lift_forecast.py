"""The touchdown forecast: the load's height above the deck and its relative vertical velocity
over the next seconds, and the clearance C that follows, so a "land now / wait" window can be
read off.

The height h (the underside centre's, above the deck below it) falls as the hoist pays out rope
(the operator's command, read by the hoist encoder) and swings with the waves (the two ships'
relative motion and the load's). The wave part y = h + l (l the rope paid out) is a narrow-band
process: an AR model fitted to its recent past (fusion.wave_predictor) runs it forward; the hoist
is taken to go on at its present rate. C is h less the lowest corner's offset below the centre,
held as it is at the issue (the load's tilt, slow beside the waves). The forecast's variances are
the model's backtested k-step errors over the series it was fitted to.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from boomtip.fusion.wave_predictor import backtest_variance, fit_ar, forecast

__all__ = ["TouchdownForecasts", "touchdown_forecasts"]

FORECAST_DT_S = 0.2  # the wave part resampled at this step (a 9 s wave: 45 samples a period)
AR_ORDER = 24  # 4.8 s of memory: half a wave period and more
ISSUE_EVERY_S = 0.5  # a forecast issued this often
STALE_STEPS = 2  # a grid point with no sample for this many steps is in a gap: no forecast, no fit across it


@dataclass
class TouchdownForecasts:
    """Forecasts issued at t_issue (I,), each over the leads (K,): the height, the relative
    vertical velocity, the clearance and their 1-sigma (I, K)."""

    t_issue: np.ndarray
    lead_s: np.ndarray
    height_m: np.ndarray
    relative_vz_mps: np.ndarray
    clearance_m: np.ndarray
    sigma_m: np.ndarray
    sigma_rate_mps: np.ndarray


def touchdown_forecasts(t_s: np.ndarray, height_m: np.ndarray, hoist_m: np.ndarray, horizon_s: float,
                        history_s: float, offset_m: np.ndarray | None = None) -> TouchdownForecasts:
    """Causal forecasts over a run: at each issue time, only what came before it is used.
    t_s, height_m (the filter's), hoist_m (the rope paid out) and offset_m (the lowest point's
    depth below the centre: height - C; none: 0) at the frames' times."""
    steps = int(round(horizon_s / FORECAST_DT_S))
    lead = FORECAST_DT_S * np.arange(1, steps + 1)
    offset_m = np.zeros_like(height_m) if offset_m is None else offset_m
    ok = np.isfinite(height_m) & np.isfinite(hoist_m) & np.isfinite(offset_m)
    empty = np.zeros((0, steps))
    if np.count_nonzero(ok) < 2:
        return TouchdownForecasts(np.zeros(0), lead, empty, empty, empty, empty, empty)
    t, h, l = t_s[ok], height_m[ok], hoist_m[ok]
    grid = np.arange(t[0], t[-1] + 1e-9, FORECAST_DT_S)
    # each grid point takes the last sample at or before it (no sample after it ever reaches a
    # forecast issued there); a point whose last sample is older than STALE_STEPS is in a gap
    last = np.searchsorted(t, grid + 1e-9, "right") - 1
    fresh = grid - t[last] <= STALE_STEPS * FORECAST_DT_S
    y, lg, og = (h + l)[last], l[last], offset_m[ok][last]
    n_hist = int(round(history_s / FORECAST_DT_S))
    issues, out = [], []
    stride = max(int(round(ISSUE_EVERY_S / FORECAST_DT_S)), 1)
    for k in range(max(3 * AR_ORDER, 2), len(grid), stride):  # one small fit per issue (a few hundred a run)
        start = max(0, k + 1 - n_hist)
        gap = np.flatnonzero(~fresh[start:k + 1])
        if not fresh[k] or (len(gap) and k - (start + gap[-1]) < 3 * AR_ORDER):
            continue  # in a gap, or too little since one to fit
        hist = y[start + (gap[-1] + 1 if len(gap) else 0):k + 1]
        model = fit_ar(hist, AR_ORDER, FORECAST_DT_S)
        if model is None:
            continue
        y_pred, _ = forecast(model, hist, steps + 1)  # one step more: the last lead's central difference
        var = backtest_variance(model, hist, steps)
        rate_l = (lg[k] - lg[k - 1]) / FORECAST_DT_S  # the hoist goes on as it goes now
        h_pred = y_pred[:steps] - (lg[k] + rate_l * lead)
        rate = _central_rate(np.concatenate([[hist[-1]], y_pred]))[None, :] - rate_l
        sig_rate = np.sqrt(_backtest_rate_variance(model, hist, steps))
        issues.append(grid[k])
        out.append((h_pred, rate[0], h_pred - og[k], np.sqrt(var), sig_rate))
    if not out:
        return TouchdownForecasts(np.zeros(0), lead, empty, empty, empty, empty, empty)
    h, r, c, s, sr = (np.array(v) for v in zip(*out))
    return TouchdownForecasts(np.array(issues), lead, h, r, c, s, sr)


def _central_rate(y: np.ndarray) -> np.ndarray:
    """(y[k+1] - y[k-1]) / 2 dt for k = 1..len-2 along the last axis."""
    return (y[..., 2:] - y[..., :-2]) / (2.0 * FORECAST_DT_S)


def _backtest_rate_variance(model, y: np.ndarray, steps: int) -> np.ndarray:
    """The variance of the forecast rate's error at each lead, over the series the model was
    fitted to (every sample an origin), as `backtest_variance` does for the level."""
    p = len(model.coeffs)
    z = np.asarray(y, dtype=float) - model.mean
    h = steps + 1
    origins = np.arange(p, len(z) - h)
    if len(origins) < 10:
        return np.full(steps, np.nan)
    buf = np.lib.stride_tricks.sliding_window_view(z, p)[origins - p].copy()
    pred = np.empty((len(origins), h + 1))
    pred[:, 0] = z[origins - 1]  # the last sample known at each origin
    for k in range(h):  # a recursion over forecast steps, vectorised over the origins
        nxt = buf[:, ::-1] @ model.coeffs
        pred[:, k + 1] = nxt
        buf = np.column_stack([buf[:, 1:], nxt])
    truth = np.stack([z[origins - 1 + k] for k in range(h + 1)], axis=1)
    return np.mean((_central_rate(pred) - _central_rate(truth)) ** 2, axis=0)
