"""The feeder's registration methods (`registration.method`): the setting validates, and each
method registers a model's own points, moved by a known pose, back to that pose."""

from __future__ import annotations

import math

import numpy as np
import pytest
from boomtip.tools.config.processing import Processing
from boomtip.data.poses import inverse, pose_matrix, pose_vector, transform
from boomtip.perception.feeder_registration import FeederModel, RegistrationConfig
from pydantic import ValidationError


def _structure(rng: np.random.Generator) -> np.ndarray:
    """A feeder's returns above its deck (map frame): two bulwarks along x, a container and a
    hatch coaming across it, so that x, y and yaw are all pinned."""
    def box_walls(x0, x1, y0, y1, h, m):
        return [np.column_stack([np.full(m, x0), rng.uniform(y0, y1, m), rng.uniform(0.3, h, m)]),
                np.column_stack([np.full(m, x1), rng.uniform(y0, y1, m), rng.uniform(0.3, h, m)]),
                np.column_stack([rng.uniform(x0, x1, m), np.full(m, y0), rng.uniform(0.3, h, m)]),
                np.column_stack([rng.uniform(x0, x1, m), np.full(m, y1), rng.uniform(0.3, h, m)]),
                np.column_stack([rng.uniform(x0, x1, m), rng.uniform(y0, y1, m), np.full(m, h)])]
    parts = []
    for sy in (-1, 1):
        parts.append(np.column_stack([rng.uniform(-40, 40, 800), np.full(800, sy * 9.85), rng.uniform(0.3, 1.2, 800)]))
        parts.append(np.column_stack([rng.uniform(-40, 40, 800), sy * rng.uniform(9.85, 10.15, 800), np.full(800, 1.2)]))
    parts += box_walls(-21.0, -9.0, -1.2, 1.2, 2.6, 400) + box_walls(5.0, 17.0, -4.0, 4.0, 0.9, 400)
    return np.vstack(parts)


def test_the_method_setting_validates_and_reaches_the_feeder_chain():
    assert RegistrationConfig().method == "point_to_plane"
    for method in ("point_to_plane", "kiss_icp", "kiss_icp_refined"):
        p = Processing.model_validate({"feeder": {"perception": {"registration": {"method": method}}}})
        assert p.feeder.perception.registration.method == method
    with pytest.raises(ValidationError, match="'point_to_plane', 'kiss_icp' or 'kiss_icp_refined'") as err:
        Processing.model_validate({"feeder": {"perception": {"registration": {"method": "icp"}}}})
    assert err.value.errors()[0]["loc"] == ("feeder", "perception", "registration", "method")


@pytest.mark.parametrize("method, tol_m, tol_deg", [("point_to_plane", 1e-5, 3e-5), ("kiss_icp", 1e-3, 2e-3),
                                                    ("kiss_icp_refined", 1e-5, 3e-5)])
def test_each_method_registers_a_shifted_model_back_to_its_pose(method, tol_m, tol_deg):
    """The frame is the model's own points (sampled at 1 cm: every point kept) seen from a pose
    5 cm / 4 cm / 0.05 deg from the prediction. kiss-icp stops when its step falls below 1e-4
    (its convergence criterion): it lands within a millimetre; the point-to-plane ICP exactly
    (over this test's structure seeds 0-3: kiss-icp alone 0.2-0.7 mm and 0.8-1.6 mdeg off, the
    others at most 1e-6 m and 1.1e-5 deg)."""
    cfg = RegistrationConfig(method=method, icp_sample_m=0.01)
    structure_map = _structure(np.random.default_rng(3))
    T_level_map0 = pose_matrix(0.0, 0.0, -45.0, 0.0, 0.0, 0.0)
    model = FeederModel(cfg)
    model.set_keyframe(transform(T_level_map0, structure_map), inverse(T_level_map0))
    truth = np.array([0.21, -0.13, -44.6, 0.004, -0.006, math.radians(0.3)])
    frame_level = transform(pose_matrix(*truth), structure_map)
    guess = truth + [0.05, -0.04, 0.01, 0.001, -0.001, math.radians(0.05)]
    reg = model.register(frame_level, inverse(pose_matrix(*guess)), prior_sigma_m=0.05)
    assert reg.status == "ok" and reg.fitness == 1.0 and reg.kiss == (method != "point_to_plane")
    err = pose_vector(inverse(reg.T_map_level)) - truth
    assert np.abs(err[:3]).max() < tol_m, err
    assert np.degrees(np.abs(err[3:])).max() < tol_deg, err
    # the information is the point-to-plane residuals' about the solution, whichever method found it
    assert np.all(np.linalg.eigvalsh(reg.info6) > 0)
    assert reg.info6[0, 0] > 3e4 and reg.info6[1, 1] > 3e4  # 6.1e4 and 1.3e5


def test_point_to_plane_is_unchanged_by_the_kiss_settings():
    """The default method ignores the per-frame kiss-icp settings: the same pose bit for bit."""
    structure_map = _structure(np.random.default_rng(5))
    T_level_map0 = pose_matrix(0.0, 0.0, -45.0, 0.0, 0.0, 0.0)
    truth = np.array([0.1, 0.05, -44.8, 0.0, 0.002, math.radians(-0.2)])
    frame_level = transform(pose_matrix(*truth), structure_map)
    poses = []
    for cfg in (RegistrationConfig(), RegistrationConfig(kiss_max_correspondence_m=0.3, kiss_kernel_m=0.02)):
        model = FeederModel(cfg)
        model.set_keyframe(transform(T_level_map0, structure_map), inverse(T_level_map0))
        poses.append(model.register(frame_level, inverse(pose_matrix(*(truth + [0.03, 0.02, 0, 0, 0, 0]))), 0.05).T_map_level)
    assert np.array_equal(poses[0], poses[1])
