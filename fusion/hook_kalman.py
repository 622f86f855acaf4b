"""Multi-rate EKF / UKF for the crane hook (lower block), after document 002 chapter 4.

:class:`HookFilter` is :class:`~boomtip.fusion.hook_kalman_core.HookKalmanCore` (the crane
model's prediction, encoder and MRU updates; the state layout is in
fusion/models/crane_pendulum.py) plus the sway measurements, applied when they arrive (4.6.3):

* LiDAR (20 Hz): hook position relative to the boom tip in WORLD axes
  ``h(x) = l u(a, b)`` (eq. 4.26 with our world-axes angles).  Chi-square gated on the
  normalised innovation (3 dof, ``lidar_gate_probability``); after
  ``reacquire_after_rejections`` consecutive gated fixes the sway states are re-initialised
  from the fix.  A NaN fix (no detection) is skipped: the hook is bridged by prediction.
* rope direction (20 Hz, same frames; perception.rope): the sway angles ``(a, b)`` directly,
  a linear update (:meth:`HookFilter.update_rope`), gated on 2 dof.  Not in document 002: at
  200 m the block gets 0-3 LiDAR returns, the rope's first tens of metres hundreds.

Outputs: hook position/velocity relative to the boom tip in world axes
(:meth:`HookFilter.hook_position_velocity`); the boom tip and hook in the world frame from the
full state are an evaluation (tools/hook_eval.py).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from scipy.stats import chi2

from boomtip.data.crane_model import CraneParams
from boomtip.fusion.consistency import Innovations
from boomtip.fusion.hook_config import HookFilterConfig
from boomtip.fusion.hook_kalman_core import HookKalmanCore
from boomtip.fusion.hook_kalman_steps import stacked_correction
from boomtip.fusion.models.crane_pendulum import (
    HOOK_COLS,
    IA,
    IAD,
    IB,
    IBD,
    IL,
    lidar_h_jac,
    sway_angles_from_direction,
)

__all__ = ["HookFilter"]

_HOOK_COLS_A = np.array(HOOK_COLS, np.intp)
_SWAY_AB = np.array([IA, IB], np.intp)


class HookFilter(HookKalmanCore):
    """Multi-rate hook-state estimator (document 002 chapter 4).

    >>> f = HookFilter("ekf", "flexible")
    >>> f.initialize_from_measurements(p_rel, (nu, mu, l), (roll, pitch, roll_rate, pitch_rate), t0)
    >>> f.predict(0.005); f.update_mru(...); f.update_encoders(...); f.update_lidar(p_rel, t)
    >>> p_rel, v_rel = f.hook_position_velocity()
    """

    def __init__(
        self,
        kind: Literal["ekf", "ukf"] = "ekf",
        model: Literal["rigid", "flexible"] = "flexible",
        params: CraneParams | None = None,
        config: HookFilterConfig | None = None,
    ) -> None:
        super().__init__(kind, model, params, config)
        self._R_lidar = np.eye(3) * self.cfg.measurement.sigma_lidar_m**2
        self._gate = float(chi2.ppf(self.cfg.lidar_gate_probability, 3))
        self.n_lidar_accepted = 0
        self.n_lidar_rejected = 0
        self.n_reacquired = 0
        self._consecutive_rejections = 0
        self._gate_rope = float(chi2.ppf(self.cfg.lidar_gate_probability, 2))
        self.n_rope_accepted = 0
        self.n_rope_rejected = 0
        self._consecutive_rope_rejections = 0
        self.last_nis: float | None = None
        self.nis_history: list[float] = []
        self.innovations = Innovations()  # every fix's NIS, gated ones too: the consistency without truth

    def _lidar_terms(self, z, R):
        """(C, S) of the correction (hook_kalman_steps.stacked_correction) at the current
        estimate: C's rows the cross covariance (EKF: P H^T; UKF: of the sigma points and their
        measurements) and the negated innovation, S the innovation's covariance."""
        kf = self._kf
        x, n = kf.x, self.n
        if self.kind == "ekf":
            p, Hs = lidar_h_jac(x)  # Hs: 3 x 6, w.r.t. HOOK_COLS
            C = kf.M.take(_HOOK_COLS_A, 1) @ Hs.T  # rows P H^T (n, 3), then (the mean's) replaced
            C[n] = p - z
            S = Hs @ C.take(_HOOK_COLS_A, 0)
            S += R
            return C, S
        sig = self._pts.sigma_points(x, kf.P)  # (2n+1, n)
        a, b, l = sig[:, IA], sig[:, IB], sig[:, IL]
        ca = np.cos(a)
        Z = np.stack([-l * np.sin(a), l * ca * np.sin(b), -l * ca * np.cos(b)], 1)
        zp = self._Wm @ Z
        D = Z - zp
        Wc = self._Wc
        S = (D.T * Wc) @ D + R
        C = np.empty((n + 1, 3))
        np.matmul((sig - x).T * Wc, D, out=C[:n])  # cross covariance (n, 3)
        C[n] = zp - z
        return C, S

    def lidar_innovation(self, z, R: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(innovation y, its covariance S) of a LiDAR fix before any update."""
        self._flush()
        C, S = self._lidar_terms(np.asarray(z, float), self._R_lidar if R is None else R)
        return -C[self.n], S

    def update_lidar(self, p_rel_tip_world, t: float | None = None, sigma_m: float | None = None,
                     cov_m2: np.ndarray | None = None) -> bool:
        """Correct with a LiDAR hook fix (world axes, relative to the boom tip).

        ``sigma_m`` (isotropic) or ``cov_m2`` (3x3, e.g. a sparse fix: loose across the rope,
        tighter along it) replaces the configured R for this fix.
        Returns False when the fix is gated out (or NaN: no detection).  After
        ``reacquire_after_rejections`` consecutive gated fixes the sway states are
        re-initialised from the fix (lost-and-found hook) and it is applied.
        """
        self.advance_to(self.t if t is None else t)  # (closes a pending window)
        z = np.asarray(p_rel_tip_world, float)
        if not np.all(np.isfinite(z)):
            return False
        # A per-fix covariance (from the detection: range, point spacing, point count) replaces R.
        if cov_m2 is not None and np.all(np.isfinite(cov_m2)):
            R = np.asarray(cov_m2, float).reshape(3, 3)
        elif sigma_m is not None and np.isfinite(sigma_m):
            R = np.eye(3) * sigma_m**2
        else:
            R = self._R_lidar
        C, S = self._lidar_terms(z, R)
        kf = self._kf
        M_new, nis = stacked_correction(kf.M, C, S, True)
        self.last_nis = nis
        self.innovations.add("lidar_block", self.t, nis, 3)
        if nis > self._gate:
            self._consecutive_rejections += 1
            if self._consecutive_rejections < self.cfg.reacquire_after_rejections:
                self.n_lidar_rejected += 1
                return False
            self._reacquire(z)
            C, S = self._lidar_terms(z, R)  # x, P changed
            M_new = stacked_correction(kf.M, C, S)
        else:
            self.nis_history.append(nis)
        self._consecutive_rejections = self._consecutive_rope_rejections = 0
        # K = P H^T S^-1 (EKF) or Pxz S^-1 (UKF); P - K S K^T (= filterpy's Joseph form
        # with the optimal gain, and its UKF update)
        kf.M = M_new
        self.n_lidar_accepted += 1
        return True

    def update_rope(self, direction, cov, t: float | None = None) -> bool:
        """Correct with the rope's direction (unit vector from the tip towards the hook, world
        axes; perception.rope) and its covariance (3x3, rank 2, across the rope).

        The rope hangs along u(a, b), so the direction measures the sway angles directly:
        z = (a, b) = (asin(-u_x), atan2(u_y, -u_z)), R = J cov J^T with J = d(a, b)/du. The
        measurement is then linear in the state (exact in the EKF and the UKF). Gated on its
        normalised innovation (2 dof, ``lidar_gate_probability``); after
        ``reacquire_after_rejections`` consecutive gated directions the sway is re-initialised
        from one. Returns False when gated out (or NaN).
        """
        zr = sway_angles_from_direction(direction, cov)
        if zr is None:
            self.advance_to(self.t if t is None else t)  # (closes a pending window)
            return False
        return self.update_sway_angles(zr[0], zr[1], direction, t)

    def update_sway_angles(self, z: np.ndarray, R: np.ndarray, direction, t: float | None = None) -> bool:
        """:meth:`update_rope` with the direction's sway angles z = (a, b) and their 2x2
        covariance R already computed (:func:`~boomtip.fusion.models.crane_pendulum.sway_angles_from_directions`
        for a whole run); ``direction`` re-initialises the sway after gated directions."""
        self.advance_to(self.t if t is None else t)  # (closes a pending window)
        kf = self._kf
        ii = _SWAY_AB

        def terms():
            C = kf.M.take(ii, 1)  # rows P[:, ii], x[ii]
            y = z - C[-1]
            y[1] = (y[1] + math.pi) % (2 * math.pi) - math.pi
            C[-1] = -y
            S = C.take(ii, 0)
            S += R
            return C, S

        C, S = terms()
        M_new, nis = stacked_correction(kf.M, C, S, True)
        self.innovations.add("lidar_rope", self.t, nis, 2)
        if not nis <= self._gate_rope:  # (a NaN NIS is a rejection too)
            self._consecutive_rope_rejections += 1
            if self._consecutive_rope_rejections < self.cfg.reacquire_after_rejections:
                self.n_rope_rejected += 1
                return False
            self._reacquire(np.asarray(direction, float))
            C, S = terms()
            M_new = stacked_correction(kf.M, C, S)
        # Any accepted sway measurement clears both rejection runs: a rope fit locked on a wrong
        # line (a tagline) must not re-initialise the sway while the block fixes agree with it,
        # nor the block fixes while the rope does.
        self._consecutive_rope_rejections = self._consecutive_rejections = 0
        kf.M = M_new
        self.n_rope_accepted += 1
        return True

    def _reacquire(self, z) -> None:
        kf = self._kf
        a, b = self._angles_from_lidar(z)
        x = kf.x.copy()
        x[[IA, IB]] = a, b
        x[[IAD, IBD]] = 0.0
        P = kf.P.copy()
        P0 = self._default_P0()
        for i in (IA, IAD, IB, IBD):
            P[i, :] = 0.0
            P[:, i] = 0.0
            P[i, i] = P0[i, i]
        kf.set(x, P)
        self._A = None
        self.n_reacquired += 1
