"""The library API (boomtip.perception): each stage on the user's own points, given as numpy or as
an Open3D point cloud (legacy or tensor), with nothing but the data; bad input fails in the
stage's own words."""

from __future__ import annotations

import subprocess
import sys
import traceback
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

import boomtip.perception as bp
from boomtip.data.block_model import lower_block_mesh, visible_model_points

PERCEPTION_DIR = Path(bp.__file__).resolve().parent
DECK_Z_M = -40.0
WIRE_DOWN = np.array([0.0, 0.0, -1.0])
TIP = np.zeros(3)


def deck_with_box(seed: int = 7) -> np.ndarray:
    """Sensor frame looking down: 5000 points of a 20 x 20 m deck 40 m below, 500 of a box top
    3 m above it; 1 cm noise."""
    rng = np.random.default_rng(seed)
    deck = np.column_stack([rng.uniform(-10, 10, 5000), rng.uniform(-10, 10, 5000), np.full(5000, DECK_Z_M)])
    box = np.column_stack([rng.uniform(3, 6, 500), rng.uniform(-2, 1, 500), np.full(500, DECK_Z_M + 3.0)])
    pts = np.vstack([deck, box])
    return pts + rng.normal(0.0, 0.01, pts.shape)


def legacy(pts: np.ndarray) -> o3d.geometry.PointCloud:
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))


def tensor(pts: np.ndarray, dtype=np.float32) -> o3d.t.geometry.PointCloud:
    return o3d.t.geometry.PointCloud(o3d.core.Tensor(pts.astype(dtype)))


AS = {"numpy": lambda p: p, "legacy": legacy, "tensor32": tensor, "tensor64": lambda p: tensor(p, np.float64)}


def test_as_points_reads_every_input_type():
    pts = deck_with_box()
    assert bp.as_points(pts) is pts  # float64 (N, 3): no copy
    for kind, make in AS.items():
        out = bp.as_points(make(pts))
        assert out.dtype == np.float64 and out.shape == pts.shape, kind
        assert np.allclose(out, pts, atol=1e-5), kind
    for empty in ([], np.zeros((0, 3)), legacy(np.zeros((0, 3))), o3d.t.geometry.PointCloud()):
        assert bp.as_points(empty).shape == (0, 3)
    for bad in (np.zeros((10, 4)), np.zeros(3), "points", o3d.geometry.TriangleMesh()):
        with pytest.raises(ValueError, match=r"\(N, 3\)"):
            bp.as_points(bad)


@pytest.mark.parametrize("search", ["below", "all"])
def test_deck_from_numpy_and_open3d_gives_the_same_plane_and_D(search):
    pts = deck_with_box()
    cfg = None if search == "below" else bp.DeckConfig(search=search)  # "below": the default
    results = {kind: bp.detect_deck(make(pts), WIRE_DOWN, TIP, cfg) for kind, make in AS.items()}
    ref = results["numpy"]
    for kind, res in results.items():
        assert res.status == "ok", (kind, res.status)
        assert abs(res.D_m - (-DECK_Z_M)) < 0.005, (kind, res.D_m)
        assert res.plane_sensor[2] > 0.9999  # the deck, not the box top: normal up, towards the sensor
        assert np.allclose(res.plane_sensor, ref.plane_sensor, atol=1e-5), kind
        assert res.D_m == pytest.approx(ref.D_m, abs=1e-5)
    # float64 in, float64 out: the same numbers to the last bit, call after call
    assert results["legacy"].D_m == results["tensor64"].D_m == ref.D_m
    assert bp.detect_deck(pts, [0, 0, -1], [0, 0, 0], cfg).D_m == ref.D_m


def test_plane_stages_accept_open3d_clouds():
    pts = deck_with_box()
    up = -WIRE_DOWN
    for kind, make in AS.items():
        cloud = make(pts)
        assert np.allclose(bp.fit_plane_lsq(cloud), bp.fit_plane_lsq(pts), atol=1e-5), kind
        fit = bp.ransac_plane(cloud)
        assert fit is not None and fit.n_inliers > 4900, kind
        assert abs(bp.heave_distance(fit.plane, WIRE_DOWN, TIP) - 40.0) < 0.005
        mp = bp.multi_plane_deck(cloud, up)
        assert mp is not None and mp.deck.n_inliers > 4900, kind
        out, _, stats = bp.preprocess(cloud, cfg=bp.PreprocessConfig(voxel_size_m=0.5))
        assert stats["input"] == len(pts) and 0 < len(out) < len(pts), kind


