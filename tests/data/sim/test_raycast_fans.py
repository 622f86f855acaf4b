"""Fan casting (data/sim/raycast.py `RayCaster.cast_fans`, `Fans.reaching_box`): the LiDAR's
hits must be those of the per-ray reference (every ray in world axes, moved into every body's
frame at its own column's pose, cast into every body: `tools.bench_raycast.reference_lidar_hits`),
ray by ray: the same body and face, ranges within 1e-4 m; and the box test must never drop a
ray that meets the box."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.tools.config.scenario import load_scenario
from boomtip.data.sim.fans import Fans
from boomtip.data.sim.raycast import Hits
from boomtip.data.sim.sensors import spherical_dirs
from boomtip.data.sim.simulator import Simulation
from boomtip.tools.bench.raycast import SPINNING_128x1024, hits_difference, reference_lidar_hits

SPIN_SMALL = ["lidar.pattern=spinning", "lidar.channels=32", "lidar.columns=256"]


def assert_same_hits(sim, times, fixed):
    for t in times:
        fans, *_ = sim._lidar_hits(t, sim._scene_poses, fixed)
        ref = reference_lidar_hits(sim, t, fixed)
        d = hits_difference(fans, ref)
        assert d["different"] == 0, d
        assert d["max_range_diff_m"] <= 1e-4
        assert np.array_equal(fans.body, ref.body) and np.array_equal(fans.face, ref.face)
        np.testing.assert_allclose(fans.cos_incidence, ref.cos_incidence, atol=1e-6)
        assert fans.hit.sum() > 0.1 * len(fans.range_m)  # the frame really sees the scene
        if fans.flat_face is not None:  # the materials' index, as the sensor model's lookup has it
            hit = ref.body >= 0
            assert np.array_equal(fans.flat_face[hit], sim.world.faces.offset[ref.body[hit]] + ref.face[hit])


@pytest.mark.parametrize("overrides", [
    [],  # document 000's grid, one pose per frame
    ["lidar.motion_during_sweep=true", "lidar.sweep_fraction=0.5"],
    [*SPIN_SMALL, "lidar.motion_during_sweep=true"],
    [*SPIN_SMALL, "lidar.motion_during_sweep=false"],
    ["sea.clutter=true", "lidar.motion_during_sweep=true"],  # a static body (the sea) too
])
def test_fan_hits_are_the_per_ray_reference_hits(overrides):
    sim = Simulation(load_scenario("sts-loaded", ["duration_s=1", *overrides]))
    assert_same_hits(sim, [0.0, 0.37, 2.9], sim._sensor_fixed_hits("lidar"))


@pytest.mark.parametrize("overrides", [[], [*SPIN_SMALL, "lidar.motion_during_sweep=true"]])
def test_fan_hits_without_fixed_hits(overrides):
    """Every body cast, the crane vessel too: the grid's first cast is kept as the best hits,
    the spinning LiDAR's rays are culled per body."""
    sim = Simulation(load_scenario("sts-loaded", ["duration_s=1", *overrides]))
    assert_same_hits(sim, [0.0, 0.61], None)


def test_grid_fixed_hits_give_way_where_a_cast_body_is_nearer():
    """The grid merges the fixed hits into its first cast: where the cast body is nearer it
    wins, elsewhere (ties too) the fixed body does. Fixed hits made up on the crane, half of
    them nearer and half farther than the feeder's hits on the same rays."""
    sim = Simulation(load_scenario("sts-loaded", ["duration_s=1"]))
    cast_all, *_ = sim._lidar_hits(0.37, sim._scene_poses, None)
    on_feeder = np.flatnonzero(cast_all.body == 1)[::7]
    t = np.full(len(cast_all.range_m), np.inf, dtype=np.float32)
    face = np.full(len(t), -1, dtype=np.int64)
    cos = np.zeros(len(t), dtype=np.float32)
    nearer = on_feeder[::2]
    t[on_feeder] = cast_all.range_m[on_feeder] * np.float32(1.5)
    t[nearer] = cast_all.range_m[nearer] * np.float32(0.5)
    face[on_feeder], cos[on_feeder] = 3, 0.25
    fixed = {0: (t, face, cos)}
    hits, *_ = sim._lidar_hits(0.37, sim._scene_poses, fixed)
    assert np.array_equal(hits.body[on_feeder], np.where(np.isin(on_feeder, nearer), 0, 1))
    assert_same_hits(sim, [0.37], fixed)


