"""Truth simulation of the crane hook (data/crane_model.py, data/sim/crane_truth.py): physics checks."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from boomtip.data.crane_model import (
    CraneParams,
    JointStates,
    VesselState,
    crane_accelerations,
    hook_relative_kinematics,
    tip_kinematics,
    vessel_rotation,
)
from boomtip.data.sim.crane_joints import CraneJointProfiles, JointMove, JointProfile
from boomtip.data.sim.crane_programmes import HOOK_SCENARIOS
from boomtip.data.sim.crane_truth import crane_truth_chunks, simulate_crane
from boomtip.data.sim.vessel_waves import CallableVesselMotion, StaticVessel, VesselWaves

DEG = math.pi / 180
G_VEC = np.array([0.0, 0.0, -9.81])


def _static(nu=0.3, mu=50 * DEG, l=80.0):
    return CraneJointProfiles.from_moves(nu, mu, l)


def _swing_energy_per_kg(tr):
    """Kinetic + potential energy of the hook per kg, zero when hanging at rest."""
    v2 = (tr.v_hook_world**2).sum(1)
    return 0.5 * v2 + 9.81 * (tr.p_hook_rel_tip[:, 2] + tr.l)


def test_vessel_rotation_convention():
    roll, pitch = 0.03, -0.02
    R = vessel_rotation(roll, pitch)
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    np.testing.assert_allclose(R, Ry @ Rx, atol=1e-15)


def test_joint_profile_trapezoid():
    prof = JointProfile(0.0, [JointMove(t_start_s=1.0, target=2.0, v_max=0.5, a_max=0.25),
                              JointMove(t_start_s=10.0, target=1.9, v_max=0.5, a_max=0.25)])
    t = np.linspace(0, 20, 20001)
    q, qd, qdd = prof.evaluate(t)
    assert q[0] == 0.0 and abs(q[-1] - 1.9) < 1e-12
    assert np.abs(qd).max() <= 0.5 + 1e-12 and np.abs(qdd).max() <= 0.25 + 1e-12
    np.testing.assert_allclose(np.gradient(q, t)[1:-1], qd[1:-1], atol=1e-3)
    # scalar path == vectorised path
    for tt in (0.5, 2.0, 4.0, 6.5, 10.3, 12.0):
        np.testing.assert_allclose(prof.evaluate(tt), [v[int(round(tt * 1000))] for v in (q, qd, qdd)], atol=1e-9)
    with pytest.raises(ValueError):
        JointProfile(0.0, [JointMove(t_start_s=0.0, target=5.0, v_max=0.5, a_max=0.25),
                           JointMove(t_start_s=1.0, target=0.0, v_max=0.5, a_max=0.25)])


def test_pendulum_settles_with_damping():
    P = CraneParams(flexible=False, sway_damping_per_s=0.1)
    tr = simulate_crane(P, _static(), None, 150.0, initial_state=(0.15, 0.0, -0.1, 0.02, 0, 0))
    assert abs(tr.a[-1]) < 1e-4 and abs(tr.b[-1]) < 1e-4
    np.testing.assert_allclose(tr.p_hook_rel_tip[-1], [0, 0, -80.0], atol=0.01)
    # undamped: the swing is about the vertical (mean angle ~ 0 over whole periods)
    tr0 = simulate_crane(CraneParams(flexible=False), _static(), None, 4 * 2 * math.pi * math.sqrt(80 / 9.81),
                         initial_state=(0.1, 0, 0, 0, 0, 0))
    assert abs(tr0.a.mean()) < 2e-3 and np.abs(tr0.a).max() > 0.099


@pytest.mark.parametrize("axis", [0, 2])
def test_small_angle_period(axis):
    l = 50.0
    y0 = [0.0] * 6
    y0[axis] = 0.01
    tr = simulate_crane(CraneParams(flexible=False), _static(l=l), None, 80.0, initial_state=y0)
    ang = tr.a if axis == 0 else tr.b
    s = np.sign(ang)
    idx = np.where(s[:-1] * s[1:] < 0)[0]
    # linear interpolation of the zero crossings
    tz = tr.t[idx] - ang[idx] * (tr.t[idx + 1] - tr.t[idx]) / (ang[idx + 1] - ang[idx])
    period = 2 * np.mean(np.diff(tz))
    expected = 2 * math.pi * math.sqrt(l / 9.81)
    assert abs(period / expected - 1) < 0.005


@pytest.mark.slow
def test_energy_conserved_rigid_rk4():
    """Rigid boom, static vessel and crane, fixed rope: RK4 at 1 kHz conserves the swing energy."""
    tr = simulate_crane(CraneParams(flexible=False), _static(), None, 100.0, method="rk4", dt_s=1e-3,
                        initial_state=(0.2, 0.0, 0.1, 0.03, 0, 0))
    E = _swing_energy_per_kg(tr)
    assert E[0] > 10
    assert np.abs(E - E[0]).max() / E[0] < 1e-6


def test_energy_conserved_flexible_coupled():
    """Hook + boom mass + spring (c_f = 0) on a tilted static vessel: total energy conserved,
    i.e. the closed-form boom/pendulum coupling is a consistent Lagrangian system."""
    P = CraneParams(c_f=0.0)
    tilt = CallableVesselMotion(lambda t: (0.02, 0.0, 0.0) if np.ndim(t) == 0 else (np.full(np.shape(t), 0.02),) + (np.zeros(np.shape(t)),) * 2,
                                lambda t: (-0.01, 0.0, 0.0) if np.ndim(t) == 0 else (np.full(np.shape(t), -0.01),) + (np.zeros(np.shape(t)),) * 2)
    tr = simulate_crane(P, _static(), tilt, 100.0, method="dop853", rtol=1e-11,
                        initial_state=(0.1, 0.0, 0.05, 0.0, 0.002, 0.0))
    g = P.g
    E = (0.5 * P.m_b * (tr.v_tip_world**2).sum(1) + 0.5 * P.m * (tr.v_hook_world**2).sum(1)
         + P.m * g * tr.p_hook_world[:, 2] + P.m_b * g * tr.p_tip_world[:, 2] + 0.5 * P.k_f * tr.nu_f**2)
    E_dyn = 0.5 * P.m * (tr.v_hook_world**2).sum(1).max() + 0.5 * P.k_f * 0.002**2
    assert np.ptp(tr.nu_f) > 1e-3  # the boom really oscillates
    assert np.abs(E - E[0]).max() / E_dyn < 1e-6


@pytest.mark.slow
def test_rigid_is_flexible_with_infinite_stiffness():
    sc = HOOK_SCENARIOS["hook-4"]()
    rigid = simulate_crane(CraneParams(flexible=False), sc.joints, sc.vessel, 40.0)
    # fixed-step RK4 (1 kHz is stable for the ~540 rad/s boom mode; DOP853 would crawl)
    stiff = simulate_crane(CraneParams(k_f=1e16), sc.joints, sc.vessel, 40.0, method="rk4")
    soft = simulate_crane(CraneParams(), sc.joints, sc.vessel, 40.0)
    assert np.abs(stiff.p_hook_world - rigid.p_hook_world).max() < 1e-4
    assert np.abs(stiff.p_tip_world - rigid.p_tip_world).max() < 1e-4
    # the stiff boom keeps a tiny undamped ~86 Hz vibration: velocities agree to 1 mm/s
    assert np.abs(stiff.v_hook_world - rigid.v_hook_world).max() < 1e-3
    assert np.abs(stiff.nu_f).max() < 1e-6  # vs ~4e-3 rad for k_f = 2e11
    assert np.abs(soft.p_tip_world - rigid.p_tip_world).max() > 0.1  # the default boom is not rigid


def test_rope_force_along_rope_and_tip_kinematics():
    """Newton: hook acceleration - g is parallel to the rope; tip velocity = d/dt tip position."""
    sc = HOOK_SCENARIOS["hook-4"]()
    tr = simulate_crane(CraneParams(), sc.joints, sc.vessel, 20.0, initial_state=(0.05, 0, -0.03, 0.01, 0.001, 0))
    dt = tr.t[1] - tr.t[0]
    v_num = np.gradient(tr.p_tip_world, dt, axis=0)
    assert np.abs(v_num[2:-2] - tr.v_tip_world[2:-2]).max() < 1e-3
    a_hook = np.gradient(tr.v_hook_world, dt, axis=0)[5:-5]
    u = (tr.p_hook_rel_tip / np.linalg.norm(tr.p_hook_rel_tip, axis=1)[:, None])[5:-5]
    f = a_hook - G_VEC
    perp = f - (f * u).sum(1)[:, None] * u
    assert np.abs(perp).max() < 1e-4 * np.abs(f).max()


def test_core_uses_same_tip_acceleration_as_kinematics():
    """At a = b = 0 the pendulum equations read a'' = a_tip_x / l, b'' = -a_tip_y / l
    (rigid): the hand-coded rotation in the core agrees with the scipy-based kinematics."""
    rng = np.random.default_rng(3)
    n = 50
    J = JointStates(*(rng.normal(0, 0.3, n) for _ in range(6)), np.full(n, 60.0), rng.normal(0, 0.5, n), rng.normal(0, 0.1, n))
    V = VesselState(*(rng.normal(0, 0.03, n) for _ in range(6)))
    z = np.zeros(n)
    add, bdd, _ = crane_accelerations(CraneParams(flexible=False), z, z, z, z, J, V)
    _, _, a_tip = tip_kinematics(CraneParams(flexible=False), J, V)
    np.testing.assert_allclose(add * 60.0, a_tip[:, 0], atol=1e-9)
    np.testing.assert_allclose(-bdd * 60.0, a_tip[:, 1], atol=1e-9)


def test_vessel_callables_match_waves():
    waves = VesselWaves.regular(1.0, 8.0)
    cb = CallableVesselMotion(lambda t: waves.evaluate(t)[0:3], lambda t: waves.evaluate(t)[3:6])
    t = np.linspace(0, 10, 11)
    np.testing.assert_allclose(np.array(cb.evaluate(t)), np.array(waves.evaluate(t)))
    np.testing.assert_allclose(np.array(cb.evaluate(3.3)), np.array(waves.evaluate(3.3)))
    assert abs(max(waves.evaluate(np.linspace(0, 8, 801)).pitch) - DEG) < 1e-6


def test_scenarios():
    P = CraneParams()
    sc1 = HOOK_SCENARIOS["hook-1"](P)
    assert sc1.duration_s == 700
    j = sc1.joints.evaluate(np.array([0.0, 700.0]))
    np.testing.assert_allclose(j.nu, [90 * DEG, 0.0], atol=1e-12)
    np.testing.assert_allclose(j.mu, [30 * DEG, 60 * DEG], atol=1e-12)
    tip_z0 = P.c[2] + P.h + P.L * math.sin(30 * DEG)
    assert abs(tip_z0 - j.l[0] - 10.0) < 1e-9  # hook starts on the deck
    # slewing finishes before luffing (document 002 5.2.1)
    assert sc1.joints.slew.t_end_s < sc1.joints.luff.t_end_s
    # scenario 3: hanging hook on a straight line at 50 m, constant x, y from -60 to 60
    sc3 = HOOK_SCENARIOS["hook-3"](P)
    t = np.linspace(0, 650, 1301)
    j3 = sc3.joints.evaluate(t)
    p_tip, _, _ = tip_kinematics(P, j3, _zero_vessel(t))
    np.testing.assert_allclose(p_tip[:, 2] - j3.l, 50.0, atol=1e-9)
    np.testing.assert_allclose(p_tip[:, 0], 120.0, atol=1e-9)
    assert abs(p_tip[0, 1] + 60) < 1e-9 and abs(p_tip[-1, 1] - 60) < 1e-9
    np.testing.assert_allclose(np.gradient(j3.nu, t)[1:-1], j3.nu_dot[1:-1], atol=2e-6)
    np.testing.assert_allclose(np.gradient(j3.l_dot, t)[1:-1], j3.l_ddot[1:-1], atol=1e-5)
    # scenario 4: all joints reach their targets
    sc4 = HOOK_SCENARIOS["hook-4"](P)
    j4 = sc4.joints.evaluate(np.array([100.0]))
    np.testing.assert_allclose([j4.nu[0], j4.mu[0], j4.l[0]], [110 * DEG, 20 * DEG, 180.0], atol=1e-9)


def _zero_vessel(t):
    return StaticVessel().evaluate(t)


def test_rk4_and_dop853_agree():
    sc = HOOK_SCENARIOS["hook-2"]()
    a = simulate_crane(CraneParams(), sc.joints, sc.vessel, 15.0, method="rk4")
    b = simulate_crane(CraneParams(), sc.joints, sc.vessel, 15.0, method="dop853")
    assert np.abs(a.p_hook_world - b.p_hook_world).max() < 1e-6
    assert np.abs(a.nu_f - b.nu_f).max() < 1e-8


def test_truth_in_chunks_is_the_whole_runs_truth_bit_for_bit():
    """Chunks of 1.3 s (not a multiple of the solver's steps; the programme's breakpoints at 10 and
    18.9 s fall inside chunks) with the rope stretch and the drag on: every track identical."""
    sc = HOOK_SCENARIOS["hook-2"]()
    kw = dict(rope_ea_n=1.5e11, wind_mps=(6.0, -3.0), drag_area_m2=8.0)
    whole = simulate_crane(CraneParams(), sc.joints, sc.vessel, 20.5, **kw)
    chunks = list(crane_truth_chunks(CraneParams(), sc.joints, sc.vessel, 20.5, chunk_s=1.3, **kw))
    assert [len(c) for c in chunks[:-1]] == [260] * (len(chunks) - 1) and sum(map(len, chunks)) == len(whole) == 4101
    for f in dataclasses.fields(whole):
        v = getattr(whole, f.name)
        if isinstance(v, np.ndarray):
            assert np.array_equal(np.concatenate([getattr(c, f.name) for c in chunks]), v), f.name


# --------------------------------------------------------------------------------------
# The truth beyond the nominal model: rope stretch and wind drag
# --------------------------------------------------------------------------------------
def test_rope_stretch_lengthens_the_pendulum_not_the_encoder():
    P = CraneParams()
    ea = 1e9  # N: m g / EA ~ 1 %
    joints = CraneJointProfiles.from_moves(0.3, 50 * DEG, 80.0, hoist_moves=[(5.0, 60.0)])
    tr = simulate_crane(P, joints, None, 40.0, rope_ea_n=ea)
    s = 1.0 + P.m * P.g / ea
    assert tr.l[0] == 80.0 and abs(tr.l[-1] - 60.0) < 1e-9  # the hoist programme, as the encoder reads it
    np.testing.assert_allclose(tr.l_rope, tr.l * s, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(tr.p_hook_rel_tip, axis=1), tr.l * s, rtol=1e-6)
    # hanging straight down while hoisting: the hook moves at the stretched rate
    np.testing.assert_allclose(tr.v_hook_rel_tip[:, 2], -tr.l_dot * s, atol=1e-9)


def test_steady_wind_tilts_the_hanging_hook_to_the_drag_angle():
    P = CraneParams(m=1e4, flexible=False)  # a light hook, so the angle is measurable
    wind = (12.0, 9.0)  # 15 m/s
    tr = simulate_crane(P, _static(), None, 400.0, wind_mps=wind, drag_area_m2=20.0)
    f_drag = 0.5 * 1.225 * 1.2 * 20.0 * 15.0**2
    expected = math.atan(f_drag / (P.m * P.g))  # ~1.9 deg
    u = tr.p_hook_rel_tip[-1] / np.linalg.norm(tr.p_hook_rel_tip[-1])
    assert abs(math.acos(-u[2]) / expected - 1) < 0.02  # the drag's own damping has settled the swing
    np.testing.assert_allclose(u[:2] / np.linalg.norm(u[:2]), np.array(wind) / 15.0, atol=1e-3)  # downwind


def test_drag_sees_the_hooks_velocity():
    """With the wind equal to the hook's own horizontal velocity there is no drag: the drag's
    hand-coded tip velocity agrees with the kinematics."""
    from boomtip.data.sim.crane_truth import _accelerations_with_drag

    rng = np.random.default_rng(1)
    n = 40
    J = JointStates(*(rng.normal(0, 0.3, n) for _ in range(6)), rng.uniform(40, 90, n), rng.normal(0, 0.5, n),
                    rng.normal(0, 0.1, n))
    V = VesselState(*(rng.normal(0, 0.03, n) for _ in range(6)))
    a, ad, b, bd, f, fd = (rng.normal(0, s, n) for s in (0.1, 0.05, 0.1, 0.05, 0.003, 0.003))
    P = CraneParams()
    _, v_tip, _ = tip_kinematics(P, J, V, f, fd, 0.0)
    _, rd = hook_relative_kinematics(J.l, J.l_dot, a, ad, b, bd)
    v_hook = v_tip + rd
    args = (np.sin, np.cos, P.as_tuple(), True, a, ad, b, bd, *J, *V, f, fd)
    nominal = crane_accelerations(P, a, ad, b, bd, J, V, f, fd)
    with_drag = _accelerations_with_drag(1e-3, v_hook[:, 0], v_hook[:, 1])(*args)
    for x, y in zip(nominal, with_drag):
        np.testing.assert_allclose(y, x, rtol=0, atol=1e-15)
    moving_air = _accelerations_with_drag(1e-3, v_hook[:, 0] + 5.0, v_hook[:, 1])(*args)
    assert np.all(np.abs(moving_air[0] - nominal[0]) > 0)


@pytest.mark.parametrize("method", ["dop853", "rk4"])
def test_truth_extras_off_by_default(method):
    sc = HOOK_SCENARIOS["hook-4"]()
    base = simulate_crane(CraneParams(), sc.joints, sc.vessel, 6.0, method=method)
    explicit = simulate_crane(CraneParams(), sc.joints, sc.vessel, 6.0, method=method, rope_ea_n=None,
                              wind_mps=(0.0, 0.0), drag_area_m2=0.0, drag_coefficient=1.2, air_density_kgpm3=1.225)
    no_area = simulate_crane(CraneParams(), sc.joints, sc.vessel, 6.0, method=method, wind_mps=(10.0, -4.0))
    for tr in (explicit, no_area):
        for fld in dataclasses.fields(tr):
            v = getattr(base, fld.name)
            if isinstance(v, np.ndarray):
                np.testing.assert_array_equal(getattr(tr, fld.name), v, err_msg=fld.name)
    np.testing.assert_array_equal(base.l_rope, base.l)
