"""Simulated LiDAR and radar against exact geometry (data/sensors.py, data/raycast.py,
data/simulator.py). Mirrors document 000 Tables 3.2/3.3 (LiDAR/radar verification): cloud
shape, translation, rotation about the ship's centre, cargo shadows, reflector intensity,
Doppler for translation and rotation, plus the noise/dropout/pattern models.

Poses are recomputed here from the scenario's sinusoids (not via data/motion.py), so the
expected values are independent of the simulator's own kinematics. The mount chain is the
TRUE one (`sim.world`: the surveyed mounts rotated by `world.mismatch`), since the built-in
scenarios' world deviates a little from the installation the source metadata carries;
`test_true_mount_is_the_surveyed_mount_rotated_by_the_mismatch` checks that chain.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy import stats
from scipy.spatial.transform import Rotation

from boomtip.tools.config.scenario import load_scenario
from boomtip.data.sim.world import DOFS
from boomtip.data.sim.scene import Label, build_bodies
from boomtip.data.sim.sensors import (FaceLookup, lidar_pattern, radar_pattern, random_words32, standard_normal32,
                                      word_threshold)
from boomtip.data.sim.simulator import FrameRng, SimScene, Simulation

ALL_ZERO = [f"{ship}.motion.{dof}.amplitude=0" for ship in ("crane", "feeder") for dof in DOFS]
CRANE_LABELS = {int(Label.CRANE_HULL), int(Label.CRANE_DECK), int(Label.CRANE_STRUCTURE)}
FEEDER_LABELS = {int(Label.FEEDER_HULL), int(Label.FEEDER_DECK), int(Label.FEEDER_BULWARK), int(Label.REFLECTOR),
                 int(Label.FALSE_BRIGHT), int(Label.CARGO)}
DECK = int(Label.FEEDER_DECK)


# ---------------------------------------------------------------------------------------
# Fixtures: meshes are built once per module and shared by every SimScene with the same geometry


@pytest.fixture(scope="module")
def bodies_empty():
    return build_bodies(load_scenario("sts-empty"))


@pytest.fixture(scope="module")
def bodies_cargo():
    return build_bodies(load_scenario("sts-empty", ["feeder.cargo=true"]))


def make_sim(bodies, *overrides, base="sts-empty"):
    s = load_scenario(base, ["duration_s=1", *overrides])
    return Simulation(s, SimScene(s, bodies=bodies))


@pytest.fixture(scope="module")
def sim_empty(bodies_empty):
    return make_sim(bodies_empty)


# ---------------------------------------------------------------------------------------
# Independent kinematics


def body_pose(s, ship: str, t: float) -> tuple[np.ndarray, np.ndarray]:
    """R_world_body, p_world_body from the scenario's sinusoids (irregular sea off)."""
    v = getattr(s.world, ship)
    assert not v.irregular.enabled
    q = np.array([getattr(v.motion, d).amplitude * np.sin(2 * np.pi * t / getattr(v.motion, d).period_s
                                                           + np.deg2rad(getattr(v.motion, d).phase_deg)) for d in DOFS])
    rest = np.zeros(3) if ship == "crane" else np.asarray(v.geometry.position_m, float)
    return Rotation.from_euler("xyz", np.deg2rad(q[3:])).as_matrix(), rest + q[:3]


def sensor_pose(sim: Simulation, sensor: str, t: float) -> tuple[np.ndarray, np.ndarray]:
    """The sensor's TRUE world pose at true time t (the mounts as they really are)."""
    R_c, p_c = body_pose(sim.scenario, "crane", t)
    T = sim.world.T_crane_boomtip @ sim.world.T_boomtip_sensor[sensor]
    return R_c @ T[:3, :3], R_c @ T[:3, 3] + p_c


def to_world(sim, sensor, t, p_sensor):
    R, p = sensor_pose(sim, sensor, t)
    return p_sensor @ R.T + p


def to_body(s, ship, t, p_world):
    R, p = body_pose(s, ship, t)
    return (p_world - p) @ R


def deck_plane_world(s, t):
    R, o = body_pose(s, "feeder", t)
    n = R[:, 2]
    return n, -(s.world.feeder.geometry.freeboard_m + n @ o)


def point_velocity_fd(s, ship, t, p_world, h=1e-5):
    """Velocity of the body-fixed points now at p_world, by central difference of their trajectory."""
    p_b = to_body(s, ship, t, p_world)
    def at(tt):
        R, o = body_pose(s, ship, tt)
        return p_b @ R.T + o
    return (at(t + h) - at(t - h)) / (2 * h)


