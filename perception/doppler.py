"""Radar Doppler velocity and relative heave rate (document 000 section 4.1.3, REFERENCE.md).

Inputs are radar detections in the SENSOR frame: unit beam directions ``b_i`` (N, 3) and range
rates ``r_dot_i`` in m/s, POSITIVE WHEN THE RANGE GROWS (target receding).

Velocity convention
-------------------
``u`` is the velocity of the observed rigid body (the feeder) RELATIVE TO THE SENSOR, evaluated at
the sensor origin (the body's velocity field extended to the origin), in sensor axes, m/s:
``u = v_body(p_sensor) - p_sensor_dot``. The relative velocity of a body point x is
``v(x) = u + w x x`` and its range rate is ``r_dot = b . v(x)`` with ``b = x/|x|``. Because
``b . (w x |x| b) = 0`` the rotation drops out and ``r_dot_i = b_i . u`` EXACTLY: one scan
observes u (3 unknowns, the rank-3 result of doc. 000 eq. 4.23) and nothing of w.
Range rate is a scalar (d|x|/dt), so the same holds if the sensor axes rotate; u is then the
apparent velocity of the body point momentarily at the origin, expressed in the sensor axes.

Heave-rate convention
---------------------
``wire_dir`` is the unit direction of the crane wire / gravity, pointing DOWN from the tip.
D is the distance from the tip down along ``wire_dir`` to the deck plane; D decreases when the
deck comes up towards the tip.
  * :func:`d_dot_document`: document 000 eq. 4.29 (rotation and deck tilt ignored):
    ``D_dot = u . wire_dir``.
  * :func:`d_dot_rotation_aware`: exact, ``D_dot = (n . u + D n . (w x wire_dir)) / (n . wire_dir)``
    (REFERENCE.md: ``-[n.u - D n.(w x e_z)] / (n.e_z)`` with e_z = -wire_dir), valid in a frame that
    TRANSLATES with the tip but does NOT rotate (gravity-levelled), where wire_dir is constant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from boomtip.perception.cloud import as_points

__all__ = [
    "DopplerConfig",
    "DopplerFit",
    "doppler_velocity",
    "d_dot_document",
    "d_dot_rotation_aware",
    "deck_angular_velocity",
]


class DopplerConfig(BaseModel):
    """Robust least-squares ego/target velocity from range rates (m/s)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    inlier_threshold_mps: float = Field(0.3, gt=0, description="|r_dot - b.u| below this is an inlier, m/s")
    confidence: float = Field(0.999, gt=0, lt=1, description="RANSAC confidence of one all-inlier triplet")
    max_iterations: int = Field(500, ge=1, description="cap on RANSAC hypotheses")
    batch_size: int = Field(128, ge=1, description="hypotheses solved and scored at once")
    min_inliers: int = Field(3, ge=3, description="fewer inliers -> None")
    refit_iterations: int = Field(2, ge=1, description="least-squares refit / inlier re-selection rounds")
    huber_delta_mps: float | None = Field(
        None, gt=0, description="if set, final Huber IRLS on the inliers with this delta, m/s"
    )
    huber_iterations: int = Field(5, ge=1)
    max_condition: float = Field(1e3, gt=1, description="cond(B_inliers) above this -> degenerate, None")
    start: Literal["ransac", "trimmed"] = Field(
        "ransac",
        description="'trimmed': least squares on all detections, then re-fit on those within the band "
        "until stable (radar false alarms are rare, gross outliers: 3-4 passes of 3x3 normal equations); "
        "falls back to RANSAC when fewer than trimmed_min_fraction stay in the band",
    )
    trimmed_min_fraction: float = Field(0.7, gt=0, le=1)
    min_triplet_det: float = Field(1e-6, gt=0, description="|det| of a minimal 3x3 beam set below this is skipped")


@dataclass
class DopplerFit:
    """Velocity fit.

    velocity_sensor: u (3,), m/s, relative velocity of the observed body at the sensor origin,
        sensor axes (see module docstring for the sign).
    inlier_mask: bool (N,).
    residual_rms_mps: RMS of r_dot - b.u over the inliers, m/s.
    covariance: 3x3, (m/s)^2, sigma^2 (B^T W B)^-1 over the inliers with sigma^2 the residual variance
        (dof N_in - 3).
    condition_number: cond of the inlier beam matrix B (geometry quality; large = poorly observed axis).
    iterations: RANSAC hypotheses drawn.
    """

    velocity_sensor: np.ndarray
    inlier_mask: np.ndarray
    residual_rms_mps: float
    covariance: np.ndarray
    condition_number: float
    iterations: int