def test_fan_hits_match_with_stretched_bodies_and_no_fixed_hits():
    """The hook scene: a moving boom carries the sensor, the rope is scaled along its axis."""
    from boomtip.data.sim.hook_world import HookSimulation

    sim = HookSimulation(load_scenario("hook-2", ["duration_s=2", "lidar.channels=32", "lidar.columns=256"]))
    assert any(s is not None for s in sim._scene_poses(np.array([0.5]), "lidar")[4])
    assert_same_hits(sim, [0.5, 1.3], None)


def test_fan_casting_skips_the_rays_that_cannot_reach_the_feeder():
    sim = Simulation(load_scenario("sts-loaded", ["duration_s=1", *SPINNING_128x1024]))
    feeder = sim.world.caster.scenes[1]
    sent = []

    class Counting:  # wraps the feeder's scene to see how many rays it is asked to cast
        def cast_rays(self, rays):
            sent.append(len(rays))
            return feeder.cast_rays(rays)

    sim.world.caster.scenes[1] = Counting()
    hits, *_ = sim._lidar_hits(0.2, sim._scene_poses, sim._sensor_fixed_hits("lidar"))
    on_feeder = int((hits.body == 1).sum())
    assert len(sent) == 1 and on_feeder <= sent[0] < 0.35 * len(hits.range_m)


