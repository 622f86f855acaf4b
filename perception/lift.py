"""The load under the hook and the deck below it, in one levelled LiDAR frame (the hook
pipeline's: z up, origin at the boom tip, metres): the clearance C from the load's lowest point
down to the deck, and where that point would touch the deck.

    points below the block, about the rope's line continued   -> the load (within its radius,
                                                                  connected to the rope's line)
                                                                  and the deck (a ring beyond it)
    deck ring -> its dominant height (or about the last deck) -> a plane fitted, outliers out
    load      -> with its model: the top face's plane, its rectangle and the underside's lowest
                 corner; without: its lowest points seen
    C = the corners' heights above the deck plane straight below each, each weighted by its
        chance to be the lowest (the least of noisy heights would read low)

C is a difference of two heights measured in the same frame a few metres apart, so the levelling's
error (a tilt of the whole frame) moves both alike and cancels but for the slope it puts on that
offset. Built from the installation (the load's model, the block's height) and the settings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.special import ndtr

from boomtip.perception.geometry import plane_sigma_at
from boomtip.perception.residual_spread import ResidualSpread

__all__ = ["LiftConfig", "LoadClearance", "measure_clearance", "height_plane", "rope_line_xy", "footprint_radius_m", "plane_height_at", "index_mask",
           "chance_lowest", "chance_weighted"]

STATUS_OK = "ok"
MAX_REFITS = 5  # a plane refitted without its outliers at most this often
PLANE_PARAMETERS = 3  # z = a + b x + c y: a plane fit's residuals have this many degrees of freedom fewer than points
MAD_FLOOR_M = 1e-4  # a plane's robust sigma never below this (points exactly on it would reject all else)
LOWEST_SEEN_POINTS = 5  # without a model: the load's bottom is the mean of its few lowest points
MIN_CHANCE = 1e-3  # a corner less likely than this to be the lowest adds nothing to C or its rate
SEARCH_DEPTH_M = 40.0  # the load and its deck are looked for this far below the hook at most


class LiftConfig(BaseModel):
    """Where the load and the deck are searched, and how much of each a fix needs."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    load_margin_m: float = Field(0.8, gt=0, description="the load's footprint radius plus this: its points")
    unknown_load_radius_m: float = Field(8.0, gt=0, description="the footprint radius searched without a load model")
    deck_ring_m: float = Field(6.0, gt=0, description="the deck: a ring this wide beyond the load's footprint")
    below_block_m: float = Field(0.5, ge=0, description="the load's points start this far below the block's bottom")
    above_deck_m: float = Field(0.15, ge=0, description="the load's points lie at least this far above the deck")
    deck_gate_m: float = Field(0.6, gt=0, description="the deck's points lie this close to the last deck height")
    height_bin_m: float = Field(0.1, gt=0, description="bins of the deck's height histogram")
    min_deck_points: int = Field(30, ge=4)
    min_top_points: int = Field(8, ge=4)
    top_fraction: float = Field(0.5, gt=0, le=1, description="the top face holds at least this share of the load's points")
    outlier_sigmas: float = Field(3.0, gt=0, description="plane residuals beyond this many robust sigmas are left out")
    cluster_beams: float = Field(3.0, gt=0, description="the load is what connects to the rope's line with gaps of at "
                                 "most this many beam spacings (at the hook's range)")
    min_cluster_gap_m: float = Field(0.5, gt=0, description="and never less than this")
    core_radius_m: float = Field(1.0, gt=0, description="of the connected groups, the load has the most points this close "
                                 "to the rope's line")
    top_spread_memory_s: float = Field(1.0, ge=0, description="the load top's residual spread (its height's sigma) pooled "
                                       "over the frames of about this long (perception.residual_spread; 0: each frame's own)")


