"""The feeder filter's models and updates: the Singer discretisation against its closed form,
the measurement models against finite differences, gating, dropout, honest covariances."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from boomtip.fusion.feeder_filter import FeederFilter, FeederFilterConfig
from boomtip.fusion.models.relative_motion import (
    _singer_block,
    deck_plane,
    deck_plane_rate,
    deck_spin_jacobian,
    feeder_mru_measurement,
    numeric_jacobian,
    omega,
    point_velocity,
    point_velocity_jacobian,
    rotation,
    transition,
    well_observed,
)


def test_singer_transition_matches_closed_form():
    dt, tau = 0.1, 1.5
    F, _ = _singer_block(dt, tau)
    a = math.exp(-dt / tau)
    # acceleration decays, velocity and position integrate it (closed form of da = -a/tau dt)
    assert F[2, 2] == pytest.approx(a, rel=1e-12)
    assert F[1, 2] == pytest.approx(tau * (1 - a), rel=1e-10)
    assert F[0, 2] == pytest.approx(tau * dt - tau * tau * (1 - a), rel=1e-9)


def test_singer_process_noise_matches_a_numerical_integral():
    from scipy.integrate import quad_vec
    from scipy.linalg import expm

    dt, tau, rate_tau = 0.1, 1.5, 8.0
    A = np.array([[0.0, 1.0, 0.0], [0.0, -1.0 / rate_tau, 1.0], [0.0, 0.0, -1.0 / tau]])
    G = np.array([0.0, 0.0, 1.0])
    F_ref = expm(A * dt)
    Q_ref = quad_vec(lambda s: np.outer(expm(A * s) @ G, expm(A * s) @ G), 0.0, dt)[0]
    F, Q = _singer_block(dt, tau, rate_tau)
    assert np.allclose(F, F_ref, atol=1e-12) and np.allclose(Q, Q_ref, rtol=1e-6, atol=1e-15)


def test_damped_rates_have_a_bounded_variance():
    tau, sigma, rate_tau = np.full(6, 1.5), np.full(6, 0.7), np.full(6, 8.0)
    F, Q = transition(0.05, tau, sigma, rate_tau)
    P = np.zeros((18, 18))
    for _ in range(20000):
        P = F @ P @ F.T + Q
    # stationary rate variance of v' = a - v/T with a Singer acceleration: s^2 tau T^2 / (tau + T)
    expected = 0.7 ** 2 * 1.5 * 8.0 ** 2 / (1.5 + 8.0)
    assert P[6, 6] == pytest.approx(expected, rel=0.02)


def test_singer_steady_state_variance_is_sigma_squared():
    tau, sigma = np.full(6, 1.5), np.full(6, 0.7)
    F, Q = transition(0.05, tau, sigma)
    P = np.zeros((18, 18))
    for _ in range(2000):
        P = F @ P @ F.T + Q
    assert np.sqrt(P[12, 12]) == pytest.approx(0.7, rel=1e-3)  # the acceleration's stated 1-sigma


def test_deck_plane_is_the_map_frames_z_plane():
    x = np.zeros(18)
    x[:6] = [0.3, -0.2, -45.0, 0.02, -0.03, 0.1]
    a, b, c = deck_plane(x)
    R = rotation(*x[3:6])
    for u, v in ((0.0, 0.0), (5.0, -3.0), (-20.0, 7.0)):  # points of the map's z = 0 plane lie on it
        p = x[:3] + R @ np.array([u, v, 0.0])
        assert p[2] == pytest.approx(a * p[0] + b * p[1] + c, abs=1e-9)


def _rigid_state():
    x = np.zeros(22)
    x[:6] = [0.5, 0.2, -44.0, 0.01, 0.02, 0.03]
    x[6:12] = [0.1, -0.2, 0.7, 0.01, -0.02, 0.005]
    return x


def test_point_velocity_is_the_rigid_field():
    x = _rigid_state()
    xi = np.array([0.3, 0.0, -0.5])
    tip_v = np.array([0.2, 0.1, -0.05])
    # finite difference of the body point at xi moved along the motion
    dt = 1e-6
    R0, R1 = rotation(*x[3:6]), rotation(*(x[3:6] + dt * x[9:12]))
    body = R0.T @ (xi - x[:3])
    p1 = x[:3] + dt * x[6:9] + R1 @ body
    v_fd = (p1 - xi) / dt - tip_v
    assert np.allclose(point_velocity(x, xi, tip_v), v_fd, atol=1e-5)


def test_omega_is_the_angular_velocity_of_the_euler_rates():
    pose = np.array([0.0, 0.0, 0.0, 0.03, -0.05, 0.4])
    rates = np.array([0.0, 0.0, 0.0, 0.02, -0.01, 0.03])
    dt = 1e-6
    R0, R1 = rotation(*pose[3:]), rotation(*(pose[3:] + dt * rates[3:]))
    W = (R1 @ R0.T - np.eye(3)) / dt  # [w]x in the level axes
    assert np.allclose(omega(pose, rates), [W[2, 1], W[0, 2], W[1, 0]], atol=1e-6)


def test_numeric_jacobian_matches_analytic_on_a_linear_map():
    A = np.arange(12.0).reshape(2, 6)
    J = numeric_jacobian(lambda x: A @ x[:6], np.ones(22), np.arange(6))
    assert np.allclose(J[:, :6], A, atol=1e-6) and not J[:, 6:].any()


def test_degenerate_registration_updates_only_the_observed_direction():
    # a deck with one long edge along x: y and yaw known, x not
    info = np.diag([1e-2, 1e6, 1e8])
    A, _ = well_observed(info, max_sigma_m=0.05)
    assert A.shape == (2, 3)
    assert np.allclose(A[:, 0], 0.0, atol=1e-9)  # nothing of x
    f = FeederFilter()
    f.start(0.0, np.zeros(6), np.eye(6) * 1e-4, np.zeros(3))
    f.predict(0.1, np.zeros(3), 0.0)
    x_before = f.x.copy()
    f.update_registration(np.array([0.5, 0.01, 0.0]), info)
    assert f.x[0] == pytest.approx(x_before[0], abs=1e-9)  # x untouched by a wrong, unobserved value
    assert f.x[1] != pytest.approx(x_before[1], abs=1e-6)


def test_gating_refuses_an_outlier_then_reacquires():
    cfg = FeederFilterConfig(max_rejections=3)
    f = FeederFilter(cfg)
    f.start(0.0, np.array([0, 0, -45.0, 0, 0, 0]), np.eye(6) * 1e-6, np.zeros(3))
    cov = np.diag([1e-8, 1e-8, 1e-6])
    wrong = deck_plane(np.r_[0, 0, -40.0, np.zeros(15)])  # 5 m off
    results = []
    for k in range(5):
        f.predict(0.1 * (k + 1), np.zeros(3), 0.0)
        results.append(f.update_deck("deck_lidar", wrong, cov))
    assert results[:3] == [False, False, False] and results[3]  # gated three times, then taken
    assert f.updates.counts["deck_lidar"]["reacquired"] == 1
    assert abs(f.x[2] + 40.0) < 0.05


def test_nan_measurement_leaves_the_state_finite():
    f = FeederFilter()
    f.start(0.0, np.zeros(6), np.eye(6) * 1e-4, np.zeros(3))
    f.predict(0.1, np.zeros(3), 0.0)
    assert not f.update_deck("deck_lidar", np.array([np.nan, 0, 0]), np.eye(3))
    assert not f.update_point_velocity(np.array([0.0, np.inf, 0.0]), np.eye(3), np.zeros(3))
    assert np.all(np.isfinite(f.x)) and f.updates.counts["deck_lidar"]["bad"] == 1


@pytest.mark.slow
def test_covariance_grows_through_a_dropout_and_is_honest():
    """A stationary-in-distribution Singer process tracked with deck planes, then 5 s without
    any: the position error stays within the reported 3 sigma in >= 97 % of 200 seeds' ends."""
    cfg = FeederFilterConfig()
    hits, grew = 0, 0
    for seed in range(200):
        rng = np.random.default_rng(seed)
        f = FeederFilter(cfg)
        F, Q = transition(0.1, f.tau, f.sigma_acc, f.rate_tau)
        truth = np.zeros(18)
        truth[2] = -45.0
        f.start(0.0, truth[:6], np.eye(6) * 1e-6, np.zeros(3))
        L = np.linalg.cholesky(Q + 1e-15 * np.eye(18))
        for k in range(1, 101):
            truth = F @ truth + L @ rng.standard_normal(18)
            f.predict(0.1 * k, np.zeros(3), 0.0)
            if k <= 50:
                z = deck_plane(truth) + rng.normal(0, [1e-4, 1e-4, 2e-3])
                f.update_deck("deck_lidar", z, np.diag([1e-8, 1e-8, 4e-6]))
            if k == 50:
                var_at_dropout = f.P[2, 2]
        err = abs(f.x[2] - truth[2])
        hits += err <= 3 * math.sqrt(f.P[2, 2])
        grew += f.P[2, 2] > 10 * var_at_dropout
    assert hits >= 194 and grew == 200


