"""Hoist-rope direction from the boom-tip LiDAR: the hook's sway angles, measured where the
LiDAR sees best.

The rope hangs straight from the boom tip's sheave to the lower block (the block's weight keeps
it taut). A 200 m block gets 0-3 returns per frame from an OS1-128, but the rope's first tens
of metres below the tip, a few metres from the sensor, get hundreds. Their axis, a line
through the known suspension point, is the hook's direction u from the tip; with the hoist
length it is the hook's position across the rope, to a lateral error of l times the angular
error (centimetres per frame at 200 m with a well-levelled cloud).

Steps (all vectorised over points):

1. Gate: points between ``min_depth_m`` below the suspension point (sheave, boom) and
   ``block_clearance_m`` above the block, within a cone about the predicted direction (its
   3 sigma, at least ``gate_m`` beyond the rope's radius).
2. Hypotheses: lines through the suspension point and candidate points (deep ones: a surface
   point's radius offset matters less there); the one with the most points within
   ``ransac_tolerance_m`` of the rope's surface wins (cargo or the boom beside the rope lose).
3. Gauss-Newton on the rope's surface: residual ``|perp(p)| - radius`` per point (the LiDAR
   sees the rope's near side; its surface, not the points' centroid, is ``radius`` from the
   axis), two parameters: the direction's tilt in a tangent basis. The inlier band shrinks to
   ``inlier_m`` over the iterations.

The radius is the rope's nominal one (the scenario's ``hook.rope_radius_m``), not estimated:
with the sensor beside the rope, a radius error shifts the axis towards the sensor by the same
amount at every depth, which a free radius can only separate from a tilt through the points'
depth spread, a short lever (a free radius would cost centimetres at 200 m).

Returns the direction and its covariance (3x3, rank 2, across the rope), so the filter can
turn it into its own angles (fusion.hook_kalman.HookFilter.update_rope).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.perception.cloud import as_points
from boomtip.perception.timing import StageTimes

__all__ = ["RopeConfig", "RopeFix", "fit_rope", "tangent_basis"]


class RopeConfig(BaseModel):
    """Thresholds of :func:`fit_rope` (metres, radians unless the name says otherwise)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    enabled: bool = Field(True, description="fit the rope's direction in every frame (a second hook measurement)")
    radius_m: float = Field(0.04, gt=0, description="the rope's nominal radius (the runner takes the scenario's)")
    suspension_m: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="where the rope leaves the tip, levelled frame (the boom tip is the origin)"
    )
    min_depth_m: float = Field(2.0, ge=0, description="ignore returns closer below the suspension point (sheave, boom)")
    block_clearance_m: float = Field(1.0, ge=0, description="ignore returns closer above the block (hoist length)")
    gate_m: float = Field(0.15, gt=0, description="gate half-width beyond the radius, at least")
    gate_sigmas: float = Field(3.0, gt=0, description="the gate grows with the predicted direction's sigma x depth")
    max_gate_m: float = Field(2.0, gt=0, description="gate half-width at most")
    ransac_hypotheses: int = Field(48, ge=1, description="candidate lines through the suspension point")
    ransac_tolerance_m: float = Field(0.08, gt=0, description="a point within this of a hypothesis' surface counts")
    inlier_m: float = Field(0.03, gt=0, description="final band about the fitted surface (2x the range noise)")
    iterations: int = Field(8, ge=1)
    min_points: int = Field(30, ge=3, description="fewer inliers: no fix")
    min_span_m: float = Field(3.0, gt=0, description="inliers must span this much depth (a lever arm for the tilt)")
    angle_sigma_floor_rad: float = Field(
        1.0e-4, ge=0, description="added to the fit's statistical sigma: the rope's surface is not a perfect "
        "cylinder (strands; the simulated rope is a 24-gon), and the levelling's attitude error (0.03 mrad)"
    )


