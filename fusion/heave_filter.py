"""Relative-heave Kalman filter (document 000, section 4.2).

State x = [D, D_dot, D_ddot] (m, m/s, m/s^2): the distance from the boom tip straight down to the
feeder deck, its rate and its acceleration. Constant-acceleration model driven by white-noise
jerk of power spectral density q (m^2/s^5). Measurements are scalar D (deck / reflector detection)
or D_dot (radar Doppler), each with its own sigma, fused as they come (no correction when one is
missing).

Beyond the document's filter:
- chi-square gating on the normalised innovation, with re-initialisation of a component after too
  many consecutive rejections (so a real jump cannot lock the filter out for ever);
- exact out-of-sequence handling: measurements are kept in acquisition-time order with a filter
  checkpoint after each; a late measurement rolls the filter back and replays, which gives exactly
  what in-order processing would give.

Built on filterpy's ``KalmanFilter``; checkpoints hold plain (x, P) arrays that are loaded back into
the one filter object (no per-step deep copies).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from filterpy.kalman import KalmanFilter
from pydantic import BaseModel, ConfigDict, Field, field_validator
from scipy.stats import chi2

from boomtip.fusion.consistency import Innovations
from boomtip.fusion.noise_matching import NoiseMatch, matched_ratio

Quantity = Literal["D", "D_dot"]
Status = Literal["accepted", "gated", "too_old", "reinitialised", "invalid"]

# Row of H (and state index) per measured quantity.
_INDEX = {"D": 0, "D_dot": 1}
_H = {
    "D": np.array([[1.0, 0.0, 0.0]]),
    "D_dot": np.array([[0.0, 1.0, 0.0]]),
}


class HeaveFilterConfig(BaseModel):
    """Tuning of the relative-heave filter."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    # ~ a 2 m, 10 s heave under jerk_psd_from_sea_state's rule; fusion.tuning sizes it from a sea state.
    jerk_psd: float = Field(0.2, gt=0.0, description="q, white-jerk PSD [m^2/s^5]")
    gate_chi2_probability: float = Field(0.9999, gt=0.0, lt=1.0)
    max_delay_s: float = Field(1.0, ge=0.0, description="oldest accepted t_acq behind the newest")
    initial_sigma: tuple[float, float, float] = Field(
        (1.0, 1.0, 1.0), description="1-sigma of [D, D_dot, D_ddot] for unmeasured components"
    )
    max_consecutive_rejections: int = Field(10, ge=0)
    noise_memory_s: float = Field(5.0, ge=0.0, description="a source noisier than its sigma says has its variance "
                                  "widened by covariance matching over about this much of its recent innovations "
                                  "(fusion.noise_matching; 0: sigmas as given)")
    # D's sigma while D has never been measured and no initial_D was given (Doppler-only runs).
    unknown_D_sigma_m: float = Field(100.0, gt=0.0)

    @field_validator("initial_sigma")
    @classmethod
    def _positive(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if not all(math.isfinite(s) and s > 0.0 for s in v):
            raise ValueError("initial_sigma entries must be finite and > 0")
        return v


def jerk_psd_from_sea_state(components: Iterable[tuple[float, float]]) -> float:
    """White-jerk PSD q [m^2/s^5] matching a sum of sinusoidal relative-heave components.

    ``components`` are (amplitude_m, period_s) of the relative heave D (both ships' heave and the
    lever-arm terms already summed upstream).

    Rule: a component A sin(w t) has jerk amplitude A w^3, i.e. jerk variance A^2 w^6 / 2.
    White noise of PSD q averaged over a time tau has variance q / tau; taking each component's
    correlation time tau = 1 / w = T / (2 pi) and equating gives q_k = A^2 w^5 / 2, and
    q = sum(q_k). (Equivalently: total jerk variance times its variance-weighted correlation time.)
    Summing per component keeps q monotonic: it grows with any amplitude, falls with any period.
    """
    comps = [(float(a), float(t)) for a, t in components]
    if not comps:
        raise ValueError("need at least one (amplitude_m, period_s) component")
    if any(not (math.isfinite(a) and math.isfinite(t)) or t <= 0.0 or a < 0.0 for a, t in comps):
        raise ValueError("amplitudes must be >= 0 and periods > 0")
    q = sum(a * a * (2.0 * math.pi / t) ** 5 / 2.0 for a, t in comps)
    if q <= 0.0:
        raise ValueError("all amplitudes are zero: no jerk to match")
    return q


def transition_matrix(dt_s: float) -> np.ndarray:
    """F(dt) of the constant-acceleration model."""
    return np.array([[1.0, dt_s, 0.5 * dt_s * dt_s], [0.0, 1.0, dt_s], [0.0, 0.0, 1.0]])


def process_noise(dt_s: float, jerk_psd: float) -> np.ndarray:
    """Q(dt), the exact discretisation of white jerk with PSD ``jerk_psd``."""
    d2 = dt_s * dt_s
    d3 = d2 * dt_s
    d4 = d3 * dt_s
    d5 = d4 * dt_s
    return jerk_psd * np.array(
        [
            [d5 / 20.0, d4 / 8.0, d3 / 6.0],
            [d4 / 8.0, d3 / 3.0, d2 / 2.0],
            [d3 / 6.0, d2 / 2.0, dt_s],
        ]
    )


def predict_state(
    x: np.ndarray, P: np.ndarray, dt_s: float, jerk_psd: float
) -> tuple[np.ndarray, np.ndarray]:
    """(F x, F P F^T + Q) for dt_s >= 0, written out in scalars.

    Same numbers as the matrix form; about 6x faster for 3x3, which matters for estimate() at
    200 Hz. Uses the upper triangle of P (P is kept symmetric), so the result is exactly symmetric.
    """
    t = dt_s
    h = 0.5 * t * t
    (p00, p01, p02), (_, p11, p12), (_, _, p22) = P.tolist()
    x0, x1, x2 = np.ravel(x).tolist()
    # Rows of A = F P (row 2 is P's own), then M = A F^T.
    a00 = p00 + t * p01 + h * p02
    a01 = p01 + t * p11 + h * p12
    a02 = p02 + t * p12 + h * p22
    a11 = p11 + t * p12
    a12 = p12 + t * p22
    t2 = t * t
    t3 = t2 * t
    q = jerk_psd
    m00 = a00 + t * a01 + h * a02 + q * t3 * t2 / 20.0
    m01 = a01 + t * a02 + q * t2 * t2 / 8.0
    m02 = a02 + q * t3 / 6.0
    m11 = a11 + t * a12 + q * t3 / 3.0
    m12 = a12 + q * t2 / 2.0
    m22 = p22 + q * t
    x_pred = np.array([x0 + t * x1 + h * x2, x1 + t * x2, x2])
    P_pred = np.array([[m00, m01, m02], [m01, m11, m12], [m02, m12, m22]])
    return x_pred, P_pred


@dataclass(frozen=True, slots=True)
class Measurement:
    """One scalar measurement of D [m] or D_dot [m/s]."""

    t_acq_s: float  # when the sensor saw it
    t_arrival_s: float  # when it reaches the filter (>= t_acq_s); add() is called in this order
    quantity: Quantity
    value: float
    sigma: float  # 1-sigma noise, same unit as value
    source: str
    sigma_systematic: float = 0.0  # 1-sigma of a bias no averaging removes (reported, not filtered)
    sigma_clock_s: float = 0.0  # 1-sigma of its time stamp's offset: a bias of the rate times it (reported)

    def __post_init__(self) -> None:
        if self.quantity not in _INDEX:
            raise ValueError(f"quantity must be 'D' or 'D_dot', got {self.quantity!r}")
        if self.t_arrival_s < self.t_acq_s:
            raise ValueError("t_arrival_s must be >= t_acq_s")


@dataclass(frozen=True, slots=True)
class _Checkpoint:
    """Filter state right after processing one measurement (or the start state)."""

    t_s: float
    x: np.ndarray  # (3, 1); never mutated in place, so entries can share arrays
    P: np.ndarray  # (3, 3)
    known: tuple[bool, bool]  # D, D_dot measured at least once
    rejected: tuple[tuple, tuple]  # recent consecutive gated (t, value, sigma) of D, D_dot
    noise: tuple[tuple[str, NoiseMatch], ...] = ()  # per source: how much noisier than stated it is


@dataclass(slots=True)
class _Entry:
    key: tuple
    m: Measurement
    status: Status
    after: _Checkpoint
    nis: float = math.nan  # the normalised innovation squared it met (NaN: it set its component)
    noise_scale: float = 1.0  # the factor its stated variance was widened by (noise_matching)


def _consistent(rejected: tuple, m: "Measurement") -> bool:
    """Do the recent rejected measurements and m lie on one straight line within 3 sigma?"""
    t = np.array([r[0] for r in rejected] + [m.t_acq_s])
    v = np.array([r[1] for r in rejected] + [m.value])
    sig = np.array([r[2] for r in rejected] + [m.sigma])
    if np.ptp(t) <= 0:
        return bool(np.ptp(v) <= 3 * sig.max())
    coef = np.polyfit(t - t[-1], v, 1)
    resid = v - np.polyval(coef, t - t[-1])
    return bool(np.sqrt(np.mean(resid**2)) <= 3 * np.sqrt(np.mean(sig**2)))


def _inv_1x1(S: np.ndarray) -> np.ndarray:
    """Inverse of the (1, 1) innovation covariance; filterpy lets us replace its np.linalg.inv."""
    return 1.0 / S


def _sym(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)


class HeaveFilter:
    """Relative-heave filter with gating and exact out-of-sequence measurement handling.

    Call ``add`` in arrival order; acquisition times may be out of order by up to
    ``config.max_delay_s``. Call ``estimate`` at any time for the causal estimate.
    """

    def __init__(self, config: HeaveFilterConfig | None = None, initial_D: float | None = None):
        self.config = config or HeaveFilterConfig()
        self.gate = float(chi2.ppf(self.config.gate_chi2_probability, df=1))
        sig = self.config.initial_sigma
        # Prior for components not measured yet. Without initial_D, D starts at 0 with a large
        # variance: a D_dot-only filter then integrates D, which drifts (expected).
        d0 = 0.0 if initial_D is None else float(initial_D)
        sd0 = self.config.unknown_D_sigma_m if initial_D is None else sig[0]
        self._initial_D = initial_D
        self._x0 = np.array([[d0], [0.0], [0.0]])
        self._P0 = np.diag([sd0**2, sig[1] ** 2, sig[2] ** 2])
        self._kf = KalmanFilter(dim_x=3, dim_z=1)
        self._kf.inv = _inv_1x1
        self._entries: list[_Entry] = []  # processed measurements, acquisition-time order
        self._keys: list[tuple] = []  # their sort keys, for bisect
        self._base: _Checkpoint | None = None  # state before the first entry (None: nothing yet)
        # (measurement, status) for everything add() did not accept, as decided on arrival.
        # A later replay may revise a buffered measurement's gating; add() reports the first call.
        self.rejected: list[tuple[Measurement, Status]] = []
        # the NIS of measurements that can no longer be replayed: final
        self._settled_nis = Innovations()

    # ---- public API -------------------------------------------------------------------------

    def add(self, m: Measurement) -> Status:
        """Process one measurement (in arrival order) and return its status.

        "accepted": applied (the first measurement of a quantity sets that component);
        "gated": normalised innovation y^2/S above the chi-square gate, not applied;
        "reinitialised": out of the gate after max_consecutive_rejections gated ones in a row, so
        the component was restarted from it; "too_old": t_acq more than max_delay_s behind the
        newest processed measurement; "invalid": non-finite value/time or sigma <= 0.
        A late (out-of-sequence) measurement is inserted in acquisition order and the filter is
        replayed from the checkpoint before it, re-deciding the gating of every later one.
        """
        if not (
            math.isfinite(m.value) and math.isfinite(m.sigma) and m.sigma > 0.0
            and math.isfinite(m.t_acq_s)
        ):
            return self._reject(m, "invalid")
        newest = self._newest()
        if newest is not None and m.t_acq_s < newest.t_s - self.config.max_delay_s:
            return self._reject(m, "too_old")

        # Canonical order: ties in t_acq are broken by content, not arrival, so the result does
        # not depend on the arrival order at all.
        key = (m.t_acq_s, m.quantity, m.source, m.value, m.sigma)
        pos = bisect_right(self._keys, key)
        self._keys.insert(pos, key)
        # Status and checkpoint are placeholders; the replay below fills them in.
        self._entries.insert(pos, _Entry(key, m, "invalid", self._base))  # type: ignore[arg-type]
        # Roll back to the checkpoint just before the new measurement and replay forward.
        cp = self._entries[pos - 1].after if pos > 0 else self._base
        for entry in self._entries[pos:]:
            entry.status, entry.after, entry.nis, entry.noise_scale = self._step(cp, entry.m)
            cp = entry.after
        status = self._entries[pos].status
        self._prune()
        if status == "gated":
            self.rejected.append((m, status))
        return status

    def estimate(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Causal estimate (x (3,), P (3,3)) at ``t_s``; does not change the filter.

        For t_s at or after the newest processed acquisition time, the newest state is predicted
        forward. For an earlier t_s (backward prediction is not possible) the filter's own history
        is used: the checkpoint at or before t_s, predicted forward to t_s, i.e. what the filter
        knew from measurements acquired up to t_s. Before the retained history (max_delay_s) the
        oldest retained checkpoint is returned as is. Before any measurement: NaNs (D =
        initial_D if given) with a large P.
        """
        cp = self._checkpoint_at(t_s)
        if cp is None:
            x = np.array([np.nan if self._initial_D is None else self._initial_D, np.nan, np.nan])
            big = self.config.unknown_D_sigma_m**2
            return x, np.diag([self._P0[0, 0], big, big])
        dt_s = t_s - cp.t_s
        if dt_s <= 0.0:
            return cp.x[:, 0].copy(), cp.P.copy()
        return predict_state(cp.x, cp.P, dt_s, self.config.jerk_psd)

    def innovations(self) -> Innovations:
        """The NIS (one degree of freedom) and noise scale of every measurement that met the
        filter's prediction, per source, at its acquisition time (a gated one too: its innovation
        is evidence all the same)."""
        out = Innovations.merged([self._settled_nis])
        for e in self._entries:
            out.add(e.m.source, e.m.t_acq_s, e.nis, 1, e.noise_scale)  # a NaN NIS (not met) is not kept
        return out

    @property
    def last_time_s(self) -> float:
        """Newest processed acquisition time (NaN before any measurement)."""
        newest = self._newest()
        return math.nan if newest is None else newest.t_s

    # ---- internals --------------------------------------------------------------------------

    def _reject(self, m: Measurement, status: Status) -> Status:
        self.rejected.append((m, status))
        return status

    def _newest(self) -> _Checkpoint | None:
        return self._entries[-1].after if self._entries else self._base

    def _checkpoint_at(self, t_s: float) -> _Checkpoint | None:
        newest = self._newest()
        if newest is None or t_s >= newest.t_s:
            return newest
        i = bisect_right(self._keys, (t_s, "\uffff"))  # entries with t_acq <= t_s
        if i > 0:
            return self._entries[i - 1].after
        # The base is the newest state before the entries: at or before t_s, or else the oldest
        # retained one (returned as is by estimate()).
        return self._base if self._base is not None else self._entries[0].after

    def _prune(self) -> None:
        """Fold entries older than max_delay_s into the base checkpoint: they can never move."""
        horizon_s = self._entries[-1].after.t_s - self.config.max_delay_s
        n = 0
        while n < len(self._entries) and self._entries[n].after.t_s < horizon_s:
            n += 1
        if n:
            for e in self._entries[:n]:
                self._settled_nis.add(e.m.source, e.m.t_acq_s, e.nis, 1, e.noise_scale)
            self._base = self._entries[n - 1].after
            del self._entries[:n]
            del self._keys[:n]

    def _step(self, prev: _Checkpoint | None, m: Measurement) -> tuple[Status, _Checkpoint, float, float]:
        """Predict ``prev`` to m.t_acq_s and apply m; pure apart from the scratch filterpy object.
        Also returns the normalised innovation squared m met (NaN when it set its component) and
        the factor its variance was widened by."""
        kf = self._kf
        if prev is None:  # first measurement ever: start from the prior at its time
            kf.x, kf.P = self._x0, self._P0
            known, rejected, noise = [False, False], [(), ()], {}
        else:
            kf.x, kf.P = prev.x, prev.P
            known, rejected, noise = list(prev.known), list(prev.rejected), dict(prev.noise)
            dt_s = m.t_acq_s - prev.t_s
            if dt_s > 0.0:
                kf.F = transition_matrix(dt_s)
                kf.Q = process_noise(dt_s, self.config.jerk_psd)
                kf.predict()
                kf.P = _sym(kf.P)

        i = _INDEX[m.quantity]
        stated_var = m.sigma * m.sigma
        match = noise.get(m.source, NoiseMatch())
        var = stated_var * match.scale
        nis = math.nan
        if not known[i]:
            status = "accepted"  # the first measurement of a quantity sets that component
            self._set_component(i, m.value, var)
            known[i] = True
            rejected[i] = ()
        else:
            y = m.value - kf.x[i, 0]
            nis = y * y / (kf.P[i, i] + stated_var)  # the monitor's: against the noise as stated
            if self.config.noise_memory_s > 0:
                ratio = matched_ratio(np.array([y]), np.array([[stated_var]]), kf.P[i:i + 1, i:i + 1], self.gate,
                                       match.scale)
                noise[m.source] = match.after(m.t_acq_s, ratio, self.config.noise_memory_s)
            if y * y / (kf.P[i, i] + var) <= self.gate:
                # (1,1) arrays: a column z, as filterpy needs with H, and R not scalar (skips eye()).
                kf.update(np.array([[m.value]]), R=np.array([[var]]), H=_H[m.quantity])  # Joseph
                kf.P = _sym(kf.P)
                status, rejected[i] = "accepted", ()
            elif len(rejected[i]) >= self.config.max_consecutive_rejections and _consistent(rejected[i], m):
                # The rejected measurements agree with each other (a straight line through them
                # within 3 sigma): the quantity has really moved, or the filter diverged. Restart
                # from the data. Garbage (a bad plane, a bad spin estimate) does not agree with
                # itself and stays gated.
                self._set_component(i, m.value, var)
                status, rejected[i] = "reinitialised", ()
            else:
                status = "gated"  # not applied; the state stays predicted to t_acq
                keep = self.config.max_consecutive_rejections
                rejected[i] = (rejected[i] + ((m.t_acq_s, m.value, m.sigma),))[-keep:] if keep else ()
        return status, _Checkpoint(m.t_acq_s, kf.x, kf.P, (known[0], known[1]),
                                   (rejected[0], rejected[1]), tuple(noise.items())), float(nis), match.scale

    def _set_component(self, i: int, value: float, var: float) -> None:
        """Replace component i by a measurement: old correlations with it no longer hold."""
        kf = self._kf
        x = kf.x.copy()
        P = kf.P.copy()
        x[i, 0] = value
        P[i, :] = 0.0
        P[:, i] = 0.0
        P[i, i] = var
        kf.x, kf.P = x, P
