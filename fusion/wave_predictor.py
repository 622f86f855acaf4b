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
