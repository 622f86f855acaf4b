"""The radar's detections registered to a feeder model: their covariance, the x / y / yaw
registration with z, roll and pitch held, and the radar-minus-LiDAR offset."""

import math

import numpy as np
import open3d as o3d
import pytest

from boomtip.fusion.radar_offset import RadarOffset
from boomtip.perception.feeder_radar import RadarRegistrationConfig, detection_covariance, register_radar
from boomtip.perception.geometry import rpy_matrix
from boomtip.perception.point_to_plane import Surface

SIGMA = (0.144, math.radians(0.289), math.radians(0.433))  # document 000's radar: range, azimuth, elevation


def _spherical(points: np.ndarray) -> np.ndarray:
    r = np.linalg.norm(points, axis=1)
    return np.column_stack([r, np.arctan2(points[:, 1], points[:, 0]), np.arcsin(points[:, 2] / r)])


def _cartesian(rae: np.ndarray) -> np.ndarray:
    r, a, e = rae.T
    return np.column_stack([r * np.cos(e) * np.cos(a), r * np.cos(e) * np.sin(a), r * np.sin(e)])


@pytest.mark.parametrize("point", [(25.0, 0.0, 0.0), (3.0, -4.0, -24.0), (1.0, 2.0, -28.0)])
def test_the_covariance_is_that_of_range_azimuth_and_elevation_noise(point):
    """Against the spread of detections drawn with the three noises (the sensor convention:
    azimuth about z from x, elevation towards z)."""
    rng = np.random.default_rng(5)
    p = np.array([point])
    rae = _spherical(p) + rng.standard_normal((200_000, 3)) * np.array(SIGMA)
    empirical = np.cov(_cartesian(rae).T)
    model = detection_covariance(p, *SIGMA)[0]
    assert np.allclose(model, empirical, atol=0.03 * np.abs(empirical).max())


def test_a_detection_straight_below_has_no_azimuth_spread():
    cov = detection_covariance(np.array([[0.0, 0.0, -20.0]]), *SIGMA)[0]
    r = 20.0 * SIGMA[2]
    assert np.allclose(cov, np.diag([r * r, 0.0, SIGMA[0] ** 2]))


def _feeder_model(rng):
    """A deck with hatch coamings and cargo: boxes on a plane, with normals."""
    pts = [np.column_stack([rng.uniform(-20, 20, 20000), rng.uniform(-8, 8, 20000), np.zeros(20000)])]
    for x0, y0, w, d, h in [(-15, -5, 10, 4, 1.5), (0, 1, 12, 5, 2.5), (-4, -6, 3, 3, 4.0)]:
        n = 3000
        u, v = rng.uniform(0, 1, n), rng.uniform(0, 1, n)
        pts += [np.column_stack([x0 + u * w, np.full(n, y0), v * h]), np.column_stack([x0 + u * w, np.full(n, y0 + d), v * h]),
                np.column_stack([np.full(n, x0), y0 + u * d, v * h]), np.column_stack([np.full(n, x0 + w), y0 + u * d, v * h]),
                np.column_stack([x0 + u * w, y0 + v * d, np.full(n, h)])]
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.vstack(pts))).voxel_down_sample(0.2)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(10))
    return Surface(np.asarray(cloud.points), np.asarray(cloud.normals)), np.vstack(pts)


@pytest.fixture(scope="module")
def feeder_model():
    return _feeder_model(np.random.default_rng(11))


def _frame(model_points, pose, rng, n=500):
    """Detections of the model seen from a radar 28 m above it: the model's points at the pose
    (map -> level), with the radar's noise drawn in its own angles."""
    R = rpy_matrix(pose[3:])
    chosen = model_points[rng.choice(len(model_points), n, replace=False)]
    level = chosen @ R.T + pose[:3]
    radar = np.array([0.0, 0.0, 0.0])  # the radar at the level frame's origin, axes level
    rae = _spherical(level - radar) + rng.standard_normal((n, 3)) * np.array(SIGMA)
    return _cartesian(rae) + radar


def test_the_registration_finds_x_y_and_yaw_within_its_stated_sigma(feeder_model):
    """Over 40 frames: each registration's error against its own information (inflation 1)
    is chi-square with 3 degrees of freedom (mean 3), and z / roll / pitch stay where given."""
    surface, points = feeder_model
    cfg = RadarRegistrationConfig(info_inflation=1.0)
    truth = np.array([1.5, -0.8, -28.0, 0.01, -0.02, 0.03])
    guess = truth + np.array([0.15, -0.12, 0.0, 0.0, 0.0, math.radians(0.3)])
    rng = np.random.default_rng(2)
    d2, errors = [], []
    for _ in range(40):
        level = _frame(points, truth, rng)
        reg = register_radar(surface, level, np.eye(3), np.zeros(3), SIGMA, guess, cfg)  # the radar at the level origin
        assert reg.status == "ok" and reg.matched > 300
        e = reg.x_y_yaw - truth[[0, 1, 5]]
        errors.append(e)
        d2.append(float(e @ reg.info @ e))
    errors = np.array(errors)
    assert np.all(np.abs(errors.mean(axis=0)) < [0.005, 0.005, math.radians(0.02)])  # no bias (4 sigma of the mean)
    assert np.all(errors.std(axis=0) < [0.012, 0.012, math.radians(0.08)])  # 8 / 6 mm, 0.056 deg
    assert 2.0 < np.mean(d2) < 4.2  # honest: 3 expected, the mean of 40 spreads +-0.4


def test_too_few_detections_on_the_model_is_no_registration(feeder_model):
    surface, _ = feeder_model
    far = np.array([[100.0, 100.0, 0.0]] * 50)
    reg = register_radar(surface, far, np.eye(3), np.zeros(3), SIGMA, np.array([0, 0, -28.0, 0, 0, 0]),
                         RadarRegistrationConfig())
    assert reg.status.startswith("0 radar detections") and not reg.info.any()


def test_the_offset_is_a_running_mean_with_its_spread():
    off = RadarOffset(frames=100)
    rng = np.random.default_rng(0)
    lidar = np.array([1.0, 2.0, math.pi - 0.001])
    for _ in range(400):
        off.add(lidar + np.array([0.02, -0.01, 0.002]) + rng.normal(0, [0.05, 0.05, 0.001]), lidar)
    assert np.allclose(off.mean, [0.02, -0.01, 0.002], atol=[0.015, 0.015, 0.0003])  # the yaw wraps across pi
    assert np.allclose(np.sqrt(np.diag(off.covariance())), [0.005, 0.005, 0.0001], rtol=0.3)