@dataclass
class RopeFix:
    """The rope's direction (unit, levelled frame: from the suspension point towards the block)
    and its covariance, or a reason in ``status`` (``direction`` NaN)."""

    direction: np.ndarray
    cov: np.ndarray  # (3, 3), rank 2 (across the rope)
    mask: np.ndarray  # (N,) the rope's points
    n_points: int
    rms_m: float
    depth_span_m: tuple[float, float]
    status: str
    radius_m: float = float("nan")  # the radius the points themselves fit best (a check of the nominal one)

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def tangent_basis(u: np.ndarray) -> np.ndarray:
    """(3, 2): two unit vectors perpendicular to the unit vector u and to each other
    (e1 = u x a / |u x a| with a = x or y, e2 = u x e1; the cross products written out on floats:
    numpy's cross on 3-vectors costs more than the arithmetic, and this runs per Gauss-Newton step)."""
    ux, uy, uz = (float(c) for c in u)
    if abs(ux) < 0.9:  # a = x: u x a = (0, uz, -uy)
        e1x, e1y, e1z = 0.0, uz, -uy
    else:  # a = y: u x a = (-uz, 0, ux)
        e1x, e1y, e1z = -uz, 0.0, ux
    nrm = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    e1x, e1y, e1z = e1x / nrm, e1y / nrm, e1z / nrm
    return np.array([[e1x, uy * e1z - uz * e1y],
                     [e1y, uz * e1x - ux * e1z],
                     [e1z, ux * e1y - uy * e1x]])