def distance_to_faces(p_body: np.ndarray, body, labels: np.ndarray, pad: float = 0.01) -> np.ndarray:
    """Distance from each point to the nearest face of `body` carrying the point's label."""
    tri_all = body.vertices[body.triangles]
    out = np.full(len(p_body), np.inf)
    for lab in np.unique(labels):
        pm = np.flatnonzero(labels == lab)
        fm = np.flatnonzero(body.face_label == lab)
        if not len(fm):
            continue
        tri = tri_all[fm]
        lo, hi = tri.min(axis=1) - pad, tri.max(axis=1) + pad
        for chunk in np.array_split(pm, max(1, len(pm) // 64)):
            p = p_body[chunk]
            near = np.all((p[:, None] >= lo[None]) & (p[:, None] <= hi[None]), axis=2)
            pi, fi = np.nonzero(near)
            if not len(pi):
                continue
            cp = trimesh.triangles.closest_point(tri[fi], p[pi])
            d = np.linalg.norm(cp - p[pi], axis=1)
            best = np.full(len(chunk), np.inf)
            np.minimum.at(best, pi, d)
            out[chunk] = best
    return out


def mesh_distances(sim, sensor, frame, t_points=None, n_max=150, seed=0):
    """Distance of a subsample of a frame's points to the mesh (and label) they claim to hit.
    t_points: per-point absolute times (motion during sweep); default the frame time."""
    rng = np.random.default_rng(seed)
    lab = frame.fields["label"]
    s = sim.scenario
    bodies = {b.name: b for b in sim.world.bodies}
    dists = []
    for ship, labels in (("crane", CRANE_LABELS), ("feeder", FEEDER_LABELS)):
        idx = np.flatnonzero(np.isin(lab, list(labels)))
        if len(idx) > n_max:
            idx = rng.choice(idx, n_max, replace=False)
        if t_points is None:
            p_b = to_body(s, ship, frame.t_s, to_world(sim, sensor, frame.t_s, frame.points_sensor[idx]))
        else:
            p_b = np.array([to_body(s, ship, tt, to_world(sim, sensor, tt, p[None]))[0]
                            for tt, p in zip(t_points[idx], frame.points_sensor[idx])])
        dists.append(distance_to_faces(p_b, bodies[ship], lab[idx]))
    return np.concatenate(dists)


def ray_index(points_sensor: np.ndarray, pattern) -> np.ndarray:
    """Which pattern ray each point of an ideal (noise-free) frame came from."""
    def azel(d):
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        return np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi), np.arcsin(np.clip(d[:, 2], -1, 1))
    az_p, el_p = azel(pattern.dirs_sensor)
    uaz, iaz_p = np.unique(np.round(az_p, 9), return_inverse=True)
    uel, iel_p = np.unique(np.round(el_p, 9), return_inverse=True)
    table = np.full(len(uaz) * len(uel), -1)
    table[iaz_p * len(uel) + iel_p] = np.arange(len(az_p))
    az, el = azel(points_sensor)
    ia = np.clip(np.searchsorted(uaz, az), 1, len(uaz) - 1)
    ia -= (az - uaz[ia - 1]) < (uaz[ia] - az)
    ie = np.clip(np.searchsorted(uel, el), 1, len(uel) - 1)
    ie -= (el - uel[ie - 1]) < (uel[ie] - el)
    k = table[ia * len(uel) + ie]
    assert np.all(k >= 0)
    dots = np.einsum("ij,ij->i", pattern.dirs_sensor[k], points_sensor / np.linalg.norm(points_sensor, axis=1, keepdims=True))
    assert np.all(dots > 1 - 1e-10), "points do not lie on the pattern's rays"
    return k


def sine(ship, dof, amp, phase_deg=0.0, period=10.0):
    p = f"{ship}.motion.{dof}"
    return [f"{p}.amplitude={amp}", f"{p}.period_s={period}", f"{p}.phase_deg={phase_deg}"]


# ---------------------------------------------------------------------------------------
# Mount and patterns


def test_default_mount_looks_straight_down(sim_empty):
    for sensor, cfg in (("lidar", sim_empty.scenario.installation.lidar), ("radar", sim_empty.scenario.installation.radar)):
        T = sim_empty.meta.T_boomtip_sensor[sensor]
        np.testing.assert_allclose(T[:3, 0], [0, 0, -1], atol=1e-12)  # boresight x down
        np.testing.assert_allclose(abs(T[0, 1]), 1, atol=1e-12)  # y along the ship
        np.testing.assert_allclose(T[:3, 3], cfg.mount.xyz_m)
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)


@pytest.mark.parametrize("sensor", ["lidar", "radar"])
def test_true_mount_is_the_surveyed_mount_rotated_by_the_mismatch(sim_empty, sensor):
    """The world's mount = the surveyed one (the metadata's) rotated about the sensor's own
    axes by `world.mismatch.<sensor>_mount_rpy_deg`; the same translation and boom tip."""
    s = sim_empty.scenario
    error = getattr(s.world.mismatch, f"{sensor}_mount_rpy_deg")
    assert np.any(np.asarray(error) != 0)  # the built-in scenario really deviates
    T_survey, T_true = sim_empty.meta.T_boomtip_sensor[sensor], sim_empty.world.T_boomtip_sensor[sensor]
    np.testing.assert_allclose(T_true[:3, :3], T_survey[:3, :3] @ Rotation.from_euler("xyz", error, degrees=True).as_matrix(),
                               atol=1e-12)
    np.testing.assert_allclose(T_true[:3, 3], T_survey[:3, 3], atol=1e-12)
    np.testing.assert_allclose(sim_empty.world.T_crane_boomtip, sim_empty.meta.T_crane_boomtip, atol=0)
    # the true sensor model keeps the surveyed mount; only the scene's pose chain is true
    np.testing.assert_allclose(getattr(sim_empty.world, sensor).mount.matrix(), T_survey, atol=1e-12)
    # With no mismatch the two agree.
    zero = make_sim(sim_empty.world.bodies, "mismatch={}")
    np.testing.assert_allclose(zero.world.T_boomtip_sensor[sensor], zero.meta.T_boomtip_sensor[sensor], atol=1e-12)


def test_hull_meshes_are_outward_facing(bodies_empty):
    for body in bodies_empty:
        tri = body.vertices[body.triangles]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        for lab in (int(Label.CRANE_DECK), int(Label.FEEDER_DECK)):
            m = body.face_label == lab
            if m.any():
                assert np.all(n[m, 2] > 0.99), f"{body.name}: {lab} faces point down"
        hull_label = int(Label.CRANE_HULL) if body.name == "crane" else int(Label.FEEDER_HULL)
        hull_deck = np.isin(body.face_label, [hull_label, int(Label.CRANE_DECK), int(Label.FEEDER_DECK)])
        mesh = trimesh.Trimesh(body.vertices, body.triangles[hull_deck], process=True)
        hull = max(mesh.split(only_watertight=True), key=lambda c: abs(c.volume))
        assert hull.is_winding_consistent and hull.volume > 0, f"{body.name} hull inside-out"


def test_grid_pattern_covers_the_fov(sim_empty):
    cfg = sim_empty.scenario.installation.lidar
    pat = lidar_pattern(cfg)
    n_az = int(round(cfg.fov_h_deg / cfg.res_h_deg)) + 1
    n_el = int(round(cfg.fov_v_deg / cfg.res_v_deg)) + 1
    assert len(pat.dirs_sensor) == n_az * n_el
    np.testing.assert_allclose(np.linalg.norm(pat.dirs_sensor, axis=1), 1)
    az = np.rad2deg(np.arctan2(pat.dirs_sensor[:, 1], pat.dirs_sensor[:, 0]))
    el = np.rad2deg(np.arcsin(pat.dirs_sensor[:, 2]))
    np.testing.assert_allclose([az.min(), az.max()], [-cfg.fov_h_deg / 2, cfg.fov_h_deg / 2], atol=1e-9)
    np.testing.assert_allclose([el.min(), el.max()], [-cfg.fov_v_deg / 2, cfg.fov_v_deg / 2], atol=1e-9)
    rcfg = sim_empty.scenario.installation.radar
    assert len(radar_pattern(rcfg).dirs_sensor) == (int(round(rcfg.fov_az_deg / rcfg.res_az_deg)) + 1) * (
        int(round(rcfg.fov_el_deg / rcfg.res_el_deg)) + 1)