@dataclass
class LoadClearance:
    """One frame's clearance: C (m) and its 1-sigma, the load's likeliest lowest point and its
    underside's centre (levelled frame), the deck's height under each; status says why not when
    C is NaN. C is the candidates' heights weighted by their chance to be the lowest, so it equals
    lowest_point_m's height above deck_z_m only where that corner is surely the lowest."""

    status: str
    clearance_m: float = math.nan
    sigma_m: float = math.nan
    lowest_point_m: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    underside_centre_m: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    centre_sigma_m: float = math.nan  # the underside centre's 1-sigma per horizontal axis
    deck_z_m: float = math.nan  # under the likeliest lowest point
    landing_z_m: float = math.nan  # the deck under the underside's centre
    centre_height_sigma_m: float = math.nan  # the centre's height above the deck: its 1-sigma
    n_load: int = 0
    n_deck: int = 0
    deck_plane: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))  # z = a + b x + c y about the load
    candidates_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # the underside's corners (or lowest seen)
    candidate_sigmas_m: np.ndarray = field(default_factory=lambda: np.zeros(0))  # their heights' 1-sigma from the face's fit
    load_mask: np.ndarray | None = None
    deck_mask: np.ndarray | None = None
    top_spread: ResidualSpread | None = None  # the load top's residual spread, pooled up to this frame
    deck_sigma_m: float = math.nan  # the deck plane's height under the underside's centre: its 1-sigma
    deck_hidden: str | None = None  # why the deck came from the feeder's predicted pose, not this frame's returns

    @property
    def ok(self) -> bool:
        return self.status == STATUS_OK

    @property
    def centre_clearance_m(self) -> float:
        """The underside centre's height above the deck below it: it moves with the relative
        vertical motion alone, not with the load's tilting as the lowest corner does."""
        return float(self.underside_centre_m[2] - self.landing_z_m)

    @property
    def landing_m(self) -> np.ndarray:
        """The landing point: the underside's centre dropped onto the deck (levelled frame)."""
        return np.array([self.underside_centre_m[0], self.underside_centre_m[1], self.landing_z_m])


def height_plane(points: np.ndarray, outlier_sigmas: float) -> tuple[np.ndarray, np.ndarray] | None:
    """z = a + b x + c y by least squares, refitted without the points beyond `outlier_sigmas`
    robust (MAD) sigmas until the inliers settle (a few rounds): ((a, b, c), the inliers' mask);
    None with < 4 points."""
    keep = np.ones(len(points), bool)
    for k in range(MAX_REFITS):
        if np.count_nonzero(keep) < 4:
            return None
        p = points[keep]
        coef, *_ = np.linalg.lstsq(np.column_stack([np.ones(len(p)), p[:, 0], p[:, 1]]), p[:, 2], rcond=None)
        resid = points[:, 2] - plane_height_at(coef, points[:, :2])
        mad = float(np.median(np.abs(resid[keep] - np.median(resid[keep]))))
        inliers = np.abs(resid) <= outlier_sigmas * max(1.4826 * mad, MAD_FLOOR_M)
        if np.array_equal(inliers, keep) or k == MAX_REFITS - 1:
            break
        keep = inliers
    return coef, keep


def _as_plane(coef: np.ndarray) -> np.ndarray:
    """z = a + b x + c y as [n, d] with a unit normal."""
    n = np.array([-coef[1], -coef[2], 1.0])
    s = np.linalg.norm(n)
    return np.append(n / s, -coef[0] / s)


