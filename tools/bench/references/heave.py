"""A frozen earlier implementation of the heave chain's reflector, Doppler and deck-spin stages
(docstrings and comments left out): the baseline that `boomtip bench perception` times the stages
against, with the same algorithms and results. No run uses it. The deck stage's reference:
tools/bench/references/heave_deck.py."""

from __future__ import annotations

import math

import numpy as np

from boomtip.perception.cloud import as_points
from boomtip.perception.doppler import DopplerConfig, DopplerFit
from boomtip.perception.doppler import doppler_velocity as current_doppler_velocity
from boomtip.perception.geometry import NormalRate, heave_distance, prediction_sigma_of_points, inv3, sym3_eigvals
from boomtip.perception.reflectors import (
    INTENSITY_REFERENCE_RANGE_M,
    ReflectorConfig,
    ReflectorResult,
    triplets,
    intensity_threshold,
)
from boomtip.perception.timing import StageTimes


class ReferenceNormalRate(NormalRate):
    """The deck's spin by the quadratic fit, in the earlier implementation."""

    def _fit(self) -> list[list[float]]:
        if self._coef is None:
            tt = np.asarray(self.t) - self.t[-1]
            deg = 2 if len(tt) >= 6 else 1
            V = np.vander(tt, deg + 1, increasing=True)  # columns 1, t, t^2
            VtV = V.T @ V
            inv = inv3(VtV) if deg == 2 else np.linalg.inv(VtV)
            coef = (inv @ (V.T @ np.asarray(self.n))).tolist()
            self._coef = coef if deg == 2 else coef + [[0.0, 0.0, 0.0]]
        return self._coef


def fit_plane_heave(points: np.ndarray, wire_dir: np.ndarray, p_tip: np.ndarray, offset_m: float = 0.0) -> tuple[np.ndarray, float, float]:
    c = points.mean(axis=0)
    X = points - c
    evals, evecs = np.linalg.eigh(X.T @ X)
    n = evecs[:, 0]
    d = -float(n @ c)
    plane = np.array([n[0], n[1], n[2], d]) if d >= 0 else -np.array([n[0], n[1], n[2], d])
    fitted = plane.copy()
    plane[3] += offset_m
    D = heave_distance(plane, wire_dir, p_tip)
    if not np.isfinite(D) or len(points) < 4:
        return plane, D, float("nan")
    return plane, D, prediction_sigma_of_points(points, fitted, c, evals, evecs, p_tip + D * wire_dir)


def group_markers(points: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = len(points)
    if n == 0:
        return np.zeros(0, dtype=np.intp), np.zeros((0, 3)), np.zeros(0, dtype=np.intp)
    cells = np.floor(points / cell_m).astype(np.int64)
    cells -= cells.min(axis=0)
    span = cells.max(axis=0) + 1
    key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]
    first = np.empty(n, dtype=bool)
    first[0] = True
    np.not_equal(key_sorted[1:], key_sorted[:-1], out=first[1:])
    starts = np.flatnonzero(first)
    labels = np.empty(n, dtype=np.intp)
    labels[order] = np.cumsum(first) - 1
    counts = np.empty_like(starts)
    counts[:-1] = starts[1:] - starts[:-1]
    counts[-1] = n - starts[-1]
    centroids = np.add.reduceat(points[order], starts, axis=0) / counts[:, None]
    return labels, centroids, counts


def plane_through_markers(centroids: np.ndarray, threshold_m: float) -> np.ndarray:
    tri = triplets(len(centroids))
    a = centroids[tri[:, 0]]
    e1 = centroids[tri[:, 1]] - a
    e2 = centroids[tri[:, 2]] - a
    n = np.empty_like(e1)
    n[:, 0] = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
    n[:, 1] = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
    n[:, 2] = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        n /= np.sqrt(n[:, 0] ** 2 + n[:, 1] ** 2 + n[:, 2] ** 2)[:, None]
    d = -(n[:, 0] * a[:, 0] + n[:, 1] * a[:, 1] + n[:, 2] * a[:, 2])
    inl = np.abs(centroids @ n.T + d) < threshold_m
    return inl[:, int(np.argmax(inl.sum(axis=0)))]