def test_frame_schedule(sim_empty):
    frames = list(sim_empty)
    s = sim_empty.scenario
    lid = [f for f in frames if f.sensor == "lidar"]
    rad = [f for f in frames if f.sensor == "radar"]
    assert len(lid) == round(s.duration_s * s.installation.lidar.rate_hz) and len(rad) == round(s.duration_s * s.installation.radar.rate_hz)
    assert len(frames) == len(sim_empty)
    np.testing.assert_allclose([f.t_s for f in lid], np.arange(len(lid)) / s.installation.lidar.rate_hz)
    assert [f.index for f in lid] == list(range(len(lid)))
    assert all(a.t_s <= b.t_s for a, b in zip(frames, frames[1:]))
    assert all(f.error is None for f in frames)
    # Stamps are on each sensor's own clock: a frame stamped t shows the scene at true time
    # t - <sensor>_clock_offset_s.
    mm = s.world.mismatch
    for f, offset in ((lid[3], mm.lidar_clock_offset_s), (rad[5], mm.radar_clock_offset_s)):
        assert offset != 0
        cast = sim_empty.lidar_frame if f.sensor == "lidar" else sim_empty.radar_frame
        np.testing.assert_array_equal(cast(f.index, f.t_s - offset).points_sensor, f.points_sensor)
        assert not np.array_equal(cast(f.index, f.t_s).points_sensor, f.points_sensor)


# ---------------------------------------------------------------------------------------
# Cloud shape: points lie on the meshes (Table 3.2/3.3 test 1)


@pytest.mark.parametrize("sensor", ["lidar", "radar"])
@pytest.mark.parametrize("t", [0.0, 0.7])
def test_ideal_points_lie_on_the_meshes(sim_empty, sensor, t):
    f = sim_empty.lidar_frame(3, t) if sensor == "lidar" else sim_empty.radar_frame(3, t)
    lab = f.fields["label"]
    assert len(f) > 100
    assert np.isin(lab, list(CRANE_LABELS | FEEDER_LABELS)).all()
    assert (lab == DECK).sum() > 0.3 * len(f)  # mostly deck, looking down at the feeder
    d = mesh_distances(sim_empty, sensor, f)
    assert len(d) >= min(len(f), 150)
    assert np.max(d) < 1e-3, f"{np.sum(d >= 1e-3)} points off their mesh, worst {np.max(d):.4f} m"


def test_points_off_by_a_pose_error_would_be_detected(sim_empty):
    """Guard on the guard: the mesh check rejects a cloud placed with a slightly wrong pose."""
    f = sim_empty.lidar_frame(0, 0.0)
    shifted = type(f)(f.sensor, f.index, f.t_s, f.points_sensor + [0.05, 0.0, 0.0], f.fields)  # 5 cm along the boresight
    d = mesh_distances(sim_empty, "lidar", shifted)
    assert np.mean(d > 1e-3) > 0.5


def test_deck_points_on_the_analytic_deck_plane(sim_empty):
    t = 0.4
    f = sim_empty.lidar_frame(4, t)
    deck = f.fields["label"] == DECK
    p_w = to_world(sim_empty, "lidar", t, f.points_sensor[deck])
    n, d = deck_plane_world(sim_empty.scenario, t)
    assert np.max(np.abs(p_w @ n + d)) < 1e-3


def test_lambertian_inverse_square_intensity_on_the_deck(sim_empty):
    t = 2.5  # feeder at full roll and pitch: the deck normal is tilted
    f = sim_empty.lidar_frame(25, t)
    deck = f.fields["label"] == DECK
    R, _ = sensor_pose(sim_empty, "lidar", t)
    n, _ = deck_plane_world(sim_empty.scenario, t)
    p = f.points_sensor[deck]
    r = np.linalg.norm(p, axis=1)
    cos_inc = np.abs((p / r[:, None]) @ R.T @ n)
    k = f.fields["intensity"][deck] * r**2 / cos_inc  # reflectivity * reference range^2
    assert np.ptp(k) / np.mean(k) < 1e-4


# ---------------------------------------------------------------------------------------
# Translation (test 3)


@pytest.mark.parametrize("dofs", [("heave",), ("surge", "sway", "heave")])
def test_translated_feeder_moves_its_points_exactly(bodies_empty, dofs):
    amps = {"surge": 3.0, "sway": 2.0, "heave": 2.0}
    ov = ALL_ZERO + [x for d in dofs for x in sine("feeder", d, amps[d], phase_deg=0.0)]
    sim = make_sim(bodies_empty, *ov)
    s = sim.scenario
    t0, t1 = 0.0, 2.5  # translation 0 at t0, full amplitude at t1
    f0, f1 = sim.lidar_frame(0, t0), sim.lidar_frame(25, t1)
    _, o0 = body_pose(s, "feeder", t0)
    _, o1 = body_pose(s, "feeder", t1)
    delta = o1 - o0
    np.testing.assert_allclose(delta, [amps.get(d, 0) if d in dofs else 0 for d in ("surge", "sway", "heave")], atol=1e-12)
    # Deck points: world height follows the heave exactly.
    z0 = to_world(sim, "lidar", t0, f0.points_sensor[f0.fields["label"] == DECK])[:, 2]
    z1 = to_world(sim, "lidar", t1, f1.points_sensor[f1.fields["label"] == DECK])[:, 2]
    deck_z = s.world.feeder.geometry.position_m[2] + s.world.feeder.geometry.freeboard_m
    np.testing.assert_allclose(z0, deck_z, atol=1e-3)
    np.testing.assert_allclose(z1, deck_z + delta[2], atol=1e-3)
    # The same ray hitting the deck in both frames moves along the ray by exactly delta_z in height.
    k0, k1 = ray_index(f0.points_sensor, sim.lidar_pattern), ray_index(f1.points_sensor, sim.lidar_pattern)
    common, i0, i1 = np.intersect1d(k0[f0.fields["label"] == DECK], k1[f1.fields["label"] == DECK], return_indices=True)
    assert len(common) > 1000
    p0 = to_world(sim, "lidar", t0, f0.points_sensor[f0.fields["label"] == DECK][i0])
    p1 = to_world(sim, "lidar", t1, f1.points_sensor[f1.fields["label"] == DECK][i1])
    np.testing.assert_allclose((p1 - p0)[:, 2], delta[2], atol=1e-3)
    # Every feeder point of the moved frame, shifted back by the translation, lies on the
    # feeder mesh at its t0 pose (bulwarks and hull sides pin the horizontal part too).
    lab1 = f1.fields["label"]
    fe = np.isin(lab1, list(FEEDER_LABELS))
    back = to_world(sim, "lidar", t1, f1.points_sensor[fe]) - delta
    R0, _ = body_pose(s, "feeder", t0)
    p_b = (back - o0) @ R0
    body = next(b for b in sim.world.bodies if b.name == "feeder")
    sel = np.random.default_rng(1).choice(len(p_b), min(300, len(p_b)), replace=False)
    d = distance_to_faces(p_b[sel], body, lab1[fe][sel])
    assert np.max(d) < 1e-3
    assert (lab1 == int(Label.FEEDER_BULWARK)).sum() > 20  # vertical surfaces are in view


