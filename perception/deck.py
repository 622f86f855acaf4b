"""Deck detection (document 000, 4.1.1): the feeder deck plane in the sensor frame, then D
by intersecting the wire (straight down from the boom tip) with it (eq. 4.8)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.perception.cloud import as_points
from boomtip.perception.geometry import heave_distance, prediction_sigma
from boomtip.perception.multi_plane import MultiPlaneConfig, multi_plane_deck
from boomtip.perception.plane import PlaneFit, RansacConfig, ransac_plane_cols
from boomtip.perception.plane_moments import moments_cols, select_inliers, eigh3
from boomtip.perception.plane_refine import refine_plane_biweight_cols
from boomtip.perception.preprocess import PreprocessConfig, preprocess
from boomtip.perception.timing import StageTimes


class DeckConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    prior_band_m: float = Field(1.5, gt=0, description="with a prior and no plane near it: search the points this far "
                                "beyond the tolerance about it along the wire (a tilted deck spans more than its D)")
    preprocess: PreprocessConfig = PreprocessConfig(min_range_m=2.0)
    multi_plane: MultiPlaneConfig = MultiPlaneConfig()
    min_points: int = Field(50, ge=3, description="fewer points after preprocessing: no measurement")
    search: Literal["below", "all"] = Field(
        "below",
        description="'all': document 000's Algorithm 3 (fit max_planes planes in turn, keep the deck); "
        "'below': after each plane, search only the points below it, since under the deck metric "
        "(the lowest large horizontal plane) a plane above the current best can never win",
    )
    below_margin_m: float = Field(0.3, ge=0, description="'below' search: points this far beyond the plane")
    biweight_iterations: int = Field(10, ge=0, description="after the search, this many biweight IRLS rounds refine "
                                     "the deck plane (0: the inlier band's least squares alone)")
    biweight_scale: float = Field(2.0, gt=0, description="biweight scale, in RANSAC inlier bands")
    min_extent_m: float = Field(
        4.0, gt=0, description="a deck spans at least this much in both in-plane directions "
        "(2 sigma of its inliers): a strip of hull side or a bulwark top does not",
    )


# LiDAR: dense and precise (cm noise). No voxel grid: RANSAC scores hypotheses on a random
# subsample anyway, and the final least-squares refit is better with every deck point.
LIDAR_DECK = DeckConfig(
    preprocess=PreprocessConfig(min_range_m=2.0),
    multi_plane=MultiPlaneConfig(ransac=RansacConfig(distance_threshold_m=0.08, subsample_size=1500, refit_iterations=2)),
)
# Radar: sparse (hundreds of points) and noisy (0.1-0.2 m): a wider inlier band, no voxels.
RADAR_DECK = DeckConfig(
    preprocess=PreprocessConfig(min_range_m=2.0, max_range_m=150.0),
    multi_plane=MultiPlaneConfig(
        ransac=RansacConfig(distance_threshold_m=0.45, subsample_size=1000, min_inliers=20, refit_iterations=3),
        min_inliers=20, merge_distance_m=1.0,
    ),
    min_points=20,
    # sparse and noisy: the biweight's reweighting adds to radar D's error more than it settles it
    biweight_iterations=0,
)


def status_ok(status: str) -> bool:
    """A measurement: "ok", or "ok (...)" with a remark (a capped RANSAC)."""
    return status == "ok" or status.startswith("ok (")


@dataclass
class DeckResult:
    """Result of :func:`detect_deck` (sensor frame, metres)."""

    D_m: float  # distance from the tip down the wire to the deck, NaN without a measurement
    plane_sensor: np.ndarray | None  # [a, b, c, d], unit normal towards the sensor
    fit: PlaneFit | None  # the deck plane's fit, inlier mask over points_used
    points_used: np.ndarray  # the points after preprocessing
    status: str  # "ok" or why there is no measurement
    sigma_m: float = float("nan")  # 1-sigma of D from the fit (plane prediction error at the wire)

    @property
    def ok(self) -> bool:
        return status_ok(self.status)


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
    max_D_m: float | None = None,
) -> DeckResult:
    """The feeder deck plane in one frame and D, the distance from the tip down the wire to it.

    points_sensor: (N, 3) sensor frame, metres (or an Open3D point cloud); non-finite points are
        dropped by the preprocessing.
    wire_dir_sensor: (3,) unit direction of the wire (gravity, pointing down) in the sensor frame.
    p_tip_sensor: (3,) the boom tip (where the wire leaves it) in the sensor frame.
    cfg: default :class:`DeckConfig` (``LIDAR_DECK`` / ``RADAR_DECK`` are tuned per sensor).
    rng: drives the RANSAC (default: seeded, the same result every call).
    times: collects the stages' times under ``prefix``.
    prior_D_m: where the deck is expected (another method's D in the same frame, or the last
        deck carried forward): of the deck-like planes found, the one whose D lies nearest it,
        within prior_tol_m, is the deck; none within it is no measurement. Without a prior, the
        lowest deck-like plane. A sea that returns echoes is a large plane below the deck: the
        prior is what keeps the deck from being taken for it.
    max_D_m: no deck lies farther down the wire (the sea's calm surface below the tip): planes
        beyond it (the sea, the deck's mirror image in a radar's echoes) are never the deck.
    Returns a :class:`DeckResult`; without a measurement D_m is NaN and status says why.
    """
    points_sensor = as_points(points_sensor)
    wire_dir_sensor = np.asarray(wire_dir_sensor, dtype=np.float64)
    p_tip_sensor = np.asarray(p_tip_sensor, dtype=np.float64)
    cfg = cfg or DeckConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    times = times if times is not None else StageTimes()
    with times.stage(f"{prefix}.preprocess"):
        pts, _, _ = preprocess(points_sensor, None, cfg.preprocess, rng)
        searched, rows = pts, None  # rows: the searched points' rows of pts, when the sea's are left out
        if max_D_m is not None:  # below the sea nothing is searched (a tilted deck reaches the band's depth)
            above = pts @ wire_dir_sensor <= float(wire_dir_sensor @ p_tip_sensor) + max_D_m + cfg.prior_band_m
            if not above.all():
                rows = above.nonzero()[0]
                searched = pts[rows]
        # (3, N), one contiguous row per axis, for every pass below (no copy after a range crop)
        cols = np.ascontiguousarray(searched.T)
    if len(searched) < cfg.min_points:
        return DeckResult(float("nan"), None, None, pts, f"too few points ({len(searched)} < {cfg.min_points})")
    with times.stage(f"{prefix}.planes"):
        if cfg.search == "all":
            result = multi_plane_deck(searched, -wire_dir_sensor, cfg.multi_plane, rng)
            deck = result.deck if result is not None else None
        else:
            candidates = _deck_like_planes_cols(cols, -wire_dir_sensor, cfg, rng)
            if max_D_m is not None:  # above the sea
                candidates = [c for c in candidates if heave_distance(c.plane, wire_dir_sensor, p_tip_sensor) <= max_D_m]
            deck = candidates[-1] if candidates else None  # the lowest
            if prior_D_m is not None:
                deck = _nearest_the_prior(cols, candidates, wire_dir_sensor, p_tip_sensor, prior_D_m, prior_tol_m, cfg, rng)
                if deck is None:
                    return DeckResult(float("nan"), None, None, pts, f"no deck plane within {prior_tol_m:.2f} m of the "
                                      f"expected D = {prior_D_m:.2f} m")
    if deck is None:
        above = "" if max_D_m is None else f" above the sea (D <= {max_D_m:.2f} m, the calm waterline below the tip)"
        return DeckResult(float("nan"), None, None, pts, "no deck plane" + above)
    x_in = None  # the deck inliers' columns, once gathered
    if cfg.biweight_iterations:
        with times.stage(f"{prefix}.refine"):
            thr = cfg.multi_plane.ransac.distance_threshold_m
            plane = refine_plane_biweight_cols(cols, deck.plane, cfg.biweight_scale * thr, cfg.biweight_iterations)
            idx = select_inliers(cols, plane, thr)
            if len(idx) >= 3:
                x_in = cols.take(idx, axis=1)
                mask = np.zeros(cols.shape[1], dtype=bool)
                mask[idx] = True
                deck = replace(deck, plane=plane, inlier_mask=mask, **_inlier_moments(x_in))
    with times.stage(f"{prefix}.intersect"):
        D = heave_distance(deck.plane, wire_dir_sensor, p_tip_sensor)
        if not math.isfinite(D) or D <= 0:  # D is a Python float
            return DeckResult(float("nan"), deck.plane, _on_rows(deck, rows, len(pts)), pts, "wire does not meet the deck plane")
        if max_D_m is not None and D > max_D_m:  # the prior's band found a plane below the sea
            return DeckResult(float("nan"), deck.plane, _on_rows(deck, rows, len(pts)), pts, f"the plane found lies below "
                              f"the sea (D = {D:.2f} m beyond the calm waterline's {max_D_m:.2f} m)")
        if x_in is None:
            x_in = cols.take(deck.inlier_mask.nonzero()[0], axis=1)
        if deck.centroid is None:
            deck = replace(deck, **_inlier_moments(x_in))
        resid = deck.plane[:3] @ x_in
        resid += deck.plane[3]
        sigma = prediction_sigma(x_in.shape[1], float(resid @ resid), deck.centroid, deck.scatter_evals,
                                 deck.scatter_evecs, p_tip_sensor + D * wire_dir_sensor)
    status = "ok"
    if deck.capped:  # still a measurement, but the search did not reach its confidence
        status = f"ok (RANSAC capped at {deck.iterations} of {min(deck.needed, 1e9):.0f} hypotheses)"
    return DeckResult(D, deck.plane, _on_rows(deck, rows, len(pts)), pts, status, sigma)


def _on_rows(fit: PlaneFit, rows: np.ndarray | None, n: int) -> PlaneFit:
    """The fit with its inlier mask over all n preprocessed points, from the rows it searched."""
    if rows is None:
        return fit
    mask = np.zeros(n, dtype=bool)
    mask[rows[fit.inlier_mask]] = True
    return replace(fit, inlier_mask=mask)


def _inlier_moments(x_in: np.ndarray) -> dict:
    """A PlaneFit's moment fields for the inliers stored column-wise, (3, M)."""
    centroid, scatter = moments_cols(x_in)
    evals, evecs = eigh3(scatter)
    return {"centroid": centroid, "scatter_evals": evals, "scatter_evecs": evecs}


def _nearest_the_prior(cols, candidates, wire, p_tip, prior_D_m, tol_m, cfg, rng) -> PlaneFit | None:
    """Of the candidates, the plane whose D lies nearest the prior, within tol_m. When none does
    (a larger plane below, the sea, hid the deck from the downward search), the deck is sought
    among the points (columns, (3, N)) in a band about the prior along the wire."""
    def D(c):
        d = heave_distance(c.plane, wire, p_tip)
        return abs(d - prior_D_m) if np.isfinite(d) else np.inf

    best = min(candidates, key=D, default=None)
    if best is not None and D(best) <= tol_m:
        return best
    along = wire @ cols
    along -= wire @ p_tip + prior_D_m
    band = (np.abs(along, out=along) <= tol_m + cfg.prior_band_m).nonzero()[0]
    if len(band) < cfg.min_points:
        return None
    mp = cfg.multi_plane
    fit = ransac_plane_cols(cols.take(band, axis=1), mp.ransac, rng, axis=-wire, max_axis_angle_deg=mp.max_tilt_deg)
    if fit is None:
        return None
    mask = np.zeros(cols.shape[1], dtype=bool)
    mask[band[fit.inlier_mask]] = True
    plane = replace(fit, inlier_mask=mask)
    return plane if D(plane) <= tol_m and deck_like_fit(plane, wire, cfg.min_extent_m) else None


def deck_like(inliers: np.ndarray, plane: np.ndarray, wire_dir: np.ndarray, min_extent_m: float) -> bool:
    """A deck, not a strip: the inliers span min_extent_m in both in-plane directions, and the
    wire from the sensor meets the plane within their extent (cargo may hide the point below
    the tip, but the deck around it is seen)."""
    c = inliers.mean(axis=0)
    X = inliers - c
    evals, evecs = np.linalg.eigh(X.T @ X / len(inliers))
    return _deck_like(c, evals, evecs, plane, wire_dir, min_extent_m)


def deck_like_fit(fit: PlaneFit, wire_dir: np.ndarray, min_extent_m: float) -> bool:
    """:func:`deck_like` from a fit's inlier moments (no pass over the points)."""
    return _deck_like(fit.centroid, fit.scatter_evals / fit.n_inliers, fit.scatter_evecs, fit.plane, wire_dir, min_extent_m)


def _deck_like(c, cov_evals, evecs, plane, wire_dir, min_extent_m) -> bool:
    # the extents in Python floats (the same roundings as numpy's): four numbers, where numpy's
    # per-call overhead costs more than the arithmetic, for every candidate plane of every frame
    _, v1, v2 = cov_evals.tolist()
    e0 = 4 * math.sqrt(max(v1, 0.0))  # +-2 sigma along the two in-plane axes
    if e0 < min_extent_m:
        return False
    e1 = 4 * math.sqrt(max(v2, 0.0))
    denom = float(plane[:3] @ wire_dir)
    if abs(denom) < 1e-6:
        return False
    p_d = wire_dir * (-plane[3] / denom)
    q0, q1 = ((p_d - c) @ evecs[:, 1:]).tolist()
    return abs(q0) <= e0 and abs(q1) <= e1


def lowest_large_plane(pts: np.ndarray, up_sensor: np.ndarray, cfg: DeckConfig, rng: np.random.Generator) -> PlaneFit | None:
    """The lowest of :func:`deck_like_planes` (None when there is none)."""
    planes = deck_like_planes(pts, up_sensor, cfg, rng)
    return planes[-1] if planes else None


BELOW_SIGMAS = 3.0  # a plane below must lie beyond this many of the current plane's own noise sigmas


def below_margin(residuals_m: np.ndarray, band_m: float, floor_m: float) -> float:
    """How far below a plane the next search starts: BELOW_SIGMAS of the plane's own noise
    (1.4826 MAD of its inliers' residuals, |r| < band_m: a plane close below does not inflate
    it), never under floor_m. A sensor noisier than its data sheet otherwise leaves the lower
    tail of the deck's own returns below the margin, where it fits a plane of its own and is
    taken for the deck (a D too long by about the noise)."""
    near = residuals_m[np.abs(residuals_m) < band_m]
    if len(near) < 10:
        return floor_m
    sigma = 1.4826 * float(np.median(np.abs(near - np.median(near))))
    return max(floor_m, BELOW_SIGMAS * sigma)


def deck_like_planes(pts: np.ndarray, up_sensor: np.ndarray, cfg: DeckConfig, rng: np.random.Generator) -> list[PlaneFit]:
    """Candidates for the feeder deck, from the top down: the deck-like near-horizontal planes
    holding at least min_area_fraction of the first (largest) plane's points, each search run
    only on the points below the plane before (Algorithm 3's metric with the improved
    selection). Without a prior the deck is the lowest of them."""
    return _deck_like_planes_cols(np.ascontiguousarray(as_points(pts).T), up_sensor, cfg, rng)


def _deck_like_planes_cols(cols: np.ndarray, up_sensor: np.ndarray, cfg: DeckConfig, rng: np.random.Generator) -> list[PlaneFit]:
    """:func:`deck_like_planes` on points stored column-wise, (3, N) C-contiguous."""
    mp = cfg.multi_plane
    wire = -up_sensor
    current = ransac_plane_cols(cols, mp.ransac, rng, axis=up_sensor, max_axis_angle_deg=mp.max_tilt_deg)
    if current is None:
        return []
    # Planes that are not deck-like (a patch of the crane's own deck off to the side, a strip
    # of hull) still bound the search: only what lies below them can be the feeder deck.
    found = [current] if deck_like_fit(current, wire, cfg.min_extent_m) else []
    need = max(mp.min_inliers, int(mp.min_area_fraction * current.n_inliers))
    for _ in range(mp.max_planes - 1):
        # Normals point towards the sensor, so points below the plane have negative distance.
        r = current.plane[:3] @ cols
        r += current.plane[3]
        below = (r < -below_margin(r, mp.ransac.distance_threshold_m, cfg.below_margin_m)).nonzero()[0]
        if len(below) < need:
            break
        cand = ransac_plane_cols(cols.take(below, axis=1), mp.ransac, rng, axis=up_sensor, max_axis_angle_deg=mp.max_tilt_deg,
                                 min_support=need / len(below))  # smaller planes are refused below anyway
        if cand is None or cand.n_inliers < need:
            break
        mask = np.zeros(cols.shape[1], dtype=bool)
        mask[below[cand.inlier_mask]] = True
        current = replace(cand, inlier_mask=mask)
        if deck_like_fit(current, wire, cfg.min_extent_m):
            found.append(current)
    return found  # from the top down