def plane_height_at(coef: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The height z = a + b x + c y of the plane coef = (a, b, c) at xy (2,) or (N,2)."""
    return coef[0] + xy @ coef[1:]


def rope_line_xy(hook_m: np.ndarray, z_m: np.ndarray | float) -> np.ndarray:
    """Where the rope's line from the tip (the levelled frame's origin) through the hook's
    reference point lies at the height(s) z: (2,) or (N,2). The load hangs on it."""
    z = np.asarray(z_m, float)
    return hook_m[:2] + (z[..., None] - hook_m[2]) * (hook_m[:2] / hook_m[2])


def footprint_radius_m(load_size_m: tuple[float, float, float] | None, cfg: LiftConfig) -> float:
    """How far from the rope's line the load reaches: half its diagonal, or the search's radius
    without a model."""
    return 0.5 * math.hypot(*load_size_m[:2]) if load_size_m else cfg.unknown_load_radius_m


def _dominant(z: np.ndarray, bin_m: float) -> float:
    """The centre of the most populated height bin."""
    lo = math.floor(z.min() / bin_m)
    counts = np.bincount(np.floor(z / bin_m).astype(int) - lo)
    return (lo + int(np.argmax(counts)) + 0.5) * bin_m


def measure_clearance(points_level: np.ndarray, hook_m: np.ndarray, block_height_m: float,
                      load_size_m: tuple[float, float, float] | None, cfg: LiftConfig,
                      deck_prior_z_m: float | None = None, range_noise_m: float = 0.0,
                      angular_step_rad: float = 0.0, t_s: float = math.nan,
                      top_spread: ResidualSpread = ResidualSpread(),
                      deck_fallback: tuple[np.ndarray, float] | None = None) -> LoadClearance:
    """The clearance in one levelled frame (at t_s), about the hook's reference point `hook_m`
    (the hook filter's estimate, levelled frame); `deck_prior_z_m` the deck's last height there,
    if any; `top_spread` the load top's residual spread pooled over the frames before (without
    a finite t_s, the frame's own spread alone). The LiDAR's range noise and angular step size
    the sigmas. `deck_fallback`: the deck plane (z = a + b x + c y) and its height's 1-sigma
    from the feeder's predicted pose, taken when the frame shows too little of the deck about
    the load (the load hides it)."""
    if len(points_level) == 0 or not np.all(np.isfinite(hook_m)) or hook_m[2] >= 0:
        return LoadClearance("no points or no hook")
    radius = footprint_radius_m(load_size_m, cfg)
    # Only the points in a box about the rope's line reach the load or its deck ring: a few
    # comparisons cull most of the cloud (and its NaNs, which compare false) before any distance.
    reach = radius + cfg.load_margin_m + cfg.deck_ring_m + float(np.hypot(*hook_m[:2])) / -hook_m[2] * SEARCH_DEPTH_M
    x, y = points_level[:, 0], points_level[:, 1]
    finite = np.flatnonzero((np.abs(x - hook_m[0]) < reach) & (np.abs(y - hook_m[1]) < reach) & np.isfinite(points_level[:, 2]))
    pts = points_level[finite]
    if len(pts) == 0:
        return LoadClearance("no points about the hook")
    # The load hangs on the rope's line continued below the hook: its axis at each point's height.
    d = np.linalg.norm(pts[:, :2] - rope_line_xy(hook_m, pts[:, 2]), axis=1)
    below = pts[:, 2] < hook_m[2] - block_height_m - cfg.below_block_m
    inner = radius + cfg.load_margin_m
    ring = below & (d > inner) & (d < inner + cfg.deck_ring_m)
    deck_fit, hidden = _deck_about_load(pts[ring, :], deck_prior_z_m, cfg)
    if deck_fit is None and deck_fallback is None:
        return LoadClearance(hidden)
    if deck_fit is None:  # the feeder's predicted deck: no returns of it in this frame
        deck_coef, ring_idx, deck_pts = np.asarray(deck_fallback[0], float), np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    else:
        deck_coef, deck_rows = deck_fit
        ring_idx, deck_pts, hidden = np.flatnonzero(ring)[deck_rows], pts[ring][deck_rows], None
    # The load: inside its footprint, below the block, clear of the deck under it.
    deck_under = plane_height_at(deck_coef, pts[:, :2])
    load = below & (d <= inner) & (pts[:, 2] > deck_under + cfg.above_deck_m)
    if np.count_nonzero(load) >= cfg.min_top_points:  # what hangs from the hook, not the cargo beside it
        load = _hanging(pts, load, d, max(cfg.cluster_beams * float(np.linalg.norm(hook_m)) * angular_step_rad,
                                          cfg.min_cluster_gap_m), cfg.core_radius_m)
    n_load = int(np.count_nonzero(load))
    load_idx = np.flatnonzero(load)
    masks = dict(load_mask=index_mask(len(points_level), finite[load_idx]), deck_mask=index_mask(len(points_level), finite[ring_idx]))
    if n_load < cfg.min_top_points:
        return LoadClearance("too few load points", n_load=n_load, n_deck=len(deck_pts), **masks)
    under = (_underside_with_model(pts[load], load_size_m, cfg, range_noise_m, top_spread, t_s) if load_size_m
             else _lowest_seen(pts[load], range_noise_m))
    if under is None:
        return LoadClearance("no top face on the load", n_load=n_load, n_deck=len(deck_pts), **masks)
    # the lowest point is the one nearest the deck below it (a rolling deck is not level); which
    # one that is, is uncertain when others lie within their sigmas: C is each corner's height
    # weighted by its chance to be the lowest (the least of noisy heights would read low)
    cand = under.candidates
    heights = cand[:, 2] - plane_height_at(deck_coef, cand[:, :2])
    if not np.all(np.isfinite(heights)):
        return LoadClearance("the load's corners not finite", n_load=n_load, n_deck=len(deck_pts), **masks,
                             top_spread=under.spread)
    chance = chance_lowest(heights, under.sigma_candidates_m)
    k_low = int(np.argmax(chance))
    lowest = cand[k_low]
    deck_z, centre = float(plane_height_at(deck_coef, lowest[:2])), under.centre
    plane = _as_plane(deck_coef)

    def deck_sigma(xy: np.ndarray) -> float:
        if hidden is not None:
            return float(deck_fallback[1])
        s_d = plane_sigma_at(deck_pts, plane, np.array([xy[0], xy[1], float(plane_height_at(deck_coef, xy))]))
        return s_d if math.isfinite(s_d) else range_noise_m

    # the centre: midway between two edges, each known to a beam spacing s (uniform): s / sqrt(24);
    # a corner's place as uncertain, and its height over the deck changes with it as the two
    # faces' slopes differ
    sigma_centre = max(float(np.linalg.norm(centre)) * angular_step_rad / math.sqrt(24.0), range_noise_m)
    sigma_place = sigma_centre * float(np.linalg.norm(under.gradient - deck_coef[1:]))
    var_each = np.array([s**2 + deck_sigma(xy) ** 2 + sigma_place**2 for s, xy in zip(under.sigma_candidates_m, cand[:, :2])])
    clearance, sigma = chance_weighted(chance, heights, var_each)
    sigma_centre_height = math.sqrt(under.sigma_centre_m**2 + deck_sigma(centre[:2]) ** 2 + sigma_place**2)
    return LoadClearance(STATUS_OK, clearance, sigma, lowest, centre, sigma_centre, deck_z,
                         float(plane_height_at(deck_coef, centre[:2])), sigma_centre_height, n_load, len(deck_pts), deck_coef, cand,
                         under.sigma_candidates_m, **masks, top_spread=under.spread, deck_sigma_m=deck_sigma(centre[:2]),
                         deck_hidden=hidden)


def _deck_about_load(ring_pts: np.ndarray, deck_prior_z_m: float | None, cfg: LiftConfig) -> tuple[tuple | None, str | None]:
    """The deck plane in the ring about the load: ((coef, rows of ring_pts on it), None), or
    (None, why not). Its height: the last deck's, else the ring's dominant one."""
    if len(ring_pts) < cfg.min_deck_points:
        return None, "too few deck points about the load"
    zr = ring_pts[:, 2]
    centre = deck_prior_z_m if deck_prior_z_m is not None and math.isfinite(deck_prior_z_m) else _dominant(zr, cfg.height_bin_m)
    near = np.abs(zr - centre) <= cfg.deck_gate_m
    if np.count_nonzero(near) < cfg.min_deck_points and deck_prior_z_m is not None:  # lost it: search afresh
        near = np.abs(zr - _dominant(zr, cfg.height_bin_m)) <= cfg.deck_gate_m
    fit = height_plane(ring_pts[near], cfg.outlier_sigmas) if np.count_nonzero(near) >= cfg.min_deck_points else None
    if fit is None:
        return None, "no deck plane about the load"
    return (fit[0], np.flatnonzero(near)[fit[1]]), None


def _hanging(pts: np.ndarray, candidates: np.ndarray, d: np.ndarray, gap_m: float, core_m: float) -> np.ndarray:
    """Of the candidate points, the connected group (no gap wider than gap_m) with the most
    points within core_m of the rope's line: the load that hangs there, not the cargo or
    bulwark within its radius, nor a sling's few points."""
    idx = np.flatnonzero(candidates)
    pairs = cKDTree(pts[idx]).query_pairs(gap_m, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(idx), len(idx)))
    n, label = connected_components(graph, directed=False)
    core = np.bincount(label[d[idx] <= core_m], minlength=n)
    best = int(np.argmax(core)) if core.any() else int(label[np.argmin(d[idx])])
    out = np.zeros(len(pts), bool)
    out[idx[label == best]] = True
    return out