def slab_hits(lo, hi, o, d):
    """Rays (origin o, directions d, body frame) that meet the box [lo, hi], in float64."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - o) / d, (hi - o) / d
    t_near = np.nanmax(np.minimum(t0, t1), axis=1)
    t_far = np.nanmin(np.maximum(t0, t1), axis=1)
    return t_far >= np.maximum(t_near, 0.0)


@pytest.mark.parametrize("seed", range(6))
def test_reaching_box_keeps_every_ray_that_meets_the_box(seed):
    rng = np.random.default_rng(seed)
    az = np.sort(rng.uniform(-np.pi, np.pi, 90))
    el = np.linspace(-0.6, 0.6, 40)
    az_g, el_g = np.meshgrid(az, el, indexing="ij")
    fans = Fans(spherical_dirs(az_g.ravel(), el_g.ravel()), az, el)
    lo = rng.uniform(-20, 0, 3)
    hi = lo + rng.uniform(0.5, 15, 3)
    meets_any = 0
    for _ in range(20):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        A = q * np.sign(np.linalg.det(q))  # a rotation
        o = rng.uniform(-30, 30, 3)
        kept = np.zeros(len(fans.dirs), dtype=bool)
        ray_k, fan = fans.reaching_box(lo, hi, fans.axes_in(np.eye(3)[None], A[None]), o[None], None)
        assert np.array_equal(fan, ray_k // len(el))
        kept[ray_k] = True
        meets = slab_hits(lo, hi, o, fans.dirs @ A.T)
        assert not np.any(meets & ~kept)
        meets_any += meets.sum()
        if np.all((o >= lo) & (o <= hi)):  # the sensor inside the box: every ray meets it
            assert kept.all()
    assert meets_any > 0


@pytest.mark.parametrize("seed", range(6))
def test_fans_cutting_box_holds_every_ray_that_meets_the_box(seed):
    """The one-pose cast's fan range: every ray meeting the (possibly stretched) box lies in a
    fan within it, and its first and last fans do cut the box."""
    rng = np.random.default_rng(seed)
    span = np.pi * (2 / 3 if seed % 2 else 2)  # a grid's 120 degrees, or a whole turn
    az = np.sort(rng.uniform(-span / 2, span / 2, 120))
    el = np.linspace(-0.3, 0.3, 30)
    az_g, el_g = np.meshgrid(az, el, indexing="ij")
    fans = Fans(spherical_dirs(az_g.ravel(), el_g.ravel()), az, el)
    lo = rng.uniform(-20, 0, 3)
    hi = lo + rng.uniform(0.5, 15, 3)
    corners = np.where(np.arange(8)[:, None] >> np.array([2, 1, 0]) & 1, hi, lo)
    cut_some = 0
    for i in range(30):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        A = q * np.sign(np.linalg.det(q))  # a rotation
        o = rng.uniform(-30, 30, 3)
        scale = rng.uniform(0.5, 2.0, 3) if i % 3 == 0 else None
        fr = fans.fans_cutting_box(corners, A, o, scale)
        s = np.ones(3) if scale is None else scale
        meets = slab_hits(lo, hi, o / s, (fans.dirs @ A.T) / s).reshape(len(az), len(el))
        inside = np.zeros(len(az), dtype=bool)
        inside[fr.start:fr.stop] = True
        assert not np.any(meets.any(axis=1) & ~inside)
        for f in (fr.start, fr.stop - 1) if len(fr) else ():
            n_f = np.array([-np.sin(az[f]), np.cos(az[f]), 0.0])
            g = ((corners * s - o) @ A) @ n_f  # the corners' distances to fan f's plane
            assert g.min() <= 0 <= g.max()
        cut_some += len(fr) > 0
    assert cut_some > 0


def test_grid_casts_only_the_fans_cutting_the_feeder_box():
    sim = Simulation(load_scenario("sts-loaded", ["duration_s=1"]))
    feeder = sim.world.caster.scenes[1]
    sent = []

    class Counting:
        def cast_rays(self, rays):
            sent.append(len(rays))
            return feeder.cast_rays(rays)

    sim.world.caster.scenes[1] = Counting()
    hits, *_ = sim._lidar_hits(0.2, sim._scene_poses, sim._sensor_fixed_hits("lidar"))
    n_el = len(sim.lidar_pattern.fans.el_rad)
    assert len(sent) == 1 and sent[0] % n_el == 0
    assert int((hits.body == 1).sum()) <= sent[0] < 0.9 * len(hits.range_m)



def test_one_pose_rays_of_a_fan_range_are_the_rows_of_every_ray():
    """The rays of the fans cast are, bit for bit, those rows of every ray's rays: a ray does
    not depend on which fans are cast (nor on the buffer's previous content)."""
    rng = np.random.default_rng(5)
    az, el = np.deg2rad(np.linspace(-60, 60, 241)), np.deg2rad(np.linspace(-15, 15, 61))
    az_g, el_g = np.meshgrid(az, el, indexing="ij")
    fans = Fans(spherical_dirs(az_g.ravel(), el_g.ravel()), az, el)
    for _ in range(20):
        A = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        o = rng.uniform(-50, 50, 3)
        every = fans.body_frame_rays_one_pose(A, o).copy()
        assert np.array_equal(every[:, 3:], (A @ fans.dirs.T).T.astype(np.float32))
        assert np.array_equal(every[:, :3], np.broadcast_to(o.astype(np.float32), (len(every), 3)))
        first, stop = sorted(rng.integers(0, len(az) + 1, 2))
        part = fans.body_frame_rays_one_pose(A, o, range(first, stop))
        assert np.array_equal(part, every[first * len(el):stop * len(el)])


def test_reaching_box_per_fan_poses_and_scale():
    """One pose per fan and a stretched body: rays are x_b = S^-1 (A x_s + o) per fan."""
    rng = np.random.default_rng(3)
    az = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    el = np.linspace(-0.4, 0.4, 24)
    az_g, el_g = np.meshgrid(az, el, indexing="ij")
    fans = Fans(spherical_dirs(az_g.ravel(), el_g.ravel()), az, el)
    lo, hi = np.array([-0.5, -0.5, 0.0]), np.array([0.5, 0.5, 1.0])
    angle = np.linspace(0, 0.5, 64)
    A = np.zeros((64, 3, 3))
    A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1], A[:, 2, 2] = np.cos(angle), -np.sin(angle), np.sin(angle), np.cos(angle), 1
    o = np.column_stack([rng.uniform(-4, 4, 64), rng.uniform(-4, 4, 64), np.full(64, -1.0)])
    scale = np.column_stack([np.linspace(3, 9, 64), np.ones(64), np.linspace(2, 8, 64)])
    kept = np.zeros(len(fans.dirs), dtype=bool)
    ray_k, fan = fans.reaching_box(lo, hi, fans.axes_in(np.eye(3)[None], A), o, scale)
    assert np.array_equal(fan, ray_k // len(el))
    kept[ray_k] = True
    fan = np.repeat(np.arange(64), 24)
    d = np.einsum("kij,kj->ki", A[fan], fans.dirs) / scale[fan]
    meets = slab_hits(lo, hi, o[fan] / scale[fan], d)
    assert meets.any() and not np.any(meets & ~kept)
    assert kept.sum() < 0.5 * len(kept)


def test_fans_need_ascending_elevations():
    az, el = np.array([0.0, 1.0]), np.array([0.2, 0.1])
    az_g, el_g = np.meshgrid(az, el, indexing="ij")
    with pytest.raises(ValueError, match="ascending"):
        Fans(spherical_dirs(az_g.ravel(), el_g.ravel()), az, el)


def test_hits_body_and_face_from_the_flat_face_index():
    """Given the flat face index and the bodies' face offsets, a hit's body is the last offset
    at or below it and its face the rest; a miss (inf) reads -1 whatever its index says."""
    offsets = np.array([0, 10, 25])  # bodies of 10, 15 and more faces
    flat = np.array([3, 12, 9, 30, 25, 10, 7], dtype=np.int32)
    range_m = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, np.inf], dtype=np.float32)
    hits = Hits(range_m, None, None, np.zeros(7, dtype=np.float32), flat_face=flat, face_offset=offsets)
    np.testing.assert_array_equal(hits.body, [0, 1, 0, 2, 2, 1, -1])
    np.testing.assert_array_equal(hits.face, [3, 2, 9, 5, 0, 0, -1])
    with pytest.raises(ValueError, match="flat face index"):
        Hits(range_m, None, None, np.zeros(7, dtype=np.float32))