# -- a feeder MRU (document 004's second MRU) ---------------------------------------------
def _offsets_state(pose, rates, psi_off, psi_body, tilt):
    x = np.zeros(22)
    x[:6], x[6:12] = pose, rates
    x[18], x[19], x[20:22] = psi_off, psi_body, tilt
    return x


def test_feeder_mru_measurement_is_the_body_in_its_heading_frame():
    pose = np.array([1.0, -2.0, -40.0, 0.02, -0.035, 0.1])
    x = _offsets_state(pose, np.zeros(6), 0.03, 0.2, (0.004, -0.002))
    R_level_map = Rotation.from_euler("xyz", pose[3:]).as_matrix()
    R_body_map = Rotation.from_euler("xyz", [0.004, -0.002, 0.2]).as_matrix()
    R_expected = Rotation.from_euler("z", -0.03).as_matrix() @ R_level_map @ R_body_map.T
    rpy = feeder_mru_measurement(x)[:3]
    assert np.allclose(Rotation.from_euler("xyz", rpy).as_matrix(), R_expected, atol=1e-12)


def test_feeder_mru_rates_are_what_the_mru_would_differentiate():
    """The angular velocity the model predicts equals the one from the Euler rates of the
    MRU's own angles (finite differences of the modelled rotation over time)."""
    pose = np.array([0.0, 0.0, -40.0, 0.02, -0.035, 0.1])
    rates = np.array([0.1, 0.0, 0.3, 0.01, -0.02, 0.004])
    x = _offsets_state(pose, rates, 0.05, 0.3, (0.003, 0.001))
    dt = 1e-6
    xp, xm = x.copy(), x.copy()
    xp[:6] += rates * dt
    xm[:6] -= rates * dt
    a_p, a_m = feeder_mru_measurement(xp)[:3], feeder_mru_measurement(xm)[:3]
    euler_rates = (a_p - a_m) / (2 * dt)
    w_from_mru = omega(np.r_[0, 0, 0, feeder_mru_measurement(x)[:3]], np.r_[0, 0, 0, euler_rates])
    assert np.allclose(feeder_mru_measurement(x)[3:], w_from_mru, atol=1e-8)


