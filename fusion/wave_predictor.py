"""A wave-band predictor for D when every sensor is silent: an autoregressive model fitted by
least squares to the filter's own recent estimates (the last minute, a few samples per second)
and run forward. Relative heave is a narrow-band wave process: an AR model of modest order
follows its oscillation for seconds, where the constant-acceleration filter (document 000's
model) runs away quadratically. Its variance grows with the model's own impulse response.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ArModel:
    coeffs: np.ndarray  # (p,) y_k = sum_i a_i y_{k-i} + e_k, on the mean-removed series
    mean: float
    sigma: float  # 1-sigma of the one-step residual
    dt_s: float


def fit_ar(y: np.ndarray, order: int, dt_s: float) -> ArModel | None:
    """Least-squares AR(order) of a regularly sampled series; None when there is too little."""
    y = np.asarray(y, dtype=float)
    if len(y) < 3 * order or not np.all(np.isfinite(y)):
        return None
    mean = float(y.mean())
    z = y - mean
    # rows: [z_{k-1}, ..., z_{k-p}] -> z_k
    X = np.lib.stride_tricks.sliding_window_view(z[:-1], order)[:, ::-1]
    target = z[order:]
    coeffs, *_ = np.linalg.lstsq(X, target, rcond=None)
    resid = target - X @ coeffs
    return ArModel(coeffs, mean, float(np.sqrt(np.mean(resid**2))), dt_s)


def forecast(model: ArModel, history: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """The next `steps` values after `history` (its last `order` samples) and their variance."""
    p = len(model.coeffs)
    buf = list(np.asarray(history[-p:], dtype=float) - model.mean)
    out = np.empty(steps)
    for k in range(steps):  # a recursion over forecast steps (tens), not over points
        nxt = float(np.dot(model.coeffs, buf[::-1][:p]))
        out[k] = nxt
        buf.append(nxt)
        buf = buf[-p:]
    # impulse response psi_j of the AR filter: var_k = sigma^2 sum_{j<k} psi_j^2
    psi = np.zeros(steps)
    psi[0] = 1.0
    for j in range(1, steps):
        m = min(j, p)
        psi[j] = float(np.dot(model.coeffs[:m], psi[j - 1::-1][:m]))
    var = model.sigma**2 * np.cumsum(psi**2)
    return out + model.mean, var


def backtest_variance(model: ArModel, y: np.ndarray, steps: int) -> np.ndarray:
    """The variance of the model's k-step forecast errors (k = 1..steps) over the series it was
    fitted to, every sample an origin: the model's own variance (its one-step residual through
    its impulse response) assumes the model is the process; a broadband sea's AR of modest
    order is not, and its k-step errors can be several times that sigma a few seconds ahead.
    steps is cut to what the series holds (at least 10 origins per step); the last value
    stands for the steps beyond."""
    p = len(model.coeffs)
    z = np.asarray(y, dtype=float) - model.mean
    n_orig = len(z) - p - steps
    h = steps if n_orig >= 10 else max(len(z) - p - 10, 0)
    if h < 1:
        return np.full(steps, np.nan)
    origins = np.arange(p, len(z) - h)  # the first forecast sample of each origin
    buf = np.lib.stride_tricks.sliding_window_view(z, p)[origins - p].copy()  # (O, p), oldest first
    err2 = np.empty(h)
    for k in range(h):  # a recursion over forecast steps, vectorised over the origins
        nxt = buf[:, ::-1] @ model.coeffs
        err2[k] = np.mean((nxt - z[origins + k]) ** 2)
        buf = np.column_stack([buf[:, 1:], nxt])
    return np.concatenate([err2, np.full(steps - h, err2[-1])])
