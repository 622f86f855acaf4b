"""Tests for perception.doppler: Doppler least squares and the relative heave rate (signs!)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from boomtip.perception.doppler import (
    DopplerConfig,
    d_dot_document,
    d_dot_rotation_aware,
    deck_angular_velocity,
    doppler_velocity,
)
from boomtip.perception.plane import fit_plane_lsq, wire_plane_distance

DOWN = np.array([0.0, 0.0, -1.0])  # wire direction in a levelled frame
E_Z = -DOWN


def skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])


def deck_points(rng, n=400, tilt_deg=3.0, depth=40.0, half=(60.0, 40.0)):
    """Points of a tilted deck below the sensor (levelled frame, sensor at the origin)."""
    axis = np.array([0.6, 0.8, 0.0])
    nrm = Rotation.from_rotvec(axis * math.radians(tilt_deg)).apply(E_Z)
    e1 = np.cross(nrm, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(nrm, e1)
    st = np.column_stack([rng.uniform(-half[0], half[0], n), rng.uniform(-half[1], half[1], n)])
    c = np.array([0.0, 0.0, -depth])
    return c + st[:, :1] * e1 + st[:, 1:] * e2, nrm


def rigid_motion(x0: np.ndarray, u: np.ndarray, w: np.ndarray, t: float) -> np.ndarray:
    """Rigid motion whose velocity field at t = 0 is v(x) = u + w x x."""
    return x0 @ expm(t * skew(w)).T + t * u


def plane_D(points: np.ndarray) -> float:
    return wire_plane_distance(fit_plane_lsq(points), DOWN)


# --------------------------------------------------------------------------------------
# Doppler least squares
# --------------------------------------------------------------------------------------
def test_range_rate_sign_and_exact_recovery_with_rotation():
    rng = np.random.default_rng(10)
    x, _ = deck_points(rng)
    u = np.array([0.4, -0.3, 1.2])
    w = rng.normal(size=3)
    w *= 0.05 / np.linalg.norm(w)
    v = u + np.cross(w, x)
    b = x / np.linalg.norm(x, axis=1, keepdims=True)
    r_dot = np.einsum("ij,ij->i", b, v)
    # sign: positive when the range grows (finite difference of |x|)
    h = 1e-5
    fd = (np.linalg.norm(rigid_motion(x, u, w, h), axis=1) - np.linalg.norm(rigid_motion(x, u, w, -h), axis=1)) / (2 * h)
    assert np.allclose(r_dot, fd, atol=1e-7)
    # rotation drops out: r_dot = b . u exactly
    assert np.allclose(r_dot, b @ u, atol=1e-12)
    fit = doppler_velocity(b, r_dot, DopplerConfig(), rng)
    assert fit is not None
    assert np.allclose(fit.velocity_sensor, u, atol=1e-9)
    assert fit.inlier_mask.all()
    assert fit.residual_rms_mps < 1e-9
    assert fit.covariance.shape == (3, 3)
    # unnormalised beams are accepted (normalised internally)
    fit2 = doppler_velocity(b * 7.0, r_dot, DopplerConfig(), rng)
    assert np.allclose(fit2.velocity_sensor, u, atol=1e-9)


def test_outlier_rejection_400_detections():
    rng = np.random.default_rng(11)
    x, _ = deck_points(rng, n=400)
    b = x / np.linalg.norm(x, axis=1, keepdims=True)
    u = np.array([-0.8, 0.5, 1.5])
    r_dot = b @ u + rng.normal(0, 0.05, 400)
    bad = rng.random(400) < 0.10
    r_dot[bad] = rng.uniform(-5, 5, bad.sum())
    fit = doppler_velocity(b, r_dot, DopplerConfig(), rng)
    assert fit is not None
    err = fit.velocity_sensor - u
    # the heave-relevant (along-wire) component within 1 cm/s
    assert abs(err @ DOWN) < 0.01, err
    # horizontal components are less well observed from above (beams close to vertical): their
    # standard error is 5-7 mm/s here, so the whole vector is checked against the covariance
    assert np.all(np.abs(err) < 4 * np.sqrt(np.diag(fit.covariance))), (err, fit.covariance)
    assert err @ np.linalg.solve(fit.covariance, err) < 16.0
    assert np.all(np.sqrt(np.diag(fit.covariance)) < 0.01)
    assert 0.04 < fit.residual_rms_mps < 0.06
    # the outliers are (almost all) rejected: the robust fit equals least squares on the true inliers
    assert np.count_nonzero(fit.inlier_mask & bad) <= 3
    oracle = np.linalg.lstsq(b[~bad], r_dot[~bad], rcond=None)[0]
    assert np.all(np.abs(fit.velocity_sensor - oracle) < 0.002)
    # plain least squares on everything is far off
    plain = np.linalg.lstsq(b, r_dot, rcond=None)[0]
    assert np.max(np.abs(plain - u)) > 0.05
    # without measurement noise, outliers (beyond the threshold) cost nothing
    r_clean = b @ u
    r_clean[bad] += rng.choice([-1.0, 1.0], bad.sum()) * rng.uniform(0.5, 5.0, bad.sum())
    fit_c = doppler_velocity(b, r_clean, DopplerConfig(), rng)
    assert np.allclose(fit_c.velocity_sensor, u, atol=1e-9)
    # Huber IRLS on the inliers gives the same answer within noise
    fit_h = doppler_velocity(b, r_dot, DopplerConfig(huber_delta_mps=0.1), np.random.default_rng(1))
    assert np.all(np.abs(fit_h.velocity_sensor - u) < 0.015)


TRIMMED = DopplerConfig(inlier_threshold_mps=0.25, start="trimmed")  # the pipeline's radar setting


def _outlier_scan(seed: int, n: int = 500, p_bad: float = 0.05):
    rng = np.random.default_rng(seed)
    x, _ = deck_points(rng, n=n)
    b = x / np.linalg.norm(x, axis=1, keepdims=True)
    u = np.array([-0.8, 0.5, 1.5])
    r_dot = b @ u + rng.normal(0, 0.05, n)
    bad = rng.random(n) < p_bad
    r_dot[bad] += rng.choice([-1.0, 1.0], bad.sum()) * rng.uniform(1.0, 5.0, bad.sum())
    return x, b, u, r_dot, bad


@pytest.mark.parametrize("prior", [None, "true", "wrong"])
def test_trimmed_fit_equals_least_squares_on_its_inliers(prior):
    """The trimmed start (normal equations from one table of per-detection sums) must give the
    same u, residual RMS and covariance as plain least squares on the detections it keeps,
    with no prior, a good prior (last scan's u) or a wrong one (it must fall back, not follow it)."""
    x, b, u, r_dot, bad = _outlier_scan(21)
    u_prior = {None: None, "true": u + 0.02, "wrong": u + np.array([3.0, -2.0, 4.0])}[prior]
    fit = doppler_velocity(x * 3.0, r_dot, TRIMMED, np.random.default_rng(0), u_prior)  # unnormalised beams
    assert fit is not None
    assert fit.iterations == 0  # settled by trimming, no RANSAC hypotheses drawn
    m = fit.inlier_mask
    assert not (m & bad).any() and m[~bad].mean() > 0.99
    bi, ri = b[m], r_dot[m]
    u_ls = np.linalg.lstsq(bi, ri, rcond=None)[0]
    np.testing.assert_allclose(fit.velocity_sensor, u_ls, atol=1e-10)
    e = bi @ u_ls - ri
    assert fit.residual_rms_mps == pytest.approx(math.sqrt(e @ e / len(e)), rel=1e-6)
    np.testing.assert_allclose(fit.covariance, (e @ e) / (len(e) - 3) * np.linalg.inv(bi.T @ bi), rtol=1e-6)
    assert fit.condition_number == pytest.approx(np.linalg.cond(bi), rel=2.0)  # a cheap bound, same scale


def test_trimmed_fit_maps_its_mask_past_invalid_detections():
    x, b, u, r_dot, bad = _outlier_scan(22, n=300)
    r_dot[:7] = np.nan
    x[7:10] = np.inf
    fit = doppler_velocity(x, r_dot, TRIMMED, np.random.default_rng(0))
    assert fit is not None and len(fit.inlier_mask) == 300
    assert not fit.inlier_mask[:10].any()
    assert not (fit.inlier_mask & bad).any() and fit.inlier_mask[10:][~bad[10:]].all()
    assert np.all(np.abs(fit.velocity_sensor - u) < 0.03)


def test_trimmed_start_hands_over_to_ransac_when_too_much_is_outlying():
    """40 % gross outliers: fewer than trimmed_min_fraction stay in the band, so RANSAC decides."""
    x, b, u, r_dot, bad = _outlier_scan(23, p_bad=0.4)
    fit = doppler_velocity(b, r_dot, TRIMMED, np.random.default_rng(0))
    assert fit is not None and fit.iterations > 0
    assert abs((fit.velocity_sensor - u) @ DOWN) < 0.01


def test_two_bodies_majority_wins():
    """35 % of the detections come from a second rigid body (e.g. the crane vessel's own deck):
    the fit locks onto the majority body (the feeder). NOTE: with a majority of detections on another
    body the fit would follow that body; the caller should keep detections of the feeder region."""
    rng = np.random.default_rng(14)
    x, _ = deck_points(rng, n=400)
    b = x / np.linalg.norm(x, axis=1, keepdims=True)
    u_feeder = np.array([0.3, -0.2, 1.1])
    u_crane = np.array([-0.5, 0.9, -0.6])
    other = rng.random(400) < 0.35
    r_dot = np.where(other, b @ u_crane, b @ u_feeder) + rng.normal(0, 0.02, 400)
    fit = doppler_velocity(b, r_dot, DopplerConfig(), rng)
    assert fit is not None
    assert np.all(np.abs(fit.velocity_sensor - u_feeder) < 0.02)
    assert np.all(fit.inlier_mask[~other])  # every feeder detection is kept ...
    # ... plus the few crane detections whose range rate happens to fit the feeder within 0.3 m/s
    assert np.mean(fit.inlier_mask[other]) < 0.15


def test_doppler_none_cases():
    rng = np.random.default_rng(12)
    b = np.array([[0.0, 0.0, -1.0], [0.1, 0.0, -1.0]])
    assert doppler_velocity(b, np.array([1.0, 1.0]), DopplerConfig(), rng) is None
    # degenerate: all beams (nearly) parallel
    bb = np.tile([0.0, 0.0, -1.0], (50, 1)) + rng.normal(0, 1e-6, (50, 3))
    assert doppler_velocity(bb, bb @ np.array([0.1, 0.2, 0.3]), DopplerConfig(), rng) is None
    # non-finite rates are ignored
    x, _ = deck_points(rng, n=50)
    bd = x / np.linalg.norm(x, axis=1, keepdims=True)
    r = bd @ np.array([0.1, 0.2, 0.3])
    r[:5] = np.nan
    fit = doppler_velocity(bd, r, DopplerConfig(), rng)
    assert fit is not None and not fit.inlier_mask[:5].any()
    assert np.allclose(fit.velocity_sensor, [0.1, 0.2, 0.3], atol=1e-9)


# --------------------------------------------------------------------------------------
# Heave rate: signs and the exact relation
# --------------------------------------------------------------------------------------
def test_d_dot_document_sign_horizontal_translating_deck():
    rng = np.random.default_rng(13)
    x, _ = deck_points(rng, tilt_deg=0.0)
    u = np.array([0.7, -0.2, 0.9])  # deck rising towards the tip at 0.9 m/s
    h = 1e-4
    fd = (plane_D(rigid_motion(x, u, np.zeros(3), h)) - plane_D(rigid_motion(x, u, np.zeros(3), -h))) / (2 * h)
    assert fd == pytest.approx(-0.9, abs=1e-7)  # D shrinks
    assert d_dot_document(u, DOWN) == pytest.approx(fd, abs=1e-7)
    # exact relation agrees when the deck is level and not rotating
    plane = fit_plane_lsq(x)
    assert d_dot_rotation_aware(u, plane, DOWN, np.zeros(3), 40.0) == pytest.approx(fd, abs=1e-7)


@pytest.mark.parametrize("seed", [20, 21, 22])
def test_d_dot_rotation_aware_matches_finite_difference(seed):
    rng = np.random.default_rng(seed)
    x, _ = deck_points(rng, n=300, tilt_deg=3.0)
    u = rng.normal(size=3)
    w = rng.normal(size=3)
    w *= 0.05 / np.linalg.norm(w)
    h = 1e-4
    fd = (plane_D(rigid_motion(x, u, w, h)) - plane_D(rigid_motion(x, u, w, -h))) / (2 * h)
    plane = fit_plane_lsq(x)
    D = wire_plane_distance(plane, DOWN)
    exact = d_dot_rotation_aware(u, plane, DOWN, w, D)
    assert exact == pytest.approx(fd, abs=1e-6)
    assert d_dot_rotation_aware(u, -plane, DOWN, w) == pytest.approx(exact, abs=1e-12)  # sign-invariant, D from plane
    # u as recovered from the radar (noise-free) gives the same
    b = x / np.linalg.norm(x, axis=1, keepdims=True)
    r_dot = np.einsum("ij,ij->i", b, u + np.cross(w, x))
    u_hat = doppler_velocity(b, r_dot, DopplerConfig(), rng).velocity_sensor
    assert d_dot_rotation_aware(u_hat, plane, DOWN, w, D) == pytest.approx(fd, abs=1e-6)
    # the document's formula misses by centimetres per second
    assert abs(d_dot_document(u_hat, DOWN) - fd) > 0.01


def test_document_error_is_periodic_and_rotation_aware_is_exact():
    """Feeder pitching 2.5 deg, rolling 1 deg, heaving 2 m, surging 0.5 m and swaying 1 m with a 10 s
    period, with a static trim/heel, seen from a fixed tip about 43 m above (levelled frame)."""
    T, A_p, A_r, A_h = 10.0, math.radians(2.5), math.radians(1.0), 2.0
    om = 2 * math.pi / T
    tilt0 = Rotation.from_rotvec([math.radians(1.5), math.radians(2.0), 0.0]).as_matrix()  # static trim/heel
    p_cog = np.array([4.0, -6.0, -43.0])  # deck reference point (body origin) below and off the tip

    def pose(t):
        th, ph = A_p * math.sin(om * t), A_r * math.sin(om * t + 0.7)
        R = Rotation.from_euler("YX", [th, ph]).as_matrix() @ tilt0
        p = p_cog + np.array([0.5 * math.sin(om * t + 1.0), 1.0 * math.sin(om * t + 2.0), A_h * math.sin(om * t + 0.3)])
        return R, p

    def velocity(t):
        th = A_p * math.sin(om * t)  # the roll angle does not enter the rate below
        th_d, ph_d = A_p * om * math.cos(om * t), A_r * om * math.cos(om * t + 0.7)
        w = th_d * np.array([0.0, 1.0, 0.0]) + ph_d * Rotation.from_euler("Y", th).apply([1.0, 0.0, 0.0])
        _, p = pose(t)
        p_d = om * np.array([0.5 * math.cos(om * t + 1.0), 1.0 * math.cos(om * t + 2.0), A_h * math.cos(om * t + 0.3)])
        u = p_d - np.cross(w, p)  # body velocity field at the tip (origin)
        return u, w

    def deck_plane(t):
        R, p = pose(t)
        n = R @ E_Z
        return np.concatenate([n, [-n @ p]])

    def D(t):
        return wire_plane_distance(deck_plane(t), DOWN)

    ts = np.linspace(0.0, 20.0, 81)
    h = 1e-4
    err_doc, err_exact = [], []
    for t in ts:  # 81 time samples, not points
        fd = (D(t + h) - D(t - h)) / (2 * h)
        u, w = velocity(t)
        err_doc.append(d_dot_document(u, DOWN) - fd)
        err_exact.append(d_dot_rotation_aware(u, deck_plane(t), DOWN, w, D(t)) - fd)
    err_doc, err_exact = np.array(err_doc), np.array(err_exact)
    assert np.max(np.abs(err_exact)) < 1e-6
    assert np.max(np.abs(err_doc)) > 0.01  # visible: centimetres per second
    assert err_doc.max() > 0.005 and err_doc.min() < -0.005  # changes sign: periodic, not a bias
    # periodic with the wave period
    assert np.allclose(err_doc[:41], err_doc[40:], atol=1e-9)


def test_omega_along_normal_is_unobservable_and_irrelevant():
    rng = np.random.default_rng(30)
    x, n = deck_points(rng, n=300, tilt_deg=4.0)
    plane = fit_plane_lsq(x)
    n = plane[:3]
    u = np.array([0.2, -0.4, 0.8])
    w_perp = np.cross(n, rng.normal(size=3))
    w_perp *= 0.03 / np.linalg.norm(w_perp)
    w_full = w_perp + 0.07 * n  # plus a yaw rate about the deck normal
    D = wire_plane_distance(plane, DOWN)
    # D_dot does not depend on the component along n (algebraically)
    assert d_dot_rotation_aware(u, plane, DOWN, w_full, D) == pytest.approx(
        d_dot_rotation_aware(u, plane, DOWN, w_perp, D), abs=1e-12
    )
    # ... and the finite difference with the FULL rotation agrees
    h = 1e-4
    fd = (plane_D(rigid_motion(x, u, w_full, h)) - plane_D(rigid_motion(x, u, w_full, -h))) / (2 * h)
    assert d_dot_rotation_aware(u, plane, DOWN, w_perp, D) == pytest.approx(fd, abs=1e-6)
    # the normals over a frame give w_perp, not w_full
    dt = 0.01
    n_next = fit_plane_lsq(rigid_motion(x, u, w_full, dt))[:3]
    w_est = deck_angular_velocity(n, n_next, dt)
    assert abs(w_est @ n) < 1e-3 * np.linalg.norm(w_est)
    assert np.allclose(w_est, w_perp, atol=0.07 * 0.03 * 0.5 + 1e-4)  # O(dt) error from the yaw coupling
    # without yaw it is exact for small dt
    n_next2 = fit_plane_lsq(rigid_motion(x, u, w_perp, 1e-3))[:3]
    assert np.allclose(deck_angular_velocity(n, n_next2, 1e-3), w_perp, atol=1e-6)
    # orientation flip of the second normal is handled; identical normals give zero
    assert np.allclose(deck_angular_velocity(n, -n_next2, 1e-3), w_perp, atol=1e-6)
    assert np.allclose(deck_angular_velocity(n, n, 0.1), 0.0)
    # using the estimated w_perp in D_dot matches the finite difference to well under a mm/s
    assert d_dot_rotation_aware(u, plane, DOWN, w_est, D) == pytest.approx(fd, abs=1e-3)