def detect_reflectors(
    points_sensor: np.ndarray,
    intensity: np.ndarray,
    wire_dir_sensor: np.ndarray,
    p_tip_sensor: np.ndarray,
    cfg: ReflectorConfig | None = None,
    rng: np.random.Generator | None = None,
    times: StageTimes | None = None,
) -> ReflectorResult:
    points_sensor = as_points(points_sensor)
    intensity = np.asarray(intensity).reshape(-1)
    if len(intensity) != len(points_sensor):
        raise ValueError(f"intensity has {len(intensity)} values, points have {len(points_sensor)}")
    wire_dir_sensor = np.asarray(wire_dir_sensor, dtype=np.float64)
    p_tip_sensor = np.asarray(p_tip_sensor, dtype=np.float64)
    cfg = cfg or ReflectorConfig()
    times = times if times is not None else StageTimes()
    empty = np.zeros((0, 3))
    with times.stage("reflectors.threshold"):
        p = points_sensor
        r2 = p[:, 0] * p[:, 0] + p[:, 1] * p[:, 1] + p[:, 2] * p[:, 2]
        if cfg.range_compensate:
            step = max(1, len(r2) // 2000)
            thr = intensity_threshold(intensity[::step] * (r2[::step] / INTENSITY_REFERENCE_RANGE_M**2), cfg)
            idx = np.flatnonzero(intensity * r2 > thr * INTENSITY_REFERENCE_RANGE_M**2)
        else:
            thr = intensity_threshold(intensity, cfg)
            idx = np.flatnonzero(intensity > thr)
        bright = p[idx]
        bright = bright[np.isfinite(bright).all(axis=1) & np.isfinite(intensity[idx])]
    if len(bright) < 3:
        return ReflectorResult(float("nan"), None, empty, bright, thr, f"no reflectors ({len(bright)} bright points)")
    if len(bright) > cfg.max_bright_points:
        return ReflectorResult(float("nan"), None, empty, bright[:0], thr,
                               f"{len(bright)} bright points: intensity threshold {thr:.3g} lets diffuse returns through")
    with times.stage("reflectors.markers"):
        labels, centroids, counts = group_markers(bright, cfg.cluster_cell_m)
        n_markers = len(counts)
        if n_markers < cfg.min_markers:
            return ReflectorResult(float("nan"), None, centroids, bright, thr, f"too few markers ({n_markers} < {cfg.min_markers})")
        order = np.argsort(-counts)[: cfg.max_markers_ransac]
        on_plane = np.zeros(n_markers, dtype=bool)
        on_plane[order[plane_through_markers(centroids[order], cfg.plane_threshold_m)]] = True
        good = centroids[on_plane]
        if len(good) < cfg.min_markers:
            return ReflectorResult(float("nan"), None, good, bright, thr, f"too few markers on one plane ({len(good)} < {cfg.min_markers})")
        c = good - good.mean(axis=0)
        spread = 2 * math.sqrt(max(sym3_eigvals(c.T @ c)[1], 0.0) / len(c))
    if spread < cfg.min_spread_m:
        return ReflectorResult(float("nan"), None, good, bright, thr, f"markers collinear (spread {spread:.2f} m)")
    with times.stage("reflectors.plane"):
        plane, D, sigma = fit_plane_heave(bright[on_plane[labels]], wire_dir_sensor, p_tip_sensor,
                                          offset_m=cfg.marker_height_m)
    return ReflectorResult(D, plane, good, bright, thr, "ok" if np.isfinite(D) else "wire parallel to the plane", sigma)


def _trimmed_fit(bT: np.ndarray, r: np.ndarray, cfg: DopplerConfig, valid: np.ndarray | None, n_all: int,
                 u_prior: np.ndarray | None = None) -> "DopplerFit | None":
    n = len(r)
    bx, by, bz = bT
    Z = np.empty((10, n))
    np.multiply(bx, bT, out=Z[0:3])
    np.multiply(by, bT[1:], out=Z[3:5])
    np.multiply(bz, bz, out=Z[5])
    np.multiply(bT, r, out=Z[6:9])
    np.multiply(r, r, out=Z[9])

    def solve(w: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float] | None:
        xx, xy, xz, yy, yz, zz, yx_, yy_, yz_, rr = (Z @ w).tolist()
        c00, c01, c02 = yy * zz - yz * yz, xz * yz - xy * zz, xy * yz - xz * yy
        det = xx * c00 + xy * c01 + xz * c02
        if abs(det) < 1e-300:
            return None
        c11, c12, c22 = xx * zz - xz * xz, xy * xz - xx * yz, xx * yy - xy * xy
        inv = np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]]) / det
        u = inv @ np.array([yx_, yy_, yz_])
        sse = max(rr - float(u[0] * yx_ + u[1] * yy_ + u[2] * yz_), 0.0)
        frob_a2 = xx * xx + yy * yy + zz * zz + 2.0 * (xy * xy + xz * xz + yz * yz)
        return u, inv, sse, frob_a2

    if u_prior is not None:
        u = np.asarray(u_prior, dtype=float)
    else:
        sol = solve(np.ones(n))
        if sol is None:
            return None
        u = sol[0]
    mask, sol = None, None
    for it in range(6):
        res = u @ bT
        res -= r
        np.abs(res, out=res)
        if it == 0 and u_prior is None:
            k = n // 2
            band = max(cfg.inlier_threshold_mps, 4.45 * float(np.partition(res, k)[k]))
        else:
            band = cfg.inlier_threshold_mps
        new = res < band
        if mask is not None and np.array_equal(new, mask):
            break
        mask = new
        n_in = int(np.count_nonzero(mask))
        if n_in < max(3, cfg.trimmed_min_fraction * n):
            return None
        sol = solve(mask.astype(np.float64))
        if sol is None:
            return None
        u = sol[0]
    if sol is None or n_in < max(3, cfg.min_inliers):
        return None
    u, inv, sse, frob_a2 = sol
    cond = float(math.sqrt(math.sqrt(frob_a2) * np.linalg.norm(inv)))
    if cond > cfg.max_condition:
        return None
    sigma2 = sse / max(n_in - 3, 1)
    if valid is None:
        full = mask
    else:
        full = np.zeros(n_all, dtype=bool)
        full[np.flatnonzero(valid)[mask]] = True
    return DopplerFit(u, full, float(math.sqrt(sse / n_in)), sigma2 * inv, cond, 0)