def _wave_truth(t: float) -> np.ndarray:
    """Pose and Euler rates of a feeder rolling 1 deg, pitching 2.5 deg and yawing 0.3 deg
    over 10 s (document 000's evaluation sea), heaving 2 m."""
    w = 2 * math.pi / 10.0
    amp = np.array([0.3, 0.2, 2.0, math.radians(1.0), math.radians(2.5), math.radians(0.3)])
    phase = np.array([0.0, 1.0, 0.5, 0.2, 1.3, 2.1])
    x = np.zeros(18)
    x[:6] = amp * np.sin(w * t + phase)
    x[2] -= 45.0
    x[6:12] = amp * w * np.cos(w * t + phase)
    x[12:18] = -amp * w * w * np.sin(w * t + phase)
    return x


def _mru_run(with_mru: bool, seed: int = 3):
    """Deck planes for 30 s, then 40 s without (no registration at all): with a feeder MRU
    its offsets are learnt while the deck is seen, and the yaw, roll and pitch then hold."""
    rng = np.random.default_rng(seed)
    f = FeederFilter()
    psi_off, psi_body, tilt = math.radians(2.0), math.radians(6.0), np.radians([0.2, -0.1])
    truth = _wave_truth(0.0)
    f.start(0.0, truth[:6], np.diag([1e-6, 1e-6, 1e-6, 1e-8, 1e-8, 1e-8]), np.zeros(3))
    sa, sr = math.radians(0.02), math.radians(0.025)
    errors = []
    for k in range(1, 1401):
        t = 0.05 * k
        truth = _wave_truth(t)
        f.predict(t, np.zeros(3), 0.0)
        if with_mru:
            xt = _offsets_state(truth[:6], truth[6:12], psi_off, psi_body, tilt)
            z = feeder_mru_measurement(xt)
            rpy = z[:3] + rng.normal(0, sa, 3)
            # the MRU logs Euler-angle rates: invert omega at its angles
            E = numeric_jacobian(lambda v: omega(np.r_[0, 0, 0, rpy], np.r_[0, 0, 0, v[:3]]), np.zeros(3), np.arange(3))
            rpy_rate = np.linalg.solve(E, z[3:]) + rng.normal(0, sr, 3)
            f.update_feeder_mru(rpy, rpy_rate, sa, sr)
        if t <= 30.0 and k % 2 == 0:
            z = deck_plane(truth) + rng.normal(0, [1e-4, 1e-4, 2e-3])
            f.update_deck("deck_lidar", z, np.diag([1e-8, 1e-8, 4e-6]))
        e = f.x[:6] - truth[:6]
        errors.append((t, e, np.sqrt(np.diag(f.P)[:6])))
    return f, (psi_off, psi_body, tilt), errors


