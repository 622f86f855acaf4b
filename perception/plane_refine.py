"""The deck plane's last step: an M-estimate (Tukey's biweight) from RANSAC's plane, for
surfaces that are not flat at the centimetre level. Sensor frame, metres; planes as in
:mod:`boomtip.perception.plane`."""

from __future__ import annotations

import math

import numpy as np

from boomtip.perception.cloud import as_points
from boomtip.perception.plane import orient_plane_towards
from boomtip.perception.plane_moments import _plane_and_eig

__all__ = ["refine_plane_biweight", "refine_plane_biweight_cols"]


def _biweight_step(cols: np.ndarray, plane: np.ndarray, inv_scale2: float) -> tuple[np.ndarray, float]:
    """One weighted total-least-squares round over (3, M) points; (plane, how far it moved)."""
    # in one buffer: w = 1 - r^2 / scale^2, the same operations in the same order as the expression
    w = plane[:3] @ cols
    w += plane[3]
    np.multiply(w, w, out=w)
    w *= inv_scale2
    np.subtract(1.0, w, out=w)  # 0 beyond the scale
    np.maximum(w, 0.0, out=w)
    w *= w
    wsum = float(w.sum())
    if wsum <= 0.0:
        return plane, 0.0
    xw = cols * w
    centre = xw.sum(axis=1) / wsum
    scatter = np.einsum("ij,kj->ik", xw, cols)
    scatter -= wsum * (centre[:, None] * centre)  # np.outer's products, without its wrapper
    new = _plane_and_eig(centre, scatter)[0]
    if new[:3] @ plane[:3] < 0:  # keep the start's orientation while iterating
        new = -new
    step = new[:3] - plane[:3]
    return new, abs(new[3] - plane[3]) + 10.0 * math.sqrt(step.dot(step))  # np.linalg.norm's arithmetic


def refine_plane_biweight(points: np.ndarray, plane: np.ndarray, scale_m: float, iterations: int = 10,
                          tol_m: float = 1e-4, max_points: int = 8192) -> np.ndarray:
    """M-estimate of a plane from a start near it: iteratively reweighted total least squares
    with Tukey's biweight (weight (1 - (r/scale)^2)^2 inside |r| < scale, 0 outside).

    RANSAC's consensus plane is one of many near-equal ones on a surface that is not flat at
    the centimetre level (a cambered road, a sagging deck): which one depends on the seed, and
    a least-squares refit on a hard inlier band inherits it. The biweight's smooth weights
    converge to the same plane from any of them (on real Ouster scans: 0.1-0.8 cm from seed to
    seed where the band's refit spread 2-5 cm). Stops when the plane moves less than tol_m
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
    # start are all the iterations can ever weigh, so they are gathered once
    r = plane[:3] @ cols
    r += plane[3]
    near = cols.take((np.abs(r, out=r) < 2.0 * scale_m).nonzero()[0], axis=1)
    if near.shape[1] < 3:
        return plane
    origin = np.add.reduce(near, axis=1) / near.shape[1]  # ndarray.mean's arithmetic, without its wrapper
    near -= origin[:, None]  # raw moments about a point on the plane: no cancellation at 100 m
    plane[3] += plane[:3] @ origin
    inv_scale2 = 1.0 / (scale_m * scale_m)
    stride = -(-near.shape[1] // max_points)
    sub = np.ascontiguousarray(near[:, ::stride]) if stride > 1 else near
    for _ in range(iterations):
        plane, moved = _biweight_step(sub, plane, inv_scale2)
        if moved < tol_m:
            break
    if sub is not near:
        plane, _ = _biweight_step(near, plane, inv_scale2)  # the last round on every point
    plane[3] -= plane[:3] @ origin
    return orient_plane_towards(plane)