def index_mask(n: int, idx: np.ndarray) -> np.ndarray:
    """A mask over a frame's n points, true at idx."""
    m = np.zeros(n, bool)
    m[idx] = True
    return m


def chance_lowest(heights_m: np.ndarray, sigmas_m: np.ndarray) -> np.ndarray:
    """Each candidate's chance to be the lowest, their heights Gaussian and independent with
    these 1-sigma: the product of its chances to lie below each other one, normalised (exact for
    two candidates, close for a box's four corners)."""
    below = ndtr((heights_m[None, :] - heights_m[:, None]) / np.maximum(np.hypot(sigmas_m[:, None], sigmas_m[None, :]), 1e-12))
    np.fill_diagonal(below, 1.0)
    chance = below.prod(axis=1)
    return chance / chance.sum()


def chance_weighted(chance: np.ndarray, values: np.ndarray, variances: np.ndarray) -> tuple[float, float]:
    """The candidates' values (each with its variance) mixed by their chance to be the lowest,
    those below MIN_CHANCE left out: the mixture's mean and 1-sigma (their spread included)."""
    likely = chance >= MIN_CHANCE
    w = chance[likely] / chance[likely].sum()
    mean = float(w @ values[likely])
    return mean, math.sqrt(float(w @ (variances[likely] + (values[likely] - mean) ** 2)))


