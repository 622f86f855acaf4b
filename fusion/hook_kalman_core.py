"""The Kalman machinery of the hook filter: the estimate (x, P), its prediction by the crane
model (EKF or UKF) and the updates by the crane's own sensors (encoders, MRU).
:class:`~boomtip.fusion.hook_kalman.HookFilter` adds the sway measurements (LiDAR block fix,
rope direction).

EKF (the equations of filterpy's ``ExtendedKalmanFilter``, written out: its per-call
overhead would dominate the 200 Hz loop): ``P = F P F^T + Q`` with ``F = I + A dt + (A dt)^2 / 2``
and the continuous Jacobian ``A`` of the equations of motion (fusion/models/jacobian.py),
refreshed every ``jacobian_interval_s`` (20 Hz; ``0`` = every step; ``F`` is rebuilt only when
``A`` or ``dt`` changes); the mean ``x' = F x + c`` about the model's derivative at A's state
(``ekf_mean="jacobian"``: one model evaluation per A instead of two per step; the hook within
micrometres) or by the integrator on the model (``"model"``).
UKF (the equations of filterpy's ``UnscentedKalmanFilter``, Merwe sigma points with
Simulink's defaults alpha=1e-3, beta=2, kappa=0): the sigma points are propagated by one
batched (vectorised) step (fusion/models/batched_model.py: the tip's kinematics once per
step for the step's input times) and recomputed from (x, P) before every LiDAR update.
The sigma points step once per ``ukf_window_s`` (25 ms, five MRU samples; fusion/hook_window.py),
by the midpoint rule with its second stage linearised at the mean (``ukf_midpoint``).
The integrator (``HookFilterConfig.integrator``): the explicit midpoint rule by default, two
evaluations of the crane model per step (the UKF's window, the EKF's model mean) instead of
RK4's four (document 002 4.4); at 5 ms the estimates agree to micrometres (the pendulum's and the deflection's periods are
seconds; BENCHMARKS.md, tests/fusion).  The
linear sensors (encoders, MRU) use the exact linear Kalman update in both filters (for a
linear h the unscented transform gives the same result).  Every correction is
``x + K y``, ``P - K S K^T`` through the Cholesky factor of ``S`` (filterpy's EKF uses the
Joseph form, equal for the optimal gain), on the estimate stacked as [P; x^T]
(fusion/hook_kalman_steps.py).  P is symmetrised after every prediction.

Encoders (100 Hz) measure slew, luff and hoist length (document 002 measures only slew and
luff); the MRU (200 Hz) roll, pitch and their rates.
"""

from __future__ import annotations

import math
from typing import Literal, Sequence

import numpy as np

from boomtip.data.crane_model import CraneParams
from boomtip.fusion.hook_config import HookFilterConfig
from boomtip.fusion.hook_kalman_steps import FastMerweSigmaPoints, KalmanState, selection_correction
from boomtip.fusion.hook_window import PredictionWindow
from boomtip.fusion.models.autodiff import accel_jacobian
from boomtip.fusion.models.batched_model import (
    midpoint_linearised_sigma_points,
    midpoint_sigma_points,
    rk4_sigma_points,
    split_accelerations,
)
from boomtip.fusion.models.crane_pendulum import (
    HOOK_IX,
    IA,
    IAD,
    IB,
    IBD,
    IF,
    IFD,
    IL,
    IMU,
    INU,
    IPITCH,
    IROLL,
    STATE_NAMES,
    hook_pos_vel,
    midpoint_batch,
    midpoint_float,
    process_noise,
    rk4_batch,
    rk4_float,
)
from boomtip.fusion.models.jacobian import continuous_jacobian, jacobian_and_accelerations

__all__ = ["HookKalmanCore"]