def test_incidence_on_a_stretched_body_is_that_of_its_world_normal():
    """The rope is its mesh stretched along its axis: a hit's |cos| of incidence is that of the
    ray's world direction with the face's world normal (the inverse transpose of the stretch),
    in `cast` and in the fans' cast alike."""
    from boomtip.data.sim.hook_world import HookSimulation

    sim = HookSimulation(load_scenario("hook-2", ["duration_s=2", "lidar.channels=32", "lidar.columns=256"]))
    R_ws, p_ws, Rs, ps, scales = sim._scene_poses(np.array([0.5]), "lidar")
    rope = next(b for b, s in enumerate(scales) if s is not None and np.ptp(s[0]) > 1)  # unequal stretch
    dirs_w = sim.lidar_pattern.dirs_sensor @ R_ws[0].T
    hits = sim.world.caster.cast(p_ws[0], dirs_w, Rs, ps, None, scales, None, want_normals=True)
    on_rope = hits.body == rope
    assert on_rope.sum() > 20
    true_cos = np.abs(np.einsum("ij,ij->i", hits.normal_world[on_rope], dirs_w[on_rope]))
    np.testing.assert_allclose(hits.cos_incidence[on_rope], true_cos, atol=1e-5)
    assert np.ptp(true_cos) > 0.3  # grazing and head-on returns both
    fans, *_ = sim._lidar_hits(0.5, sim._scene_poses, None)
    np.testing.assert_allclose(fans.cos_incidence[on_rope], true_cos, atol=1e-5)
