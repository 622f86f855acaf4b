"""The small pieces of the hook filter's Kalman equations (fusion/hook_kalman_core.py): the
estimate's container, filterpy's Merwe sigma points vectorised, and the correction through the
Cholesky factor of the innovation's covariance."""

from __future__ import annotations

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints
from scipy.linalg.lapack import dpotrf, dtrtri

__all__ = ["KalmanState", "FastMerweSigmaPoints", "stacked_correction", "selection_correction"]


class KalmanState:
    """The estimate (x, P) as one array ``M`` ((n + 1) x n): rows 0..n-1 the covariance P, row n
    the mean x. A prediction ``M' = blockdiag(F, 1) (M F^T) + [Q; c^T]`` and a correction
    (:func:`stacked_correction`) carry the mean in the covariance's products: at 200 Hz the
    filter's cost is numpy's per-call overhead, and this drops a third of the calls. ``x`` and
    ``P`` are views of M; M is replaced, never changed in place, so its identity marks the state.
    The EKF and UKF equations are written out in :class:`~boomtip.fusion.hook_kalman_core.HookKalmanCore`
    (filterpy's ExtendedKalmanFilter / UnscentedKalmanFilter; their per-call overhead would dominate
    the 200 Hz loop)."""

    __slots__ = ("M", "n")

    def __init__(self, n: int) -> None:
        self.n = n
        self.M = np.vstack([np.eye(n), np.zeros((1, n))])

    @property
    def x(self) -> np.ndarray:
        return self.M[self.n]

    @property
    def P(self) -> np.ndarray:
        return self.M[: self.n]

    def set(self, x, P) -> None:
        M = np.empty((self.n + 1, self.n))
        M[: self.n] = P
        M[self.n] = x
        self.M = M


class FastMerweSigmaPoints(MerweScaledSigmaPoints):
    """filterpy's Merwe points with a vectorised ``sigma_points`` (same result)."""

    def sigma_points(self, x, P):
        n = self.n
        lambda_ = self.alpha**2 * (n + self.kappa) - n
        M = (lambda_ + n) * np.asarray(P)
        # the upper Cholesky factor U^T U = M (filterpy's default scipy.linalg.cholesky),
        # straight from LAPACK
        U, info = dpotrf(M)
        if info != 0:  # lost positive definiteness: clip the eigenvalues
            w, V = np.linalg.eigh(0.5 * (M + M.T))
            U = (V * np.sqrt(np.clip(w, 1e-300, None))).T
        x = np.asarray(x, float)
        return np.concatenate([x[None, :], x + U, x - U], axis=0)


def stacked_correction(M: np.ndarray, C: np.ndarray, S: np.ndarray, nis: bool = False):
    """The Kalman correction of the stacked estimate M ((n + 1) x n, :class:`KalmanState`):
    C ((n + 1) x k) holds P H^T in its first n rows and the negated innovation -y^T in its last,
    S (k x k) the innovation's covariance. Returns M' = [P - K S K^T; (x + K y)^T] (and y^T S^-1 y
    with ``nis``) for the gain K = P H^T S^-1.

    With the Cholesky factor S = U^T U and G = C U^-1: G[:n] G[:n]^T = K S K^T and
    -G[n] G[:n]^T = (K y)^T, so M' = M - G G[:n]^T, one product for both. Two small LAPACK calls
    instead of numpy.linalg.inv (whose Python overhead would dominate the 200 Hz linear updates).
    """
    n = M.shape[1]
    U, info = dpotrf(S)
    if info == 0:
        Ui, info = dtrtri(U)
    if info != 0:  # S not positive definite (a broken P): the plain formulas
        SiCT = np.linalg.solve(S, C[:n].T)  # S^-1 (P H^T)^T
        M_new = M - C @ SiCT
        if nis:
            y = -C[n]
            return M_new, float(y @ np.linalg.solve(S, y))
        return M_new
    G = C @ Ui
    M_new = M - G @ G[:n].T
    if nis:
        w = G[n]
        return M_new, float(w @ w)
    return M_new


def selection_correction(M: np.ndarray, ii: np.ndarray, R: np.ndarray, z: np.ndarray, nis: bool = False):
    """:func:`stacked_correction` for z = x[ii] + noise (R, k x k): C = M[:, ii] less z in the
    mean's row (P H^T = P[:, ii] for symmetric P; -y = x[ii] - z), S = P[ii, ii] + R."""
    C = M.take(ii, 1)
    C[-1] -= z
    S = C.take(ii, 0)
    S += R
    return stacked_correction(M, C, S, nis)
