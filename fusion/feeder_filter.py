"""The feeder's 6-DOF motion relative to the crane vessel: an extended Kalman filter after
document 004 (pose, velocity and acceleration of the relative motion), fed by what the
boom-tip sensors see of the feeder instead of a laser tracker and a second MRU.

Every update is chi-square gated. A kind of measurement refused `max_rejections` times in a
row is taken the next time with its covariance as the state's (a re-acquisition: the filter,
not the sensor, was wrong, e.g. after a long outage). An update that would leave a non-finite
state or a covariance that is not positive is not applied. The measurement vector shrinks with
what arrives (004's Algorithm 1): a missing sensor is simply no update.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from boomtip.fusion.consistency import Innovations, chi2_quantile
from boomtip.fusion.noise_matching import NoiseMatch, matched_ratio
from boomtip.fusion.models.relative_motion import (
    ACC,
    BODY_TILT,
    BODY_YAW,
    HEADING_OFFSET,
    N_MOTION,
    N_STATE,
    OFFSETS,
    POSE,
    RATE,
    deck_plane,
    deck_plane_rate,
    deck_spin_jacobian,
    feeder_mru_measurement,
    numeric_jacobian,
    omega,
    point_velocity,
    point_velocity_jacobian,
    transition,
    well_observed,
)
from pydantic import BaseModel, ConfigDict, Field

DEG = math.pi / 180.0


class FeederFilterConfig(BaseModel):
    """Nominal for ship-to-ship transfer in seas up to Hs 4 m; nothing here is the sea state."""

    model_config = ConfigDict(extra="forbid")

    tau_s: float = Field(1.5, gt=0, description="correlation time of each DOF's acceleration (Singer)")
    rate_tau_s: float = Field(8.0, gt=0, description="the rates return to zero over this (two ships keep station: no lasting drift)")
    sigma_acc_mps2: tuple[float, float, float] = Field((0.3, 0.3, 1.0), description="x, y, z acceleration 1-sigma")
    sigma_angacc_degps2: tuple[float, float, float] = Field((1.5, 1.5, 0.3), description="roll, pitch, yaw acceleration 1-sigma")
    gate_probability: float = Field(0.9999, gt=0.5, lt=1, description="chi-square gate of every update")
    max_rejections: int = Field(10, ge=1, description="refused this often in a row, a kind is taken as a re-acquisition")
    max_sigma_m: float = Field(0.05, gt=0, description="registration directions known worse than this are not updated")
    registration_floor: tuple[float, float] = Field((0.015, 0.025), description="1-sigma a registration is never better than: m (x, y), "
                                                    "deg (yaw); registrations to the merged model are off by up to about this "
                                                    "much, whatever their information says")
    error_correlation_s: float = Field(0.1, ge=0, description="a kind of measurement's errors are taken as independent only "
                                       "this far apart (the levelling's attitude, the deck's waves and the registration's "
                                       "map are shared by frames closer in time): a kind arriving faster carries its "
                                       "covariance times this over its interval, so its information per second stays "
                                       "what independent frames at this spacing would give (0: every frame independent)")
    noise_memory_s: float = Field(5.0, ge=0, description="a kind noisier than its stated covariance has it widened to "
                                  "match its recent innovations over about this long (fusion.noise_matching; 0: as stated)")
    init_sigma_rate: tuple[float, float] = Field((0.5, 2.0), description="first-frame 1-sigma of the rates: m/s, deg/s")
    # A feeder MRU (when the source has one): its offsets from the map frame.
    heading_offset_walk_degps: float = Field(0.005, ge=0, description="random walk of the heading offset between the ships' "
                                             "heading frames (004: moored or on DP, slowly varying), deg per sqrt(s)")
    body_yaw_prior_deg: float = Field(10.0, gt=0, description="1-sigma of the feeder MRU's yaw from the map's x (the crane's "
                                      "heading at the first frame) before any measurement: ships alongside")
    body_tilt_prior_deg: float = Field(0.5, gt=0, description="1-sigma of the feeder MRU's tilt from the deck normal "
                                       "(mounting, bias, camber, the crane side's levelling)")
    feeder_mru_floor: tuple[float, float] = Field((0.005, 0.01), description="1-sigma a feeder MRU sample is never better "
                                                  "than: deg (angles), deg/s (rates)")


@dataclass
class FeederUpdates:
    """What became of the filter's updates (its states' history is the estimator's)."""

    counts: dict[str, dict[str, int]] = field(default_factory=dict)  # kind -> accepted / gated / re-acquired / bad
    # every update's normalised innovation squared per kind: a consistency check that needs no truth
    innovations: Innovations = field(default_factory=Innovations)


