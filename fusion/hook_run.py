"""The hook filter run over recorded measurement streams: :func:`run_hook_filter` applies every
sample at its time stamp, predicts in between and records the estimate at a fixed rate."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Literal, Sequence

import numpy as np

from boomtip.data.crane_model import CraneParams
from boomtip.data.hook_streams import HookMeasurements
from boomtip.fusion.consistency import Innovations
from boomtip.fusion.hook_config import HookFilterConfig
from boomtip.fusion.hook_kalman import HookFilter
from boomtip.fusion.rope_strain import rope_length
from boomtip.fusion.models.crane_pendulum import HOOK_COLS, hook_pos_vel_batch, sway_angles_from_directions

_OUTPUT_CHUNK = 8192  # recorded samples per block of the vectorised hook outputs

__all__ = ["HookMeasurements", "HookFilterRun", "HookRunChunk", "merged_events", "run_hook_filter", "with_levelling_bias"]


def with_levelling_bias(p_rel: np.ndarray, cov_p: np.ndarray, sigma_rad: float) -> np.ndarray:
    """The reported covariance of the hook relative to the tip: the filter's own plus a
    constant tilt of the levelling (sigma per horizontal axis), which moves the hook by
    l * tilt across the rope. A bias is not white noise: the filter cannot average it away,
    so it is added to what the filter reports rather than to its measurement noise."""
    if sigma_rad <= 0:
        return cov_p
    l2 = np.einsum("ni,ni->n", p_rel, p_rel)[:, None, None]
    u = p_rel / np.sqrt(np.maximum(l2[:, :, 0], 1e-12))
    across = np.eye(3) - u[:, :, None] * u[:, None, :]
    return cov_p + (sigma_rad**2) * l2 * across


def along_rope_sigma(p_rel: np.ndarray, sigma_m: np.ndarray | None, cov_m2: np.ndarray | None, default_m: float) -> np.ndarray:
    """Each fix's 1-sigma along the rope (its direction from the tip): u^T C u of its
    covariance where it has one, else its sigma, else the configured one."""
    with np.errstate(invalid="ignore", divide="ignore"):
        u = p_rel / np.linalg.norm(p_rel, axis=1, keepdims=True)
    var = np.full(len(p_rel), default_m ** 2)
    if sigma_m is not None:
        var = np.where(np.isfinite(sigma_m), np.asarray(sigma_m, dtype=float) ** 2, var)
    if cov_m2 is not None:
        along = np.einsum("ni,nij,nj->n", u, cov_m2, u)
        var = np.where(np.isfinite(along), along, var)
    return np.sqrt(var)


def with_length_sigma(p_rel: np.ndarray, cov_p: np.ndarray, length_sigma_m: np.ndarray) -> np.ndarray:
    """cov_p plus the rope length's uncertainty (1-sigma, m) along the rope."""
    u = p_rel / np.maximum(np.linalg.norm(p_rel, axis=1), 1e-9)[:, None]
    return cov_p + (np.asarray(length_sigma_m) ** 2)[:, None, None] * (u[:, :, None] * u[:, None, :])


@dataclass
class HookRunChunk:
    """Consecutive recorded samples of a run (what :class:`HookFilterRun` holds for the whole run)."""

    t: np.ndarray  # (M,)
    x: np.ndarray  # (M, n)
    p_rel: np.ndarray  # (M, 3) hook position relative to the boom tip, world axes
    v_rel: np.ndarray  # (M, 3)
    cov_p: np.ndarray  # (M, 3, 3)
    cov_v: np.ndarray  # (M, 3, 3) float32
    P_diag: np.ndarray  # (M, n) float32


@dataclass
class HookFilterRun:
    """A run's recorded samples (None when they went to a ``sink`` instead) and its statistics."""

    t: np.ndarray | None
    p_rel: np.ndarray | None  # (N, 3) hook position relative to the boom tip, world axes
    v_rel: np.ndarray | None
    cov_p: np.ndarray | None  # (N, 3, 3)
    cov_v: np.ndarray | None  # (N, 3, 3) float32
    x: np.ndarray | None  # (N, n)
    P_diag: np.ndarray | None  # (N, n) float32
    runtime_s: float
    realtime_fraction: float
    n_lidar_accepted: int
    n_lidar_rejected: int
    n_reacquired: int
    lidar_accepted: np.ndarray  # (K,) bool per LiDAR sample
    kind: str
    model: str
    n_rope_accepted: int = 0
    n_rope_rejected: int = 0
    nis: np.ndarray = field(default_factory=lambda: np.zeros(0))
    innovations: Innovations = field(default_factory=Innovations)  # every fix's NIS per stream (fusion.consistency)
    cpu_s: float = float("nan")  # the process's CPU time over the same loop as runtime_s
    n_samples: int = 0  # recorded samples


