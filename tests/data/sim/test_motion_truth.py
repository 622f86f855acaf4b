"""Ship motion kinematics (data/motion.py) and the closed-form relative heave D, D_dot
(data/truth.py), including document 000 Table 3.6 verification cases 1-7.

Geometry of sts-empty: crane origin at the world origin, boom tip at (10, -40, 52) in the crane
body frame; feeder body origin at (0, -41, 0) (waterline), deck 4 m above it. So at rest
D0 = 52 - 4 = 48 m, and the tip's lever arm over the feeder origin is (10, 1) m.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from boomtip.data.poses import rpy_matrices
from boomtip.data.sim.motion import ShiftedSines, ShipMotion, euler_rates_to_omega_world
from boomtip.tools.config.scenario import load_scenario
from boomtip.data.sim.world import DOFS, IrregularSea, Motion
from boomtip.data.sim.scene import feeder_deck_plane_body
from boomtip.data.sim.scene import build_bodies
from boomtip.data.sim.simulator import SimScene, Simulation
from boomtip.data.sim.truth import plane_to_world, relative_heave, tip_states

PERIOD = 10.0
W = 2 * np.pi / PERIOD
N_PERIODS = 2
RATE = 200.0
ALL_ZERO = [f"{ship}.motion.{dof}.amplitude=0" for ship in ("crane", "feeder") for dof in DOFS]


@pytest.fixture(scope="module")
def bodies():
    """Meshes are irrelevant to the truth: build them once and reuse them in every SimScene."""
    return build_bodies(load_scenario("sts-empty"))


@pytest.fixture
def sim_of(bodies):
    def make(s):
        return Simulation(s, SimScene(s, bodies=bodies))
    return make


@pytest.fixture
def truth(sim_of):
    return lambda *ov, **kw: _truth(sim_of, *ov, **kw)


def _truth(sim_of, *overrides: str, duration: float = N_PERIODS * PERIOD):
    """Truth of sts-empty with every motion switched off, then the given overrides applied.
    Returns t, D, D_dot over exactly N_PERIODS input periods (no end point)."""
    s = load_scenario("sts-empty", ALL_ZERO + [f"duration_s={duration}", f"truth_rate_hz={RATE}", *overrides])
    tr = sim_of(s).truth
    n = int(round(duration * RATE))
    return tr.t_s[:n], tr.columns["D"][:n], tr.columns["D_dot"][:n]


def sine(ship: str, dof: str, amp: float, phase_deg: float = 30.0, period: float = PERIOD) -> list[str]:
    p = f"{ship}.motion.{dof}"
    return [f"{p}.amplitude={amp}", f"{p}.period_s={period}", f"{p}.phase_deg={phase_deg}"]


def harmonic(t, x, w=W):
    """Amplitude and phase of x's component at angular frequency w, as A sin(w t + phase).
    Exact for uniform samples over whole periods."""
    s = 2 * np.mean(x * np.sin(w * t))
    c = 2 * np.mean(x * np.cos(w * t))
    return np.hypot(s, c), np.arctan2(c, s)


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


# ---------------------------------------------------------------------------------------
# Rotational kinematics


def test_euler_rates_to_omega_world_matches_rotation_finite_difference():
    rng = np.random.default_rng(0)
    rpy = rng.uniform([-np.pi, -1.4, -np.pi], [np.pi, 1.4, np.pi], size=(50, 3))
    rates = rng.normal(scale=0.7, size=(50, 3))
    w = euler_rates_to_omega_world(rpy, rates)
    h = 1e-6
    R0 = Rotation.from_euler("xyz", rpy)
    Rp = Rotation.from_euler("xyz", rpy + h * rates)
    Rm = Rotation.from_euler("xyz", rpy - h * rates)
    # Forward form from the brief: R(t+h) R(t)^T ~ exp([w]x h)
    step = Rp * R0.inv()
    err = (Rotation.from_rotvec(w * h).inv() * step).magnitude() / h
    assert np.max(err) < 1e-5
    # Central form, much tighter
    w_fd = (Rp * Rm.inv()).as_rotvec() / (2 * h)
    np.testing.assert_allclose(w, w_fd, atol=1e-8)
    # World axes, not body axes: the body-axes vector differs for these attitudes.
    w_body = np.einsum("kji,kj->ki", R0.as_matrix(), w)
    assert np.max(np.abs(w_body - w_fd)) > 0.1


def test_euler_rates_single_axis():
    z = np.zeros((1, 3))
    for i in range(3):
        rates = np.zeros((1, 3))
        rates[0, i] = 0.3
        w = euler_rates_to_omega_world(z, rates)
        np.testing.assert_allclose(w[0], np.eye(3)[i] * 0.3, atol=1e-15)


def make_motion(seed=3, irregular=False):
    rng = np.random.default_rng(seed)
    spec = {}
    for i, dof in enumerate(DOFS):
        spec[dof] = {"amplitude": float(rng.uniform(0.5, 3.0) if i < 3 else rng.uniform(2, 15)),
                     "period_s": float(rng.uniform(5, 14)), "phase_deg": float(rng.uniform(0, 360))}
    irr = IrregularSea(enabled=irregular, response={d: 0.3 for d in DOFS})
    return ShipMotion(Motion.model_validate(spec), irr, (5.0, -20.0, 1.0), seed=seed)


@pytest.mark.parametrize("irregular", [False, True])
def test_body_states_match_finite_differences(irregular):
    m = make_motion(irregular=irregular)
    t = np.linspace(0.3, 37.0, 40)
    h = 1e-5
    s, sp, sm = m.states(t), m.states(t + h), m.states(t - h)
    np.testing.assert_allclose(s.velocity_mps, (sp.position_m - sm.position_m) / (2 * h), atol=1e-7)
    np.testing.assert_allclose(s.rpy_rate_radps, (sp.rpy_rad - sm.rpy_rad) / (2 * h), atol=1e-7)
    w_fd = (sp.rotation * sm.rotation.inv()).as_rotvec() / (2 * h)
    np.testing.assert_allclose(s.omega_radps, w_fd, atol=1e-7)
    # Velocity of a body-fixed point: v_o + w x (p - o) against the point's own trajectory.
    p_body = np.array([30.0, -8.0, 12.0])
    def point(st):
        return st.rotation.apply(p_body) + st.position_m
    v_fd = (point(sp) - point(sm)) / (2 * h)
    v = np.array([s.point_velocity(point(s)[k], k) for k in range(len(t))])
    np.testing.assert_allclose(v, v_fd, atol=1e-6)
    # Matrices agree with rotation and position
    T = s.matrices()
    np.testing.assert_allclose(T[:, :3, :3], s.rotation.as_matrix())
    np.testing.assert_allclose(T[:, :3, 3], s.position_m)


@pytest.mark.parametrize("irregular", [False, True])
def test_shifted_sines_are_the_bank_at_each_offset(irregular):
    """A sweep's columns by angle addition: the bank's DOFs at t + c to rounding (metres, rad)."""
    bank = make_motion(irregular=irregular).bank
    offsets = np.arange(1024) / 1024 / 10.0
    shifted = ShiftedSines(bank, offsets)
    for t in (0.0, 0.37, 612.9):
        np.testing.assert_allclose(shifted.eval(t), bank.eval(t + offsets), rtol=0, atol=1e-12)


@pytest.mark.parametrize("irregular", [False, True])
def test_bank_at_one_instant_is_its_evaluation_there(irregular):
    """The frame's pose path: one instant's DOFs as `eval` gives them (the same sums, which
    numpy may add in another order over the irregular sea's 65 terms)."""
    bank = make_motion(irregular=irregular).bank
    for t in (0.0, 0.37, 612.9):
        at, direct = bank.at(t), bank.eval(np.array([t]))
        assert at.shape == direct.shape == (1, 6)
        if irregular:
            np.testing.assert_allclose(at, direct, rtol=0, atol=1e-15)
        else:
            assert np.array_equal(at, direct)


def test_rotation_matrices_of_many_instants_are_each_instants():
    rng = np.random.default_rng(5)
    rpy = rng.uniform(-0.4, 0.4, (257, 3))
    R = rpy_matrices(rpy)
    assert R.shape == (257, 3, 3) and R.flags.c_contiguous
    one_by_one = np.concatenate([rpy_matrices(rpy[k:k + 1]) for k in range(len(rpy))])
    np.testing.assert_allclose(R, one_by_one, rtol=0, atol=1e-15)
    np.testing.assert_allclose(R, Rotation.from_euler("xyz", rpy).as_matrix(), rtol=0, atol=1e-15)


@pytest.mark.slow
def test_sweep_poses_are_the_poses_at_the_column_times():
    """The LiDAR's per-column poses from offsets (the frame path) against the poses evaluated
    at each column's time, for both ships and the sensor."""
    s = load_scenario("sts-irregular", ["lidar.pattern=spinning", "lidar.columns=256", "lidar.motion_during_sweep=true"])
    sim = Simulation(s)
    offsets = sim.lidar_pattern.column_time_s
    for t in (0.0, 4.3):
        direct = sim._scene_poses(t + offsets, "lidar")
        shifted = sim._scene_poses(np.array([t]), "lidar", offsets)
        for a, b in zip(direct[:2], shifted[:2]):
            np.testing.assert_allclose(b, a, rtol=0, atol=1e-12)
        for key in (2, 3):
            for a, b in zip(direct[key], shifted[key]):
                assert b.shape == a.shape == (256, *a.shape[1:])
                np.testing.assert_allclose(b, a, rtol=0, atol=1e-12)


def test_ship_motion_is_the_scenario_sinusoid():
    motion = Motion.model_validate({"heave": {"amplitude": 2.0, "period_s": 8.0, "phase_deg": 30},
                                    "pitch": {"amplitude": 3.0, "period_s": 12.0, "phase_deg": -45}})
    m = ShipMotion(motion, IrregularSea(), (1.0, 2.0, 3.0), seed=0)
    t = np.linspace(0, 20, 101)
    st = m.states(t)
    np.testing.assert_allclose(st.position_m[:, 2], 3.0 + 2.0 * np.sin(2 * np.pi * t / 8 + np.deg2rad(30)), atol=1e-12)
    np.testing.assert_allclose(st.position_m[:, :2], np.tile([1.0, 2.0], (len(t), 1)), atol=1e-12)
    np.testing.assert_allclose(st.rpy_rad[:, 1], np.deg2rad(3.0) * np.sin(2 * np.pi * t / 12 + np.deg2rad(-45)), atol=1e-12)
    np.testing.assert_allclose(st.rpy_rad[:, [0, 2]], 0, atol=1e-15)


def test_plane_to_world_contains_transformed_points():
    m = make_motion()
    st = m.states(np.array([1.0, 4.0, 9.0]))
    plane_b = np.array([0.0, 0.0, 1.0, -4.0])
    plane_w = plane_to_world(plane_b, st)
    pts_b = np.array([[0, 0, 4.0], [20, -5, 4.0], [-30, 9, 4.0]])
    for k in range(3):
        p_w = st.rotation[k].apply(pts_b) + st.position_m[k]
        np.testing.assert_allclose(p_w @ plane_w[k, :3] + plane_w[k, 3], 0, atol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(plane_w[k, :3]), 1.0)


# ---------------------------------------------------------------------------------------
# Document 000 Table 3.6, cases 1-7


def test_case1_both_static_D_constant_tip_minus_deck(truth):
    s = load_scenario("sts-empty")
    tip_z = s.installation.crane.geometry.boom_tip_m[2]
    deck_z = s.world.feeder.geometry.position_m[2] + s.world.feeder.geometry.freeboard_m
    _, D, D_dot = truth()
    np.testing.assert_allclose(D, tip_z - deck_z, atol=1e-12)
    np.testing.assert_allclose(D_dot, 0, atol=1e-12)
    _, D2, _ = truth("crane.geometry.boom_tip_m=[10, -40, 60]", "feeder.geometry.freeboard_m=6",
                     "feeder.geometry.position_m=[0, -41, 1.5]")
    np.testing.assert_allclose(D2, 60 - 7.5, atol=1e-12)


@pytest.mark.parametrize("ship, sign", [("feeder", -1.0), ("crane", 1.0)])
def test_case2_3_heave_gives_same_frequency_phase_and_amplitude(truth, ship, sign):
    amp, phase = 1.7, 30.0
    t, D, D_dot = truth(*sine(ship, "heave", amp, phase))
    # Feeder heave up shortens D, crane heave up lengthens it: D = D0 -/+ heave exactly.
    heave = amp * np.sin(W * t + np.deg2rad(phase))
    np.testing.assert_allclose(D, 48.0 + sign * heave, atol=1e-9)
    np.testing.assert_allclose(D_dot, sign * amp * W * np.cos(W * t + np.deg2rad(phase)), atol=1e-9)
    a, ph = harmonic(t, D - D.mean())
    assert a == pytest.approx(amp, rel=1e-9)
    expected_phase = np.deg2rad(phase) + (0 if sign > 0 else np.pi)
    assert abs(wrap(ph - expected_phase)) < 1e-9
    assert D.mean() == pytest.approx(48.0, abs=1e-9)  # offset: the rest distance


@pytest.mark.parametrize("ship", ["feeder", "crane"])
@pytest.mark.parametrize("dof", ["surge", "sway"])
def test_case2_3_surge_sway_leave_D_constant_over_a_level_deck(truth, ship, dof):
    # D is the vertical distance to the (unbounded) deck plane: with the deck level, horizontal
    # translation of either ship cannot change it.
    t, D, D_dot = truth(*sine(ship, dof, 5.0))
    np.testing.assert_allclose(D, 48.0, atol=1e-9)
    np.testing.assert_allclose(D_dot, 0, atol=1e-9)


def feeder_rot_D(dof, angle, lever, fb=4.0, dz=52.0):
    """Exact D for a single feeder roll or pitch over a level-at-rest deck. lever = tip - origin."""
    dx, dy = lever
    if dof == "roll":  # n = Rx e_z = (0, -sin, cos)
        return dz - dy * np.tan(angle) - fb / np.cos(angle)
    return dz + dx * np.tan(angle) - fb / np.cos(angle)  # pitch: n = Ry e_z = (sin, 0, cos)


@pytest.mark.parametrize("dof", ["roll", "pitch"])
def test_case4_feeder_rotation_amplitude_grows_with_lever_arm(truth, dof):
    amp_deg, phase = 2.0, 30.0
    ang = lambda t: np.deg2rad(amp_deg) * np.sin(W * t + np.deg2rad(phase))
    results = {}
    # tip at (10, -40); lever arm (tip - feeder origin) is set by moving the feeder
    for pos in ([0, -41, 0], [-15, -52, 0]):
        lever = (10 - pos[0], -40 - pos[1])
        t, D, D_dot = truth(*sine("feeder", dof, amp_deg, phase), f"feeder.geometry.position_m={pos}")
        np.testing.assert_allclose(D, feeder_rot_D(dof, ang(t), lever), atol=1e-9)
        arm = lever[1] if dof == "roll" else lever[0]
        a, ph = harmonic(t, D - D.mean())
        # linearised: D - D0 = -dy*roll or +dx*pitch, so the amplitude is arm * angle amplitude
        assert a == pytest.approx(abs(arm) * np.deg2rad(amp_deg), rel=2e-3)
        sign = -np.sign(arm) if dof == "roll" else np.sign(arm)
        assert abs(wrap(ph - np.deg2rad(phase) - (0 if sign > 0 else np.pi))) < 1e-6
        # the rest of D's variation is the small second-order term at 2w
        resid = D - D.mean() - a * np.sin(W * t + ph)
        assert np.max(np.abs(resid)) < 5e-3
        results[abs(arm)] = a
    small, big = sorted(results)
    assert results[big] > results[small] * (big / small) * 0.99


@pytest.mark.parametrize("dof", ["roll", "pitch"])
def test_case5_crane_rotation_amplitude_grows_with_lever_arm(truth, dof):
    amp_deg, phase = 1.5, 30.0
    results = {}
    for tip in ([10, -40, 52], [25, -60, 52]):
        t, D, D_dot = truth(*sine("crane", dof, amp_deg, phase), f"crane.geometry.boom_tip_m={tip}")
        a_rad = np.deg2rad(amp_deg) * np.sin(W * t + np.deg2rad(phase))
        if dof == "roll":  # Rx: z' = y sin + z cos
            tip_z = tip[1] * np.sin(a_rad) + tip[2] * np.cos(a_rad)
        else:  # Ry: z' = -x sin + z cos
            tip_z = -tip[0] * np.sin(a_rad) + tip[2] * np.cos(a_rad)
        np.testing.assert_allclose(D, tip_z - 4.0, atol=1e-9)
        arm = tip[1] if dof == "roll" else -tip[0]
        a, ph = harmonic(t, D - D.mean())
        assert a == pytest.approx(abs(arm) * np.deg2rad(amp_deg), rel=1e-3)
        assert abs(wrap(ph - np.deg2rad(phase) - (0 if arm > 0 else np.pi))) < 1e-6
        results[abs(arm)] = a
    small, big = sorted(results)
    assert results[big] > results[small] * (big / small) * 0.99


@pytest.mark.parametrize("dof", ["roll", "pitch"])
def test_case6_feeder_zero_lever_arm(truth, dof):
    amp_deg = 2.5
    # Feeder origin straight below the tip: no first-order term, D varies only by fb (1/cos - 1).
    t, D, _ = truth(*sine("feeder", dof, amp_deg), "feeder.geometry.position_m=[10, -40, 0]")
    a, _ = harmonic(t, D - D.mean())
    assert a < 1e-9
    assert np.ptp(D) <= 4.0 * (1 / np.cos(np.deg2rad(amp_deg)) - 1) + 1e-12
    # Rotation centre in the deck plane straight below the tip: D exactly constant.
    t, D, D_dot = truth(*sine("feeder", dof, amp_deg), "feeder.geometry.position_m=[10, -40, 0]",
                        "feeder.geometry.freeboard_m=1e-9")
    np.testing.assert_allclose(D, 52.0, atol=1e-8)
    np.testing.assert_allclose(D_dot, 0, atol=1e-8)


@pytest.mark.parametrize("dof", ["roll", "pitch"])
def test_case7_crane_zero_lever_arm(truth, dof):
    amp_deg = 2.0
    # Tip straight above the crane's rotation centre: no first-order term.
    t, D, _ = truth(*sine("crane", dof, amp_deg), "crane.geometry.boom_tip_m=[0, 0, 52]")
    a, _ = harmonic(t, D - D.mean())
    assert a < 1e-9
    assert np.ptp(D) <= 52.0 * (1 - np.cos(np.deg2rad(amp_deg))) + 1e-12
    # Tip at the rotation centre itself (deck moved below it): D exactly constant.
    t, D, D_dot = truth(*sine("crane", dof, amp_deg), "crane.geometry.boom_tip_m=[0, 0, 0]",
                        "crane.geometry.waterline_z_m=null", "feeder.geometry.position_m=[0, -1, -60]")
    np.testing.assert_allclose(D, 56.0, atol=1e-9)
    np.testing.assert_allclose(D_dot, 0, atol=1e-9)


@pytest.mark.parametrize("ship", ["feeder", "crane"])
def test_case6_7_yaw_alone_leaves_D_constant(truth, ship):
    # Big yaw and big lever arms: a level deck stays level, the tip keeps its height.
    t, D, D_dot = truth(*sine(ship, "yaw", 25.0), "feeder.geometry.position_m=[-20, -30, 0]")
    np.testing.assert_allclose(D, 48.0, atol=1e-9)
    np.testing.assert_allclose(D_dot, 0, atol=1e-9)


# ---------------------------------------------------------------------------------------
# D_dot is the derivative of D


def all_dofs_scenario(irregular: bool = False):
    rng = np.random.default_rng(11)
    ov = []
    for ship in ("crane", "feeder"):
        for i, dof in enumerate(DOFS):
            amp = rng.uniform(0.5, 2.5) if i < 3 else rng.uniform(1.0, 6.0)
            ov += sine(ship, dof, round(amp, 3), round(rng.uniform(0, 360), 2), round(rng.uniform(6, 13), 3))
    if irregular:
        ov += ["crane.irregular.enabled=true", "feeder.irregular.enabled=true"]
    return load_scenario("sts-empty", ov + ["duration_s=30"])


def heave_at(sim: Simulation, t):
    w, s = sim.world, sim.scenario
    crane, feeder = w.crane_motion.states(t), w.feeder_motion.states(t)
    for dof in range(3):  # every DOF really moves
        assert np.ptp(crane.position_m[:, dof]) > 0 and np.ptp(feeder.rpy_rad[:, dof]) > 0
    p, v = tip_states(crane, np.asarray(s.installation.crane.geometry.boom_tip_m))
    return relative_heave(p, v, feeder_deck_plane_body(s), feeder)


@pytest.mark.parametrize("irregular", [False, True])
def test_D_dot_equals_central_difference_of_D_all_12_dofs(sim_of, irregular):
    sim = sim_of(all_dofs_scenario(irregular))
    t = np.linspace(0.0, 29.0, 300)
    h = 1e-5
    D, D_dot = heave_at(sim, t)
    Dp, _ = heave_at(sim, t + h)
    Dm, _ = heave_at(sim, t - h)
    fd = (Dp - Dm) / (2 * h)
    assert np.max(np.abs(D_dot - fd)) < 1e-5
    assert np.max(np.abs(D_dot)) > 0.5  # the motion is not trivial
    # The truth table the simulator writes is the same function.
    tr = sim.truth
    k = np.arange(0, len(tr.t_s), 97)
    D_tab, Dd_tab = heave_at(sim, tr.t_s[k])
    np.testing.assert_allclose(tr.columns["D"][k], D_tab, atol=1e-12)
    np.testing.assert_allclose(tr.columns["D_dot"][k], Dd_tab, atol=1e-12)


def test_D_dot_exact_relation_with_tip_velocity_field(sim_of):
    """REFERENCE: D_dot = -[n.u - D n.(w x e_z)] / (n.e_z), u = v(p_t) - p_t_dot."""
    sim = sim_of(all_dofs_scenario())
    s, w = sim.scenario, sim.world
    t = np.linspace(0.0, 29.0, 200)
    crane, feeder = w.crane_motion.states(t), w.feeder_motion.states(t)
    p_t, v_t = tip_states(crane, np.asarray(s.installation.crane.geometry.boom_tip_m))
    D, D_dot = relative_heave(p_t, v_t, feeder_deck_plane_body(s), feeder)
    n = plane_to_world(feeder_deck_plane_body(s), feeder)[:, :3]
    u = feeder.velocity_mps + np.cross(feeder.omega_radps, p_t - feeder.position_m) - v_t
    wxez = np.cross(feeder.omega_radps, [0.0, 0.0, 1.0])
    expected = -(np.einsum("ij,ij->i", n, u) - D * np.einsum("ij,ij->i", n, wxez)) / n[:, 2]
    np.testing.assert_allclose(D_dot, expected, atol=1e-10)
    # and the document's approximation -(u.e_z) differs by a periodic cm/s-level error
    err = np.abs(D_dot - (-u[:, 2]))
    assert 1e-3 < err.max() < 1.0


@pytest.mark.parametrize("seed", [0, 1])
def test_irregular_sea_significant_height(seed):
    irr = IrregularSea(enabled=True, hs_m=2.5, tp_s=9.0, n_components=128, response={"heave": 0.8, "pitch": 2.0})
    m = ShipMotion(Motion(), irr, (0.0, 0.0, 0.0), seed=seed)
    a = m.bank.amplitude
    hs_heave = 4 * np.sqrt(np.sum(a[2] ** 2) / 2)
    assert hs_heave == pytest.approx(0.8 * 2.5, rel=0.05)
    assert 4 * np.sqrt(np.sum(a[4] ** 2) / 2) == pytest.approx(np.deg2rad(2.0 * 2.5), rel=0.05)
    np.testing.assert_array_equal(a[[0, 1, 3, 5]], 0)  # DOFs without a response stay still
    # most energy near the peak period
    w = m.bank.omega[2]
    peak = np.abs(w - 2 * np.pi / 9.0) < 0.3 * 2 * np.pi / 9.0
    assert np.sum(a[2][peak] ** 2) > 0.5 * np.sum(a[2] ** 2)
    # reproducible from the seed, different for another seed
    m2 = ShipMotion(Motion(), irr, (0.0, 0.0, 0.0), seed=seed)
    np.testing.assert_array_equal(m2.bank.phase, m.bank.phase)
    assert not np.array_equal(ShipMotion(Motion(), irr, (0.0, 0.0, 0.0), seed=seed + 5).bank.phase, m.bank.phase)
