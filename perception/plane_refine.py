"""The deck plane's last step: an M-estimate (Tukey's biweight) from RANSAC's plane, for
surfaces that are not flat at the centimetre level. Sensor frame, metres; planes as in
:mod:`boomtip.perception.plane`."""

from __future__ import annotations

import math

import numpy as np

from boomtip.perception.cloud import as_points
from boomtip.perception.plane import orient_plane_towards
from boomtip.perception.plane_moments import eigh3

__all__ = ["refine_plane_biweight", "refine_plane_biweight_cols"]


def _biweight_step(rows4: np.ndarray, plane: list[float], inv_scale: float) -> tuple[list[float], float]:
    """One weighted total-least-squares round over (4, M) rows x, y, z, 1; (plane, how far it
    moved), planes as lists of four Python floats.

    Per round: one product for r / scale (d rides on the row of ones), four in-place passes for
    the weights w = (1 - (r / scale)^2)^2 (0 beyond the scale), and ONE product rows (rows w)^T
    (1.5x faster than (rows w) rows^T here) whose 4 x 4 result holds the weighted sums of x x^T,
    of x and of w; the rest is 3x3 (the eigendecomposition) or 3-long, in Python floats. As a
    weighted sum and mean, a scatter and a 3x3 fit in numpy, the same round would take some
    thirty numpy calls, whose per-call overhead would show in the deck's refine stage."""
    w = np.array([v * inv_scale for v in plane]) @ rows4  # r / scale
    np.multiply(w, w, out=w)
    np.subtract(1.0, w, out=w)
    np.maximum(w, 0.0, out=w)
    w *= w
    (sxx, sxy, sxz, sx), (_, syy, syz, sy), (_, _, szz, sz), (_, _, _, wsum) = (rows4 @ (rows4 * w).T).tolist()
    if not wsum > 0.0:
        return plane, 0.0
    cx, cy, cz = sx / wsum, sy / wsum, sz / wsum
    scatter = np.array([[sxx - wsum * (cx * cx), sxy - wsum * (cx * cy), sxz - wsum * (cx * cz)],
                        [sxy - wsum * (cy * cx), syy - wsum * (cy * cy), syz - wsum * (cy * cz)],
                        [sxz - wsum * (cz * cx), syz - wsum * (cz * cy), szz - wsum * (cz * cz)]])
    (n0, _, _), (n1, _, _), (n2, _, _) = eigh3(scatter)[1].tolist()  # the least eigenvector: the normal
    norm = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    n0, n1, n2 = n0 / norm, n1 / norm, n2 / norm
    d = -(n0 * cx + n1 * cy + n2 * cz)
    p0, p1, p2, p3 = plane
    if n0 * p0 + n1 * p1 + n2 * p2 < 0:  # keep the start's orientation while iterating
        n0, n1, n2, d = -n0, -n1, -n2, -d
    moved = abs(d - p3) + 10.0 * math.sqrt((n0 - p0) ** 2 + (n1 - p1) ** 2 + (n2 - p2) ** 2)
    return [n0, n1, n2, d], moved


def refine_plane_biweight(points: np.ndarray, plane: np.ndarray, scale_m: float, iterations: int = 10,
                          tol_m: float = 1e-4, max_points: int = 8192) -> np.ndarray:
    """M-estimate of a plane from a start near it: iteratively reweighted total least squares
    with Tukey's biweight (weight (1 - (r/scale)^2)^2 inside |r| < scale, 0 outside).

    RANSAC's consensus plane is one of many near-equal ones on a surface that is not flat at
    the centimetre level (a cambered road, a sagging deck): which one depends on the seed, and
    a least-squares refit on a hard inlier band inherits it. The biweight's smooth weights
    converge to the same plane from any of them (on real scans millimetres apart from seed to
    seed, where the band's refit spreads by centimetres). Stops when the plane moves less than tol_m
    over a 10 m span. The iterations run on at most max_points of the points near the start (an
    even stride through them), the last on all of them. Sensor frame, metres; oriented like
    the start (d >= 0)."""
    cols = np.ascontiguousarray(as_points(points).T)
    return refine_plane_biweight_cols(cols, plane, scale_m, iterations, tol_m, max_points)


def refine_plane_biweight_cols(cols: np.ndarray, plane: np.ndarray, scale_m: float, iterations: int = 10,
                               tol_m: float = 1e-4, max_points: int = 8192) -> np.ndarray:
    """:func:`refine_plane_biweight` on points stored column-wise, (3, N) C-contiguous float64."""
    plane = np.asarray(plane, dtype=np.float64).copy()
    # the plane moves by centimetres from a RANSAC start: the points within two scales of the
    # start are all the iterations can ever weigh, so they are gathered once, with a row of ones
    r = plane[:3] @ cols
    r += plane[3]
    idx = (np.abs(r, out=r) < 2.0 * scale_m).nonzero()[0]
    m = len(idx)
    if m < 3:
        return plane
    near = np.empty((4, m))
    cols.take(idx, axis=1, out=near[:3])
    near[3] = 1.0
    origin = np.add.reduce(near[:3], axis=1) / m  # ndarray.mean's arithmetic, without its wrapper
    near[:3] -= origin[:, None]  # raw moments about a point on the plane: no cancellation at 100 m
    plane[3] += plane[:3] @ origin
    stride = -(-m // max_points)
    sub = np.ascontiguousarray(near[:, ::stride]) if stride > 1 else near
    p = plane.tolist()
    for _ in range(iterations):
        p, moved = _biweight_step(sub, p, 1.0 / scale_m)
        if moved < tol_m:
            break
    if sub is not near:
        p, _ = _biweight_step(near, p, 1.0 / scale_m)  # the last round on every point
    plane = np.array(p)
    plane[3] -= plane[:3] @ origin
    return orient_plane_towards(plane)
