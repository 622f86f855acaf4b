"""The cached-index point-to-plane ICP against Open3D's registration_icp on the same inputs."""

import numpy as np
import open3d as o3d
import pytest

from boomtip.perception.point_to_plane import Surface, Correspondences, icp_point_to_plane, rotation_zyx


def _structure(rng: np.random.Generator) -> np.ndarray:
    """Points on a few axis-aligned walls and boxes: enough to pin all six degrees of freedom."""
    faces = []
    for x0, y0, w, d, h in [(0, 0, 12, 2.5, 2.6), (14, -4, 6, 2.5, 5.2), (-10, 3, 3, 8, 1.2), (-4, -8, 20, 0.3, 1.0)]:
        n = 900
        u, v = rng.uniform(0, 1, n), rng.uniform(0, 1, n)
        faces += [np.column_stack([x0 + u * w, np.full(n, y0), v * h]), np.column_stack([np.full(n, x0), y0 + u * d, v * h]),
                  np.column_stack([x0 + u * w, y0 + v * d, np.full(n, h)])]
    return np.vstack(faces)


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(3)
    model = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(_structure(rng))).voxel_down_sample(0.25)
    model.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(10))
    T_true = np.eye(4)
    T_true[:3, :3] = rotation_zyx(0.004, -0.003, 0.02)
    T_true[:3, 3] = (0.3, -0.2, 0.05)
    src_model = _structure(rng) + rng.normal(0, 0.02, (len(_structure(rng)), 3))  # another sampling, with noise
    src = (src_model - T_true[:3, 3]) @ T_true[:3, :3]  # source frame: model = T_true applied to it
    return model, src, T_true


@pytest.mark.parametrize("tukey_m", [0.1, 0.3])
def test_the_poses_are_open3ds(scene, tukey_m):
    model, src, _ = scene
    reg = o3d.pipelines.registration
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(src))
    surface = Surface(np.asarray(model.points), np.asarray(model.normals))
    for guess_shift in (0.0, 0.1, 0.25):
        guess = np.eye(4)
        guess[:3, 3] = (guess_shift, -guess_shift, 0.0)
        ref = reg.registration_icp(cloud, model, 1.0, guess, reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=tukey_m)),
                                   reg.ICPConvergenceCriteria(1e-4, 1e-4, 30))
        got = icp_point_to_plane(surface, src, guess, 1.0, tukey_m, 1e-4, 30)
        assert np.abs(got.T - np.asarray(ref.transformation)).max() < 1e-9
        assert got.fitness == pytest.approx(ref.fitness, abs=1e-12)
        assert len(got.source_index) == len(np.asarray(ref.correspondence_set))


def test_it_finds_the_pose(scene):
    model, src, T_true = scene
    surface = Surface(np.asarray(model.points), np.asarray(model.normals))
    got = icp_point_to_plane(surface, src, np.eye(4), 1.0, 0.3, 1e-6, 50)
    assert np.abs(got.T[:3, 3] - T_true[:3, 3]).max() < 0.01
    assert np.abs(got.T[:3, :3] - T_true[:3, :3]).max() < 5e-4
    assert got.iterations >= 2


def test_no_overlap_keeps_the_guess():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 5, (500, 3))
    surface = Surface(pts, np.tile([0.0, 0.0, 1.0], (500, 1)))
    got = icp_point_to_plane(surface, pts + 100.0, np.eye(4), 1.0, 0.3, 1e-4, 30)
    assert np.array_equal(got.T, np.eye(4)) and got.fitness == 0.0 and got.iterations == 0


def test_a_surface_needs_matching_normals():
    with pytest.raises(ValueError, match="points and normals"):
        Surface(np.zeros((5, 3)), np.zeros((4, 3)))


def test_a_non_finite_guess_matches_nothing():
    """A NaN pose (a filter gone wrong upstream) is no overlap, not an exception."""
    rng = np.random.default_rng(1)
    pts = rng.uniform(0, 5, (300, 3))
    surface = Surface(pts, np.tile([0.0, 0.0, 1.0], (300, 1)))
    guess = np.eye(4)
    guess[0, 3] = np.nan
    got = icp_point_to_plane(surface, pts, guess, 1.0, 0.3, 1e-4, 30)
    assert got.fitness == 0.0 and len(got.source_index) == 0 and got.iterations == 0
    src_i, srf_i, _ = surface.nearest(np.vstack([pts[:3], [np.inf, 0.0, 0.0]]), 1.0)
    assert list(src_i) == [0, 1, 2] and list(srf_i) == [0, 1, 2]


def test_tracked_correspondences_are_a_full_querys(scene):
    """Re-querying only the points that moved by half their nearest-second gap gives every
    nearest point a full query gives, over steps from a millimetre to a metre; the small steps
    query a few of the points."""
    model, src, _ = scene
    surface = Surface(np.asarray(model.points), np.asarray(model.normals))
    source = src[::3]
    tracked = Correspondences(surface, source, 1.0)
    queried = []
    full_query = surface.nearest_two
    surface.nearest_two = lambda q: (queried.append(len(q)), full_query(q))[1]
    rng = np.random.default_rng(5)
    for step_m in (0.0, 0.001, 0.002, 0.003, 0.01, 0.3, 1.0, 0.001):
        T = np.eye(4)
        T[:3, :3] = rotation_zyx(*rng.normal(0, step_m / 20, 3))
        T[:3, 3] = rng.normal(0, step_m, 3)
        moved = source @ T[:3, :3].T + T[:3, 3]
        queried.append(0)
        src_i, srf_i, d2 = tracked.at(moved)
        ref_src, ref_srf, ref_d2 = surface.nearest(moved, 1.0)
        assert np.array_equal(src_i, ref_src) and np.array_equal(srf_i, ref_srf)
        assert np.allclose(d2, ref_d2, rtol=0, atol=1e-12)
    per_step = [sum(queried[i + 1:i + 2]) for i in range(len(queried)) if queried[i] == 0][:8]
    assert per_step[0] == len(source)  # the first: all of them
    assert max(per_step[1:4]) < 0.2 * len(source)  # millimetres: a few
    assert per_step[6] > 0.9 * len(source)  # a metre: nearly all


def test_tracked_correspondences_skip_non_finite_rows(scene):
    model, src, _ = scene
    surface = Surface(np.asarray(model.points), np.asarray(model.normals))
    source = src[:50].copy()
    tracked = Correspondences(surface, source, 1.0)
    moved = source.copy()
    moved[[3, 7]] = np.nan
    src_i, _, _ = tracked.at(moved)
    ref_src, _, _ = surface.nearest(moved, 1.0)
    assert np.array_equal(src_i, ref_src) and 3 not in src_i and 7 not in src_i
    src_i, _, _ = tracked.at(source)  # finite again: queried then
    assert np.array_equal(src_i, surface.nearest(source, 1.0)[0])
