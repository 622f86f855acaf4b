"""Several planes in one cloud, and which of them is the feeder deck (document 000, Appendix F,
Algorithm 3, with an improved selection metric).

Sensor frame, metres; planes ``[a, b, c, d]`` oriented towards the sensor as in
perception.plane, whose RANSAC (:func:`~boomtip.perception.plane.ransac_plane`) finds each one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.perception.cloud import as_points
from boomtip.perception.plane import PlaneFit, RansacConfig, ransac_plane, wire_plane_distance

__all__ = ["MultiPlaneConfig", "MultiPlaneResult", "multi_plane_deck", "select_deck_plane"]


class MultiPlaneConfig(BaseModel):
    """Sequential multi-plane search that picks the feeder deck (improved Algorithm 3 of document 000)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    ransac: RansacConfig = Field(default_factory=RansacConfig)
    max_planes: int = Field(6, ge=1, description="planes extracted at most (N of Algorithm 3)")
    max_tilt_deg: float = Field(15.0, ge=0, le=90, description="deck normal within this angle of 'up'")
    min_inliers: int = Field(30, ge=3, description="candidate needs this many inliers; stop when fewer points remain")
    min_area_fraction: float = Field(
        0.15, ge=0, le=1, description="candidate needs this fraction of the largest horizontal candidate's inliers"
    )
    horizontal_only: bool = Field(
        True,
        description="discard RANSAC hypotheses tilted more than max_tilt_deg before scoring, so walls and "
        "cargo sides never consume a plane slot",
    )
    removal_factor: float = Field(
        2.0, ge=1.0, description="points within removal_factor * distance_threshold of a found plane are removed "
        "before the next search (removes the noise tails of a plane so they do not form a parallel 'shadow' plane)",
    )
    merge_distance_m: float = Field(
        0.25, ge=0, description="a later, smaller candidate that is parallel (merge_angle_deg) and within this "
        "offset of an earlier, larger one is a fragment of it and cannot be chosen as the deck",
    )
    merge_angle_deg: float = Field(2.0, ge=0, description="parallelism tolerance for fragments")


@dataclass
class MultiPlaneResult:
    """Result of :func:`multi_plane_deck`.

    deck: the chosen feeder-deck plane (a member of ``candidates``), sensor frame.
    deck_index: its index in ``candidates``.
    candidates: every plane extracted, in extraction order (inlier masks over the original cloud).
    distances_m: distance along the wire from the sensor origin to each candidate (NaN if parallel).
    tilts_deg: angle between each candidate's normal and up_sensor, degrees.
    eligible: bool per candidate, True if it passed every test (tilt, size, area fraction, not a
        fragment, below the sensor, inside the optional distance window).
    fragment_of: per candidate, index of the larger parallel plane it is a fragment of, or -1.
    """

    deck: PlaneFit
    deck_index: int
    candidates: list[PlaneFit]
    distances_m: np.ndarray
    tilts_deg: np.ndarray
    eligible: np.ndarray
    fragment_of: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))


