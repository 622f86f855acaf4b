"""A frozen earlier implementation of the heave chain's LiDAR deck stage (docstrings and comments
left out): the baseline that `boomtip bench perception` times the stage against, with the same
algorithm and results. No run uses it. The other stages' reference: tools/bench/references/heave.py."""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from boomtip.perception.cloud import as_points
from boomtip.perception.deck import DeckConfig, DeckResult
from boomtip.perception.geometry import heave_distance, plane_sigma_at
from boomtip.perception.plane import PlaneFit, RansacConfig, needed_iterations, select_inliers, orient_plane_towards
from boomtip.perception.preprocess import PreprocessConfig
from boomtip.perception.timing import StageTimes


def deck_like(inliers: np.ndarray, plane: np.ndarray, wire_dir: np.ndarray, min_extent_m: float) -> bool:
    c = inliers.mean(axis=0)
    X = inliers - c
    evals, evecs = np.linalg.eigh(X.T @ X / len(inliers))
    extent = 4 * np.sqrt(np.maximum(evals[1:], 0))
    if extent[0] < min_extent_m:
        return False
    denom = float(plane[:3] @ wire_dir)
    if abs(denom) < 1e-6:
        return False
    p_d = wire_dir * (-plane[3] / denom)
    q = (p_d - c) @ evecs[:, 1:]
    (q0, q1), (e0, e1) = q.tolist(), extent.tolist()
    return abs(q0) <= e0 and abs(q1) <= e1


def _plane_from_scatter(centroid: np.ndarray, scatter: np.ndarray) -> np.ndarray:
    _, vecs = np.linalg.eigh(scatter)
    n = vecs[:, 0]
    n = n / np.linalg.norm(n)
    plane = np.empty(4)
    plane[:3] = n
    plane[3] = -float(n @ centroid)
    return orient_plane_towards(plane)


def fit_plane_cols(cols: np.ndarray) -> np.ndarray:
    m = cols.shape[1]
    s = cols.sum(axis=1)
    raw = np.einsum("ij,kj->ik", cols, cols)
    scatter = raw - np.outer(s, s) / m
    return _plane_from_scatter(s / m, scatter)


def ransac_plane(
    points: np.ndarray,
    cfg: RansacConfig | None = None,
    rng: np.random.Generator | None = None,
    *,
    axis: np.ndarray | None = None,
    max_axis_angle_deg: float | None = None,
    min_support: float = 0.0,
) -> PlaneFit | None:
    pts = as_points(points)
    cfg = cfg or RansacConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    n_pts = len(pts)
    if n_pts < 3:
        return None
    thr = float(cfg.distance_threshold_m)
    cols = np.ascontiguousarray(pts.T)
    s = min(n_pts, cfg.subsample_size)
    sub = cols.take(rng.integers(0, n_pts, size=s), axis=1) if s < n_pts else cols
    centre = sub.mean(axis=1)
    sub_c = sub - centre[:, None]
    sub_rows = sub_c.T
    sub_h = np.ones((4, s), dtype=np.float32)
    sub_h[:3] = sub_c
    thr32 = np.float32(thr)
    chunk = max(1, 262143 // (4 * s))
    cos_max = None
    if axis is not None and max_axis_angle_deg is not None:
        ax = np.asarray(axis, dtype=np.float64)
        ax = ax / np.linalg.norm(ax)
        cos_max = math.cos(math.radians(max_axis_angle_deg))
    best_count = -1
    best_n = None
    best_d = 0.0
    drawn = 0
    needed = min(float(cfg.max_iterations), needed_iterations(min_support, cfg.confidence))
    deadline = time.perf_counter() + 1e-3 * cfg.max_time_ms if cfg.max_time_ms is not None else math.inf
    timed_out = False
    while drawn < min(needed, cfg.max_iterations):
        if drawn and deadline < math.inf and time.perf_counter() > deadline:
            timed_out = True
            break
        b = min(cfg.batch_size, cfg.max_iterations - drawn)
        tri = rng.integers(0, s, size=(b, 3))
        drawn += b
        p0 = sub_rows[tri[:, 0]]
        e1 = sub_rows[tri[:, 1]] - p0
        e2 = sub_rows[tri[:, 2]] - p0
        nrm = np.cross(e1, e2)
        norms = np.sqrt(np.einsum("ij,ij->i", nrm, nrm))
        scale = np.maximum(np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e2, e2))
        ok = norms > 1e-9 * np.maximum(scale, 1e-12)
        if not np.any(ok):
            continue
        nrm = nrm[ok] / norms[ok, None]
        p0 = p0[ok]
        if cos_max is not None:
            keep = np.abs(nrm @ ax) >= cos_max
            if not np.any(keep):
                continue
            nrm, p0 = nrm[keep], p0[keep]
        d = -np.einsum("ij,ij->i", nrm, p0)
        hyp = np.empty((len(d), 4), dtype=np.float32)
        hyp[:, :3] = nrm
        hyp[:, 3] = d
        dist = np.empty((len(d), s), dtype=np.float32)
        for c0 in range(0, len(d), chunk):
            np.matmul(hyp[c0 : c0 + chunk], sub_h, out=dist[c0 : c0 + chunk])
        np.abs(dist, out=dist)
        counts = (dist < thr32).view(np.uint8).sum(axis=1, dtype=np.int32)
        k = int(np.argmax(counts))
        if counts[k] > best_count:
            best_count = int(counts[k])
            best_n = nrm[k]
            best_d = float(d[k])
            needed = needed_iterations(max(best_count / s, min_support), cfg.confidence)
    if best_n is None:
        return None
    plane_c = np.concatenate([best_n, [best_d]])
    full_rounds = cfg.refit_iterations
    if cfg.refit_first_on_subsample and full_rounds >= 1:
        full_rounds -= 1
        idx_s = select_inliers(sub_c, plane_c, thr)
        if len(idx_s) >= 3:
            plane_c = fit_plane_cols(sub_c.take(idx_s, axis=1))
    plane = np.concatenate([plane_c[:3], [plane_c[3] - plane_c[:3] @ centre]])
    idx = select_inliers(cols, plane, thr)
    x_in = None
    for r in range(full_rounds):
        if r > 0:
            idx = select_inliers(cols, plane, thr)
            x_in = None
        if len(idx) < 3:
            break
        x_in = cols.take(idx, axis=1)
        plane = fit_plane_cols(x_in)
    n_in = len(idx)
    if n_in < max(cfg.min_inliers, 3):
        return None
    plane = orient_plane_towards(plane)
    mask = np.zeros(n_pts, dtype=bool)
    mask[idx] = True
    if x_in is None:
        x_in = cols.take(idx, axis=1)
    r_in = plane[:3] @ x_in + plane[3]
    rms = float(np.sqrt(np.einsum("i,i->", r_in, r_in) / n_in))
    return PlaneFit(plane=plane, inlier_mask=mask, inlier_ratio=n_in / n_pts, rms_m=rms, iterations=drawn,
                    needed=needed, capped=timed_out or drawn < needed)