class HookKalmanCore(PredictionWindow):
    """Multi-rate estimate of the crane and hook state (document 002 chapter 4): prediction by
    the crane model, updates by the encoders and the MRU, hook outputs from the state."""

    def __init__(
        self,
        kind: Literal["ekf", "ukf"] = "ekf",
        model: Literal["rigid", "flexible"] = "flexible",
        params: CraneParams | None = None,
        config: HookFilterConfig | None = None,
    ) -> None:
        if kind not in ("ekf", "ukf"):
            raise ValueError(kind)
        if model not in ("rigid", "flexible"):
            raise ValueError(model)
        self.kind, self.model = kind, model
        self.params = params or CraneParams()
        self.cfg = config or HookFilterConfig()
        self.flex = model == "flexible"
        self.n = n = 21 if self.flex else 19
        self.dt_s = 1.0 / self.cfg.predict_rate_hz
        self._prm = self.params.as_tuple()
        self._I = np.eye(n)
        self.t = 0.0
        self.initialized = False
        m = self.cfg.measurement
        self._R_enc = np.array([m.sigma_slew_rad, m.sigma_luff_rad, m.sigma_hoist_m]) ** 2
        self._R_mru = np.array([m.sigma_mru_angle_rad, m.sigma_mru_angle_rad,
                                m.sigma_mru_rate_rad_s, m.sigma_mru_rate_rad_s]) ** 2
        # MRU + encoders with the same time stamp as one update (H selects states, R diagonal)
        self._me_idx = np.array([IROLL, IPITCH, IROLL + 1, IPITCH + 1, INU, IMU, IL], np.intp)
        self._me_R = np.diag(np.concatenate([self._R_mru, self._R_enc]))
        self._mru_idx = self._me_idx[:4].copy()
        self._mru_R = np.diag(self._R_mru)
        # the sample kinds of the window's batch: MRU, MRU + encoders, encoders, slew and luff
        self._kinds = [(self._mru_idx, self._R_mru), (self._me_idx, np.diag(self._me_R).copy()),
                       (self._me_idx[4:].copy(), self._R_enc), (self._me_idx[4:6].copy(), self._R_enc[:2])]
        self._q_cache: dict[float, np.ndarray] = {}
        self._q_step_cache: dict[float, np.ndarray] = {}
        # the linearisation (EKF: the covariance and the mean; UKF: its window) and its time
        self._A: np.ndarray | None = None
        self._A_t = -math.inf
        self._jac_interval = float(self.cfg.jacobian_interval_s)
        # the UKF's prediction window (HookFilterConfig.ukf_window_s; fusion/hook_window.py)
        self._init_window(self.cfg.ukf_window_s if kind == "ukf" else 0.0)
        # the EKF's step for (self._A, self._F_key = round(dt, 12)): F^T, blockdiag(F / 2, 1) and
        # [Q; c^T] for the stacked estimate (hook_kalman_steps.KalmanState)
        self._FT: np.ndarray | None = None
        self._Fh_stacked: np.ndarray | None = None
        self._QC: np.ndarray | None = None
        self._F_key: float | None = None
        self._lin_cache: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        self.n_jacobians = 0
        # EKF mean by the Jacobian (HookFilterConfig.ekf_mean): the step's affine term for (A,
        # dt) from the model's derivative at A's state (self._f_offset, as the window's)
        self._ekf_affine = kind == "ekf" and self.cfg.ekf_mean == "jacobian"
        if kind == "ekf" and self.cfg.jacobian == "autodiff":
            accel_jacobian(self._prm, self.flex)  # generate the code now (once per params)
        self._kf = KalmanState(n)
        if kind == "ukf":
            self._pts = FastMerweSigmaPoints(n, alpha=self.cfg.ukf_alpha, beta=self.cfg.ukf_beta,
                                             kappa=self.cfg.ukf_kappa)
            self._Wm, self._Wc = self._pts.Wm, self._pts.Wc
            self._Wc_half = 0.5 * self._Wc
            # the generated model (tip kinematics once per step); the core itself if untraceable
            generated = self.cfg.ukf_model == "generated" and split_accelerations(self._prm, self.flex) is not None
            if self.cfg.integrator == "rk4":
                self._step_sigma = rk4_sigma_points if generated else rk4_batch
            else:
                self._step_sigma = midpoint_sigma_points if generated else midpoint_batch
            # the second stage linearised at the mean (HookFilterConfig.ukf_midpoint) with a
            # window (whose Jacobian it takes; a Jacobian per 5 ms step would cost more than it saves)
            self._ukf_linear_stage = (self.windowed and self.cfg.integrator == "midpoint"
                                      and self.cfg.ukf_midpoint == "linearised")
            self._ukf_core = not generated
        self._step_float = rk4_float if self.cfg.integrator == "rk4" else midpoint_float

    # ------------------------------------------------------------------ state access
    @property
    def x(self) -> np.ndarray:
        """The estimate at the latest sample (a pending window is closed first)."""
        self._flush()
        return self._kf.x

    @property
    def P(self) -> np.ndarray:
        self._flush()
        return self._kf.P

    def state_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in zip(STATE_NAMES, self.x)}

    # ------------------------------------------------------------------ initialisation
    def initialize(self, x0: Sequence[float], P0: np.ndarray | None = None, t0: float = 0.0) -> None:
        x0 = np.asarray(x0, float)[: self.n].copy()
        if len(x0) != self.n:
            raise ValueError(f"x0 must have {self.n} entries")
        self._kf.set(x0, self._default_P0() if P0 is None else np.array(P0, float))
        self._A = None
        self._pend_t, self._pend_kind, self._pend_z = [], [], []
        self.t = float(t0)
        self.initialized = True

    def _default_P0(self) -> np.ndarray:
        c, m = self.cfg.initial, self.cfg.measurement
        s = np.zeros(21)
        s[[IA, IB]] = c.sigma_sway_rad
        s[[IAD, IBD]] = c.sigma_sway_rate_rad_s
        s[INU], s[IMU], s[IL] = m.sigma_slew_rad, m.sigma_luff_rad, m.sigma_hoist_m
        s[[INU + 1, IMU + 1]] = c.sigma_joint_rate
        s[IL + 1] = 10 * c.sigma_joint_rate
        s[[INU + 2, IMU + 2]] = c.sigma_joint_acc
        s[IL + 2] = 10 * c.sigma_joint_acc
        s[[IROLL, IPITCH]] = m.sigma_mru_angle_rad
        s[[IROLL + 1, IPITCH + 1]] = m.sigma_mru_rate_rad_s
        s[[IROLL + 2, IPITCH + 2]] = c.sigma_vessel_acc_rad_s2
        s[IF], s[IFD] = c.sigma_deflection_rad, c.sigma_deflection_rate_rad_s
        return np.diag(s[: self.n] ** 2)

    def initialize_from_measurements(self, p_rel_tip_world, joints: Sequence[float],
                                     vessel: Sequence[float], t0: float = 0.0) -> None:
        """joints = (slew, luff, hoist); vessel = (roll, pitch, roll_rate, pitch_rate). Only the
        direction of p_rel_tip_world counts (the sway angles); the rope length is the hoist's."""
        nu, mu, l = joints
        roll, pitch, roll_rate, pitch_rate = vessel
        a, b = self._angles_from_lidar(p_rel_tip_world)
        x = np.zeros(21)
        x[[IA, IB]] = a, b
        x[INU], x[IMU], x[IL] = nu, mu, l
        x[IROLL], x[IROLL + 1], x[IPITCH], x[IPITCH + 1] = roll, roll_rate, pitch, pitch_rate
        self.initialize(x, None, t0)

    @staticmethod
    def _angles_from_lidar(p) -> tuple[float, float]:
        p = np.asarray(p, float)
        r = float(np.linalg.norm(p))
        return math.asin(max(-1.0, min(1.0, -p[0] / r))), math.atan2(p[1], -p[2])

    # ------------------------------------------------------------------ dynamics
    def continuous_jacobian(self, x=None, method: str | None = None) -> np.ndarray:
        """A = df/dx of the continuous model at x ("autodiff", "complex_step" or "numeric")."""
        x = self._kf.x if x is None else np.asarray(x, float)
        return continuous_jacobian(self._prm, self.flex, x, method or self.cfg.jacobian)

    def _linearisation(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(A = df/dx at x, f(x) - A x): f(x') ~ A x' + (f(x) - A x) near x (zero but in the
        accelerations' rows), from one call of the generated Jacobian."""
        A, acc = jacobian_and_accelerations(self._prm, self.flex, x, self.cfg.jacobian)
        self.n_jacobians += 1
        rows = self._acc_rows
        offset = np.zeros(self.n)
        offset[rows] = acc - A[rows] @ x
        return A, offset

    def process_noise(self, dt: float) -> np.ndarray:
        """Discrete Q for a step dt (eqs. 4.29-4.30)."""
        key = round(dt, 12)
        Q = self._q_cache.get(key)
        if Q is not None:
            return Q
        Q = process_noise(self.cfg.process, dt, self.n)
        if len(self._q_cache) < 64:
            self._q_cache[key] = Q
        return Q

    def _step_noise(self, dt: float) -> np.ndarray:
        """Q of one prediction step dt (:meth:`process_noise`, cached)."""
        key = round(dt, 12)
        Q = self.process_noise(dt)
        if len(self._q_step_cache) < 64:
            self._q_step_cache[key] = Q
        return Q

    # ------------------------------------------------------------------ predict
    def predict(self, dt: float | None = None) -> None:
        """Propagate the estimate by dt seconds (one step of the configured integrator)."""
        dt = self.dt_s if dt is None else float(dt)
        if dt <= 0:
            return
        kf = self._kf
        key = round(dt, 12)
        if self.windowed and dt > self.dt_s + 1e-9:
            Q = self._window_noise(dt)
        else:
            Q = self._q_step_cache.get(key)
            if Q is None:
                Q = self._step_noise(dt)
        # H = half the propagated covariance (the factor 1/2 is exact): P = H + H^T + Q is
        # the symmetrised P
        n = self.n
        if self.kind == "ekf":
            if self._A is None or self.t - self._A_t >= self._jac_interval - 1e-9:
                # f(x) ~ A x + (f(x0) - A x0) (the offset: only the accelerations' rows)
                self._A, self._f_offset = self._linearisation(kf.x)
                self._A_t = self.t
                self._F_key = None
            if key != self._F_key:  # F depends on (A, dt) only: rebuilt when either changes
                Ad = self._A * dt
                F = self._I + Ad + 0.5 * (Ad @ Ad)
                Fh = np.zeros((n + 1, n + 1))
                Fh[:n, :n] = 0.5 * F
                Fh[n, n] = 1.0
                QC = np.empty((n + 1, n))
                QC[:n] = Q
                # x' = F x + (dt + A dt^2 / 2) (f(x0) - A x0)
                QC[n] = dt * self._f_offset + (0.5 * dt) * (Ad @ self._f_offset) if self._ekf_affine else 0.0
                self._FT, self._Fh_stacked, self._QC, self._F_key = F.T, Fh, QC, key
            # rows: H = F P F^T / 2 and (F x)^T; then P = H + H^T + Q, x' = F x + c
            M = self._Fh_stacked @ (kf.M @ self._FT)
            P = M[:n]
            P += P.T
            M += self._QC
            if not self._ekf_affine:
                M[n] = self._step_float(self._prm, self.flex, kf.x.tolist(), dt)
            kf.M = M
            self.t += dt
            return
        else:
            # sigma points from (x, P), one batched step, unscented transform
            sig = self._pts.sigma_points(kf.x, kf.P)  # (2n+1, n)
            if self._ukf_linear_stage:  # the Jacobian's rows at the mean (the window's A)
                J = self._window_linearisation().take(self._acc_rows, 0)
                Xf = midpoint_linearised_sigma_points(self._prm, self.flex, sig.T, dt, J, self._ukf_core)
            else:
                Xf = self._step_sigma(self._prm, self.flex, sig.T, dt)  # (n, 2n+1)
            x = Xf @ self._Wm
            D = Xf - x[:, None]
            H = (D * self._Wc_half) @ D.T
        M = np.empty((n + 1, n))
        P = M[:n]
        np.add(H, H.T, out=P)
        P += Q
        M[n] = x
        kf.M = M
        self.t += dt

    def advance_to(self, t: float) -> None:
        """Apply the pending samples (closing the window), then predict in steps of at most one
        window (1/predict_rate without one) up to time t (no-op for t <= self.t)."""
        if self._pend_t:
            self._flush()
        while t - self.t > 1e-9:
            self.predict(min(self._step, t - self.t))

    def estimate_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(x, P) at time t, for the outputs (do not modify them). Without a window: the
        estimate advanced to t; with one: fusion/hook_window.py."""
        if not self.windowed:
            self.advance_to(t)
            return self._kf.x, self._kf.P
        return self._windowed_estimate(t)

    def _linear_update(self, idx: Sequence[int], z: np.ndarray, r_diag: np.ndarray) -> None:
        """Exact Kalman update for z = x[idx] + noise with diagonal R (H selects states):
        K = P H^T S^-1 with S = P[idx, idx] + R.  For a linear h the unscented transform
        gives the same result, so the UKF uses it too."""
        r_diag = np.asarray(r_diag, float)
        key = (tuple(idx), r_diag.tobytes())
        c = self._lin_cache.get(key)
        if c is None:
            c = self._lin_cache[key] = (np.array(idx, np.intp), np.diag(r_diag))
        self._selection_update(c[0], c[1], z)

    def _selection_update(self, ii: np.ndarray, R: np.ndarray, z) -> None:
        """:meth:`_linear_update` with the index array and the R matrix prepared."""
        z = np.asarray(z, dtype=float)
        # (z @ z is NaN or inf with any NaN or inf sample: one C call, the cheapest test at 200 Hz)
        if not math.isfinite(z @ z) and not np.all(np.isfinite(z)):  # a NaN sample updates nothing
            keep = np.isfinite(z)
            if not keep.any():
                return
            ii, R, z = ii[keep], R[np.ix_(keep, keep)], z[keep]
        self._kf.M = selection_correction(self._kf.M, ii, R, z)

    def _sample(self, kind: int, z: np.ndarray, t: float | None) -> None:
        """A sample of the crane's sensors (kind: an entry of ``self._kinds``) at time t (None:
        now): without a window applied at once; with one kept for the window's end."""
        if not self.windowed or t is None or t - self.t <= 1e-9:
            if t is not None:
                self.advance_to(t)
            elif self._pend_t:
                self._flush()
            idx, r = self._kinds[kind]
            self._linear_update(idx, z, r)
            return
        self._enqueue(kind, z, t)

    def update_encoders(self, slew_rad: float, luff_rad: float, hoist_m: float | None = None,
                        t: float | None = None) -> None:
        if hoist_m is None or not np.isfinite(hoist_m):
            self._sample(3, np.array([slew_rad, luff_rad]), t)
        else:
            self._sample(2, np.array([slew_rad, luff_rad, hoist_m]), t)

    def update_mru(self, roll_rad: float, pitch_rad: float, roll_rate_rad_s: float, pitch_rate_rad_s: float,
                   t: float | None = None) -> None:
        self.update_mru_sample(np.array([roll_rad, pitch_rad, roll_rate_rad_s, pitch_rate_rad_s]), t)

    def update_mru_sample(self, mru: np.ndarray, t: float | None = None) -> None:
        """:meth:`update_mru` with the sample as one array (roll, pitch, roll rate, pitch rate)."""
        if self.windowed:
            self._sample(0, mru, t)
            return
        if t is not None:
            self.advance_to(t)
        self._selection_update(self._mru_idx, self._mru_R, mru)

    def update_mru_and_encoders(self, mru: Sequence[float], encoders: Sequence[float], t: float | None = None) -> None:
        """An MRU sample (roll, pitch, roll rate, pitch rate) and an encoder sample (slew, luff,
        hoist) with the same time stamp as one linear update: the same result as one after the
        other (H selects states, R is diagonal)."""
        if self.windowed:
            self._sample(1, np.concatenate((mru, encoders)), t)
            return
        if t is not None:
            self.advance_to(t)
        self._selection_update(self._me_idx, self._me_R, np.concatenate((mru, encoders)))

    # ------------------------------------------------------------------ outputs
    def hook_position_velocity(self) -> tuple[np.ndarray, np.ndarray]:
        """Hook position and velocity relative to the boom tip, world axes."""
        p, v, _, _ = hook_pos_vel(self.x)
        return p, v

    def hook_position_velocity_covariance(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(p_rel, v_rel, cov_p (3,3), cov_v (3,3)) by first-order propagation of P."""
        p, v, hp, hv = hook_pos_vel(self.x)
        Ps = self._kf.P[HOOK_IX]
        return p, v, hp @ Ps @ hp.T, hv @ Ps @ hv.T