def test_doppler_rope_and_hook_accept_open3d_clouds():
    rng = np.random.default_rng(3)
    # Doppler: the deck's points as beam directions, range rates of a deck rising at 0.5 m/s.
    pts = deck_with_box()
    u = np.array([0.2, -0.1, 0.5])
    rr = (pts / np.linalg.norm(pts, axis=1, keepdims=True)) @ u + rng.normal(0, 0.01, len(pts))
    for make in AS.values():
        fit = bp.doppler_velocity(make(pts), rr)
        assert fit is not None and np.allclose(fit.velocity_sensor, u, atol=0.005)
    # Rope: the half of its surface facing a sensor beside it, 2-30 m below the tip, straight down.
    rng_rope = np.random.default_rng(0)
    d = rng_rope.uniform(2.0, 30.0, 400)
    ang = rng_rope.uniform(-1.5, 1.5, 400)
    rope = np.column_stack([0.04 * np.cos(ang), 0.04 * np.sin(ang), -d]) + rng_rope.normal(0, 0.005, (400, 3))
    for make in AS.values():
        fix = bp.fit_rope(make(rope), WIRE_DOWN, 0.01, 40.0)
        assert fix.ok and np.arccos(-fix.direction[2]) < 1e-4, (fix.status, fix.direction)
    # Hook: the block's visible top hanging 20 m below the tip.
    block = visible_model_points(lower_block_mesh(4.0), 300) + np.array([0.0, 0.0, -20.0])
    block += rng.normal(0, 0.01, block.shape)
    for make in AS.values():
        det = bp.detect_hook(make(block), np.array([0.1, 0.1, -20.0]), 20.0)
        assert det.ok and np.linalg.norm(det.position_m - [0.0, 0.0, -20.0]) < 0.05, det.status


def _own_failure(call):
    """The stage's result, or its ValueError; a traceback from inside numpy or Open3D fails."""
    try:
        return call()
    except ValueError as e:
        raised_in = Path(traceback.extract_tb(e.__traceback__)[-1].filename).resolve().parent
        assert raised_in == PERCEPTION_DIR, f"{type(e).__name__} from {raised_in}: {e}"
        return e


BAD_CLOUDS = {
    "empty": np.zeros((0, 3)),
    "nan": np.full((200, 3), np.nan),
    "empty legacy": legacy(np.zeros((0, 3))),
    "empty tensor": o3d.t.geometry.PointCloud(),
    "nan tensor": tensor(np.full((200, 3), np.nan)),
}


@pytest.mark.parametrize("kind", list(BAD_CLOUDS))
def test_empty_and_nan_input_fail_in_the_stages_own_words(kind):
    cloud = BAD_CLOUDS[kind]
    n = len(bp.as_points(cloud))
    failed = {
        "preprocess": (lambda: bp.preprocess(cloud), lambda r: len(r[0]) == 0),
        "ransac_plane": (lambda: bp.ransac_plane(cloud), lambda r: r is None),
        "fit_plane_lsq": (lambda: bp.fit_plane_lsq(cloud), lambda r: isinstance(r, ValueError)),
        "multi_plane_deck": (lambda: bp.multi_plane_deck(cloud, -WIRE_DOWN), lambda r: r is None),
        "detect_deck": (lambda: bp.detect_deck(cloud, WIRE_DOWN, TIP), lambda r: r.status != "ok" and np.isnan(r.D_m)),
        "detect_reflectors": (lambda: bp.detect_reflectors(cloud, np.ones(n), WIRE_DOWN, TIP),
                              lambda r: r.status != "ok" and np.isnan(r.D_m)),
        "doppler_velocity": (lambda: bp.doppler_velocity(cloud, np.zeros(n)), lambda r: r is None),
        "fit_rope": (lambda: bp.fit_rope(cloud, WIRE_DOWN, 0.01, 40.0), lambda r: not r.ok),
        "detect_hook": (lambda: bp.detect_hook(cloud, np.array([0.0, 0.0, -20.0]), 20.0),
                        lambda r: not r.has_fix and np.all(np.isnan(r.position_m))),
    }
    for name, (call, is_failure) in failed.items():
        assert is_failure(_own_failure(call)), name
    assert np.isnan(bp.heave_distance(np.full(4, np.nan), WIRE_DOWN, TIP))


