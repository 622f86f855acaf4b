"""The small pieces of the hook filter's Kalman equations (fusion/hook_kalman_core.py): the
estimate's container, filterpy's Merwe sigma points vectorised, and the correction through the
Cholesky factor of the innovation's covariance."""

from __future__ import annotations

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints
from scipy.linalg.lapack import dpotrf, dtrtri

__all__ = ["KalmanState", "FastMerweSigmaPoints", "kalman_correction"]


class KalmanState:
    """The estimate (x, P).  The EKF and UKF equations are written out in :class:`~boomtip.fusion.hook_kalman_core.HookKalmanCore`
    (same equations as filterpy's ExtendedKalmanFilter / UnscentedKalmanFilter; their
    per-call overhead dominated the 200 Hz loop)."""

    __slots__ = ("x", "P")

    def __init__(self, n: int) -> None:
        self.x = np.zeros(n)
        self.P = np.eye(n)


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


def kalman_correction(x, P, PHT, S, y, nis=False):
    """(x + K y, P - K S K^T[, y^T S^-1 y]) for the gain K = PHT S^-1.

    With the Cholesky factor S = U^T U and G = PHT U^-1: K S K^T = G G^T (exactly
    symmetric) and K y = G (U^-T y).  Two small LAPACK calls instead of numpy.linalg.inv
    (whose Python overhead dominated the 200 Hz linear updates).
    """
    U, info = dpotrf(S)
    if info == 0:
        Ui, info = dtrtri(U)
    if info != 0:  # S not positive definite (a broken P): the plain formulas
        K = PHT @ np.linalg.inv(S)
        if nis:
            return x + K @ y, P - K @ PHT.T, float(y @ np.linalg.solve(S, y))
        return x + K @ y, P - K @ PHT.T
    G = PHT @ Ui
    w = y @ Ui
    if nis:
        return x + G @ w, P - G @ G.T, float(w @ w)
    return x + G @ w, P - G @ G.T