def test_same_translation_of_both_ships_leaves_the_sensor_cloud_unchanged(bodies_empty):
    ov = ALL_ZERO + sine("feeder", "heave", 2.0, 20) + sine("crane", "heave", 2.0, 20) \
        + sine("feeder", "sway", 1.5, 70, 7.0) + sine("crane", "sway", 1.5, 70, 7.0)
    sim = make_sim(bodies_empty, *ov)
    f0, f1 = sim.lidar_frame(0, 0.0), sim.lidar_frame(1, 3.1)
    assert len(f0) == len(f1)
    k0, k1 = ray_index(f0.points_sensor, sim.lidar_pattern), ray_index(f1.points_sensor, sim.lidar_pattern)
    np.testing.assert_array_equal(k0, k1)
    np.testing.assert_allclose(f1.points_sensor, f0.points_sensor, atol=1e-3)
    np.testing.assert_array_equal(f1.fields["label"], f0.fields["label"])


# ---------------------------------------------------------------------------------------
# Rotation about the ship's centre (test 4)


@pytest.mark.parametrize("dof, amp", [("yaw", 6.0), ("roll", 3.0), ("pitch", 3.0)])
def test_rotated_feeder_cloud_rotates_about_its_centre(bodies_empty, dof, amp):
    sim = make_sim(bodies_empty, *ALL_ZERO, *sine("feeder", dof, amp, phase_deg=90.0))
    s = sim.scenario
    t = 0.0  # full angle
    R, o = body_pose(s, "feeder", t)
    assert np.rad2deg(Rotation.from_matrix(R).magnitude()) == pytest.approx(amp)
    f = sim.lidar_frame(0, t)
    lab = f.fields["label"]
    fe = np.isin(lab, list(FEEDER_LABELS))
    p_w = to_world(sim, "lidar", t, f.points_sensor[fe])
    sel = np.random.default_rng(2).choice(len(p_w), min(300, len(p_w)), replace=False)
    body = next(b for b in sim.world.bodies if b.name == "feeder")
    # Undo the rotation about the feeder's origin: back on the mesh at rest.
    d = distance_to_faces((p_w[sel] - o) @ R, body, lab[fe][sel])
    assert np.max(d) < 1e-3
    # Guard: undoing the same rotation about another centre does not put the points back.
    c = o + [40.0, 15.0, 10.0]
    d_wrong = distance_to_faces((p_w[sel] - c) @ R + c - o, body, lab[fe][sel])
    assert np.sum(d_wrong > 1e-2) >= 5
    # The deck plane fitted to the deck points has the rotated normal and passes through o + R (0, 0, fb).
    pd = p_w[lab[fe] == DECK]
    c = pd.mean(axis=0)
    normal = np.linalg.svd(pd - c, full_matrices=False)[2][-1]
    normal *= np.sign(normal[2])
    assert np.rad2deg(np.arccos(min(1.0, normal @ R[:, 2]))) < 0.01
    assert abs((c - (o + R @ [0, 0, s.world.feeder.geometry.freeboard_m])) @ R[:, 2]) < 1e-3


# ---------------------------------------------------------------------------------------
# Cargo shadows (test 5)


def test_cargo_casts_shadows_on_the_deck(bodies_empty, bodies_cargo):
    t = 0.3
    empty = make_sim(bodies_empty)
    loaded = make_sim(bodies_cargo, "feeder.cargo=true")
    fe, fl = empty.lidar_frame(3, t), loaded.lidar_frame(3, t)
    ke, kl = ray_index(fe.points_sensor, empty.lidar_pattern), ray_index(fl.points_sensor, loaded.lidar_pattern)
    lab_e = dict(zip(ke, fe.fields["label"]))
    lab_l = dict(zip(kl, fl.fields["label"]))
    deck_e = {k for k, v in lab_e.items() if v == DECK}
    deck_l = {k for k, v in lab_l.items() if v == DECK}
    assert deck_l <= deck_e, "cargo cannot reveal deck that the empty deck did not show"
    assert len(deck_l) < len(deck_e)
    lost = np.array(sorted(deck_e - deck_l))
    assert all(lab_l.get(k) in (int(Label.CARGO), None) for k in lost)  # now cargo (or nothing)
    # Rays now stopped by cargo stop short of where they met the deck.
    r_e = dict(zip(ke, np.linalg.norm(fe.points_sensor, axis=1)))
    r_l = dict(zip(kl, np.linalg.norm(fl.points_sensor, axis=1)))
    on_cargo = [k for k in lost if lab_l.get(k) == int(Label.CARGO)]
    assert len(on_cargo) > 100
    assert all(r_l[k] < r_e[k] - 0.01 for k in on_cargo)
    # A true shadow: some of the deck points that vanished are NOT under the cargo's footprint
    # (a vertical ray up from them misses the cargo), i.e. they are hidden behind it.
    cargo = next(b for b in loaded.world.bodies if b.name == "feeder")
    cm = cargo.face_label == int(Label.CARGO)
    cargo_mesh = trimesh.Trimesh(cargo.vertices, cargo.triangles[cm], process=False)
    row = {k: i for i, k in enumerate(ke)}
    p_deck_b = to_body(empty.scenario, "feeder", t,
                       to_world(empty, "lidar", t, fe.points_sensor[[row[k] for k in on_cargo]]))
    origins = p_deck_b - [0, 0, 0.01]
    under = cargo_mesh.ray.intersects_any(origins, np.tile([0.0, 0.0, 1.0], (len(origins), 1)))
    assert (~under).sum() > 50, "no deck point is hidden outside the cargo footprint: no shadow"
    # The shadow lies beyond the cargo, seen from the sensor: farther out horizontally.
    _, p_s = sensor_pose(empty, "lidar", t)
    shadow_w = to_world(empty, "lidar", t, fe.points_sensor[[row[k] for k, u in zip(on_cargo, under) if not u]])
    cargo_w = to_world(loaded, "lidar", t, fl.points_sensor[fl.fields["label"] == int(Label.CARGO)])
    horiz = lambda p: np.linalg.norm((p - p_s)[:, :2], axis=1)
    assert np.median(horiz(shadow_w)) > np.percentile(horiz(cargo_w), 10)


