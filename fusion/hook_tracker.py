"""The hook filter run online, frame by frame, for the perception (its prior and attitude)."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from boomtip.data.crane_model import CraneParams
from boomtip.fusion.hook_config import HookFilterConfig
from boomtip.fusion.hook_kalman import HookFilter
from boomtip.fusion.hook_run import merged_events
from boomtip.fusion.models.crane_pendulum import IF, IL, IMU, INU, IPITCH, IROLL

__all__ = ["HookTracker"]


class HookTracker:
    """The hook filter run online, frame by frame, so the perception gets the filter's state:
    its attitude levels the frame, its prediction gates the rope, and its estimate after the
    rope (with its covariance) is the block detector's prior: the association of a far, sparse
    block's few points needs to know where the block should be (document 002 runs its filter
    the same way).

    >>> tr = HookTracker(t_enc, enc, t_mru, mru, params=params)
    >>> p_pred, cov_pred = tr.predict(t)      # applies every encoder/MRU sample <= t first
    >>> roll, pitch, heading = tr.tip_attitude()
    >>> tr.correct_rope(u_rope, cov_rope)     # the rope's direction at t
    >>> p_prior, cov_prior = tr.estimate()
    >>> tr.correct(p_fix, cov_fix)            # a detection at t (gated like any LiDAR fix)

    It starts at the first ``predict`` with the hook hanging straight down at the hoist length
    and the filter's default initial covariance; detections then pull it in (a fix far outside
    the gate re-initialises the sway after ``reacquire_after_rejections`` frames).
    """

    def __init__(self, t_encoders: np.ndarray, encoders, t_mru: np.ndarray, mru,
                 kind: Literal["ekf", "ukf"] = "ekf", model: Literal["rigid", "flexible"] = "flexible",
                 params: CraneParams | None = None, config: HookFilterConfig | None = None) -> None:
        """``encoders`` (K, 3) and ``mru`` (K, 4): arrays, or tables read by row slices (kept on
        disk by the caller); only the rows up to each predicted time are read, a frame's at a time."""
        self.filter = HookFilter(kind, model, params, config)
        self._enc, self._mru = encoders, mru
        self._t_enc, self._t_mru = np.asarray(t_encoders, float), np.asarray(t_mru, float)
        self._next_mru = self._next_enc = 0  # the first sample of each stream not yet applied

    @property
    def started(self) -> bool:
        return self.filter.initialized

    def hoist_at(self, t: float) -> float:
        """The hoist encoder (column 3 of the encoder table) interpolated at t, from the two rows
        about t: np.interp's value depends on those alone, so the same number as over the whole
        log, a frame's rows read at a time."""
        i0 = max(int(np.searchsorted(self._t_enc, t, "right")) - 1, 0)
        # at least one row: a time stamp repeated at t would otherwise leave an empty slice
        i1 = max(min(int(np.searchsorted(self._t_enc, t, "left")) + 1, len(self._t_enc)), i0 + 1)
        return float(np.interp(t, self._t_enc[i0:i1], np.asarray(self._enc[i0:i1])[:, 2]))

    def _start(self, t: float) -> None:
        ie = max(0, int(np.searchsorted(self._t_enc, t, "right")) - 1)
        im = max(0, int(np.searchsorted(self._t_mru, t, "right")) - 1)
        e = np.asarray(self._enc[ie:ie + 1], float).reshape(3)
        m = np.asarray(self._mru[im:im + 1], float).reshape(4)
        self.filter.initialize_from_measurements(np.array([0.0, 0.0, -float(e[2])]), e, m, t)
        # the samples up to t are in the initial state, not applied again
        self._next_mru, self._next_enc = max(self._next_mru, self._until(self._t_mru, t)), max(self._next_enc, self._until(self._t_enc, t))

    @staticmethod
    def _until(t_stream: np.ndarray, t: float) -> int:
        """The number of a stream's samples at or before t (the same test as one by one: times <= t + 1e-9)."""
        return int(np.searchsorted(t_stream, t + 1e-9, "right"))

    def predict(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Hook position relative to the tip (world axes) and its 3x3 covariance at time t."""
        f = self.filter
        if not f.initialized:
            self._start(t)
        m0, e0 = self._next_mru, self._next_enc
        m1, e1 = max(m0, self._until(self._t_mru, t)), max(e0, self._until(self._t_enc, t))
        if m1 > m0 or e1 > e0:
            # the samples since the last predict, merged in time order (MRU first at equal
            # times): the order of one merged list over the whole run, a window of it at a time
            mru = np.asarray(self._mru[m0:m1], float).reshape(-1, 4)
            enc = np.asarray(self._enc[e0:e1], float).reshape(-1, 3)
            ev_t, ev_s, ev_i = merged_events((self._t_mru[m0:m1], self._t_enc[e0:e1]), -math.inf, math.inf)
            enc_ok = np.isfinite(enc[:, 2]).tolist()
            for te, s, i in zip(ev_t.tolist(), ev_s.tolist(), ev_i.tolist()):
                if s == 0:
                    f.update_mru_sample(mru[i], t=te)
                elif enc_ok[i]:
                    e = enc[i]
                    f.update_encoders(e[0], e[1], e[2], t=te)
        self._next_mru, self._next_enc = m1, e1
        f.advance_to(t)
        return self.estimate()

    def tip_attitude(self) -> tuple[float, float, float]:
        """(roll, pitch, heading) of the boom-tip frame at the last :meth:`predict` (rad): the
        vessel's roll and pitch and the slew plus the boom's deflection, filtered. They level
        a LiDAR frame far better than one MRU sample, whose 0.02 deg (0.35 mrad) of noise alone
        moves the cloud by 7 cm at 200 m."""
        x = self.filter.x
        heading = x[INU] + (x[IF] if len(x) > IF else 0.0)
        return float(x[IROLL]), float(x[IPITCH]), float(heading)

    def tip_attitude_sigma_rad(self) -> float:
        """The largest 1-sigma (rad) of the tip's attitude and of the slew and luff that place
        the tip: large at the start, settled within seconds."""
        P = self.filter.P
        heading_var = P[INU, INU] + (P[IF, IF] + 2.0 * P[INU, IF] if len(P) > IF else 0.0)
        return float(math.sqrt(max(P[IROLL, IROLL], P[IPITCH, IPITCH], P[INU, INU], P[IMU, IMU], heading_var)))

    def hoist(self) -> tuple[float, float]:
        """The rope's length and its rate (m, m/s) at the last :meth:`predict`, filtered."""
        x = self.filter.x
        return float(x[IL]), float(x[IL + 1])

    def correct(self, p_rel_tip_world: np.ndarray, cov_m2: np.ndarray) -> bool:
        """Apply a detection at the time of the last :meth:`predict`; False if gated out."""
        return self.filter.update_lidar(p_rel_tip_world, cov_m2=cov_m2)

    def correct_rope(self, direction: np.ndarray, cov: np.ndarray) -> bool:
        """Apply the rope's direction at the time of the last :meth:`predict`; False if gated out."""
        return self.filter.update_rope(direction, cov)

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Hook position relative to the tip (world axes) and its covariance now (after corrections)."""
        p, _, cov_p, _ = self.filter.hook_position_velocity_covariance()
        return p, cov_p

    def velocity(self) -> tuple[np.ndarray, np.ndarray]:
        """Hook velocity relative to the tip (world axes, m/s) and its covariance now."""
        _, v, _, cov_v = self.filter.hook_position_velocity_covariance()
        return v, cov_v