def merged_events(stamps: Sequence[np.ndarray], t_after: float, t_until: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One time-ordered event list over several sensors' time stamps, in (t_after, t_until]:
    (times float64, sensor = position in ``stamps`` int8, sample index int32). Equal times keep the
    sensor order (MRU, encoders, LiDAR), so the linear updates come before a LiDAR fix at the same
    stamp. Arrays, 13 bytes an event: a 700 s run has about 220,000 events, which as Python lists
    would take about 17 MB per estimator run (callers take a window of them as lists at a time)."""
    ev_t = np.concatenate([np.asarray(t, float) for t in stamps])
    ev_s = np.concatenate([np.full(len(t), k, np.int8) for k, t in enumerate(stamps)])
    ev_i = np.concatenate([np.arange(len(t), dtype=np.int32) for t in stamps])
    keep = (ev_t > t_after + 1e-9) & (ev_t <= t_until + 1e-9)
    order = np.lexsort((ev_s[keep], ev_t[keep]))
    return ev_t[keep][order], ev_s[keep][order], ev_i[keep][order]


def run_hook_filter(
    meas: HookMeasurements,
    kind: Literal["ekf", "ukf"] = "ekf",
    model: Literal["rigid", "flexible"] = "flexible",
    params: CraneParams | None = None,
    config: HookFilterConfig | None = None,
    *,
    t_end: float | None = None,
    output_rate_hz: float = 200.0,
    sink: Callable[[HookRunChunk], None] | None = None,
) -> HookFilterRun:
    """Run the filter over time-stamped measurement streams.

    The filter starts at the first LiDAR frame with a block fix or a rope direction
    (initialised from it and the latest encoder/MRU samples; a frame's rope direction is
    applied before its block fix), predicts at ``config.predict_rate_hz``, applies every
    measurement at its time stamp and records the estimate at ``output_rate_hz``.
    ``runtime_s`` is the wall-clock time of the whole loop (predictions, updates, output).
    An MRU sample and an encoder sample with the same time stamp are applied as one
    linear update (the same result as one after the other: H selects states, R is diagonal).
    The hook outputs (p_rel, v_rel and their covariances) are computed from the recorded
    states and covariance blocks in chunks of samples, vectorised (inside the timed region).
    ``sink``: each chunk of samples goes to it as it is complete (:class:`HookRunChunk`) and the
    run keeps none of them (memory flat in the run's length); the sink's own time is not counted
    in ``runtime_s`` and ``cpu_s``. Without a sink the run returns every sample.
    """
    params = params or CraneParams()
    filt = HookFilter(kind, model, params, config)
    n = filt.n
    rope, rope_cov = meas.rope_direction, meas.rope_cov
    rope_ok = np.zeros(len(meas.t_lidar), bool)
    if rope is not None and rope_cov is not None:
        rope_ok = np.all(np.isfinite(rope), 1) & np.all(np.isfinite(rope_cov.reshape(len(rope_cov), -1)), 1)
    valid = np.all(np.isfinite(meas.lidar_p_rel_tip_world), 1) | rope_ok
    has_fix = bool(valid.any())
    if has_fix:
        k0 = int(np.argmax(valid))
        t0 = float(meas.t_lidar[k0])
    else:
        # No LiDAR fix in the whole run (a block too far or hidden): start from the encoders with
        # the hook hanging straight down at the hoist length and bridge everything by prediction.
        k0 = -1
        t0 = float(max(meas.t_encoders[0], meas.t_mru[0]))
    ie = max(0, int(np.searchsorted(meas.t_encoders, t0, "right")) - 1)
    im = max(0, int(np.searchsorted(meas.t_mru, t0, "right")) - 1)
    t_last = max(meas.t_lidar[-1], meas.t_encoders[-1], meas.t_mru[-1])
    t_end = float(t_last if t_end is None else min(t_end, t_last))

    # merged event list: (time, priority, sensor, index); MRU, encoders, LiDAR at equal times
    ev_t_all, ev_s_all, ev_i_all = merged_events((meas.t_mru, meas.t_encoders, meas.t_lidar), t0, t_end)
    n_out = int(math.floor((t_end - t0) * output_rate_hz + 1e-6)) + 1
    t_out = t0 + np.arange(n_out) / output_rate_hz
    # per output sample: diag(P) (n) and P's hook block P[HOOK_IX] (36), from the flat P; both,
    # and the states, buffered for one chunk of samples at a time
    flat_idx = np.concatenate([np.arange(n) * (n + 1), np.ravel_multi_index(np.ix_(HOOK_COLS, HOOK_COLS), (n, n)).ravel()])
    chunk = min(_OUTPUT_CHUNK, n_out)
    x_buf = np.empty((chunk, n))
    pb_buf = np.empty((chunk, len(flat_idx)))
    if sink is None:
        x_all, p_all, v_all = np.empty((n_out, n)), np.empty((n_out, 3)), np.empty((n_out, 3))
        cp_all = np.empty((n_out, 3, 3))
        cv_all = np.empty((n_out, 3, 3), np.float32)  # diagnostics: float32 is plenty
        pd_all = np.empty((n_out, n), np.float32)
    sink_s = sink_cpu_s = 0.0

    def flush(a: int, b: int) -> None:
        """Samples a..b-1 (in the buffers from row 0): the hook outputs, vectorised (the 3 x 6
        Jacobians and their products are several times the outputs' size)."""
        nonlocal sink_s, sink_cpu_s
        m = b - a
        p, v, Hp, Hv = hook_pos_vel_batch(x_buf[:m])
        Ps = pb_buf[:m, n:].reshape(m, 6, 6)
        cp = with_levelling_bias(p, Hp @ Ps @ Hp.transpose(0, 2, 1), filt.cfg.levelling_bias_sigma_rad)
        if rope_len is not None:  # the length correction's own uncertainty, along the rope
            cp = with_length_sigma(p, cp, rope_len.correction(t_out[a:b], np.linalg.norm(p, axis=1))[1])
        cv = (Hv @ Ps @ Hv.transpose(0, 2, 1)).astype(np.float32)
        pd = pb_buf[:m, :n].astype(np.float32)
        if sink is None:
            x_all[a:b], p_all[a:b], v_all[a:b], cp_all[a:b], cv_all[a:b], pd_all[a:b] = x_buf[:m], p, v, cp, cv, pd
            return
        s0, c0 = time.perf_counter(), time.process_time()
        sink(HookRunChunk(t_out[a:b], x_buf[:m].copy(), p, v, cp, cv, pd))
        sink_s += time.perf_counter() - s0
        sink_cpu_s += time.process_time() - c0

    lidar_ok = np.zeros(len(meas.t_lidar), bool)
    lid, enc, mru = meas.lidar_p_rel_tip_world, meas.encoders, meas.mru
    lid_sigma = meas.lidar_sigma_m
    lid_cov = meas.lidar_cov_m2
    rope_len = None
    c = filt.cfg
    if (c.rope_strain_sigma > 0 or c.rope_offset_sigma_m > 0) and len(enc) and len(lid):  # the rope longer than read
        along = along_rope_sigma(lid, lid_sigma, lid_cov, c.measurement.sigma_lidar_m)
        if meas.lidar_model_fit is not None:  # a sparse fix's point on the block is not the model's: no length
            along = np.where(meas.lidar_model_fit, along, np.nan)
        rope_len = rope_length(meas.t_lidar, lid, along, meas.t_encoders, enc[:, 2], c.rope_offset_sigma_m, c.rope_strain_sigma,
                           c.rope_offset_walk_m_per_sqrt_s, c.rope_strain_walk_per_sqrt_s)
        enc = enc.copy()
        enc[:, 2] += rope_len.correction(meas.t_encoders, enc[:, 2])[0]
    enc_ok = np.isfinite(enc[:, 2]).tolist() if len(enc) else []

    rope_z = rope_R = None
    rope_conv_ok: list[bool] = []

    def lidar_frame(i: int, te: float | None = None) -> None:
        """One LiDAR frame: its rope direction, then its block fix."""
        if rope_ok[i]:
            if rope_conv_ok[i]:
                filt.update_sway_angles(rope_z[i], rope_R[i], rope[i], t=te)
            else:  # (no sway angles from this direction: update_rope says so)
                filt.update_rope(rope[i], rope_cov[i], t=te)
        lidar_ok[i] = filt.update_lidar(lid[i], t=te, sigma_m=None if lid_sigma is None else lid_sigma[i],
                                        cov_m2=None if lid_cov is None else lid_cov[i])

    tic, cpu0 = time.perf_counter(), time.process_time()
    if rope_ok.any():  # the rope's sway angles and their covariances, all frames at once
        rope_z, rope_R = sway_angles_from_directions(rope, rope_cov)
        rope_conv_ok = (np.all(np.isfinite(rope_z), 1) & np.all(np.isfinite(rope_R.reshape(len(rope_R), 4)), 1)).tolist()
    if not has_fix:
        filt.initialize_from_measurements(np.array([0.0, 0.0, -1.0]), enc[ie], mru[im], t0)
    elif rope_ok[k0]:  # the sway from the rope's direction, then the whole frame as any other
        filt.initialize_from_measurements(rope[k0], enc[ie], mru[im], t0)
        lidar_frame(k0)
    else:  # the sway from the block fix, which is then used
        filt.initialize_from_measurements(lid[k0], enc[ie], mru[im], t0)
        lidar_ok[k0] = True
    j0 = 0  # the first event not yet applied
    n_ev_all = len(ev_t_all)
    for a in range(0, n_out, chunk):
        # this chunk's events as Python lists (the loop indexes them one by one; lists index
        # faster than arrays), plus one beyond for the MRU + encoder pairing's look-ahead
        t_chunk = t_out[a:a + chunk].tolist()
        j1 = min(int(np.searchsorted(ev_t_all, t_chunk[-1] + 1e-9, "right")) + 1, n_ev_all)
        ev_t, ev_s, ev_i = ev_t_all[j0:j1].tolist(), ev_s_all[j0:j1].tolist(), ev_i_all[j0:j1].tolist()
        n_ev = j1 - j0
        j = 0
        for k, tk in enumerate(t_chunk, a):
            while j < n_ev and ev_t[j] <= tk + 1e-9:
                s, i, te = ev_s[j], ev_i[j], ev_t[j]
                if s == 0:
                    if j + 1 < n_ev and ev_s[j + 1] == 1 and ev_t[j + 1] - te <= 1e-9 and enc_ok[ev_i[j + 1]]:
                        filt.update_mru_and_encoders(mru[i], enc[ev_i[j + 1]], t=te)
                        j += 2
                        continue
                    filt.update_mru_sample(mru[i], t=te)
                elif s == 1:
                    e = enc[i]
                    filt.update_encoders(e[0], e[1], e[2], t=te)
                else:
                    lidar_frame(i, te)
                j += 1
            x_k, P_k = filt.estimate_at(tk)
            r = k - a
            x_buf[r] = x_k
            P_k.take(flat_idx, out=pb_buf[r])
        flush(a, k + 1)
        j0 += j
    runtime = time.perf_counter() - tic - sink_s
    cpu_s = time.process_time() - cpu0 - sink_cpu_s
    kept = sink is None
    return HookFilterRun(
        t=t_out if kept else None, p_rel=p_all if kept else None, v_rel=v_all if kept else None,
        cov_p=cp_all if kept else None, cov_v=cv_all if kept else None, x=x_all if kept else None,
        P_diag=pd_all if kept else None,
        runtime_s=runtime, realtime_fraction=runtime / max(t_end - t0, 1e-9),
        n_lidar_accepted=filt.n_lidar_accepted, n_lidar_rejected=filt.n_lidar_rejected,
        n_reacquired=filt.n_reacquired, lidar_accepted=lidar_ok, kind=kind, model=model,
        n_rope_accepted=filt.n_rope_accepted, n_rope_rejected=filt.n_rope_rejected,
        nis=np.array(filt.nis_history), innovations=filt.innovations, cpu_s=cpu_s, n_samples=n_out,
    )