def _biweight_step(cols: np.ndarray, plane: np.ndarray, inv_scale2: float) -> tuple[np.ndarray, float]:
    r = plane[:3] @ cols + plane[3]
    w = 1.0 - r * r * inv_scale2
    np.maximum(w, 0.0, out=w)
    w *= w
    wsum = float(w.sum())
    if wsum <= 0.0:
        return plane, 0.0
    xw = cols * w
    centre = xw.sum(axis=1) / wsum
    scatter = np.einsum("ij,kj->ik", xw, cols) - wsum * np.outer(centre, centre)
    new = _plane_from_scatter(centre, scatter)
    if new[:3] @ plane[:3] < 0:
        new = -new
    return new, abs(new[3] - plane[3]) + 10.0 * float(np.linalg.norm(new[:3] - plane[:3]))


def refine_plane_biweight(points: np.ndarray, plane: np.ndarray, scale_m: float, iterations: int = 10,
                          tol_m: float = 1e-4, max_points: int = 8192) -> np.ndarray:
    cols = np.ascontiguousarray(as_points(points).T)
    plane = np.asarray(plane, dtype=np.float64).copy()
    near = cols.take(np.flatnonzero(np.abs(plane[:3] @ cols + plane[3]) < 2.0 * scale_m), axis=1)
    if near.shape[1] < 3:
        return plane
    origin = near.mean(axis=1)
    near -= origin[:, None]
    plane[3] += plane[:3] @ origin
    inv_scale2 = 1.0 / (scale_m * scale_m)
    stride = -(-near.shape[1] // max_points)
    sub = np.ascontiguousarray(near[:, ::stride]) if stride > 1 else near
    for _ in range(iterations):
        plane, moved = _biweight_step(sub, plane, inv_scale2)
        if moved < tol_m:
            break
    if sub is not near:
        plane, _ = _biweight_step(near, plane, inv_scale2)
    plane[3] -= plane[:3] @ origin
    return orient_plane_towards(plane)


def preprocess(points: np.ndarray, cfg: PreprocessConfig) -> np.ndarray:
    """The deck's preprocessing: non-finite, zero-range and out-of-range points dropped."""
    if (cfg.crop_box_min, cfg.random_fraction, cfg.voxel_size_m, cfg.outlier_nb_neighbors) != (None,) * 4:
        raise ValueError("the reference covers the range crop only (the LiDAR deck's preprocessing)")
    pts = as_points(points)
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    with np.errstate(over="ignore", invalid="ignore"):
        r2 = x * x + y * y + z * z
    keep = np.isfinite(r2) & (r2 > 0.0)
    keep &= (r2 >= cfg.min_range_m**2) & (r2 <= cfg.max_range_m**2)
    return pts.take(np.flatnonzero(keep), axis=0)


def detect_deck(
    points_sensor: np.ndarray,
    wire_dir_sensor: np.ndarray,
    p_tip_sensor: np.ndarray,
    cfg: DeckConfig | None = None,
    rng: np.random.Generator | None = None,
    times: StageTimes | None = None,
    prefix: str = "deck",
    prior_D_m: float | None = None,
    prior_tol_m: float = 0.5,
) -> DeckResult:
    points_sensor = as_points(points_sensor)
    wire_dir_sensor = np.asarray(wire_dir_sensor, dtype=np.float64)
    p_tip_sensor = np.asarray(p_tip_sensor, dtype=np.float64)
    cfg = cfg or DeckConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    times = times if times is not None else StageTimes()
    with times.stage(f"{prefix}.preprocess"):
        pts = preprocess(points_sensor, cfg.preprocess)
    if len(pts) < cfg.min_points:
        return DeckResult(float("nan"), None, None, pts, f"too few points ({len(pts)} < {cfg.min_points})")
    with times.stage(f"{prefix}.planes"):
        candidates = deck_like_planes(pts, -wire_dir_sensor, cfg, rng)
        deck = candidates[-1] if candidates else None
        if prior_D_m is not None:
            deck = _nearest_the_prior(pts, candidates, wire_dir_sensor, p_tip_sensor, prior_D_m, prior_tol_m, cfg, rng)
            if deck is None:
                return DeckResult(float("nan"), None, None, pts, f"no deck plane within {prior_tol_m:.2f} m of the "
                                  f"expected D = {prior_D_m:.2f} m")
    if deck is None:
        return DeckResult(float("nan"), None, None, pts, "no deck plane")
    if cfg.biweight_iterations:
        with times.stage(f"{prefix}.refine"):
            thr = cfg.multi_plane.ransac.distance_threshold_m
            plane = refine_plane_biweight(pts, deck.plane, cfg.biweight_scale * thr, cfg.biweight_iterations)
            mask = np.abs(pts @ plane[:3] + plane[3]) < thr
            if np.count_nonzero(mask) >= 3:
                deck = replace(deck, plane=plane, inlier_mask=mask)
    with times.stage(f"{prefix}.intersect"):
        D = heave_distance(deck.plane, wire_dir_sensor, p_tip_sensor)
        if not np.isfinite(D) or D <= 0:
            return DeckResult(float("nan"), deck.plane, deck, pts, "wire does not meet the deck plane")
        sigma = plane_sigma_at(pts[deck.inlier_mask], deck.plane, p_tip_sensor + D * wire_dir_sensor)
    status = "ok"
    if deck.capped:
        status = f"ok (RANSAC capped at {deck.iterations} of {min(deck.needed, 1e9):.0f} hypotheses)"
    return DeckResult(D, deck.plane, deck, pts, status, sigma)


def _nearest_the_prior(pts, candidates, wire, p_tip, prior_D_m, tol_m, cfg, rng) -> PlaneFit | None:
    def D(c):
        d = heave_distance(c.plane, wire, p_tip)
        return abs(d - prior_D_m) if np.isfinite(d) else np.inf

    best = min(candidates, key=D, default=None)
    if best is not None and D(best) <= tol_m:
        return best
    along = (pts - p_tip) @ wire
    band = np.flatnonzero(np.abs(along - prior_D_m) <= tol_m + cfg.prior_band_m)
    if len(band) < cfg.min_points:
        return None
    mp = cfg.multi_plane
    fit = ransac_plane(pts[band], mp.ransac, rng, axis=-wire, max_axis_angle_deg=mp.max_tilt_deg)
    if fit is None:
        return None
    mask = np.zeros(len(pts), dtype=bool)
    mask[band[fit.inlier_mask]] = True
    plane = replace(fit, inlier_mask=mask)
    return plane if D(plane) <= tol_m and deck_like(pts[mask], plane.plane, wire, cfg.min_extent_m) else None


def deck_like_planes(pts: np.ndarray, up_sensor: np.ndarray, cfg: DeckConfig, rng: np.random.Generator) -> list[PlaneFit]:
    mp = cfg.multi_plane
    wire = -up_sensor
    current = ransac_plane(pts, mp.ransac, rng, axis=up_sensor, max_axis_angle_deg=mp.max_tilt_deg)
    if current is None:
        return []
    found = [current] if deck_like(pts[current.inlier_mask], current.plane, wire, cfg.min_extent_m) else []
    need = max(mp.min_inliers, int(mp.min_area_fraction * current.n_inliers))
    for _ in range(mp.max_planes - 1):
        below = np.flatnonzero(pts @ current.plane[:3] + current.plane[3] < -cfg.below_margin_m)
        if len(below) < need:
            break
        cand = ransac_plane(pts[below], mp.ransac, rng, axis=up_sensor, max_axis_angle_deg=mp.max_tilt_deg,
                            min_support=need / len(below))
        if cand is None or cand.n_inliers < need:
            break
        mask = np.zeros(len(pts), dtype=bool)
        mask[below[cand.inlier_mask]] = True
        current = replace(cand, inlier_mask=mask)
        if deck_like(pts[mask], current.plane, wire, cfg.min_extent_m):
            found.append(current)
    return found
