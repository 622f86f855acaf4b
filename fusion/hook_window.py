"""The UKF's prediction window (``HookFilterConfig.ukf_window_s``), a part of
:class:`~boomtip.fusion.hook_kalman_core.HookKalmanCore` (its estimate, prediction and Jacobian).

The sigma points step once per window (25 ms, five MRU samples). The MRU and encoder samples of
a window wait for its end and are applied there as one linear update, each row its chain's
state extrapolated back to the sample's time (fusion/models/linear_chains.py); a LiDAR frame
closes the window at its time. The window's Q is the noise of its 5 ms steps carried to its end
by the model linearised (A = df/dx, taken at a window's start every ``jacobian_interval_s``):
the vessel's and the joints' noise moves the sway within the window (the relative sway rate
follows the roll rate at once). The outputs inside a window are its start with its samples so
far applied one by one, carried by that linearisation. The same estimates as a sigma-point step per sample to 0.1 mm of the hook
(tests/fusion), at a fifth of the model's cost.
"""

from __future__ import annotations

import math

import numpy as np

from boomtip.fusion.hook_kalman_steps import selection_correction, stacked_correction
from boomtip.fusion.models.crane_pendulum import IAD, IBD, IFD
from boomtip.fusion.models.linear_chains import accumulated_noise, sample_rows

__all__ = ["PredictionWindow"]


