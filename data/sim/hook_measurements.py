"""Sensor emulation for the hook filter (document 002 4.5.1, 5.1.3): the crane truth sampled at
the sensors' rates plus white Gaussian noise, as the streams the filter takes."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from pydantic import BaseModel

from boomtip.data.crane_model import DEG
from boomtip.data.sim.crane_truth import CraneTruth
from boomtip.data.hook_streams import HookMeasurements

__all__ = ["SensorSimConfig", "measurements_from_truth"]


class SensorSimConfig(BaseModel):
    """Sensor emulation (document 002 4.5.1): rates and true noise sigmas."""

    lidar_rate_hz: float = 20.0
    encoder_rate_hz: float = 100.0
    mru_rate_hz: float = 200.0
    sigma_lidar_m: float = 0.015
    sigma_encoder_rad: float = 0.1 * DEG
    sigma_hoist_m: float = 0.01
    sigma_mru_angle_rad: float = 0.02 * DEG
    sigma_mru_rate_rad_s: float = 0.025 * DEG
    # the rope's direction in the LiDAR frames (not in document 002): None = no rope stream;
    # perception.rope's per-frame noise on an OS1-128 is of the order of 0.1 mrad
    sigma_rope_rad: float | None = None


def _decimate(t: np.ndarray, rate_hz: float) -> np.ndarray:
    dt = t[1] - t[0]
    step = int(round(1.0 / (rate_hz * dt)))
    if step < 1 or abs(step * dt * rate_hz - 1.0) > 1e-6:
        raise ValueError(f"sensor rate {rate_hz} Hz must divide the truth rate {1 / dt} Hz")
    return np.arange(0, len(t), step)


def measurements_from_truth(
    truth: CraneTruth,
    sensors: SensorSimConfig | None = None,
    seed: int | np.random.Generator | None = 0,
    lidar_dropouts: Sequence[tuple[float, float]] = (),
    lidar_outliers: Sequence[tuple[float, Sequence[float]]] = (),
    rope_dropouts: Sequence[tuple[float, float]] = (),
) -> HookMeasurements:
    """Emulate the sensors (truth + white Gaussian noise, document 002 5.1.3).

    ``lidar_dropouts``: (t0, t1) windows without block detections (NaN rows).
    ``lidar_outliers``: (t, offset_m (3,)) wrong detections: the fix nearest to t is
    replaced by truth + offset.
    ``rope_dropouts``: windows without rope directions (with ``sensors.sigma_rope_rad``).
    """
    s = sensors or SensorSimConfig()
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    t = truth.t
    il = _decimate(t, s.lidar_rate_hz)
    ie = _decimate(t, s.encoder_rate_hz)
    im = _decimate(t, s.mru_rate_hz)
    lid = truth.p_hook_rel_tip[il] + rng.normal(0, s.sigma_lidar_m, (len(il), 3))
    lid[_in_windows(t[il], lidar_dropouts)] = np.nan
    for to, off in lidar_outliers:
        k = int(np.argmin(np.abs(t[il] - to)))
        lid[k] = truth.p_hook_rel_tip[il[k]] + np.asarray(off, float)
    enc = np.stack([truth.nu[ie], truth.mu[ie], truth.l[ie]], 1)
    enc += rng.normal(0, 1, enc.shape) * np.array([s.sigma_encoder_rad, s.sigma_encoder_rad, s.sigma_hoist_m])
    mru = np.stack([truth.roll[im], truth.pitch[im], truth.roll_dot[im], truth.pitch_dot[im]], 1)
    mru += rng.normal(0, 1, mru.shape) * np.array(
        [s.sigma_mru_angle_rad, s.sigma_mru_angle_rad, s.sigma_mru_rate_rad_s, s.sigma_mru_rate_rad_s])
    meas = HookMeasurements(t[il].copy(), lid, t[ie].copy(), enc, t[im].copy(), mru)
    if s.sigma_rope_rad is not None:
        meas.rope_direction, meas.rope_cov = _rope_directions(truth.p_hook_rel_tip[il], s.sigma_rope_rad, rng)
        meas.rope_direction[_in_windows(t[il], rope_dropouts)] = np.nan
    return meas


def _in_windows(t: np.ndarray, windows: Sequence[tuple[float, float]]) -> np.ndarray:
    out = np.zeros(len(t), bool)
    for t0, t1 in windows:
        out |= (t >= t0) & (t < t1)
    return out


def _rope_directions(p_rel: np.ndarray, sigma_rad: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Directions tip -> hook tilted by isotropic noise sigma_rad across the rope, and their
    covariances (rank 2)."""
    u = p_rel / np.linalg.norm(p_rel, axis=1, keepdims=True)
    a = np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(u, e1)
    n = rng.normal(0.0, sigma_rad, (len(u), 2))
    d = u + n[:, :1] * e1 + n[:, 1:] * e2
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cov = sigma_rad**2 * (np.einsum("ni,nj->nij", e1, e1) + np.einsum("ni,nj->nij", e2, e2))
    return d, cov