# ---------------------------------------------------------------------------------------
# Reflector intensity (test 6)


def reflector_check(sim, idx, t):
    f = sim.lidar_frame(idx, t)
    lab, inten = f.fields["label"], f.fields["intensity"]
    r = np.linalg.norm(f.points_sensor, axis=1)
    refl = np.flatnonzero(lab == int(Label.REFLECTOR))
    deck = lab == DECK
    assert len(refl) > 20
    p99 = np.array([np.percentile(inten[deck & (np.abs(r - r[i]) < 2.0)], 99) for i in refl])
    z_body = to_body(sim.scenario, "feeder", t, to_world(sim, "lidar", t, f.points_sensor[refl]))[:, 2]
    return f, refl, inten[refl], p99, z_body


def test_reflector_patch_tops_are_the_brightest_returns(sim_empty):
    """Points on the top face of a marker (its retro-reflective surface) outshine the deck."""
    fb = sim_empty.scenario.world.feeder.geometry.freeboard_m
    for idx in range(0, 10, 3):
        f, refl, i_refl, p99, z_body = reflector_check(sim_empty, idx, idx / 10)
        top = z_body > fb + 0.0015  # patches are 2 mm proud of the deck
        assert top.sum() > 20
        assert np.all(i_refl[top] > p99[top])
        # retro-reflection: near normal incidence a marker outshines the deck by an order of magnitude
        t = idx / 10
        R, p_s = sensor_pose(sim_empty, "lidar", t)
        n, _ = deck_plane_world(sim_empty.scenario, t)
        p = f.points_sensor[refl]
        inc = np.rad2deg(np.arccos(np.abs((p / np.linalg.norm(p, axis=1, keepdims=True)) @ R.T @ n)))
        near_normal = top & (inc < 15)
        assert near_normal.sum() > 5
        assert np.all(i_refl[near_normal] > 10 * p99[near_normal])
        # and overall: the brightest returns in the frame are reflectors
        lab, inten = f.fields["label"], f.fields["intensity"]
        brightest = np.argsort(inten)[-len(refl) // 2:]
        assert np.all(lab[brightest] == int(Label.REFLECTOR))


def test_every_reflector_point_outshines_the_deck_at_comparable_range(sim_empty):
    for idx in range(10):
        _, refl, i_refl, p99, z_body = reflector_check(sim_empty, idx, idx / 10)
        bad = i_refl <= p99
        assert not bad.any(), (f"frame {idx}: {bad.sum()} reflector point(s) not brighter than the deck, "
                               f"at body z {z_body[bad]} (side walls of the 2 mm patch)")


# ---------------------------------------------------------------------------------------
# Radar Doppler (test 6 of Table 3.3, which failed in document 000's MATLAB toolbox)


def expected_range_rate(sim, frame):
    """b . (v_hit - v_sensor), both velocities from finite differences of the body-fixed
    points' trajectories (independent of the simulator's twist)."""
    s, t = sim.scenario, frame.t_s
    p_s_sensor = frame.points_sensor
    p_w = to_world(sim, "radar", t, p_s_sensor)
    _, p_sensor = sensor_pose(sim, "radar", t)
    b = (p_w - p_sensor) / np.linalg.norm(p_w - p_sensor, axis=1, keepdims=True)
    lab = frame.fields["label"]
    v_hit = np.zeros_like(p_w)
    fe = np.isin(lab, list(FEEDER_LABELS))
    cr = np.isin(lab, list(CRANE_LABELS))
    v_hit[fe] = point_velocity_fd(s, "feeder", t, p_w[fe])
    v_hit[cr] = point_velocity_fd(s, "crane", t, p_w[cr])
    v_sensor = point_velocity_fd(s, "crane", t, p_sensor[None])[0]
    return np.einsum("ij,ij->i", b, v_hit - v_sensor), p_w, b, v_sensor


def truth_range_rate(sim, frame, p_w, b, v_sensor):
    """The same from the truth twist: v_hit = v_o + w x (p - o)."""
    tr = sim.truth
    t = frame.t_s
    col = lambda name: float(tr.at(f"feeder_{name}", t))
    v_o = np.array([col("vx"), col("vy"), col("vz")])
    w = np.array([col("wx"), col("wy"), col("wz")])
    o = np.array([col("x"), col("y"), col("z")])
    v_hit = v_o + np.cross(w, p_w - o)
    return np.einsum("ij,ij->i", b, v_hit - v_sensor), w


@pytest.mark.parametrize(
    "case, overrides",
    [
        ("translation", ALL_ZERO + sine("feeder", "surge", 1.0, 10, 9.0) + sine("feeder", "sway", 1.5, 50, 8.0)
         + sine("feeder", "heave", 2.0, 0, 10.0)),
        ("rotation", ALL_ZERO + sine("feeder", "roll", 4.0, 30, 9.0) + sine("feeder", "pitch", 5.0, 0, 10.0)
         + sine("feeder", "yaw", 6.0, 60, 12.0)),
        ("both ships", sine("feeder", "surge", 1.0, 10, 9.0) + sine("feeder", "yaw", 3.0, 60, 12.0)
         + sine("crane", "yaw", 1.0, 20, 11.0) + sine("crane", "sway", 0.8, 80, 9.0)),
    ],
)
def test_radar_range_rate_is_the_projected_relative_velocity(bodies_empty, case, overrides):
    sim = make_sim(bodies_empty, *overrides)
    frame = sim.radar_frame(5, 0.25)
    rr = frame.fields["range_rate"].astype(float)
    assert len(frame) > 100
    expected, p_w, b, v_sensor = expected_range_rate(sim, frame)
    np.testing.assert_allclose(rr, expected, atol=1e-4)
    if case != "both ships":
        assert np.max(np.abs(v_sensor)) < 1e-12  # crane static
    # the truth twist gives the same for feeder hits
    fe = np.isin(frame.fields["label"], list(FEEDER_LABELS))
    from_truth, w = truth_range_rate(sim, frame, p_w, b, v_sensor)
    np.testing.assert_allclose(rr[fe], from_truth[fe], atol=1e-4)
    assert np.ptp(rr) > 0.01 or np.max(np.abs(rr)) > 0.1  # non-trivial Doppler
    if case == "rotation":
        # the rotational part is really exercised: ignoring w would be wrong by > 1 cm/s
        _, o = body_pose(sim.scenario, "feeder", frame.t_s)
        rot_part = np.einsum("ij,ij->i", b, np.cross(w, p_w - o))
        assert np.max(np.abs(rot_part)) > 0.01


def test_radar_noise_free_reproduces_ranges_exactly(sim_empty):
    cfg = sim_empty.scenario.installation.radar
    assert cfg.range_noise_m == 0 and cfg.azimuth_noise_deg == 0 and cfg.false_alarms_per_scan == 0
    t = 0.55
    f = sim_empty.radar_frame(11, t)
    assert len(f) == len(sim_empty.radar_pattern.dirs_sensor)  # Pd = 1: every beam that hits is reported
    r = f.fields["range"].astype(float)
    np.testing.assert_allclose(np.linalg.norm(f.points_sensor, axis=1), r, rtol=1e-6)
    d = f.points_sensor / r[:, None]
    np.testing.assert_allclose(f.fields["azimuth"], np.arctan2(d[:, 1], d[:, 0]), atol=1e-6)
    np.testing.assert_allclose(f.fields["elevation"], np.arcsin(np.clip(d[:, 2], -1, 1)), atol=1e-6)
    assert np.all(f.fields["label"] != int(Label.NONE))
    # Deck beams: exact ray/plane intersection.
    deck = f.fields["label"] == DECK
    assert deck.sum() > 100
    R, p_s = sensor_pose(sim_empty, "radar", t)
    n, dd = deck_plane_world(sim_empty.scenario, t)
    b_w = d[deck] @ R.T
    r_true = -(n @ p_s + dd) / (b_w @ n)
    np.testing.assert_allclose(r[deck], r_true, atol=1e-3)
    # Same frame twice: identical (seeded per sensor and frame)
    g = sim_empty.radar_frame(11, t)
    np.testing.assert_array_equal(g.points_sensor, f.points_sensor)


def test_radar_noise_and_false_alarms(bodies_empty):
    sim = make_sim(bodies_empty, "radar.range_noise_m=0.2", "radar.range_rate_noise_mps=0.05",
                   "radar.detection_probability=0.8", "radar.false_alarms_per_scan=20")
    ideal = make_sim(bodies_empty)
    n_beams = len(sim.radar_pattern.dirs_sensor)
    real, fa, resid, rr_resid = 0, 0, [], []
    for i in range(10):
        f, g = sim.radar_frame(i, 0.05 * i), ideal.radar_frame(i, 0.05 * i)
        none = f.fields["label"] == int(Label.NONE)
        fa += none.sum()
        real += (~none).sum()
        # no angle noise configured: match detections to the ideal frame's beams by direction
        kf = ray_index(f.points_sensor[~none], sim.radar_pattern)
        kg = ray_index(g.points_sensor, ideal.radar_pattern)
        _, i_f, i_g = np.intersect1d(kf, kg, return_indices=True)
        assert len(i_f) == len(kf)
        resid.append(f.fields["range"][~none][i_f] - g.fields["range"][i_g])
        rr_resid.append(f.fields["range_rate"][~none][i_f] - g.fields["range_rate"][i_g])
    assert real / (10 * n_beams) == pytest.approx(0.8, abs=0.03)
    assert fa / 10 == pytest.approx(20, abs=5)
    assert np.std(np.concatenate(resid)) == pytest.approx(0.2, rel=0.1)
    assert np.std(np.concatenate(rr_resid)) == pytest.approx(0.05, rel=0.1)


# ---------------------------------------------------------------------------------------
# LiDAR noise model


def deck_range_residual(sim, f, t):
    deck = f.fields["label"] == DECK
    p = f.points_sensor[deck]
    r = np.linalg.norm(p, axis=1)
    R, p_s = sensor_pose(sim, "lidar", t)
    n, d = deck_plane_world(sim.scenario, t)
    b_w = (p / r[:, None]) @ R.T
    return r + (n @ p_s + d) / (b_w @ n), f.fields["intensity"][deck]


def test_ideal_lidar_has_no_range_error(sim_empty):
    res, _ = deck_range_residual(sim_empty, sim_empty.lidar_frame(2, 0.2), 0.2)
    assert np.max(np.abs(res)) < 1e-3


def test_lidar_range_noise_statistics(bodies_empty):
    sigma = 0.02
    sim = make_sim(bodies_empty, f"lidar.range_noise_m={sigma}")
    cfg = sim.world.lidar  # the true LiDAR: spec and behaviour (weak-return gain)
    res, inten = [], []
    for i, t in enumerate((0.0, 0.5)):
        r, I = deck_range_residual(sim, sim.lidar_frame(i, t), t)
        res.append(r)
        inten.append(I)
    res, inten = np.concatenate(res), np.concatenate(inten).astype(float)
    assert len(res) > 5000
    std = np.std(res)
    assert 0.5 * sigma * 1.0 <= std <= 1.5 * sigma * cfg.weak_return_noise_gain
    assert abs(np.mean(res)) < 3 * std / np.sqrt(len(res)) + 1e-4  # unbiased
    # Per point: sigma * clip(sqrt(1/I), 1, gain_max) (documented weak-return model)
    gain = np.clip(np.sqrt(1 / inten), 1.0, cfg.weak_return_noise_gain)
    z = res / (sigma * gain)
    assert np.std(z) == pytest.approx(1.0, abs=0.05)
    assert np.mean(np.abs(z) > 4) < 1e-3  # Gaussian tails


def test_lidar_range_quantisation(bodies_empty):
    step = 0.05
    sim = make_sim(bodies_empty, f"lidar.range_resolution_m={step}")
    f = sim.lidar_frame(0, 0.0)
    r = np.linalg.norm(f.points_sensor, axis=1)
    np.testing.assert_allclose(r / step, np.round(r / step), atol=1e-6)
    res, _ = deck_range_residual(sim, f, 0.0)
    assert np.max(np.abs(res)) <= step / 2 + 1e-3


@pytest.mark.parametrize("p", [0.1, 0.3])
def test_lidar_dropout_fraction(bodies_empty, sim_empty, p):
    sim = make_sim(bodies_empty, f"lidar.dropout_probability={p}")
    kept, total = 0, 0
    for i, t in enumerate((0.0, 0.3)):
        full, drop = sim_empty.lidar_frame(i, t), sim.lidar_frame(i, t)
        kf = set(ray_index(full.points_sensor, sim.lidar_pattern))
        kd = set(ray_index(drop.points_sensor, sim.lidar_pattern))
        assert kd <= kf  # dropouts only remove returns
        kept += len(kd)
        total += len(kf)
    assert 1 - kept / total == pytest.approx(p, abs=0.015)


@pytest.mark.parametrize("n", [1, 7, 400_000])
def test_standard_normal32_is_standard_normal_and_seeded(n):
    x = standard_normal32(np.random.default_rng(5), n)
    assert x.dtype == np.float32 and x.shape == (n,)
    np.testing.assert_array_equal(x, standard_normal32(np.random.default_rng(5), n))  # seeded: the same draws
    assert np.all(np.isfinite(x)) and np.max(np.abs(x)) <= np.sqrt(-2 * np.log(2.0 ** -24)) + 1e-5  # float32's tail
    if n > 1000:
        x = x.astype(float)
        assert abs(np.mean(x)) < 5 / np.sqrt(n)
        assert np.std(x) == pytest.approx(1.0, abs=5 / np.sqrt(2 * n))
        assert stats.kstest(x, "norm").pvalue > 1e-3
        assert np.mean(np.abs(x) > 3) == pytest.approx(2 * stats.norm.sf(3), rel=0.1)
        assert abs(np.corrcoef(x[: n // 2], x[n // 2:])[0, 1]) < 5 / np.sqrt(n / 2)  # the cos and sin halves


@pytest.mark.parametrize("n", [1, 7, 200_001])
def test_random_words32_are_uniform_seeded_and_continue_the_stream(n):
    words = random_words32(np.random.default_rng(3), n)
    assert words.dtype == np.uint32 and words.shape == (n,)
    rng = np.random.default_rng(3)
    np.testing.assert_array_equal(words, random_words32(rng, n))  # seeded: the same words
    assert not np.array_equal(random_words32(rng, n), words)  # the next draw goes on
    if n > 1000:
        for p in (0.02, 0.5):  # `word < word_threshold(p)` has probability p
            assert np.mean(words < word_threshold(p)) == pytest.approx(p, abs=5 * np.sqrt(p * (1 - p) / n))
        assert stats.kstest(words / 2.0 ** 32, "uniform").pvalue > 1e-3


@pytest.mark.parametrize("p", [0.0, 2.0 ** -32, 0.25, 1 - 1e-12, 1.0])
def test_word_threshold_is_the_probability_in_words(p):
    t = word_threshold(p)
    assert 0 <= t <= 2 ** 32 and abs(t / 2.0 ** 32 - p) <= 2.0 ** -32
    extremes = np.array([0, 2 ** 32 - 1], dtype=np.uint32)
    np.testing.assert_array_equal(extremes < t, [p > 0, p > 1 - 2.0 ** -32])  # p = 0: never; p = 1: always


def test_intensity_noise_is_relative(bodies_empty, sim_empty):
    sim = make_sim(bodies_empty, "lidar.intensity_noise=0.1")
    f, g = sim.lidar_frame(0, 0.0), sim_empty.lidar_frame(0, 0.0)
    np.testing.assert_allclose(f.points_sensor, g.points_sensor)
    ratio = f.fields["intensity"] / g.fields["intensity"]
    assert np.std(ratio) == pytest.approx(0.1, rel=0.1)
    assert np.mean(ratio) == pytest.approx(1.0, abs=0.01)


# ---------------------------------------------------------------------------------------
# Spinning pattern and motion during the sweep


SPIN = ["lidar.pattern=spinning", "lidar.channels=16", "lidar.columns=512", "lidar.channel_fov_deg=40"]


def test_spinning_pattern_size_and_layout(sim_empty):
    s = load_scenario("sts-empty", SPIN)
    pat = lidar_pattern(s.installation.lidar)
    assert len(pat.dirs_sensor) == 16 * 512
    np.testing.assert_allclose(np.linalg.norm(pat.dirs_sensor, axis=1), 1)
    el = np.rad2deg(np.arcsin(pat.dirs_sensor[:, 2]))
    assert len(np.unique(np.round(el, 9))) == 16
    np.testing.assert_allclose([el.min(), el.max()], [-20, 20], atol=1e-9)
    az = np.mod(np.arctan2(pat.dirs_sensor[:, 1], pat.dirs_sensor[:, 0]), 2 * np.pi)
    assert len(np.unique(np.round(az, 9))) == 512
    assert len(pat.column_time_s) == 512
    assert pat.column_time_s.min() == 0 and pat.column_time_s.max() < 1 / s.installation.lidar.rate_hz


@pytest.mark.parametrize("during", [True, False])
def test_spinning_time_offsets(bodies_empty, during):
    sim = make_sim(bodies_empty, *SPIN, f"lidar.motion_during_sweep={str(during).lower()}")
    rate = sim.scenario.installation.lidar.rate_hz
    f = sim.lidar_frame(2, 0.2)
    assert len(f) > 500
    dt = f.fields["t"].astype(float)
    if not during:
        assert np.all(dt == 0)
        return
    assert dt.min() >= 0 and dt.max() < 1 / rate
    assert dt.max() > 0.8 / rate  # the sweep really spans the frame period
    # one revolution per frame: offset = azimuth / (2 pi rate)
    k = ray_index(f.points_sensor, sim.lidar_pattern)
    az = np.mod(np.arctan2(sim.lidar_pattern.dirs_sensor[k, 1], sim.lidar_pattern.dirs_sensor[k, 0]), 2 * np.pi)
    np.testing.assert_allclose(dt, az / (2 * np.pi * rate), atol=1e-6)


@pytest.mark.parametrize("pattern", [SPIN, ["lidar.sweep_fraction=0.5"]])
def test_motion_during_sweep_points_lie_on_meshes_at_their_own_time(bodies_empty, pattern):
    # Fast motion so that a frame-time-only pose would put points centimetres off.
    ov = [*pattern, "lidar.motion_during_sweep=true", *sine("feeder", "heave", 2.0, 0, 4.0),
          *sine("feeder", "roll", 3.0, 0, 5.0), *sine("crane", "pitch", 2.0, 0, 6.0)]
    sim = make_sim(bodies_empty, *ov)
    cfg = sim.scenario.installation.lidar
    f = sim.lidar_frame(1, 0.1)
    dt = f.fields["t"].astype(float)
    limit = (cfg.sweep_fraction if cfg.pattern == "grid" else 1.0) / cfg.rate_hz
    assert dt.min() >= 0 and dt.max() < limit and dt.max() > 0.5 * limit
    d = mesh_distances(sim, "lidar", f, t_points=f.t_s + dt, n_max=120)
    assert np.max(d) < 1e-3
    d_frozen = mesh_distances(sim, "lidar", f, n_max=120)
    assert np.max(d_frozen) > 1e-2  # without the per-point time it would be wrong


def test_spray_returns_early_and_weakly_from_its_height_band():
    from boomtip.data.meshes import Label

    s = load_scenario("sts-empty", ["duration_s=0.2", "sea.spray.probability=0.2", "sea.spray.height_m=[2, 6]"])
    sim = Simulation(s)
    f = sim.lidar_frame(0, 0.0)
    spray = f.fields["label"] == int(Label.SPRAY)
    assert 0.03 < spray.mean() < 0.2  # 20 % of the rays that reach below the band
    T = sim.world.T_crane_boomtip @ sim.world.T_boomtip_sensor["lidar"]
    st = sim.world.crane_motion.states(np.array([0.0]))
    R_wc, p_wc = st.R[0], st.position_m[0]
    z = (f.points_sensor[spray] @ (R_wc @ T[:3, :3]).T + R_wc @ T[:3, 3] + p_wc)[:, 2]
    assert z.min() >= 2.0 - 0.05 and z.max() <= 6.0 + 0.05  # in the band (range noise aside)
    assert np.median(f.fields["intensity"][spray]) < 0.1 * np.median(f.fields["intensity"][~spray])
    # and with fog the far, weak returns fade out
    fog = Simulation(load_scenario("sts-empty", ["duration_s=0.2", "lidar.extinction_per_km=40"])).lidar_frame(0, 0.0)
    clear = Simulation(load_scenario("sts-empty", ["duration_s=0.2"])).lidar_frame(0, 0.0)
    assert len(fog) < len(clear) and fog.fields["intensity"].max() < clear.fields["intensity"].max()


@pytest.mark.parametrize("window", [(0.5, 300.0), (0.7, 120.7), (0.1, 0.3)])  # exact; lo rounds down; hi rounds up
def test_range_window_compares_float32_ranges_as_their_float64_values(window):
    from boomtip.data.sim.sensors import range_window

    lo, hi = range_window(*window, np.dtype(np.float32))
    assert lo.dtype == hi.dtype == np.float32
    # the float32 values either side of each bound, the bounds themselves, and a miss
    x = np.array([np.nextafter(lo, np.float32(-1)), lo, np.nextafter(lo, np.float32(1)),
                  np.nextafter(hi, np.float32(-1)), hi, np.nextafter(hi, np.float32(1e9)), np.inf], dtype=np.float32)
    wide = x.astype(np.float64)
    np.testing.assert_array_equal((x >= lo) & (x <= hi), (wide >= window[0]) & (wide <= window[1]))
    assert ((x >= lo) & (x <= hi)).tolist() == [False, True, True, True, True, False, False]


def test_signed_reflectivity_marks_the_retro_faces(bodies_empty):
    """The sensor model reads the retro flag from the reflectivity's sign bit: the same
    magnitudes, negative exactly on the retro faces (a zero reflectivity too), and a negative
    reflectivity, which would be read as retro, refused."""
    faces = FaceLookup.from_bodies(bodies_empty)
    signed = faces.reflectivity_signed
    assert faces.retro.any() and not faces.retro.all()
    assert np.array_equal(np.abs(signed), faces.reflectivity)
    assert np.array_equal(np.signbit(signed), faces.retro)
    faces.retro[0], faces.reflectivity[0] = True, 0.0
    del faces.__dict__["reflectivity_signed"]
    assert np.signbit(faces.reflectivity_signed[0])
    faces.reflectivity[1] = -0.5
    del faces.__dict__["reflectivity_signed"]
    with pytest.raises(ValueError, match="negative"):
        faces.reflectivity_signed


@pytest.mark.parametrize("seed", [0, 7, 2**32 - 1, 2**32])
def test_frame_rng_is_default_rng_of_seed_sensor_index(seed):
    """The LiDAR's per-frame generator (`FrameRng`) is `default_rng([seed, sensor, index])`:
    the same state and draws, across blocks of indices, at the ends of the uint32 range and
    (through default_rng itself) beyond it."""
    frame_rng = FrameRng(seed, 1)
    for index in [0, 1, 4095, 4096, 9001, 2**32 - 1, 2**32, 2**40]:
        ref = np.random.default_rng([seed, 1, index])
        rng = frame_rng(index)
        assert rng.bit_generator.state == ref.bit_generator.state
        assert np.array_equal(rng.random(9, dtype=np.float32), ref.random(9, dtype=np.float32))
        assert np.array_equal(rng.standard_normal(3), ref.standard_normal(3))


def test_the_worlds_noise_scale_makes_the_true_noise_a_multiple_of_the_stated():
    from boomtip.data.sim.world import true_lidar, true_radar
    from boomtip.tools.config.scenario import load_scenario

    s = load_scenario("sts-loaded", ["world.mismatch.lidar_noise_scale=2.5", "world.mismatch.radar_noise_scale=3"])
    lidar, radar = true_lidar(s.installation.lidar, s.world), true_radar(s.installation.radar, s.world)
    assert lidar.range_noise_m == 2.5 * s.installation.lidar.range_noise_m > 0
    for n in ("range_noise_m", "azimuth_noise_deg", "elevation_noise_deg", "range_rate_noise_mps"):
        assert getattr(radar, n) == 3 * getattr(s.installation.radar, n)
    assert s.installation.lidar.range_noise_m == load_scenario("sts-loaded").installation.lidar.range_noise_m  # stated: unchanged


def test_an_fmcw_radar_reports_range_rates_wrapped_into_its_unambiguous_band(bodies_empty):
    """installation.radar.unambiguous_range_rate_mps: the world reports every range rate in
    [-v, v), the true one plus a multiple of 2 v; without it the same frame is unwrapped."""
    heave = ALL_ZERO + sine("feeder", "heave", 3.0, 0, 10.0)  # 1.9 m/s at t = 0: beyond 1.25 m/s
    plain = make_sim(bodies_empty, *heave).radar_frame(5, 0.25)
    wrapped = make_sim(bodies_empty, *heave, "radar.unambiguous_range_rate_mps=1.25").radar_frame(5, 0.25)
    true, got = plain.fields["range_rate"].astype(float), wrapped.fields["range_rate"].astype(float)
    assert np.max(np.abs(true)) > 1.5 and np.all((got >= -1.25) & (got < 1.25))
    k = (true - got) / 2.5
    np.testing.assert_allclose(k, np.round(k), atol=1e-5)
    assert np.any(np.round(k) != 0)
