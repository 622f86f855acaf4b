"""Tests for perception.preprocess (cleaning, cropping, voxel / random downsampling, outliers)."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.perception.multi_plane import MultiPlaneConfig, multi_plane_deck
from boomtip.perception.preprocess import (
    PreprocessConfig,
    open3d_baseline_multi_plane,
    open3d_baseline_preprocess,
    preprocess,
    statistical_outlier_mask,
    voxel_downsample,
)


def deck_cloud(rng, n=20000, z=-40.0, noise=0.02):
    return np.column_stack([rng.uniform(-30, 30, n), rng.uniform(-10, 10, n), z + rng.normal(0, noise, n)])


def voxel_keys(p: np.ndarray, origin: np.ndarray, v: float) -> np.ndarray:
    return np.floor((p - origin) / v).astype(np.int64)


def test_invalid_points_removed_before_voxelisation():
    rng = np.random.default_rng(40)
    pts = deck_cloud(rng)
    bad = rng.choice(len(pts), 300, replace=False)
    pts[bad[:100], 0] = np.nan
    pts[bad[100:150], 2] = np.inf
    pts[bad[150:200], 1] = -np.inf
    pts[bad[200:]] = 0.0  # no-return points
    label = np.arange(len(pts))
    cfg = PreprocessConfig(voxel_size_m=0.5)
    out, attrs, stats = preprocess(pts, {"label": label}, cfg)
    assert stats["input"] == 20000 and stats["finite"] == 19700
    assert np.all(np.isfinite(out)) and np.all(np.linalg.norm(out, axis=1) > 0)
    assert not np.isin(attrs["label"], bad).any()
    # same result as voxelising the clean points only
    good = np.setdiff1d(np.arange(len(pts)), bad)
    ref, rep = voxel_downsample(pts[good], 0.5)
    assert np.allclose(out, ref) and np.array_equal(attrs["label"], good[rep])
    # the failure the cleaning prevents: NaN in the voxel keys merges everything into garbage
    with np.errstate(invalid="ignore"):
        poisoned, _ = voxel_downsample(np.nan_to_num(pts, nan=np.nan, posinf=np.nan, neginf=np.nan), 0.5)
    assert not np.all(np.isfinite(poisoned))


@pytest.mark.parametrize("reduce", ["mean", "first"])
def test_voxel_attributes_stay_aligned(reduce):
    rng = np.random.default_rng(41)
    pts = deck_cloud(rng, n=30000)
    v = 0.4
    ids = np.arange(len(pts))
    label = rng.integers(0, 7, len(pts))
    intensity = rng.random(len(pts)).astype(np.float32)
    out, attrs, stats = preprocess(
        pts, {"id": ids, "label": label, "intensity": intensity}, PreprocessConfig(voxel_size_m=v, voxel_reduce=reduce)
    )
    assert stats["voxel"] == len(out) < len(pts)
    src = attrs["id"]
    # the label / intensity of an output point are those of a real input point ...
    assert np.array_equal(attrs["label"], label[src])
    assert np.array_equal(attrs["intensity"], intensity[src]) and attrs["intensity"].dtype == np.float32
    # ... that lies in the same voxel as the output point
    origin = pts.min(axis=0)
    assert np.array_equal(voxel_keys(pts[src], origin, v), voxel_keys(out, origin, v))
    if reduce == "first":
        assert np.array_equal(out, pts[src])
    # one output point per occupied voxel, and each is the centroid of its voxel (mean mode)
    keys_in = voxel_keys(pts, origin, v)
    uniq, inv = np.unique(keys_in, axis=0, return_inverse=True)
    assert len(uniq) == len(out)
    if reduce == "mean":
        inv = inv.reshape(-1)
        cen = np.stack([np.bincount(inv, weights=pts[:, j]) for j in range(3)], 1) / np.bincount(inv)[:, None]
        order = np.lexsort(voxel_keys(out, origin, v).T[::-1])
        assert np.allclose(out[order], cen, atol=1e-9)
    # the representative is the FIRST input point of its voxel, output in first-occurrence order
    assert np.all(np.diff(src) > 0)


def test_empty_and_all_nan_clouds():
    cfg = PreprocessConfig(voxel_size_m=0.2, random_fraction=0.5, outlier_nb_neighbors=8, crop_box_min=(-1, -1, -1), crop_box_max=(1, 1, 1))
    for pts in (np.zeros((0, 3)), np.full((100, 3), np.nan), np.zeros((50, 3))):
        lab = np.arange(len(pts))
        out, attrs, stats = preprocess(pts, {"label": lab}, cfg, np.random.default_rng(0))
        assert out.shape == (0, 3)
        assert attrs["label"].shape == (0,) and attrs["label"].dtype == lab.dtype
        assert stats["outlier"] == 0 and stats["input"] == len(pts)
    out, attrs, stats = preprocess(np.zeros((0, 3)))
    assert out.shape == (0, 3) and attrs == {}
    with pytest.raises(ValueError):
        preprocess(np.zeros((3, 3)), {"x": np.zeros(2)})


def test_range_box_random_crop_keep_alignment():
    rng = np.random.default_rng(42)
    pts = rng.uniform(-50, 50, (40000, 3))
    pts[:5] = [0.1, 0.0, 0.0]  # closer than min_range
    intensity = pts[:, 0] + 2 * pts[:, 1] - pts[:, 2]  # a function of the point: alignment is checkable
    cfg = PreprocessConfig(min_range_m=0.5, max_range_m=60.0, crop_box_min=(-40, -40, -45), crop_box_max=(40, 40, 10), random_fraction=0.25)
    out, attrs, stats = preprocess(pts, {"intensity": intensity}, cfg, np.random.default_rng(1))
    r = np.linalg.norm(out, axis=1)
    assert np.all((r >= 0.5) & (r <= 60.0))
    assert np.all(out >= [-40, -40, -45]) and np.all(out <= [40, 40, 10])
    assert np.array_equal(attrs["intensity"], out[:, 0] + 2 * out[:, 1] - out[:, 2])
    assert stats["random"] == round(0.25 * stats["box"])
    assert stats["finite"] == 40000 and stats["range"] < 40000 and stats["box"] < stats["range"]
    # deterministic with the config seed when no rng is given
    a, _, _ = preprocess(pts, None, cfg)
    b, _, _ = preprocess(pts, None, cfg)
    assert np.array_equal(a, b)


def test_range_crop_returns_the_column_layout_and_aligned_attributes():
    """The range crop alone: the points in input order, as the transpose of a C-contiguous (3, M)
    array (no copy for the column layout), a new array even when every point is kept, and the
    attributes aligned whether points were dropped or not."""
    rng = np.random.default_rng(43)
    pts = rng.uniform(-50, 50, (5000, 3))
    label = np.arange(5000)
    cfg = PreprocessConfig(min_range_m=0.0, max_range_m=1000.0)
    out, attrs, stats = preprocess(pts, {"label": label}, cfg)
    assert np.array_equal(out, pts) and out.T.flags.c_contiguous and not np.shares_memory(out, pts)
    assert np.array_equal(attrs["label"], label) and not np.shares_memory(attrs["label"], label)
    assert stats["finite"] == stats["range"] == 5000
    pts[[3, 10]] = np.nan
    pts[20] = 0.0
    pts[30] = [200.0, 0.0, 0.0]
    cfg = PreprocessConfig(min_range_m=0.5, max_range_m=150.0)
    out, attrs, stats = preprocess(pts, {"label": label}, cfg)
    keep = np.setdiff1d(label, [3, 10, 20, 30])
    assert np.array_equal(out, pts[keep]) and np.array_equal(attrs["label"], keep) and out.T.flags.c_contiguous
    assert stats["finite"] == 4997 and stats["range"] == 4996


def test_statistical_outliers_match_open3d_and_remove_isolated_points():
    rng = np.random.default_rng(43)
    pts = deck_cloud(rng, n=8000)
    far = rng.uniform([-30, -10, -38], [30, 10, -20], (40, 3))  # isolated points above the deck
    cloud = np.vstack([pts, far])
    keep = statistical_outlier_mask(cloud, 16, 2.0)
    assert not keep[-40:].any()
    assert keep[:8000].mean() > 0.95
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
    _, ind = pcd.remove_statistical_outlier(16, 2.0)
    keep_o3d = np.zeros(len(cloud), bool)
    keep_o3d[np.asarray(ind)] = True
    assert np.array_equal(keep, keep_o3d)
    # the statistic as documented, from scipy's k-NN distances: the same points kept
    from scipy.spatial import cKDTree

    mean_d = cKDTree(cloud).query(cloud, k=16)[0].mean(axis=1)
    assert np.array_equal(keep, mean_d < mean_d.mean() + 2.0 * mean_d.std(ddof=1))
    out, _, stats = preprocess(cloud, None, PreprocessConfig(outlier_nb_neighbors=16))
    assert stats["outlier"] == keep.sum()


def test_statistical_outliers_drop_stacks_of_identical_points():
    # nb_neighbors identical returns have a mean neighbour distance of 0: dropped, and left out of
    # the statistic's sums (Open3D's rule)
    rng = np.random.default_rng(45)
    pts = deck_cloud(rng, n=3000)
    stacked = np.vstack([np.repeat(pts[:1], 16, axis=0), pts])
    keep = statistical_outlier_mask(stacked, 16, 2.0)
    from scipy.spatial import cKDTree

    mean_d = cKDTree(stacked).query(stacked, k=16)[0].mean(axis=1)
    judged = mean_d > 0
    assert not judged[:17].any() and judged[17:].all()  # the stack and the point it copies
    # Open3D sums over the others but divides by every point's count
    mu = mean_d[judged].sum() / len(mean_d)
    sd = np.sqrt(((mean_d[judged] - mu) ** 2).sum() / (len(mean_d) - 1))
    assert np.array_equal(keep, judged & (mean_d < mu + 2.0 * sd))
    assert keep[17:].mean() > 0.95
    assert statistical_outlier_mask(pts[:1], 16, 2.0).tolist() == [True]


def test_open3d_baselines_run_and_agree():
    rng = np.random.default_rng(44)
    deck = deck_cloud(rng, n=20000)
    top = np.column_stack([rng.uniform(-10, 0, 6000), rng.uniform(-10, 10, 6000), -35 + rng.normal(0, 0.02, 6000)])
    deck = deck[~((deck[:, 0] >= -10) & (deck[:, 0] < 0))]  # the cargo hides the deck below it
    cloud = np.vstack([deck, top])
    dirty = np.vstack([cloud, np.full((20, 3), np.nan)])
    base = open3d_baseline_preprocess(dirty, 0.3, 16, 2.0)
    ours, _, _ = preprocess(dirty, None, PreprocessConfig(voxel_size_m=0.3, outlier_nb_neighbors=16))
    assert np.all(np.isfinite(base)) and abs(len(base) - len(ours)) < 0.1 * len(ours)
    up = np.array([0.0, 0.0, 1.0])
    res_o3d = open3d_baseline_multi_plane(cloud, up, n_planes=3, threshold=0.06)
    res = multi_plane_deck(cloud, up, MultiPlaneConfig(max_planes=3), np.random.default_rng(0))
    for r in (res_o3d, res):
        assert r is not None
        assert r.deck.plane[2] > 0.999 and r.deck.plane[3] == pytest.approx(40.0, abs=0.01)
        assert any(abs(c.plane[3] - 35.0) < 0.01 for c in r.candidates)  # the cargo top was found too