@pytest.mark.slow
def test_a_feeder_mru_learns_its_offsets_and_holds_the_attitude_without_the_deck():
    f, (psi_off, psi_body, tilt), errors = _mru_run(True)
    x, s = f.offsets()
    assert abs(x[0] - psi_off) < 3 * s[0] and abs(x[1] - psi_body) < 3 * s[1]
    assert np.all(np.abs(x[2:] - tilt) < 3 * s[2:])
    assert s[1] < math.radians(1.0)  # the body's yaw is found from the tilts, to under a degree
    late = [e for t, e, _ in errors if t > 60.0]
    assert max(abs(e[5]) for e in late) < math.radians(0.05)  # 30 s without the deck: the yaw holds
    assert max(max(abs(e[3]), abs(e[4])) for e in late) < math.radians(0.03)
    inside = np.array([np.abs(e[3:]) <= 3 * s_[3:] for t, e, s_ in errors if t > 30.0])
    assert inside.mean() > 0.97  # and its covariance says so honestly
    assert f.updates.counts["feeder_mru"]["accepted"] == 1400


def test_without_a_feeder_mru_the_yaw_is_not_observed():
    f, _, errors = _mru_run(False)
    assert errors[-1][2][5] > math.radians(1.0)  # the yaw's sigma has grown: nothing measures it
    assert "feeder_mru" not in f.updates.counts


def test_a_non_finite_feeder_mru_sample_is_refused():
    f = FeederFilter()
    f.start(0.0, np.array([0, 0, -45.0, 0, 0, 0]), np.eye(6) * 1e-6, np.zeros(3))
    assert not f.update_feeder_mru(np.array([0.0, np.nan, 0.0]), np.zeros(3), 1e-4, 1e-4)
    assert np.all(np.isfinite(f.x)) and f.updates.counts["feeder_mru"]["bad"] == 1 and not f.feeder_mru_started