class FeederFilter:
    def __init__(self, cfg: FeederFilterConfig | None = None) -> None:
        self.cfg = cfg or FeederFilterConfig()
        c = self.cfg
        self.tau = np.full(6, c.tau_s)
        self.rate_tau = np.full(6, c.rate_tau_s)
        self.sigma_acc = np.array([*c.sigma_acc_mps2, *(np.array(c.sigma_angacc_degps2) * DEG)])
        self.x: np.ndarray | None = None
        self.feeder_mru_started = False
        self.tip_position: np.ndarray | None = None
        self.P: np.ndarray | None = None
        self.t_s = float("nan")
        self.rejections: dict[str, int] = {}
        self.last_update_s: dict[str, float] = {}  # kind -> the time of its last update
        self.noise_match: dict[str, NoiseMatch] = {}  # kind -> how much noisier than stated it is
        self._fq: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self.updates = FeederUpdates()

    @property
    def started(self) -> bool:
        return self.x is not None

    def start(self, t_s: float, pose: np.ndarray, pose_cov: np.ndarray, tip_velocity: np.ndarray,
              tip_position: np.ndarray | None = None) -> None:
        """Begin at a pose (the map frame's definition at the first deck frame), at rest
        within the stated rate sigmas, accelerations at their steady-state spread."""
        self.x = np.zeros(N_STATE)
        self.x[POSE] = pose
        P = np.zeros((N_STATE, N_STATE))
        P[POSE, POSE] = pose_cov
        v, w = self.cfg.init_sigma_rate
        P[RATE, RATE] = np.diag([v * v] * 3 + [(w * DEG) ** 2] * 3)
        P[ACC, ACC] = np.diag(self.sigma_acc ** 2)
        # The feeder MRU's offsets: unknown until its first sample (start_feeder_mru).
        P[OFFSETS, OFFSETS] = np.eye(OFFSETS.stop - OFFSETS.start) * math.pi ** 2
        self.P, self.t_s, self.tip_velocity = P, t_s, np.asarray(tip_velocity, dtype=float)
        self.tip_position = None if tip_position is None else np.asarray(tip_position, dtype=float)

    def predict(self, t_s: float, tip_velocity: np.ndarray, tip_velocity_sigma: float, tip_position: np.ndarray | None = None) -> None:
        """To t_s, the tip having moved relative to the vessel: by the change of its place
        (tip_position, from the MRU's filtered angles: exact across an MRU gap, and a constant
        bias cancels) when given, else at tip_velocity (trapezoidally; 1-sigma per axis
        tip_velocity_sigma)."""
        dt = t_s - self.t_s
        if dt <= 0:  # a late measurement is applied at the current time
            return
        F, Q = self._transition(dt)
        self.x = F @ self.x
        if tip_position is not None and self.tip_position is not None:
            self.x[0:3] -= np.asarray(tip_position, dtype=float) - self.tip_position
        else:
            self.x[0:3] -= 0.5 * (self.tip_velocity + tip_velocity) * dt
        self.P = F @ self.P @ F.T + Q
        self.P[0:3, 0:3] += np.eye(3) * 0.5 * (tip_velocity_sigma * dt) ** 2
        self.t_s, self.tip_velocity = t_s, np.asarray(tip_velocity, dtype=float)
        self.tip_position = None if tip_position is None else np.asarray(tip_position, dtype=float)

    def _transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(F, Q) of the whole state over dt. Cached: frame intervals repeat, and assembling the
        blocks cost more than the filter's algebra."""
        key = round(float(dt), 9)
        if key not in self._fq:
            F_motion, Q_motion = transition(dt, self.tau, self.sigma_acc, self.rate_tau)
            F, Q = np.eye(N_STATE), np.zeros((N_STATE, N_STATE))
            F[:N_MOTION, :N_MOTION], Q[:N_MOTION, :N_MOTION] = F_motion, Q_motion
            Q[HEADING_OFFSET, HEADING_OFFSET] = (self.cfg.heading_offset_walk_degps * DEG) ** 2 * dt
            if len(self._fq) > 512:
                self._fq.clear()
            self._fq[key] = (F, Q)
        return self._fq[key]

    def pose_sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.P)[POSE])

    # -- updates ---------------------------------------------------------------------------
    def _counts(self, kind: str) -> dict[str, int]:
        return self.updates.counts.setdefault(kind, {"accepted": 0, "gated": 0, "reacquired": 0, "bad": 0})

    def shared_error_factor(self, kind: str) -> float:
        """How much of a kind's error this update shares with its last one: its interval's
        shortfall from the errors' correlation time (1 when at least that far apart)."""
        last = self.last_update_s.get(kind)
        dt = self.t_s - last if last is not None else math.inf
        return max(1.0, self.cfg.error_correlation_s / dt) if dt > 0 else 1.0

    def _update(self, kind: str, z: np.ndarray, h: np.ndarray, H: np.ndarray, R: np.ndarray,
                independent: bool = False, matched: bool = True) -> bool:
        """One gated update; `independent`: this kind's errors do not carry from sample to
        sample (a data sheet's white noise), else its covariance grows by shared_error_factor;
        `matched`: its covariance is widened to its innovations (noise_matching)."""
        counts = self._counts(kind)
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(R))):
            counts["bad"] += 1
            return False
        if not independent:
            R = R * self.shared_error_factor(kind)
        self.last_update_s[kind] = self.t_s
        y = z - h
        HPHt = H @ self.P @ H.T
        match = self.noise_match.get(kind, NoiseMatch())
        try:  # the monitor's NIS is against the covariance as stated; the update uses it widened
            self.updates.innovations.add(kind, self.t_s, float(y @ np.linalg.solve(HPHt + R, y)), len(z), match.scale)
            gate = float(chi2_quantile(self.cfg.gate_probability, len(z)))
            if matched and self.cfg.noise_memory_s > 0:
                ratio = matched_ratio(y, R, HPHt, gate, match.scale)
                self.noise_match[kind] = match.after(self.t_s, ratio, self.cfg.noise_memory_s)
            R = R * match.scale
            S = HPHt + R
            Sinv = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            counts["bad"] += 1
            return False
        d2 = float(y @ Sinv @ y)
        if d2 > gate:
            self.rejections[kind] = self.rejections.get(kind, 0) + 1
            if self.rejections[kind] <= self.cfg.max_rejections:
                counts["gated"] += 1
                return False
            # The filter is what is wrong: widen it along what this measures, then take it.
            counts["reacquired"] += 1
            self.P = self.P + H.T @ np.linalg.pinv(H @ H.T) @ (np.outer(y, y) + R) @ np.linalg.pinv(H @ H.T) @ H
            S = H @ self.P @ H.T + R
            Sinv = np.linalg.inv(S)
        K = self.P @ H.T @ Sinv
        x = self.x + K @ y
        IKH = np.eye(len(self.x)) - K @ H
        P = IKH @ self.P @ IKH.T + K @ R @ K.T  # Joseph form: stays symmetric and positive
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P)) and np.all(np.diag(P) > 0)):
            counts["bad"] += 1
            return False
        self.x, self.P = x, 0.5 * (P + P.T)
        self.rejections[kind] = 0
        counts["accepted"] += 1
        return True

    def update_deck(self, kind: str, plane_abc: np.ndarray, cov: np.ndarray) -> bool:
        """The deck plane z = a x + b y + c (level frame at the tip) and its covariance."""
        # Not the yaw: a plane's normal fixes the tilt, and through the Euler angles a yaw could
        # be traded for roll and pitch that keep the normal (tens of degrees over a long outage).
        return self._update(kind, plane_abc, deck_plane(self.x), numeric_jacobian(deck_plane, self.x, np.arange(5)), cov)

    def update_deck_spin(self, kind: str, plane_abc: np.ndarray, plane_rates: np.ndarray, cov: np.ndarray) -> bool:
        """The deck plane z = a x + b y + c (level frame at the tip) and its rate of change over
        one frame's sweep, one measurement with their joint 6x6 covariance (instead of the
        plane's update, not beside it); the tip's velocity is the one given to the last predict."""
        h = np.concatenate([deck_plane(self.x), deck_plane_rate(self.x, self.tip_velocity)])
        # Not the yaw nor its rate, for update_deck's reason: the deck's spin is its tilt's rate.
        H = deck_spin_jacobian(self.x, self.tip_velocity)
        return self._update(kind, np.concatenate([plane_abc, plane_rates]), h, H, cov)

    def update_registration(self, x_y_yaw: np.ndarray, info_xy_yaw: np.ndarray, extra_cov: np.ndarray | None = None,
                            kind: str = "registration", max_sigma_m: float | None = None) -> bool:
        """A registration's x, y, yaw; only the directions its information constrains (known
        better than max_sigma_m, by default the configured one). extra_cov (3x3): errors the
        registration does not see (the frame's levelling noise, a calibration's spread)."""
        A, var = well_observed(info_xy_yaw, self.cfg.max_sigma_m if max_sigma_m is None else max_sigma_m)
        if len(var) == 0:
            counts = self._counts(kind)
            counts["degenerate"] = counts.get("degenerate", 0) + 1
            return False
        S = np.zeros((3, len(self.x)))
        S[0, 0], S[1, 1], S[2, 5] = 1.0, 1.0, 1.0
        z_full = np.array(x_y_yaw, dtype=float)
        h_full = self.x[[0, 1, 5]]
        z_full[2] = h_full[2] + (z_full[2] - h_full[2] + math.pi) % (2 * math.pi) - math.pi
        fx, fyaw = self.cfg.registration_floor
        floor = np.diag([fx * fx, fx * fx, (fyaw * DEG) ** 2]) + (extra_cov if extra_cov is not None else 0.0)
        R = np.diag(var) + A @ floor @ A.T
        # Not matched: a registration's error is its map's and its floor's, not a sensor's white
        # noise, and its innovations carry the state's own error (a drifting pose would widen it).
        return self._update(kind, A @ z_full, A @ h_full, A @ S, R, matched=False)

    def update_point_velocity(self, velocity_level: np.ndarray, cov: np.ndarray, xi_level: np.ndarray) -> bool:
        """The velocity relative to the tip of the feeder's point at xi (radar Doppler); the
        tip's own velocity is the one given to the last predict."""
        h = lambda x: point_velocity(x, xi_level, self.tip_velocity)
        # Not the yaw: it enters only by turning the roll and pitch rates into level axes, and a
        # filter let to use that would turn its yaw to explain a rate error (tens of degrees over
        # a long LiDAR outage). The radar says nothing of the yaw itself.
        H = point_velocity_jacobian(self.x, xi_level)
        H[:, 5] = 0.0
        return self._update("doppler", velocity_level, h(self.x), H, cov)

    def start_feeder_mru(self, rpy_rad: np.ndarray, angle_sigma_rad: float) -> None:
        """The offsets at the feeder MRU's first sample: body yaw and tilt at their priors,
        the heading offset what makes the MRU's yaw agree with the state's (with their
        correlation, so a later tilt comparison that moves the body yaw moves it too)."""
        c = self.cfg
        sm, st = c.body_yaw_prior_deg * DEG, c.body_tilt_prior_deg * DEG
        self.x[BODY_YAW], self.x[BODY_TILT] = 0.0, 0.0
        self.x[HEADING_OFFSET] = (self.x[5] - rpy_rad[2] + math.pi) % (2 * math.pi) - math.pi
        # heading offset = yaw - body yaw - MRU yaw: its row is the yaw's, minus the body yaw's
        P = self.P
        P[OFFSETS, :], P[:, OFFSETS] = 0.0, 0.0
        P[BODY_YAW, BODY_YAW] = sm * sm
        P[BODY_TILT, BODY_TILT] = np.eye(2) * st * st
        P[HEADING_OFFSET, :N_MOTION] = P[5, :N_MOTION]
        P[:N_MOTION, HEADING_OFFSET] = P[:N_MOTION, 5]
        P[HEADING_OFFSET, BODY_YAW] = P[BODY_YAW, HEADING_OFFSET] = -sm * sm
        P[HEADING_OFFSET, HEADING_OFFSET] = P[5, 5] + sm * sm + angle_sigma_rad ** 2
        self.feeder_mru_started = True

    def update_feeder_mru(self, rpy_rad: np.ndarray, rpy_rate_radps: np.ndarray, angle_sigma_rad: float,
                          rate_sigma_radps: float) -> bool:
        """A feeder MRU sample: its body's roll, pitch, yaw in its heading frame and their
        time derivatives (as the crane MRU's log has them), with their data-sheet 1-sigmas."""
        if not (np.all(np.isfinite(rpy_rad)) and np.all(np.isfinite(rpy_rate_radps))):
            self._counts("feeder_mru")["bad"] += 1
            return False
        fa, fr = self.cfg.feeder_mru_floor
        sa, sr = max(angle_sigma_rad, fa * DEG), max(rate_sigma_radps, fr * DEG)
        if not self.feeder_mru_started:
            self.start_feeder_mru(rpy_rad, sa)
        z = np.concatenate([rpy_rad, omega(np.r_[0.0, 0.0, 0.0, rpy_rad], np.r_[0.0, 0.0, 0.0, rpy_rate_radps])])
        h = feeder_mru_measurement(self.x)
        z[:3] = h[:3] + (z[:3] - h[:3] + math.pi) % (2 * math.pi) - math.pi
        H = numeric_jacobian(feeder_mru_measurement, self.x, np.r_[3:12, OFFSETS])
        R = np.diag([sa * sa] * 3 + [sr * sr] * 3)
        return self._update("feeder_mru", z, h, H, R, independent=True)

    def offsets(self) -> tuple[np.ndarray, np.ndarray]:
        """The feeder MRU's offsets (heading offset, body yaw, body tilt about x, y; rad) and their 1-sigmas."""
        return self.x[OFFSETS].copy(), np.sqrt(np.diag(self.P)[OFFSETS])