def _lsq(b: np.ndarray, r: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """Weighted least squares u = argmin sum w (b.u - r)^2 via the 3x3 normal equations."""
    if w is None:
        a = b.T @ b
        y = b.T @ r
    else:
        bw = b * w[:, None]
        a = bw.T @ b
        y = bw.T @ r
    return np.linalg.solve(a, y)


def _cond(b: np.ndarray) -> float:
    """cond(B) from the 3x3 B^T B (sqrt of its eigenvalue ratio): no SVD of the N x 3 matrix."""
    ev = np.linalg.eigvalsh(b.T @ b)
    return float(np.sqrt(ev[-1] / ev[0])) if ev[0] > 0 else math.inf


def _trimmed_fit(bT: np.ndarray, r: np.ndarray, cfg: DopplerConfig, valid: np.ndarray | None, n_all: int,
                 u_prior: np.ndarray | None = None) -> "DopplerFit | None":
    """Least squares on everything, then on what lies within the band, until the set is stable.

    Radar false alarms are rare, gross outliers, so this settles in 2-4 passes of 3x3 normal
    equations, and the final system gives the covariance and condition directly. None (use
    RANSAC) when too few detections stay in the band or the geometry is degenerate.
    ``bT`` is the (3, N) unit beams, one contiguous row per axis: ``u @ bT`` then runs ~3x
    faster than ``b @ u`` on (N, 3) rows. Each pass needs the normal equations of a different
    subset; one product ``Z @ w`` with the 11 x N table of the per-detection terms (b b^T, b r,
    r^2, 1) gives them all at once, the subset's size included, instead of gathering the subset
    and multiplying it out.
    """
    n = len(r)
    bx, by, bz = bT
    Z = np.empty((11, n))
    np.multiply(bx, bT, out=Z[0:3])  # xx xy xz
    np.multiply(by, bT[1:], out=Z[3:5])  # yy yz
    np.multiply(bz, bz, out=Z[5])  # zz
    np.multiply(bT, r, out=Z[6:9])  # x r, y r, z r
    np.multiply(r, r, out=Z[9])
    Z[10] = 1.0  # the count: a 0/1 weight's sum is exact

    def solve(w: np.ndarray) -> tuple[np.ndarray, tuple, float, float, int] | None:
        # The symmetric 3x3 solve in Python floats: numpy's per-call overhead on a 3x3 is
        # several times the arithmetic, and this runs up to six times per radar frame. The
        # inverse stays six Python floats (its upper triangle) until the last pass needs it.
        xx, xy, xz, yy, yz, zz, yx_, yy_, yz_, rr, count = (Z @ w).tolist()
        c00, c01, c02 = yy * zz - yz * yz, xz * yz - xy * zz, xy * yz - xz * yy
        det = xx * c00 + xy * c01 + xz * c02
        if abs(det) < 1e-300:
            return None
        c11, c12, c22 = xx * zz - xz * xz, xy * xz - xx * yz, xx * yy - xy * xy
        i00, i01, i02, i11, i12, i22 = c00 / det, c01 / det, c02 / det, c11 / det, c12 / det, c22 / det
        u0 = i00 * yx_ + i01 * yy_ + i02 * yz_
        u1 = i01 * yx_ + i11 * yy_ + i12 * yz_
        u2 = i02 * yx_ + i12 * yy_ + i22 * yz_
        # Sum of squared residuals over the subset from the same sums: r.r - u.(B^T r).
        sse = max(rr - (u0 * yx_ + u1 * yy_ + u2 * yz_), 0.0)
        frob_a2 = xx * xx + yy * yy + zz * zz + 2.0 * (xy * xy + xz * xz + yz * yz)
        return np.array([u0, u1, u2]), (i00, i01, i02, i11, i12, i22), sse, frob_a2, int(count)

    if u_prior is not None:
        # Tracking: last frame's velocity is within the band of this one's (the deck's
        # acceleration times one radar period is a few cm/s), so the wide first pass is skipped.
        u = np.asarray(u_prior, dtype=float)
    else:
        sol = solve(np.ones(n))
        if sol is None:
            return None
        u = sol[0]
    mask, sol, n_in = None, None, 0
    for it in range(6):
        res = u @ bT
        res -= r
        np.abs(res, out=res)
        if it == 0 and u_prior is None:
            # A wide first band (3 robust sigmas from the median, at least the configured one) so a
            # start biased by the outliers cannot throw good detections away; then the configured band.
            k = n // 2
            band = max(cfg.inlier_threshold_mps, 4.45 * float(np.partition(res, k)[k]))
        else:
            band = cfg.inlier_threshold_mps
        new = res < band
        # the same set as the last pass: its bytes compared (np.array_equal's checks, or an xor and
        # any(), cost several times more, most of all in a cold cache)
        if mask is not None and new.tobytes() == mask.tobytes():
            break
        mask = new
        # the set's size comes with its sums (no count_nonzero pass); too small a set is refused
        # whether or not its system could be solved
        sol = solve(mask.astype(np.float64))
        if sol is None or sol[4] < max(3, cfg.trimmed_min_fraction * n):
            return None
        u, n_in = sol[0], sol[4]
    if sol is None or n_in < max(3, cfg.min_inliers):
        return None
    u, (i00, i01, i02, i11, i12, i22), sse, frob_a2, _ = sol
    # cond(B) = sqrt(cond(B^T B)); the Frobenius-norm bound ||A|| ||A^-1|| is enough to refuse
    # degenerate beam geometry without an eigendecomposition.
    frob_inv2 = i00 * i00 + i11 * i11 + i22 * i22 + 2.0 * (i01 * i01 + i02 * i02 + i12 * i12)
    cond = math.sqrt(math.sqrt(frob_a2) * math.sqrt(frob_inv2))
    if cond > cfg.max_condition:
        return None
    sigma2 = sse / max(n_in - 3, 1)
    inv = np.array([[i00, i01, i02], [i01, i11, i12], [i02, i12, i22]])
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
    """Fit u with ``range_rate_i = b_i . u`` (sensor frame, m/s), robust to outliers.

    ``beam_dirs`` (N, 3) are normalised here, so the detections' points will do (also as an Open3D
    point cloud); ``range_rate_mps`` (N,) positive when receding.
    ``u_prior`` (e.g. the previous scan's velocity) lets the trimmed start skip its first pass.
    ``rng`` draws the RANSAC triplets (default: seeded, the same result every call).
    Steps: vectorised RANSAC over minimal 3-detection sets (batched 3x3 solves, one (N x batch)
    residual matrix per batch, adaptive stop from the best inlier ratio), least-squares refits on the
    inliers with re-selection, optional Huber IRLS, covariance ``sigma^2 (B^T B)^-1``.
    Returns None with fewer than 3 (finite) detections, fewer than ``cfg.min_inliers`` inliers, or a
    degenerate geometry (cond(B) > ``cfg.max_condition``, e.g. all beams nearly parallel).
    """
    b_all = as_points(beam_dirs)
    cfg = cfg or DopplerConfig()
    r_all = range_rate_mps
    if not (type(r_all) is np.ndarray and r_all.dtype == np.float64 and r_all.ndim == 1):  # the usual input: no call
        r_all = np.asarray(range_rate_mps, dtype=np.float64).reshape(-1)
    if len(b_all) != len(r_all):
        raise ValueError("beam_dirs and range_rate_mps must have the same length")
    n_all = len(r_all)
    # Squared norms also catch NaN/inf beams (their square is not finite) in one pass.
    n2 = np.einsum("ij,ij->i", b_all, b_all)
    # Every detection valid (the usual case) iff the sums are finite and no beam is zero: three
    # reductions instead of five full-length masks
    all_valid = math.isfinite(float(r_all.sum()) + float(n2.sum())) and float(n2.min(initial=math.inf)) > 0
    if all_valid:  # the mask is only built when RANSAC needs it (below)
        valid, valid_sel, b_sel, r, n2_sel = None, None, b_all, r_all, n2
    else:
        valid = np.isfinite(r_all) & np.isfinite(n2) & (n2 > 0)
        valid_sel, b_sel, r, n2_sel = valid, b_all[valid], r_all[valid], n2[valid]
    n = len(r)
    if n < 3:
        return None
    bT = np.divide(b_sel.T, np.sqrt(n2_sel), out=np.empty((3, n)))  # unit beams, one row per axis
    thr = cfg.inlier_threshold_mps

    if cfg.start == "trimmed" and cfg.huber_delta_mps is None:
        fit = _trimmed_fit(bT, r, cfg, valid_sel, n_all, u_prior) if u_prior is not None else None
        if fit is None:  # no prior, or the prior did not hold: the full trimmed fit
            fit = _trimmed_fit(bT, r, cfg, valid_sel, n_all)
        if fit is not None:
            return fit
    rng = rng if rng is not None else np.random.default_rng(0)  # only RANSAC draws: built here, not per call
    b = np.ascontiguousarray(bT.T)
    vidx = np.arange(n_all) if valid is None else np.flatnonzero(valid)
    best_count, best_u, drawn = -1, None, 0
    needed = float(cfg.max_iterations)
    while drawn < min(needed, cfg.max_iterations):
        k = min(cfg.batch_size, cfg.max_iterations - drawn)
        tri = rng.integers(0, n, size=(k, 3))
        drawn += k
        a = b[tri]  # (k, 3, 3): rows are the beams of one triplet
        y = r[tri]  # (k, 3)
        ok = np.abs(np.linalg.det(a)) > cfg.min_triplet_det
        if not np.any(ok):
            continue
        u = np.linalg.solve(a[ok], y[ok][..., None])[..., 0]  # (k', 3)
        # (n, k') residuals; GEMMs in column chunks small enough for OpenBLAS to stay
        # single-threaded (m*n*k < 65536*4): on a busy machine a threaded GEMM can wait tens of
        # ms for its helper thread (perception.plane)
        res = np.empty((n, len(u)))
        chunk = max(1, 262143 // (3 * n))
        for c0 in range(0, len(u), chunk):
            np.matmul(b, u[c0 : c0 + chunk].T, out=res[:, c0 : c0 + chunk])
        res -= r[:, None]
        np.abs(res, out=res)
        counts = np.count_nonzero(res < thr, axis=0)
        j = int(np.argmax(counts))
        if counts[j] > best_count:
            best_count, best_u = int(counts[j]), u[j]
            w_in = best_count / n
            needed = math.inf if w_in <= 0 else (
                1.0 if w_in >= 1 else math.log(1 - cfg.confidence) / math.log1p(-(w_in**3))
            )
    if best_u is None:
        return None

    u = best_u
    mask = np.abs(b @ u - r) < thr
    for _ in range(cfg.refit_iterations):
        if np.count_nonzero(mask) < 3:
            return None
        bi = b[mask]
        if _cond(bi) > cfg.max_condition:
            return None
        u = _lsq(bi, r[mask])
        mask = np.abs(b @ u - r) < thr
    n_in = int(np.count_nonzero(mask))
    if n_in < max(cfg.min_inliers, 3):
        return None
    bi, ri = b[mask], r[mask]
    cond = _cond(bi)
    if cond > cfg.max_condition:
        return None
    weights = None
    if cfg.huber_delta_mps is not None:
        for _ in range(cfg.huber_iterations):
            e = np.abs(bi @ u - ri)
            weights = np.where(e <= cfg.huber_delta_mps, 1.0, cfg.huber_delta_mps / np.maximum(e, 1e-12))
            u = _lsq(bi, ri, weights)
    res = bi @ u - ri
    rms = float(np.sqrt(np.mean(res * res)))
    dof = max(n_in - 3, 1)
    if weights is None:
        sigma2 = float(res @ res) / dof
        cov = sigma2 * np.linalg.inv(bi.T @ bi)
    else:
        sigma2 = float((weights * res) @ res) / dof
        cov = sigma2 * np.linalg.inv((bi * weights[:, None]).T @ bi)
    full_mask = np.zeros(n_all, dtype=bool)
    full_mask[vidx[mask]] = True
    return DopplerFit(
        velocity_sensor=u,
        inlier_mask=full_mask,
        residual_rms_mps=rms,
        covariance=cov,
        condition_number=cond,
        iterations=drawn,
    )


def d_dot_document(u_sensor: np.ndarray, wire_dir_sensor: np.ndarray) -> float:
    """Relative heave rate as in document 000 eq. 4.29 (deck rotation and tilt ignored), m/s.

    ``D_dot = u . wire_dir`` with u the deck's velocity relative to the sensor (module docstring) and
    wire_dir the unit DOWN direction. Derivation for a horizontal deck translating with u: the deck
    plane ``n.x + d = 0`` (n = -wire_dir) moves with ``d_dot = -n.u``, and ``D = -d/(n.wire_dir) = d``,
    so ``D_dot = -n.u = u.wire_dir``: a deck rising towards the tip (u.wire_dir < 0) makes D shrink.
    """
    w = np.asarray(wire_dir_sensor, dtype=np.float64)
    w = w / np.linalg.norm(w)
    return float(np.asarray(u_sensor, dtype=np.float64) @ w)


def d_dot_rotation_aware(
    u_sensor: np.ndarray,
    deck_plane_sensor: np.ndarray,
    wire_dir_sensor: np.ndarray,
    omega_sensor: np.ndarray,
    D_m: float | None = None,
) -> float:
    """Exact relative heave rate for a tilted, rotating deck, m/s.

    Frame: origin at the tip/sensor, TRANSLATING with it but NOT ROTATING (gravity-levelled), so
    ``wire_dir`` (unit, pointing down) is constant. The caller converts from the rotating sensor
    frame (MRU attitude + mount rotation) and removes the crane's own angular rate from omega.

    With the deck plane ``n.x + d = 0`` (unit n; either sign), the deck's relative velocity field
    ``v(x) = u + w x x`` (u = field at the origin, as returned by :func:`doppler_velocity`;
    w = ``omega_sensor``, the deck's angular velocity relative to this frame) and
    ``D = -d/(n.wire_dir)``:
      * a point x fixed on the deck keeps ``n.x + d = 0`` and ``n_dot = w x n``, so
        ``(w x n).x + n.(u + w x x) + d_dot = 0``; the two w terms cancel, giving ``d_dot = -n.u``;
      * ``D_dot = -d_dot/(n.w_d) + d (n_dot.w_d)/(n.w_d)^2`` with ``w_d`` = wire_dir, and
        ``n_dot.w_d = (w x n).w_d = -n.(w x w_d)``, d = -D (n.w_d), hence

        ``D_dot = (n.u + D n.(w x wire_dir)) / (n.wire_dir)``.

    Equivalently (REFERENCE.md, e_z = -wire_dir): ``D_dot = -[n.u - D n.(w x e_z)]/(n.e_z)``, i.e. the
    relative velocity of the deck point below the tip, ``v(p_d) = u + D w x wire_dir``, projected on
    the deck normal and divided by ``n.wire_dir``. Only the part of w perpendicular to n matters
    (w = lambda n gives n.(n x wire_dir) = 0). Invariant to the sign of the plane.
    ``D_m``: distance along the wire; computed from the plane when None. NaN if n.wire_dir == 0.
    """
    plane = np.asarray(deck_plane_sensor, dtype=np.float64)
    nn = np.linalg.norm(plane[:3])
    n, d = plane[:3] / nn, plane[3] / nn
    w = np.asarray(wire_dir_sensor, dtype=np.float64)
    w = w / np.linalg.norm(w)
    den = float(n @ w)
    if abs(den) < 1e-12:
        return float("nan")
    D = -d / den if D_m is None else float(D_m)
    u = np.asarray(u_sensor, dtype=np.float64)
    om = np.asarray(omega_sensor, dtype=np.float64)
    return float((n @ u + D * (n @ np.cross(om, w))) / den)


def deck_angular_velocity(normal_prev: np.ndarray, normal_curr: np.ndarray, dt_s: float) -> np.ndarray:
    """Observable part of the deck's angular velocity from two deck normals, rad/s (3,).

    For a unit normal ``n_dot = w x n``, so ``n x n_dot = w - n (n.w) = w_perp``: only the component
    of w perpendicular to n is observable from the normal; the component along n (yaw about the deck
    normal) is not, and it does not change D_dot (see :func:`d_dot_rotation_aware`).
    Discretely, the minimal rotation taking ``normal_prev`` to ``normal_curr`` is used:
    ``w_perp = angle / dt * unit(n_prev x n_curr)`` (exact for a constant w_perp). The normals are
    normalised and ``normal_curr`` is flipped if needed to match the orientation of ``normal_prev``.
    Both normals must be expressed in the same NON-ROTATING (levelled) frame, otherwise the frame's own
    rotation is included. The result is perpendicular to both normals (to the mid-normal).
    """
    a = np.asarray(normal_prev, dtype=np.float64)
    b = np.asarray(normal_curr, dtype=np.float64)
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    if a @ b < 0:
        b = -b
    axis = np.cross(a, b)
    s = float(np.linalg.norm(axis))
    if s < 1e-15:
        return np.zeros(3)
    angle = math.atan2(s, float(a @ b))
    return axis / s * (angle / float(dt_s))