@dataclass
class _Underside:
    """The load's underside as one frame sees it (levelled frame): the candidates for its lowest
    point, its centre, their heights' 1-sigma and the face's height gradient (dz/dx, dz/dy)."""

    candidates: np.ndarray
    centre: np.ndarray
    sigma_candidates_m: np.ndarray  # each candidate's height's
    sigma_centre_m: float
    gradient: np.ndarray
    spread: ResidualSpread | None = None  # the top face's residual spread, pooled with this frame's


def _underside_with_model(load: np.ndarray, size_m: tuple[float, float, float], cfg: LiftConfig,
                          range_noise_m: float, spread: ResidualSpread = ResidualSpread(),
                          t_s: float = math.nan) -> _Underside | None:
    """The underside's corners and centre from the top face (a plane through the load's points,
    the slings above it and any side seen below it left out as outliers) and the model: the top's
    rectangle about its points along their principal axis, carried down the face's normal by the
    height."""
    fit = height_plane(load, cfg.outlier_sigmas)  # the slings above it and any side below: outliers
    if fit is None or np.count_nonzero(fit[1]) < max(cfg.min_top_points, cfg.top_fraction * len(load)):
        return None
    coef, keep = fit
    top = load[keep]
    mean = top[:, :2].mean(axis=0)
    evals, evecs = np.linalg.eigh(np.cov((top[:, :2] - mean).T))
    e1, e2 = evecs[:, 1], evecs[:, 0]
    # the face's centre midway between its outermost points along each axis: the block and
    # slings' shadow on the face moves the points' centroid, not the face's edges
    a1, a2 = (top[:, :2] - mean) @ e1, (top[:, :2] - mean) @ e2
    c = mean + 0.5 * (a1.max() + a1.min()) * e1 + 0.5 * (a2.max() + a2.min()) * e2
    length, width, height = size_m
    corners_xy = np.array([c + sx * length / 2 * e1 + sy * width / 2 * e2 for sx in (-1, 1) for sy in (-1, 1)])
    n = _as_plane(coef)[:3]
    corners = np.column_stack([corners_xy, plane_height_at(coef, corners_xy)]) - height * n
    resid = top[:, 2] - plane_height_at(coef, top[:, :2])
    spread = spread.pooled(t_s, float(resid @ resid), len(top) - PLANE_PARAMETERS, cfg.top_spread_memory_s)
    s_fit = max(spread.sigma_m, range_noise_m)

    def sigma_at(xy: np.ndarray) -> float:  # the face's fit's height there: its offset and its slopes
        q = (xy - mean) @ evecs
        return s_fit * math.sqrt(1.0 / len(top) + float(np.sum(q**2 / np.maximum(evals * (len(top) - 1), 1e-9))))

    return _Underside(corners, np.append(c, plane_height_at(coef, c)) - height * n,
                      np.array([sigma_at(xy) for xy in corners_xy]), sigma_at(c), coef[1:], spread)


def _lowest_seen(load: np.ndarray, range_noise_m: float) -> _Underside:
    """Without a model: the load's lowest points seen (their few lowest, averaged: one point's
    noise is not the load's bottom), and its points' centroid for the underside's centre."""
    k = min(LOWEST_SEEN_POINTS, len(load))
    low = load[np.argsort(load[:, 2])[:k]]
    sigma = max(float(np.std(low[:, 2])), range_noise_m) / math.sqrt(k)
    return _Underside(low.mean(axis=0)[None, :], np.append(load[:, :2].mean(axis=0), low[:, 2].mean()), np.array([sigma]),
                      sigma, np.zeros(2))