def _surface_residuals(q: np.ndarray, u: np.ndarray, radius_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depth along u, distance from the axis minus the radius, and the unit offsets from the axis."""
    d = q @ u
    off = q - d[:, None] * u
    perp = np.sqrt(np.einsum("ij,ij->i", off, off))
    return d, perp - radius_m, off / np.maximum(perp, 1e-9)[:, None]


def _tilt_jacobian(d: np.ndarray, n_off: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobian (N, 2) of the surface residuals with respect to tilting u along the tangent basis
    E (3, 2) of u, and E: d res / d(tilt along e_k) = -depth (n_off . e_k), since tilting u
    moves the axis at depth d by d e_k."""
    E = tangent_basis(u)
    return -d[:, None] * (n_off @ E), E


def _fail(n: int, status: str, n_points: int = 0) -> RopeFix:
    return RopeFix(np.full(3, np.nan), np.full((3, 3), np.nan), np.zeros(n, dtype=bool), n_points, float("nan"),
                   (float("nan"), float("nan")), status)


def fit_rope(
    points_level: np.ndarray,
    u_prior: np.ndarray,
    sigma_prior_rad: float,
    hoist_length_m: float,
    cfg: RopeConfig | None = None,
    rng: np.random.Generator | None = None,
    times: StageTimes | None = None,
) -> RopeFix:
    """Fit the rope's direction in one levelled frame.

    points_level: (N, 3) levelled frame, origin at the boom tip, z up (or an Open3D point cloud).
    u_prior: (3,) predicted direction from the suspension point to the block.
    sigma_prior_rad: its angular uncertainty (the gate's width grows with it and the depth).
    hoist_length_m: rope length (encoder): returns beyond it minus the clearance are the block's.
    rng: draws the line hypotheses (default: seeded, the same result every call).
    """
    pts = as_points(points_level)
    cfg = cfg or RopeConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    times = times if times is not None else StageTimes()
    n_all = len(pts)
    u = np.asarray(u_prior, float).reshape(3)
    norm = float(np.linalg.norm(u))
    if not (np.isfinite(norm) and norm > 0):
        return _fail(n_all, f"no predicted rope direction (got {u_prior})")
    if not (np.isfinite(sigma_prior_rad) and np.isfinite(hoist_length_m)):
        return _fail(n_all, f"prediction sigma {sigma_prior_rad} rad, hoist length {hoist_length_m} m: need finite values")
    u = u / norm
    s = np.asarray(cfg.suspension_m, float)
    r = cfg.radius_m
    d_max = hoist_length_m - cfg.block_clearance_m
    with times.stage("rope.gate"):
        q = pts - s
        # the depth of every point, then the surface residual (as _surface_residuals, without
        # the unit offsets) of those at the rope's depths only: about a quarter of a frame
        d = q @ u
        cand = np.flatnonzero((d > cfg.min_depth_m) & (d < d_max))
        dc = d[cand]
        off = q[cand] - dc[:, None] * u
        res = np.sqrt(np.einsum("ij,ij->i", off, off)) - r
        half = np.minimum(cfg.gate_m + cfg.gate_sigmas * sigma_prior_rad * np.abs(dc), cfg.max_gate_m)
        gate = cand[np.abs(res) < half]
    if len(gate) < cfg.min_points:
        return _fail(n_all, f"{len(gate)} points near the predicted rope line (need {cfg.min_points})", len(gate))
    qg = q[gate]
    with times.stage("rope.ransac"):
        # Lines through the suspension point and a deep candidate (the deepest half: a surface
        # point's radius offset tilts the line by r / depth).
        deep = np.argsort(d[gate])[len(gate) // 2:]
        pick = deep if len(deep) <= cfg.ransac_hypotheses else rng.choice(deep, cfg.ransac_hypotheses, replace=False)
        U = qg[pick] / np.linalg.norm(qg[pick], axis=1, keepdims=True)  # (H, 3)
        dh = qg @ U.T  # (M, H)
        perp2 = np.einsum("ij,ij->i", qg, qg)[:, None] - dh * dh
        votes = (np.abs(np.sqrt(np.maximum(perp2, 0.0)) - r) < cfg.ransac_tolerance_m).sum(axis=0)
        u = U[int(np.argmax(votes))]
    with times.stage("rope.fit"):
        tol = cfg.ransac_tolerance_m
        for it in range(cfg.iterations):
            d, res, n_off = _surface_residuals(qg, u, r)
            m = np.abs(res) < tol
            if np.count_nonzero(m) < cfg.min_points:
                return _fail(n_all, f"{np.count_nonzero(m)} points on the rope's surface (need {cfg.min_points})",
                             int(np.count_nonzero(m)))
            J, E = _tilt_jacobian(d[m], n_off[m], u)
            step, *_ = np.linalg.lstsq(J, -res[m], rcond=None)
            u = u + E @ step
            u /= np.linalg.norm(u)
            tol = max(cfg.inlier_m, 0.5 * tol)
        d, res, n_off = _surface_residuals(qg, u, r)
        m = np.abs(res) < cfg.inlier_m
        k = int(np.count_nonzero(m))
        if k < cfg.min_points:
            return _fail(n_all, f"{k} points on the rope's surface (need {cfg.min_points})", k)
        span = (float(d[m].min()), float(d[m].max()))
        if span[1] - span[0] < cfg.min_span_m:
            return _fail(n_all, f"rope points span only {span[1] - span[0]:.1f} m of depth", k)
        J, E = _tilt_jacobian(d[m], n_off[m], u)
        JtJ = J.T @ J
        if np.linalg.cond(JtJ) > 1e12:  # every point on one side line: the tilt along it is unknown
            return _fail(n_all, "the rope's points do not fix its tilt (degenerate geometry)", k)
        rms = float(np.sqrt(np.mean(res[m] ** 2)))
        C = rms**2 * k / max(k - 2, 1) * np.linalg.inv(JtJ) + cfg.angle_sigma_floor_rad**2 * np.eye(2)
        radius = _free_radius(qg[m], u, r)
    mask = np.zeros(n_all, dtype=bool)
    mask[gate[m]] = True
    return RopeFix(u, E @ C @ E.T, mask, k, rms, span, "ok", radius)


def _free_radius(q: np.ndarray, u: np.ndarray, radius_m: float, iterations: int = 4) -> float:
    """The radius the rope's points fit best with the tilt free as well (3 unknowns). Not used for
    the direction (a radius error and a tilt are told apart only by the points' depth spread),
    but a check of the configured radius: its scatter per frame is a fraction of a millimetre,
    and 1 mm of radius error is ~4 cm at a 200 m hook."""
    for _ in range(iterations):
        d, res, n_off = _surface_residuals(q, u, radius_m)
        J_tilt, E = _tilt_jacobian(d, n_off, u)
        J = np.column_stack([J_tilt, -np.ones(len(q))])
        step, *_ = np.linalg.lstsq(J, -res, rcond=None)
        u = u + E @ step[:2]
        u /= np.linalg.norm(u)
        radius_m += float(step[2])
    return radius_m