def test_the_doppler_jacobian_matches_differences():
    x = _rigid_state()
    xi = np.array([0.3, -1.0, 2.0])
    tip = np.array([0.1, 0.2, 0.3])
    num = numeric_jacobian(lambda z: point_velocity(z, xi, tip), x, np.arange(12))
    assert np.allclose(point_velocity_jacobian(x, xi), num, atol=1e-6)


# -- the deck's spin over a sweep ---------------------------------------------------------
def test_the_deck_planes_rate_is_that_of_the_plane_moving_with_the_state():
    """The plane of the body moved along the state's motion for 1 ms (its position less the
    tip's, its angles at their rates), differenced: the model's rate."""
    x = _rigid_state()
    tip = np.array([0.1, -0.3, 0.4])
    dt = 1e-3
    moved = lambda s: np.r_[x[:3] + s * (x[6:9] - tip), x[3:6] + s * x[9:12]]
    fd = (deck_plane(moved(dt)) - deck_plane(moved(-dt))) / (2 * dt)
    assert np.allclose(deck_plane_rate(x, tip), fd, rtol=1e-6, atol=1e-9)
    assert abs(deck_plane_rate(x, tip)[2] - (x[8] - tip[2])) < 0.2  # mostly the heave rate less the tip's


# numeric_jacobian's and deck_plane_rate's default steps
JACOBIAN_STEP = 1e-6
RATE_STEP_S = 1e-2


def test_the_spins_jacobian_matches_differences_over_pose_and_rates_but_yaw():
    x = _rigid_state()
    tip = np.array([0.1, -0.3, 0.4])
    h = lambda z: np.concatenate([deck_plane(z), deck_plane_rate(z, tip)])
    num = numeric_jacobian(h, x, np.r_[0:5, 6:11])
    J = deck_spin_jacobian(x, tip)
    # The reference differences deck_plane_rate, itself a central difference over RATE_STEP_S:
    # four plane evaluations, each good to a few ulps of the plane's size (c = 44 m; the slopes'
    # intermediates are of order 1), divided by 2 JACOBIAN_STEP and 2 RATE_STEP_S. Truncation is
    # far below that: the plane is smooth over 1e-6 steps, and J's rate columns (the plane's pose
    # Jacobian) are exact to (rate dt)^2 ~ 4e-8 of themselves.
    plane_size = np.maximum(np.abs(np.r_[deck_plane(x), deck_plane(x)]), 1.0)
    roundoff = 4 * np.finfo(float).eps * plane_size / (JACOBIAN_STEP * RATE_STEP_S)
    assert np.all(np.abs(J - num) <= roundoff[:, None] + 1e-7 * np.abs(num))
    assert roundoff.max() < 1e-5  # a tolerance that still tells a wrong column (entries of order 0.01-1)
    assert np.all(J[:, [5, 11]] == 0.0) and np.all(J[:, 12:] == 0.0) and J[5, 8] == pytest.approx(1.0)  # the heave rate


def _spinning_deck(t: float) -> np.ndarray:
    x = np.zeros(22)
    x[:6] = [0.4, -0.3, -44.0, 0.01 + math.radians(1.0) * t, -0.02 + math.radians(-0.5) * t, 0.0]
    x[6:12] = [0.0, 0.0, 0.0, math.radians(1.0), math.radians(-0.5), 0.0]
    return x


def test_the_spin_measures_the_roll_and_pitch_rates_the_plane_alone_does_not():
    """A deck rolling at 1 deg/s and pitching at -0.5 deg/s, the filter starting at rest
    (2 deg/s 1-sigma) at a pose known to 0.6 deg: one spin update puts both rates within
    0.01 deg/s; one plane update leaves them nearly where they were (a tilt, not a rate)."""
    cov = np.diag([1e-8, 1e-8, 1e-6, 1e-8, 1e-8, 1e-4])
    rates = {}
    for spin in (True, False):
        truth = _spinning_deck(0.0)
        f = FeederFilter()
        f.start(0.0, truth[:6], np.eye(6) * 1e-4, np.zeros(3))
        f.predict(0.1, np.zeros(3), 0.0)
        truth = _spinning_deck(0.1)
        if spin:
            assert f.update_deck_spin("deck_spin_lidar", deck_plane(truth), deck_plane_rate(truth, np.zeros(3)), cov)
        else:
            assert f.update_deck("deck_lidar", deck_plane(truth), cov[:3, :3])
        rates[spin] = np.degrees(f.x[9:11])
    assert np.allclose(rates[True], [1.0, -0.5], atol=0.01)
    assert np.all(np.abs(rates[False] - [1.0, -0.5]) > [0.8, 0.4])
    assert f.updates.counts["deck_lidar"]["accepted"] == 1


