"""Point input of the stages (perception/cloud.py): an (N, 3) array or an Open3D cloud (legacy
or tensor) comes out as (N, 3) float64; a float64 array as is, Open3D points copied; empty input
as (0, 3). as_points converts and never filters: a non-finite point comes through unchanged
(dropping such points is preprocess's first step, as its docstring says)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from boomtip.perception.cloud import as_points
from boomtip.perception.preprocess import preprocess

NON_FINITE = np.array([[np.nan, 1.0, 2.0], [np.inf, -np.inf, 0.0], [1.0, 2.0, 3.0], [0.0, np.nan, -4.5]])


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal element for element, NaN equal to NaN."""
    return a.shape == b.shape and bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))


def test_a_float64_array_is_returned_as_is():
    pts = np.arange(12.0).reshape(4, 3)
    assert as_points(pts) is pts
    fortran = np.asfortranarray(pts)
    assert as_points(fortran) is fortran  # the layout does not matter, only dtype and shape


@pytest.mark.parametrize("dtype", [np.float32, np.int32, np.int64])
def test_other_dtypes_become_float64(dtype):
    pts = np.arange(12).reshape(4, 3).astype(dtype)
    out = as_points(pts)
    assert out.dtype == np.float64 and out.shape == (4, 3)
    assert np.array_equal(out, np.arange(12.0).reshape(4, 3))


def test_nested_lists_are_points():
    out = as_points([[1, 2, 3], [4.5, 5, 6]])
    assert out.dtype == np.float64 and np.array_equal(out, [[1, 2, 3], [4.5, 5, 6]])


@pytest.mark.parametrize("empty", [[], (), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3), np.float32)])
def test_empty_input_is_zero_by_three(empty):
    out = as_points(empty)
    assert out.shape == (0, 3) and out.dtype == np.float64


@pytest.mark.parametrize("bad, says", [
    (np.zeros(3), "got shape (3,)"),
    (np.zeros((4, 2)), "got shape (4, 2)"),
    (np.zeros((2, 3, 1)), "got shape (2, 3, 1)"),
    (None, "got shape ()"),
    ([[1, 2], [3]], "got list"),  # ragged
    ({"x": 1}, "got dict"),
    ("points", "got str"),
])
def test_anything_else_is_a_value_error_naming_it(bad, says):
    with pytest.raises(ValueError) as exc:
        as_points(bad)
    assert str(exc.value).startswith("points must be an (N, 3) array or an Open3D point cloud")
    assert says in str(exc.value)


def test_a_legacy_open3d_cloud_is_copied():
    pts = np.random.default_rng(0).normal(size=(50, 3))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    out = as_points(cloud)
    assert out.dtype == np.float64 and np.array_equal(out, pts)  # float64 both sides: exact
    out[0] = 99.0
    assert np.array_equal(np.asarray(cloud.points)[0], pts[0])  # the cloud is untouched


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_a_tensor_open3d_cloud_is_copied_as_float64(dtype):
    pts = np.random.default_rng(1).normal(size=(50, 3)).astype(dtype)
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(pts))
    out = as_points(cloud)
    assert out.dtype == np.float64 and np.array_equal(out, pts.astype(np.float64))  # float32 widens exactly
    out[0] = 99.0
    assert np.array_equal(cloud.point.positions.numpy()[0], pts[0])


def test_empty_open3d_clouds_are_zero_by_three():
    for cloud in (o3d.geometry.PointCloud(), o3d.t.geometry.PointCloud(),
                  o3d.t.geometry.PointCloud(o3d.core.Tensor(np.zeros((0, 3), np.float32)))):
        out = as_points(cloud)
        assert out.shape == (0, 3) and out.dtype == np.float64


def test_another_open3d_geometry_is_refused():
    with pytest.raises(ValueError, match="got TriangleMesh"):
        as_points(o3d.geometry.TriangleMesh())


# ---------------------------------------------------------------------------------------
# Non-finite points


def test_non_finite_points_pass_through_numpy_unchanged():
    assert as_points(NON_FINITE) is NON_FINITE
    assert _same(as_points(NON_FINITE.astype(np.float32)), NON_FINITE)
    assert _same(as_points(NON_FINITE.tolist()), NON_FINITE)


def test_non_finite_points_pass_through_open3d_unchanged():
    legacy = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(NON_FINITE))
    assert _same(as_points(legacy), NON_FINITE)
    for dtype in (np.float32, np.float64):
        tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(NON_FINITE.astype(dtype)))
        assert _same(as_points(tensor), NON_FINITE)


def test_preprocess_drops_exactly_the_non_finite_points_of_any_input():
    """The documented place for non-finite points: preprocess's first step, whatever the input type."""
    for cloud in (NON_FINITE, o3d.geometry.PointCloud(o3d.utility.Vector3dVector(NON_FINITE)),
                  o3d.t.geometry.PointCloud(o3d.core.Tensor(NON_FINITE.astype(np.float32)))):
        out, _, stats = preprocess(cloud)
        assert stats["input"] == 4 and stats["finite"] == 1
        assert np.array_equal(out, [[1.0, 2.0, 3.0]])
