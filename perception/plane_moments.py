"""A plane's least-squares fit from its points' moments, for points stored column-wise, (3, N)
C-contiguous float64, sensor frame, metres: the centroid and scatter, the 3x3 eigendecomposition,
the plane and its inliers. Planes as in :mod:`boomtip.perception.plane` ([a, b, c, d], unit normal,
d >= 0: the sensor origin on the positive side)."""

from __future__ import annotations

import math

import numpy as np

try:  # LAPACK's symmetric eigensolver as np.linalg.eigh calls it, without the wrapper (see eigh3)
    from numpy.linalg._umath_linalg import eigh_lo as _eigh_lo
except ImportError:  # pragma: no cover - a numpy that moved it: the public call
    _eigh_lo = None

__all__ = ["eigh3"]


def eigh3(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.linalg.eigh`` of one symmetric 3x3 float64 matrix (eigenvalues ascending, eigenvectors
    as columns), bit for bit: the same LAPACK routine through numpy's own ufunc, without the
    wrapper's checks, type resolution and error-state context, which cost twice the solve and
    run some ten times per LiDAR frame. A result that is not finite (non-finite input, no
    convergence) goes through np.linalg.eigh, which raises or returns exactly as before."""
    if _eigh_lo is not None:
        with np.errstate(invalid="ignore"):
            evals, vecs = _eigh_lo(a, signature="d->dd")
        if math.isfinite(evals[0] + evals[1] + evals[2]):
            return evals, vecs
    return np.linalg.eigh(a)


def plane_and_eig(centroid: np.ndarray, scatter: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plane through ``centroid`` whose normal is the smallest-eigenvalue eigenvector of
    ``scatter``, oriented towards the sensor origin (d >= 0); with the eigenvalues and vectors."""
    evals, vecs = eigh3(scatter)
    n = vecs[:, 0]
    n = n / np.sqrt(n.dot(n))  # np.linalg.norm's own arithmetic, without its wrapper
    plane = np.empty(4)
    plane[:3] = n
    plane[3] = -float(n @ centroid)
    if plane[3] < 0:  # orient_plane_towards the origin, inline: it runs for every fit
        plane = -plane
    return plane, evals, vecs


def moments_cols(cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid and scatter about it of points stored COLUMN-wise, (3, M) C-contiguous float64.

    The scatter is the raw second-moment matrix of the rows minus the centroid term.
    Rounding: entries carry an absolute error of about M |p|^2 eps; relative to the eigen-gap
    M * extent^2 that tilts the normal by |p|^2 eps / extent^2, i.e. 2e-11 rad for a 1 m patch at
    300 m range: negligible.
    """
    m = cols.shape[1]
    s = cols.sum(axis=1)
    # numpy's own sum-of-products loop, not BLAS: on a busy machine a multithreaded BLAS dot/GEMM
    # here can wait tens of ms for its helper thread, einsum never does
    raw = np.einsum("ij,kj->ik", cols, cols)
    raw -= (s[:, None] * s) / m  # np.outer's products, without its wrapper
    return s / m, raw


def fit_plane_cols(cols: np.ndarray) -> np.ndarray:
    """Least-squares plane through points stored COLUMN-wise, (3, M) C-contiguous float64, M >= 3.

    The normal is the right singular vector of the centred points with the smallest singular value,
    computed as the smallest-eigenvalue eigenvector of the 3x3 scatter matrix of the centred points
    (mathematically identical to the SVD, and 10-20x faster than an SVD of an (M, 3) matrix).
    """
    return plane_and_eig(*moments_cols(cols))[0]


def select_inliers(cols: np.ndarray, plane: np.ndarray, thr: float) -> np.ndarray:
    """Indices of the points (columns of (3, N) ``cols``) with |n . p + d| < thr."""
    r = plane[:3] @ cols
    r += plane[3]
    np.abs(r, out=r)
    # nonzero() of the 1-D mask is np.flatnonzero without its ravel and wrapper (a few us per call,
    # more in a cold cache: this runs on every cloud and subsample several times a frame)
    return (r < thr).nonzero()[0]