class PredictionWindow:
    """The window's samples, its linearisation and the outputs inside it (mixed into
    :class:`~boomtip.fusion.hook_kalman_core.HookKalmanCore`)."""

    def _init_window(self, window_s: float) -> None:
        self._window = float(window_s)
        self.windowed = self._window > self.dt_s + 1e-12
        self._step = self._window if self.windowed else self.dt_s
        # samples (time, kind, values) waiting for the window's end; a kind is an entry of
        # self._kinds (measured states, noise variances); the batches' (H, R) per pattern
        self._pend_t: list[float] = []
        self._pend_kind: list[int] = []
        self._pend_z: list[np.ndarray] = []
        self._batch_cache: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        # the window's linearisation: the state it was taken at, A there, the model's derivative
        # less A x there (non-zero in the accelerations' rows), and per step length tau the
        # (F, c) of x' = F x + c
        self._acc_rows = np.array([IAD, IBD, IFD] if self.flex else [IAD, IBD], np.intp)
        self._f_offset = np.zeros(self.n)
        self._lin_M: np.ndarray | None = None  # the stacked estimate A was taken at
        self._lin_steps: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._window_q: dict[tuple, np.ndarray] = {}  # the window's Q per (steps, step) for this A
        # the outputs inside a window: (x, P, t, samples applied) and the window start's x
        self._int: tuple[np.ndarray, np.ndarray, float, int] | None = None
        self._int_base: np.ndarray | None = None

    def _enqueue(self, kind: int, z, t: float) -> None:
        """A sample for the window's end (a sample beyond the window closes it first)."""
        if t - self.t > self._window + 1e-9:
            self._flush()
            while t - self.t > self._window + 1e-9:
                self.predict(self._window)
        self._pend_t.append(t)
        self._pend_kind.append(kind)
        self._pend_z.append(np.asarray(z, float))

    def _windowed_estimate(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`estimate_at` with a window: a complete window is closed first; inside one the
        estimate at its start with its samples so far applied one by one, carried by the model
        linearised at its start."""
        if self._pend_t and t - self.t >= self._window - 1e-9:
            self._flush()
        while t - self.t >= self._window - 1e-9:
            self.predict(self._window)
        kf = self._kf
        M, t0, applied = self._int if self._int_base is kf.M else (kf.M, self.t, 0)
        if applied < len(self._pend_t):
            # the window's samples not yet in the outputs' estimate, one by one (the window's end
            # applies them again, with the crane model's step, to the estimate at its start)
            for tj, kind, z in zip(self._pend_t[applied:], self._pend_kind[applied:], self._pend_z[applied:]):
                M = self._linear_prediction(M, tj - t0)
                ii, R = self._selection(kind)
                if not math.isfinite(z @ z):
                    keep = np.isfinite(z)
                    ii, R, z = ii[keep], R[np.ix_(keep, keep)], z[keep]
                if len(z):
                    M = selection_correction(M, ii, R, z)
                t0 = tj
            self._int, self._int_base = (M, t0, len(self._pend_t)), kf.M
        if t - t0 > 1e-9:
            M = self._linear_prediction(M, t - t0)
        n = self.n
        return M[n], M[:n]

    def _window_noise(self, dt: float) -> np.ndarray:
        """Q of a window dt: the noise its steps of at most 1 / predict_rate add, each carried
        to the window's end by the model linearised at its start (the discrete models' variance
        per second depends on their step; and the vessel's and the joints' noise moves the sway
        within the window: the relative sway rate follows the roll rate at once)."""
        m = max(1, math.ceil(dt / self.dt_s - 1e-9))
        h = dt / m
        Qh = self._q_step_cache.get(round(h, 12))
        if Qh is None:
            Qh = self._step_noise(h)
        if m == 1:
            return Qh
        F = self._linear_step(h)[0].T  # (first: the linearisation, which clears the cache when new)
        key = (m, round(h, 12))
        Q = self._window_q.get(key)
        if Q is None:
            Q = self._window_q[key] = accumulated_noise(Qh, F, m)
        return Q

    def _selection(self, kind: int) -> tuple[np.ndarray, np.ndarray]:
        """(measured state indices, R) of a sample kind (an entry of ``self._kinds``)."""
        c = self._lin_cache.get((kind,))
        if c is None:
            idx, r = self._kinds[kind]
            c = self._lin_cache[(kind,)] = (np.array(idx, np.intp), np.diag(r))
        return c

    def _window_linearisation(self) -> np.ndarray:
        """A = df/dx and the model's derivative (self._f_offset) at the estimate at a window's
        start, refreshed at the first window start at least ``jacobian_interval_s`` after the
        last (0: at every window), as the EKF's."""
        M = self._kf.M  # replaced, never changed in place: its identity marks the estimate (x is a new view each read)
        if self._A is None or (self._lin_M is not M and self.t - self._A_t >= self._jac_interval - 1e-9):
            self._A, self._f_offset = self._linearisation(self._kf.x)
            self._A_t, self._lin_M = self.t, M
            self._lin_steps, self._window_q = {}, {}
        return self._A

    def _linear_step(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The step x' = F x + c, P' = F P F^T + Q over tau of the model linearised at the window's
        start x0 (the estimate at self.t; A = df/dx there, F = I + A tau + (A tau)^2 / 2 and
        f(x) ~ A x + (f(x0) - A x0), as the EKF's mean, HookFilterConfig.ekf_mean) for the stacked
        estimate (hook_kalman_steps.KalmanState): (F^T, blockdiag(F, 1), [Q; c^T])."""
        self._window_linearisation()
        key = round(tau, 12)
        st = self._lin_steps.get(key)
        if st is None:
            n = self.n
            Ad = self._A * tau
            Fs = np.zeros((n + 1, n + 1))
            F = Fs[:n, :n]
            F[:] = self._I + Ad + 0.5 * (Ad @ Ad)
            Fs[n, n] = 1.0
            QC = np.empty((n + 1, n))
            QC[:n] = self._step_noise(tau)
            QC[n] = tau * self._f_offset + (0.5 * tau) * (Ad @ self._f_offset)
            st = self._lin_steps[key] = (F.T.copy(), Fs, QC)
        return st

    def _linear_prediction(self, M: np.ndarray, tau: float) -> np.ndarray:
        """The stacked estimate M carried over tau inside a window by the model linearised at its
        start."""
        FT, Fs, QC = self._linear_step(tau)
        M = Fs @ (M @ FT)
        M += QC
        return M

    def _flush(self) -> None:
        """Close the window: predict to its last sample's time and apply its samples as one
        linear update, each row its state extrapolated back to the sample's time
        (fusion/models/linear_chains.py)."""
        if not self._pend_t:
            return
        T = self._pend_t[-1]
        if T - self.t > 1e-12:
            self.predict(T - self.t)
        pattern = (tuple(self._pend_kind), tuple(round(T - tj, 9) for tj in self._pend_t))
        z = np.concatenate(self._pend_z)
        self._pend_t, self._pend_kind, self._pend_z = [], [], []
        c = self._batch_cache.get(pattern)
        if c is None:
            kinds = [self._kinds[k] for k in pattern[0]]
            c = (np.vstack([sample_rows(idx, tau, self.n) for (idx, _), tau in zip(kinds, pattern[1])]),
                 np.diag(np.concatenate([r for _, r in kinds])))
            if len(self._batch_cache) < 256:
                self._batch_cache[pattern] = c
        H, R = c
        if not math.isfinite(z @ z):  # a NaN sample updates nothing (z @ z: NaN or inf with one)
            keep = np.isfinite(z)
            if not keep.any():
                return
            H, R, z = H[keep], R[np.ix_(keep, keep)], z[keep]
        kf = self._kf
        C = kf.M @ H.T  # rows P H^T, (H x)^T
        C[-1] -= z
        S = H @ C[:-1]
        S += R
        kf.M = stacked_correction(kf.M, C, S)
