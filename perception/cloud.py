"""Point input for the stage functions: an (N, 3) numpy array or an Open3D point cloud.

Open3D is not imported here: a cloud of its types means the caller has imported it already, and
numpy-only users do not pay its import time.
"""

from __future__ import annotations

import numpy as np

__all__ = ["as_points"]


def as_points(cloud) -> np.ndarray:
    """The points of ``cloud`` as an (N, 3) float64 array.

    ``cloud``: an (N, 3) array (or anything numpy turns into one), an Open3D legacy
    ``open3d.geometry.PointCloud`` or a tensor ``open3d.t.geometry.PointCloud`` (any dtype or
    device; its ``positions``). A float64 array comes back as is (no copy); Open3D points are
    copied. Empty input gives shape (0, 3). Raises ValueError for anything else, so a stage
    reports a wrong input in its own words instead of failing deep inside numpy.
    """
    if type(cloud) is np.ndarray and cloud.dtype == np.float64 and cloud.ndim == 2 and cloud.shape[1] == 3:
        return cloud  # the usual input, as is: no conversion call (every stage calls this once per frame)
    if type(cloud).__module__.startswith("open3d"):
        cloud = _open3d_points(cloud)
    try:
        pts = np.asarray(cloud, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"points must be an (N, 3) array or an Open3D point cloud, got {type(cloud).__name__}") from e
    if pts.ndim == 2 and pts.shape[1] == 3:
        return pts
    if pts.size == 0:
        return pts.reshape(0, 3)
    raise ValueError(f"points must be an (N, 3) array or an Open3D point cloud, got shape {pts.shape}")


def _open3d_points(cloud) -> np.ndarray:
    import open3d as o3d  # already loaded: the cloud is one of its objects

    if isinstance(cloud, o3d.t.geometry.PointCloud):
        if cloud.is_empty() or "positions" not in cloud.point:
            return np.zeros((0, 3))
        return cloud.point.positions.cpu().numpy().astype(np.float64)  # always a copy
    if isinstance(cloud, o3d.geometry.PointCloud):
        return np.array(cloud.points, dtype=np.float64)
    raise ValueError(f"points must be an (N, 3) array or an Open3D point cloud, got {type(cloud).__name__}")