def test_a_spin_far_from_the_state_is_gated_and_its_yaw_never_moves():
    f = FeederFilter()
    truth = _spinning_deck(0.0)
    f.start(0.0, truth[:6], np.eye(6) * 1e-6, np.zeros(3))
    f.predict(0.1, np.zeros(3), 0.0)
    cov = np.diag([1e-8, 1e-8, 1e-6, 1e-8, 1e-8, 1e-4])
    wrong_rates = deck_plane_rate(_spinning_deck(0.1), np.zeros(3)) + np.array([0.0, 0.0, 5.0])  # 5 m/s of heave rate
    assert not f.update_deck_spin("deck_spin_lidar", deck_plane(_spinning_deck(0.1)), wrong_rates, cov)
    assert f.updates.counts["deck_spin_lidar"]["gated"] == 1
    truth = _spinning_deck(0.1)
    truth[11] = 0.05  # a yaw rate the spin must not be used to estimate
    yaw0 = f.x[5]
    assert f.update_deck_spin("deck_spin_lidar", deck_plane(truth), deck_plane_rate(truth, np.zeros(3)), cov)
    assert f.x[5] == yaw0 and f.x[11] == 0.0


def test_frames_closer_than_the_errors_correlation_share_their_information():
    """At 200 Hz a kind's frames share their errors (levelling, deck, map): each carries its
    covariance times the correlation time over its interval, so the information per second is
    what 10 Hz of independent frames gives; at 10 Hz nothing changes; a data sheet's white
    noise (the feeder MRU) is never scaled."""
    f = FeederFilter(FeederFilterConfig(error_correlation_s=0.1))
    f.start(0.0, np.zeros(6), np.eye(6) * 1e-4, np.zeros(3))
    assert f.shared_error_factor("deck_lidar") == 1.0  # the first one
    f.last_update_s["deck_lidar"] = -0.005
    assert f.shared_error_factor("deck_lidar") == pytest.approx(20.0)
    f.last_update_s["deck_lidar"] = -0.1
    assert f.shared_error_factor("deck_lidar") == pytest.approx(1.0)
    off = FeederFilter(FeederFilterConfig(error_correlation_s=0.0))
    off.start(0.0, np.zeros(6), np.eye(6) * 1e-4, np.zeros(3))
    off.last_update_s["deck_lidar"] = -0.005
    assert off.shared_error_factor("deck_lidar") == 1.0

    def sigma_z_after(rate_hz: float, tau_s: float = 0.1) -> float:
        g = FeederFilter(FeederFilterConfig(error_correlation_s=tau_s, noise_memory_s=0.0))
        g.start(0.0, np.zeros(6), np.eye(6) * 1e-2, np.zeros(3))
        H = np.zeros((1, len(g.x)))
        H[0, 2] = 1.0
        for k in range(1, int(rate_hz) + 1):  # one second of z measurements of 1 cm
            g.predict(k / rate_hz, np.zeros(3), 0.0)
            g._update("probe", np.zeros(1), np.zeros(1), H, np.array([[1e-4]]))
        return float(np.sqrt(g.P[2, 2]))

    at_10 = sigma_z_after(10.0)
    assert at_10 <= sigma_z_after(200.0) <= 1.5 * at_10  # 20x the frames: no more certainty than 10 Hz gives
    assert sigma_z_after(200.0, tau_s=0.0) < 0.6 * at_10  # taken as independent, they would claim much more