def multi_plane_deck(
    points: np.ndarray,
    up_sensor: np.ndarray,
    cfg: MultiPlaneConfig | None = None,
    rng: np.random.Generator | None = None,
    *,
    d_window_m: tuple[float, float] | None = None,
) -> MultiPlaneResult | None:
    """Find the FEEDER DECK plane among several planes in a boom-tip point cloud (sensor frame, m).

    ``up_sensor`` is the unit "up" direction (opposite to gravity, i.e. minus the wire direction)
    expressed in the sensor frame, e.g. from the MRU attitude and the mount rotation (doc. 000 eq. 4.3).

    Extraction (Algorithm 3 of document 000): up to ``cfg.max_planes`` RANSAC planes are fitted
    sequentially, removing each plane's points (within ``removal_factor * distance_threshold``) before
    the next search; stop early when fewer than ``cfg.min_inliers`` points remain or no plane is found.
    With ``cfg.horizontal_only`` the RANSAC only considers hypotheses within ``max_tilt_deg`` of up.

    Selection metric (document 000 uses "highest D" alone, which a handful of sea or clutter points
    below the deck can win). A candidate is ELIGIBLE when
      * its normal (oriented towards the sensor) is within ``max_tilt_deg`` of ``up_sensor``,
      * it has at least ``min_inliers`` inliers,
      * it has at least ``min_area_fraction`` of the inliers of the LARGEST near-horizontal candidate,
      * it is not a fragment of an earlier, larger, parallel plane (offset < ``merge_distance_m``),
      * it lies below the sensor (D > 0) and, if given, inside ``d_window_m`` = (D_min, D_max)
        (e.g. a gate around the Kalman filter's predicted D).
    Among eligible candidates the one with the LARGEST distance D along the wire wins: the feeder deck
    is the lowest large horizontal surface below the tip; cargo tops are above it (smaller D). The
    crane vessel's own deck is normally higher (larger freeboard) and is also rejected by this rule;
    its side walls and cargo sides fail the tilt test.

    ``rng`` drives the RANSAC (default: seeded, the same result every call).
    Returns None when no candidate is eligible.
    """
    pts = as_points(points)
    cfg = cfg or MultiPlaneConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    up = np.asarray(up_sensor, dtype=np.float64)
    up = up / np.linalg.norm(up)
    n_all = len(pts)

    remaining = np.arange(n_all)
    candidates: list[PlaneFit] = []
    removal_thr = cfg.removal_factor * cfg.ransac.distance_threshold_m
    axis = up if cfg.horizontal_only else None
    for _ in range(cfg.max_planes):
        if len(remaining) < cfg.min_inliers or len(remaining) < 3:
            break
        sub_pts = pts[remaining]
        fit = ransac_plane(
            sub_pts, cfg.ransac, rng, axis=axis, max_axis_angle_deg=cfg.max_tilt_deg if axis is not None else None
        )
        if fit is None:
            break
        full_mask = np.zeros(n_all, dtype=bool)
        full_mask[remaining[fit.inlier_mask]] = True
        candidates.append(
            replace(fit, inlier_mask=full_mask)
        )
        near = np.abs(sub_pts @ fit.plane[:3] + fit.plane[3]) < removal_thr
        near |= fit.inlier_mask
        remaining = remaining[~near]

    return select_deck_plane(pts, candidates, up, cfg, d_window_m=d_window_m)


def select_deck_plane(
    points: np.ndarray,
    candidates: list[PlaneFit],
    up_sensor: np.ndarray,
    cfg: MultiPlaneConfig | None = None,
    *,
    d_window_m: tuple[float, float] | None = None,
) -> MultiPlaneResult | None:
    """Apply the deck selection metric of :func:`multi_plane_deck` to already extracted planes.

    ``candidates`` are in extraction order (larger first, as sequential RANSAC produces them), with
    inlier masks over ``points`` (sensor frame, m) and planes oriented with d >= 0. Also used by the
    Open3D ``segment_plane`` baseline so both apply the same metric. Returns None if none is eligible.
    """
    cfg = cfg or MultiPlaneConfig()
    if not candidates:
        return None
    pts = as_points(points)
    up = np.asarray(up_sensor, dtype=np.float64)
    up = up / np.linalg.norm(up)
    wire = -up
    k = len(candidates)
    planes = np.array([c.plane for c in candidates])
    counts = np.array([c.n_inliers for c in candidates])
    cos_tilt = np.clip(planes[:, :3] @ up, -1.0, 1.0)
    tilts = np.degrees(np.arccos(cos_tilt))
    dists = np.array([wire_plane_distance(p, wire) for p in planes])

    # fragments: a later, smaller plane parallel to and within merge_distance of an earlier larger one
    # (a loop over a handful of planes, not over points)
    fragment_of = np.full(k, -1, dtype=int)
    cos_merge = math.cos(math.radians(cfg.merge_angle_deg))
    for j in range(1, k):
        cj = pts[candidates[j].inlier_mask].mean(axis=0)
        for i in range(j):
            if counts[i] < counts[j] or fragment_of[i] >= 0:
                continue
            parallel = abs(planes[i, :3] @ planes[j, :3]) >= cos_merge
            if parallel and abs(planes[i, :3] @ cj + planes[i, 3]) < cfg.merge_distance_m:
                fragment_of[j] = i
                break

    horizontal = tilts <= cfg.max_tilt_deg
    big_enough = counts >= cfg.min_inliers
    base = horizontal & big_enough & (fragment_of < 0)
    if not np.any(base):
        return None
    largest = counts[base].max()
    eligible = base & (counts >= cfg.min_area_fraction * largest) & np.isfinite(dists) & (dists > 0)
    if d_window_m is not None:
        eligible &= (dists >= d_window_m[0]) & (dists <= d_window_m[1])
    if not np.any(eligible):
        return None
    best = int(np.argmax(np.where(eligible, dists, -np.inf)))
    return MultiPlaneResult(
        deck=candidates[best],
        deck_index=best,
        candidates=candidates,
        distances_m=dists,
        tilts_deg=tilts,
        eligible=eligible,
        fragment_of=fragment_of,
    )