def test_wrong_shape_is_the_stages_error():
    for call in (lambda: bp.detect_deck(np.zeros((10, 4)), WIRE_DOWN, TIP),
                 lambda: bp.detect_hook(np.zeros(7), np.array([0.0, 0.0, -20.0]), 20.0),
                 lambda: bp.detect_reflectors(np.zeros((5, 3)), np.ones(4), WIRE_DOWN, TIP)):
        assert isinstance(_own_failure(call), ValueError)


def test_import_is_cheap_and_never_touches_the_simulator():
    """Importing the package loads neither Open3D (only the hook stage needs it) nor, with every
    export resolved, anything of the simulator or the scenario; `preprocess` stays the function
    after its submodule is imported."""
    code = (
        "import sys\n"
        "import boomtip.perception as bp\n"
        "print('open3d' in sys.modules)\n"
        "import boomtip.perception.deck\n"
        "print(callable(bp.preprocess) and not isinstance(bp.preprocess, type(sys)))\n"
        "missing = [n for n in bp.__all__ if getattr(bp, n, None) is None]\n"
        "print(missing)\n"
        "print(sorted(m for m in sys.modules if m.startswith(('boomtip.data.sim', 'boomtip.tools.config.scenario'))))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[:4] == ["False", "True", "[]", "[]"], out


def test_a_prior_keeps_the_deck_from_being_taken_for_the_sea_below_it():
    """A sea that returns echoes is a larger plane 4 m below the deck: the lowest plane is the
    sea; with the reflectors' D as prior the deck is found, and a prior far from every plane
    gives no measurement instead of a wrong one."""
    from boomtip.perception import detect_deck

    rng = np.random.default_rng(5)
    # sensor x looks down (default mount): the deck at x = 40 m (30 x 20 m), the sea at x = 44 m
    deck = np.column_stack([40 + rng.normal(0, 0.01, 3000), rng.uniform(-15, 15, 3000), rng.uniform(-10, 10, 3000)])
    sea = np.column_stack([44 + rng.normal(0, 0.02, 9000), rng.uniform(-60, 60, 9000), rng.uniform(-40, 40, 9000)])
    sea = sea[~((np.abs(sea[:, 1]) < 15) & (np.abs(sea[:, 2]) < 10))]  # the deck hides the sea below it
    pts = np.vstack([deck, sea])
    wire, tip = np.array([1.0, 0.0, 0.0]), np.zeros(3)
    assert abs(detect_deck(pts, wire, tip).D_m - 44.0) < 0.05  # no prior: the lowest, the sea
    res = detect_deck(pts, wire, tip, prior_D_m=40.1)
    assert res.status == "ok" and abs(res.D_m - 40.0) < 0.01
    res = detect_deck(pts, wire, tip, prior_D_m=30.0)
    assert res.status.startswith("no deck plane within") and not np.isfinite(res.D_m)


@pytest.mark.slow
def test_sea_clutter_is_not_taken_for_the_deck(tmp_path):
    from typer.testing import CliRunner

    from boomtip.tools.cli.commands import app

    out = tmp_path / "clutter"
    r = CliRunner().invoke(app, ["run", "-s", "sts-loaded", "--duration", "6", "--set", "sea.clutter=true",
                                 "--set", "sea.clutter_probability=0.5", "--set", "sea.spray.probability=0.1",
                                 "--out", str(out)])
    assert r.exit_code == 0, r.output
    import json

    k = json.loads((out / "kpis.json").read_text())
    assert k["measurements"]["deck_lidar"]["max"] < 0.01 and k["measurements"]["deck_lidar"]["valid_fraction"] > 0.95
    assert k["solutions"]["fused"]["max_D_m"] < 0.01  # was 4.4 m: the sea taken for the deck
