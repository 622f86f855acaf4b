"""Perception stages on synthetic clouds with known answers, and the pipeline on bad input."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.data.frames import Frame, MruLog
from boomtip.tools.config.scenario import load_scenario
from boomtip.data.sim.simulator import Simulation
from boomtip.perception.deck import LIDAR_DECK, RADAR_DECK, detect_deck
from boomtip.perception.deck_spin import deck_point_times
from boomtip.perception.doppler import doppler_velocity
from boomtip.perception.geometry import (
    NormalRate,
    fit_plane_heave,
    heave_distance,
    heave_rate_document,
    heave_rate_exact,
    least_eigvec3,
    level_rotation_rows,
    mat3_vec,
    mat3T_vec,
    omega_from_euler_rates,
    omega_from_euler_rates_floats,
    plane_sigma_at,
    quad3,
    rotation_level_sensor,
    rpy_matrix,
    tip_above_waterline_m,
    tip_in_sensor,
)
from boomtip.perception.pipeline import FRAME_STAGES, STAGES, HeavePipeline, PipelineConfig
from boomtip.perception.reflectors import ReflectorConfig, detect_reflectors
from boomtip.perception.timing import StageTimes


def _deck_scene(rng, tilt_deg=3.0, depth=40.0, cargo=True, n=20000):
    """Sensor at the origin looking down -z; a tilted deck `depth` below, cargo boxes on it,
    a higher crane-vessel deck to one side, and a few sea points below."""
    ax = np.deg2rad(tilt_deg)
    n_up = np.array([np.sin(ax), 0.0, np.cos(ax)])  # deck normal, towards the sensor
    xy = rng.uniform([-40, -10], [40, 10], size=(n, 2))
    z = -depth - (n_up[0] * xy[:, 0]) / n_up[2]
    deck = np.column_stack([xy, z])
    parts = [deck]
    if cargo:
        # Boxes 3-8 m tall covering ~40 % of the deck: their tops replace deck points.
        covered = (np.abs(xy[:, 0] - 10) < 12) | (np.abs(xy[:, 0] + 20) < 5)
        tops = deck[covered].copy()
        tops[:, 2] += np.where(tops[:, 0] > 0, 5.0, 3.0)
        parts = [deck[~covered], tops]
    crane = np.column_stack([rng.uniform(-30, 30, 3000), rng.uniform(12, 20, 3000), np.full(3000, -depth + 6)])
    sea = np.column_stack([rng.uniform(-40, 40, 40), rng.uniform(-10, 10, 40), np.full(40, -depth - 5)])
    pts = np.vstack(parts + [crane, sea]) + rng.normal(0, 0.01, (sum(len(p) for p in parts) + 3040, 3))
    return pts, n_up, depth


def test_deck_under_cargo_is_found_not_a_cargo_top():
    rng = np.random.default_rng(1)
    pts, n_up, depth = _deck_scene(rng)
    res = detect_deck(pts, np.array([0, 0, -1.0]), np.zeros(3), LIDAR_DECK, rng, StageTimes())
    assert res.status == "ok"
    assert res.D_m == pytest.approx(depth, abs=0.005)
    assert np.degrees(np.arccos(abs(res.plane_sensor[:3] @ n_up))) < 0.1


def test_no_plane_below_the_sea_is_the_deck():
    """A deck and, farther down, a larger plane (the deck's mirror image in a radar's sea echoes):
    without a prior the lowest would be taken; beyond the calm waterline it never is."""
    rng = np.random.default_rng(3)
    pts, _, depth = _deck_scene(rng, cargo=False)
    mirror = pts[pts[:, 2] < -depth + 1] + [0.0, 0.0, -8.0]  # the deck's points again, 8 m lower
    both = np.vstack([pts, mirror, mirror + rng.normal(0, 0.01, mirror.shape)])
    wire = np.array([0, 0, -1.0])
    lowest = detect_deck(both, wire, np.zeros(3), LIDAR_DECK, np.random.default_rng(1), StageTimes())
    assert lowest.D_m == pytest.approx(depth + 8.0, abs=0.01)  # the search's own choice: the lowest
    above = detect_deck(both, wire, np.zeros(3), LIDAR_DECK, np.random.default_rng(1), StageTimes(), max_D_m=depth + 4.0)
    assert above.status == "ok" and above.D_m == pytest.approx(depth, abs=0.005)
    none = detect_deck(both, wire, np.zeros(3), LIDAR_DECK, np.random.default_rng(1), StageTimes(), max_D_m=depth - 1.0)
    assert np.isnan(none.D_m) and "above the sea" in none.status
    # a prior near the mirror image (a deck lost to it earlier) still finds nothing below the sea
    held = detect_deck(both, wire, np.zeros(3), LIDAR_DECK, np.random.default_rng(1), StageTimes(),
                       prior_D_m=depth + 8.0, prior_tol_m=0.5, max_D_m=depth + 4.0)
    assert np.isnan(held.D_m)
    # what lies below the sea is not searched but stays among the points used, so that the
    # inliers still map to the frame's rows (their times: the deck's spin)
    assert len(above.points_used) == len(lowest.points_used) and len(above.fit.inlier_mask) == len(above.points_used)
    inliers = above.points_used[above.fit.inlier_mask]
    times = np.arange(len(both), dtype=float)  # each point's time: its row
    t = deck_point_times(both, times, above.points_used, above.fit.inlier_mask)
    assert t is not None and np.array_equal(both[t.astype(int)], inliers)
    assert len(t) > 1000 and t.max() < len(pts)  # the deck's rows, none of the lower copy's


def test_the_tip_above_the_waterline_tilts_with_the_vessel():
    tip = (10.0, -40.0, 52.0)
    assert tip_above_waterline_m(np.zeros(3), tip, 0.0) == pytest.approx(52.0)
    assert tip_above_waterline_m(np.zeros(3), tip, 2.0) == pytest.approx(50.0)  # the body origin 2 m below the sea
    rpy = np.radians([1.0, 2.5, 30.0])  # the yaw moves nothing up or down
    for waterline in (0.0, -3.0):  # tilted about the waterline's point below the body origin
        z = (rpy_matrix(rpy) @ (np.array(tip) - [0.0, 0.0, waterline]))[2]
        assert tip_above_waterline_m(rpy, tip, waterline) == pytest.approx(z, abs=1e-12)


def test_the_deck_search_is_bounded_by_the_sea_only_where_the_waterline_is_surveyed():
    from boomtip.data.installation import Installation

    inst = Installation()
    assert inst.crane.geometry.waterline_z_m is None  # not surveyed by default: no bound
    assert HeavePipeline(inst, None).max_deck_D(np.zeros(3)) is None
    surveyed = Installation.model_validate({"crane": {"geometry": {"waterline_z_m": 1.0}}})
    pipe = HeavePipeline(surveyed, None, PipelineConfig(beyond_waterline_m=0.5))
    assert pipe.max_deck_D(np.zeros(3)) == pytest.approx(52.0 - 1.0 + 0.5)
    with pytest.raises(ValueError, match="waterline_z_m"):
        Installation.model_validate({"crane": {"geometry": {"waterline_z_m": 60.0}}})


def test_deck_with_too_few_points_reports_why():
    res = detect_deck(np.zeros((5, 3)) + [0, 0, -40], np.array([0, 0, -1.0]), np.zeros(3), LIDAR_DECK,
                      np.random.default_rng(0), StageTimes())
    assert np.isnan(res.D_m) and "too few points" in res.status


def test_radar_deck_on_noisy_sparse_cloud():
    rng = np.random.default_rng(2)
    pts, _, depth = _deck_scene(rng, n=500, cargo=False)
    pts += rng.normal(0, 0.15, pts.shape)
    res = detect_deck(pts, np.array([0, 0, -1.0]), np.zeros(3), RADAR_DECK, rng, StageTimes())
    assert res.D_m == pytest.approx(depth, abs=0.05)


def _marker_cloud(rng, with_false=True, occlude=()):
    """Deck 45 m below with 1 m markers along both edges, diffuse background."""
    deck = np.column_stack([rng.uniform(-40, 40, 8000), rng.uniform(-11, 11, 8000), np.full(8000, -45.0)])
    inten = rng.uniform(0.1, 0.6, len(deck))
    markers = []
    for i, x in enumerate(np.arange(-36, 37, 8.0)):
        for y in (-9.0, 9.0):
            if (i, y) in occlude:
                continue
            g = np.column_stack([x + rng.uniform(-0.5, 0.5, 6), y + rng.uniform(-0.5, 0.5, 6), np.full(6, -45.0)])
            markers.append(g)
    markers = np.vstack(markers)
    pts = [deck, markers]
    ints = [inten, rng.uniform(15, 25, len(markers))]
    if with_false:
        false = np.column_stack([rng.uniform(-30, 30, 12), np.full(12, 10.8), np.full(12, -43.8)])  # bulwark tops
        pts.append(false)
        ints.append(rng.uniform(15, 25, 12))
    p = np.vstack(pts) + rng.normal(0, 0.01, (sum(len(q) for q in pts), 3))
    return p, np.concatenate(ints)


def test_reflectors_with_occlusion_and_false_bright_points():
    rng = np.random.default_rng(3)
    pts, inten = _marker_cloud(rng, with_false=True, occlude={(2, 9.0), (3, 9.0), (4, -9.0)})
    res = detect_reflectors(pts, inten, np.array([0, 0, -1.0]), np.zeros(3), ReflectorConfig(), rng, StageTimes())
    assert res.status == "ok"
    assert res.D_m == pytest.approx(45.0, abs=0.01)
    # the false bright points on the bulwark are not markers on the plane
    assert np.all(np.abs(res.marker_centroids[:, 2] + 45.0) < 0.1)


def test_reflectors_on_one_edge_only_are_rejected_as_collinear():
    rng = np.random.default_rng(4)
    pts, inten = _marker_cloud(rng, with_false=False, occlude={(i, 9.0) for i in range(20)})
    res = detect_reflectors(pts, inten, np.array([0, 0, -1.0]), np.zeros(3), ReflectorConfig(), rng, StageTimes())
    assert np.isnan(res.D_m) and "collinear" in res.status


def test_no_bright_points_means_no_reflectors():
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(-40, 40, 3000), rng.uniform(-11, 11, 3000), np.full(3000, -45.0)])
    res = detect_reflectors(pts, rng.uniform(0.1, 0.6, 3000), np.array([0, 0, -1.0]), np.zeros(3), ReflectorConfig(), rng, StageTimes())
    assert "no reflectors" in res.status


def test_plane_sigma_grows_away_from_the_points():
    rng = np.random.default_rng(6)
    p = np.column_stack([rng.uniform(-1, 1, 400), rng.uniform(-1, 1, 400), rng.normal(0, 0.01, 400)])
    plane = np.array([0, 0, 1.0, 0])
    near, far = plane_sigma_at(p, plane, np.zeros(3)), plane_sigma_at(p, plane, np.array([20.0, 0, 0]))
    assert near == pytest.approx(0.01 / 20, rel=0.3)
    assert far > 10 * near


def test_least_eigvec3_equals_lapacks_and_defers_when_the_least_eigenvalues_are_close():
    rng = np.random.default_rng(8)
    for k in range(200):
        # markers' points on a tilted deck 20-60 m away: a thin scatter, its normal the least eigenvector
        R = rotation_level_sensor(rng.uniform(-0.3, 0.3, 3), np.eye(4), np.eye(4))
        p = (rng.uniform([-8, -5, -0.02], [8, 5, 0.02], (rng.integers(20, 300), 3)) @ R.T) + rng.uniform(-60, 60, 3)
        X = p - p.mean(axis=0)
        A = X.T @ X
        evals, evecs = np.linalg.eigh(A)
        (l0, l1, l2), n = least_eigvec3(A.tolist())
        np.testing.assert_allclose([l0, l1, l2], evals, rtol=0, atol=1e-12 * evals[2])
        assert abs(abs(np.dot(n, evecs[:, 0])) - 1.0) < 1e-13 and np.linalg.norm(n) == pytest.approx(1.0, abs=1e-15)
    assert least_eigvec3(np.diag([2.0, 2.0 + 1e-9, 5.0]).tolist()) is None  # a line, or a near-round scatter
    assert least_eigvec3(np.zeros((3, 3)).tolist()) is None


def test_fit_plane_heave_gives_the_least_squares_plane_and_its_prediction_sigma():
    rng = np.random.default_rng(9)
    n_up = np.array([0.05, -0.03, 1.0]) / np.linalg.norm([0.05, -0.03, 1.0])
    xy = rng.uniform(-6, 6, (150, 2))
    p = np.column_stack([xy, -40.0 - (n_up[0] * xy[:, 0] + n_up[1] * xy[:, 1]) / n_up[2]]) + rng.normal(0, 0.01, (150, 3))
    wire, tip = np.array([0.0, 0.0, -1.0]), np.array([0.5, -0.2, 0.3])
    plane, D, sigma = fit_plane_heave(p, wire, tip, offset_m=0.002)
    c = p.mean(axis=0)
    n_svd = np.linalg.svd(p - c)[2][2]
    n_svd = n_svd if -(n_svd @ c) > 0 else -n_svd
    np.testing.assert_allclose(plane[:3], n_svd, atol=1e-12)
    assert plane[3] == pytest.approx(-(n_svd @ c) + 0.002, abs=1e-10)
    assert D == pytest.approx(heave_distance(plane, wire, tip), abs=1e-10)
    ref = np.r_[n_svd, -(n_svd @ c)]
    assert sigma == pytest.approx(plane_sigma_at(p, ref, tip + D * wire), rel=1e-9)  # at the wire's point on the plane


def test_rpy_matrix_matches_scipy():
    from scipy.spatial.transform import Rotation

    for rpy in np.random.default_rng(7).uniform(-1, 1, (20, 3)):
        assert np.allclose(rpy_matrix(rpy), Rotation.from_euler("xyz", rpy).as_matrix(), atol=1e-14)


def test_the_3x3_algebra_in_floats_equals_numpys():
    rng = np.random.default_rng(8)
    for rpy, rate in rng.uniform(-1, 1, (20, 2, 3)):
        mount = Rotation_from(rng.normal(size=3))
        rows = level_rotation_rows(rpy, mount.tolist())
        R = rpy_matrix(rpy) @ mount
        assert isinstance(rows[0][0], float) and np.allclose(rows, R, rtol=0, atol=4e-16)
        v, C = rng.normal(size=3), rng.normal(size=(3, 3))
        assert np.allclose(mat3_vec(rows, v.tolist()), R @ v, rtol=1e-15, atol=1e-15)
        assert np.allclose(mat3T_vec(rows, v.tolist()), R.T @ v, rtol=1e-15, atol=1e-15)
        assert quad3(C.tolist(), v.tolist()) == pytest.approx(v @ C @ v, rel=1e-13, abs=1e-14)
        assert omega_from_euler_rates_floats(rpy, rate) == omega_from_euler_rates(rpy, rate).tolist()


def Rotation_from(rotvec: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(rotvec).as_matrix()


def test_rotation_aware_doppler_is_exact_where_the_document_is_not():
    """A radar scan of the ideal scenario: with the deck's true normal and spin, the
    rotation-aware D-dot equals the truth; document 000's formula misses by cm/s. Frames are
    cast at true times and levelled with the TRUE attitude and mount (the simulated world's),
    so the check is of the formula alone."""
    s = load_scenario("sts-empty", ["duration_s=12"])
    sim = Simulation(s)
    w = sim.world
    errs_exact, errs_doc = [], []
    for i, t in enumerate(np.arange(0.0, 10.0, 0.5)):
        f = sim.radar_frame(i, float(t))
        beams = f.points_sensor / np.linalg.norm(f.points_sensor, axis=1, keepdims=True)
        fit = doppler_velocity(beams, f.fields["range_rate"].astype(float), None, np.random.default_rng(0))
        crane, feeder = w.crane_motion.states(np.array([t])), w.feeder_motion.states(np.array([t]))
        R_ls = rotation_level_sensor(crane.rpy_rad[0], w.T_crane_boomtip, w.T_boomtip_sensor["radar"])
        u = R_ls @ fit.velocity_sensor
        n = feeder.rotation.apply(w.deck_plane_body[:3])[0]
        truth_D = float(sim.truth.at("D", np.array([t]))[0])
        truth_V = float(sim.truth.at("D_dot", np.array([t]))[0])
        r_tip = R_ls @ tip_in_sensor(w.T_boomtip_sensor["radar"])
        exact = heave_rate_exact(u, n, feeder.omega_radps[0], crane.omega_radps[0], r_tip, truth_D)
        errs_exact.append(exact - truth_V)
        errs_doc.append(heave_rate_document(u) - truth_V)
    assert np.max(np.abs(errs_exact)) < 2e-3  # float32 range rates
    assert np.max(np.abs(errs_doc)) > 0.02


def test_normal_rate_recovers_spin_perpendicular_to_the_normal():
    w = np.array([0.02, -0.03, 0.05])
    nr = NormalRate(window_s=1.0)
    from scipy.spatial.transform import Rotation

    for t in np.arange(0, 1.01, 0.1):
        nr.add(t, Rotation.from_rotvec(w * t).apply([0.05, 0.0, 1.0]))
    n = nr.normal(1.0)
    got = nr.omega(1.0)
    w_perp = w - (w @ n) * n
    assert np.allclose(got, w_perp, atol=2e-3)


# --- the pipeline on bad input ----------------------------------------------------------------


@pytest.fixture(scope="module")
def short_sim():
    # Ideal: no mismatch between the simulated world and the installation processing knows.
    return Simulation(load_scenario("sts-empty", ["duration_s=2", "mismatch={}"]))


def test_pipeline_on_ideal_scenario_is_accurate(short_sim):
    assert short_sim.scenario.world.mismatch == type(short_sim.scenario.world.mismatch)()
    pipe = HeavePipeline(short_sim.meta.installation, short_sim.mru)
    errs: dict[str, list[float]] = {}
    for f in short_sim:
        for m in pipe.process(f).measurements:
            if m.ok:
                errs.setdefault(m.method, []).append(m.value - float(short_sim.truth.at(m.quantity, np.array([m.t_s]))[0]))
    assert np.mean(np.abs(errs["deck_lidar"])) < 2e-3
    assert np.mean(np.abs(errs["reflectors_lidar"])) < 5e-3
    assert np.mean(np.abs(errs["deck_radar"])) < 5e-3
    assert np.mean(np.abs(errs["doppler_radar_rot"])) < 0.01


def test_each_row_times_its_own_stages_and_a_share_of_the_frames_attitude(short_sim):
    pipe = HeavePipeline(short_sim.meta.installation, short_sim.mru)
    for f in (short_sim.lidar_frame(3, 0.3), short_sim.radar_frame(6, 0.3)):
        res = pipe.process(f)
        rows, ms = res.measurements, res.times.ms
        assert len(rows) == (2 if f.sensor == "lidar" else 3) and ms["attitude"] > 0
        for r in rows:
            assert "attitude" not in STAGES[r.method]
            assert r.time_ms == pytest.approx(sum(ms.get(s, 0.0) for s in STAGES[r.method]) + ms["attitude"] / len(rows), rel=1e-12)
        # the frame's rows count the attitude once between them
        own = sum(sum(ms.get(s, 0.0) for s in STAGES[r.method]) for r in rows)
        assert sum(r.time_ms for r in rows) - own == pytest.approx(sum(ms[s] for s in FRAME_STAGES), rel=1e-9)


@pytest.mark.parametrize("points", [np.zeros((0, 3)), np.full((100, 3), np.nan)])
def test_empty_and_all_nan_frames_give_reasons_not_exceptions(short_sim, points):
    pipe = HeavePipeline(short_sim.meta.installation, short_sim.mru)
    fields = {"intensity": np.ones(len(points), np.float32), "t": np.zeros(len(points), np.float32), "label": np.zeros(len(points), np.int32)}
    res = pipe.process(Frame("lidar", 0, 0.5, points, fields))
    assert {m.method for m in res.measurements} == {"deck_lidar", "reflectors_lidar"}
    assert all(not m.ok and m.status for m in res.measurements)


def test_mru_gap_is_reported(short_sim):
    m = short_sim.mru
    keep = (m.t_s < 0.4) | (m.t_s > 0.9)
    gappy = MruLog(m.t_s[keep], m.rpy_rad[keep], m.rpy_rate_radps[keep], max_gap_s=0.1)
    pipe = HeavePipeline(short_sim.meta.installation, gappy)
    res = pipe.process(short_sim.lidar_frame(6, 0.6))
    assert all("MRU" in r.status for r in res.measurements)


def test_unknown_method_is_refused(short_sim):
    from boomtip.perception.pipeline import PipelineConfig

    from pydantic import ValidationError

    with pytest.raises(ValidationError, match=r"methods\.1"):  # the config names the bad entry
        PipelineConfig(methods=("deck_lidar", "decklidar"))


def test_a_strip_of_hull_below_the_deck_is_not_a_deck():
    """A narrow near-horizontal strip below the deck (a hull side seen at a grazing angle)
    must not win the 'lowest large plane' search."""
    rng = np.random.default_rng(8)
    pts, _, depth = _deck_scene(rng, cargo=False, n=6000)
    strip = np.column_stack([rng.uniform(-60, 60, 3000), rng.uniform(30, 30.6, 3000), np.zeros(3000)])
    strip[:, 2] = -depth - 8 - 0.25 * (strip[:, 1] - 30)  # tilted 14 deg across, 0.6 m wide
    res = detect_deck(np.vstack([pts, strip]), np.array([0, 0, -1.0]), np.zeros(3), LIDAR_DECK, rng, StageTimes())
    assert res.D_m == pytest.approx(depth, abs=0.01)


def test_normal_rate_refuses_a_jump_and_recovers_from_a_bad_start():
    nr = NormalRate(window_s=1.0)
    for t in np.arange(0, 0.6, 0.1):
        assert nr.add(t, np.array([0.01 * t, 0.0, 1.0]))
    assert not nr.add(0.6, np.array([0.3, 0.0, 1.0]))  # 17 deg off: a wrong plane
    assert np.abs(nr.omega(0.6)).max() < 0.05
    # three refusals in a row: the history was the problem, start again
    assert not nr.add(0.7, np.array([0.3, 0.0, 1.0]))
    assert nr.add(0.8, np.array([0.3, 0.0, 1.0]))


def test_deck_fit_carries_its_inliers_moments_and_sigma_from_them():
    """The deck's fit carries the centroid and scatter of exactly the points in its inlier mask,
    and D's sigma computed from them equals plane_sigma_at on those points."""
    rng = np.random.default_rng(8)
    pts, _, _ = _deck_scene(rng)
    wire = np.array([0.02, 0.0, -1.0])
    wire /= np.linalg.norm(wire)
    p_tip = np.array([0.5, -0.3, 1.0])
    res = detect_deck(pts, wire, p_tip, LIDAR_DECK, rng, StageTimes())
    assert res.ok
    inl = res.points_used[res.fit.inlier_mask]
    c = inl.mean(axis=0)
    X = inl - c
    evals, evecs = np.linalg.eigh(X.T @ X)
    assert np.allclose(res.fit.centroid, c, atol=1e-9)
    # the in-plane spreads (what the deck test and the sigma use) to 1e-9; the residual one, from
    # raw moments of points 40 m away, to 1e-6
    assert np.allclose(res.fit.scatter_evals[1:], evals[1:], rtol=1e-9)
    assert res.fit.scatter_evals[0] == pytest.approx(evals[0], rel=1e-6)
    assert np.allclose(np.abs(res.fit.scatter_evecs.T @ evecs), np.eye(3), atol=1e-9)
    query = p_tip + res.D_m * wire
    assert res.sigma_m == pytest.approx(plane_sigma_at(inl, res.plane_sensor, query), rel=1e-9)
    # the refined inliers are the points within the band of the refined plane, over all points
    band = np.abs(res.points_used @ res.plane_sensor[:3] + res.plane_sensor[3]) < LIDAR_DECK.multi_plane.ransac.distance_threshold_m
    assert np.array_equal(band, res.fit.inlier_mask)


def test_normal_rate_fit_equals_a_quadratic_least_squares_fit():
    """The deck normal's fit (its normal equations solved by the adjugate) equals numpy's
    polynomial least squares, with 6+ samples (quadratic) and fewer (linear)."""
    rng = np.random.default_rng(9)
    for k, deg in ((9, 2), (5, 1)):
        nr = NormalRate(window_s=1.0)
        t = np.sort(rng.uniform(0, 0.9, k))
        normals = np.array([[0.01 * np.sin(3 * s), 0.02 * np.cos(2 * s), 1.0] for s in t])
        for ti, ni in zip(t, normals):
            assert nr.add(float(ti), ni)
        coef = np.asarray(nr._fit())
        dt = t - t[-1]
        stored = np.array(nr.n)
        for c in range(3):
            ref = np.polynomial.polynomial.polyfit(dt, stored[:, c], deg)
            assert np.allclose(coef[: deg + 1, c], ref, rtol=1e-9, atol=1e-12)
        if deg == 1:
            assert np.all(coef[2] == 0.0)
        assert nr.omega_floats(0.95) == nr.omega(0.95).tolist()
        assert nr.normal_floats(0.95) == nr.normal(0.95).tolist()


def test_repeated_time_stamps_leave_the_decks_spin_as_it_was():
    """Frames sharing a time stamp (a folder's names, a times.txt of zeros, a bag's equal
    stamps): their normals say nothing of the rate and never reach the fit (equal times would
    leave it without a slope)."""
    from boomtip.perception.geometry import NormalRate

    rate = NormalRate(window_s=1.0)
    n = np.array([0.01, -0.02, 1.0])
    assert rate.add(0.0, n)
    assert not any(rate.add(0.0, n) for _ in range(7))
    assert rate.t == [0.0] and rate.omega_floats(0.0) is None
    for k in range(1, 8):
        assert rate.add(0.1 * k, n + [0.001 * k, 0.0, 0.0])
    assert not rate.add(0.35, n)  # a late one
    w = rate.omega(0.7)
    assert w is not None and np.all(np.isfinite(w)) and abs(w[1]) > 0


def test_a_wrapping_radar_that_never_sees_a_deck_waits_then_takes_the_branch_around_zero(short_sim):
    """Radar rates that wrap and no deck distance ever (a handheld radar): the first second of
    scans gives no velocity (the alias is not known), later scans take the rates as reported
    and track from there; with a deck in view the prior comes from it instead."""
    inst = short_sim.meta.installation.model_copy(deep=True)
    inst.radar.unambiguous_range_rate_mps = 1.25
    pipe = HeavePipeline(inst, short_sim.mru)
    pipe.recent_decks = {"lidar": [], "radar": []}
    rng = np.random.default_rng(0)
    b = rng.normal(size=(200, 3)) * [0.3, 0.3, 1.0]
    b[:, 2] = -np.abs(b[:, 2])
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    points = b * 8.0  # nothing a deck plane
    rates = b @ np.array([0.2, -0.1, 0.3]) + rng.normal(0.0, 0.02, 200)
    statuses = []
    for k, t in enumerate(np.arange(0.0, 1.6, 0.1)):
        fields = {"range_rate": rates.astype(np.float32), "range": np.full(200, 8.0, np.float32)}
        res = pipe.process(Frame("radar", k, float(t), points, fields))
        statuses.append(next(m.status for m in res.measurements if m.method == "doppler_radar"))
        pipe.recent_decks = {"lidar": [], "radar": []}  # never a deck
    assert all(s.startswith("Doppler alias unknown") for s in statuses[:10])
    assert statuses[-1] == "ok" and pipe.last_doppler_level is not None
    # once it has had a prior, a scan without one (0.4 s without fits) gives no velocity
    fields = {"range_rate": rates.astype(np.float32), "range": np.full(200, 8.0, np.float32)}
    res = pipe.process(Frame("radar", 99, 1.95, points, fields))
    assert next(m.status for m in res.measurements if m.method == "doppler_radar").startswith("Doppler alias unknown")