def doppler_velocity(
    beam_dirs: np.ndarray,
    range_rate_mps: np.ndarray,
    cfg: DopplerConfig | None = None,
    rng: np.random.Generator | None = None,
    u_prior: np.ndarray | None = None,
) -> DopplerFit | None:
    b_all = as_points(beam_dirs)
    cfg = cfg or DopplerConfig()
    r_all = np.asarray(range_rate_mps, dtype=np.float64).reshape(-1)
    if len(b_all) != len(r_all):
        raise ValueError("beam_dirs and range_rate_mps must have the same length")
    n_all = len(r_all)
    n2 = np.einsum("ij,ij->i", b_all, b_all)
    valid = np.isfinite(r_all) & np.isfinite(n2) & (n2 > 0)
    if valid.all():
        valid_sel, b_sel, r, n2_sel = None, b_all, r_all, n2
    else:
        valid_sel, b_sel, r, n2_sel = valid, b_all[valid], r_all[valid], n2[valid]
    n = len(r)
    if n < 3:
        return None
    bT = np.divide(b_sel.T, np.sqrt(n2_sel), out=np.empty((3, n)))
    thr = cfg.inlier_threshold_mps
    if cfg.start == "trimmed" and cfg.huber_delta_mps is None:
        fit = _trimmed_fit(bT, r, cfg, valid_sel, n_all, u_prior) if u_prior is not None else None
        if fit is None:
            fit = _trimmed_fit(bT, r, cfg, valid_sel, n_all)
        if fit is not None:
            return fit
    return current_doppler_velocity(beam_dirs, range_rate_mps, cfg, rng, u_prior)
