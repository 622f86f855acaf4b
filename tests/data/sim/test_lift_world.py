"""The lift's world: the programme's checks, the clearance's geometry, and a short lift that
lands: the load hangs on the rope's line, then lies on the deck and moves with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from boomtip.data.frames import LIFT_TRUTH_COLUMNS
from boomtip.data.meshes import Label
from boomtip.data.sim.lift_world import LiftSimulation, clearance_to_deck, height_above_deck
from boomtip.data.poses import rpy_matrices
from boomtip.tools.config.scenario import load_scenario


def test_height_above_a_tilted_deck_is_along_the_vertical():
    R = rpy_matrices(np.array([[0.0, math.radians(5.0), 0.0]]))  # the feeder pitched 5 deg, 1 m up
    p = np.array([[0.0, 0.0, 1.0]])
    q = np.array([[10.0, 0.0, 20.0]])
    h = height_above_deck(q, R, p, 4.0)
    # the deck: n . (x - p) = 4 with n the body's z axis; under x = 10, y = 0 it lies at this z
    n = R[0][:, 2]
    z_deck = 1.0 + (4.0 - 10.0 * n[0]) / n[2]
    assert h[0] == pytest.approx(20.0 - z_deck, abs=1e-12)
    assert abs(z_deck - 5.0) > 0.5  # not the level deck's height: the pitch counts


def test_the_clearance_is_the_lowest_vertex_over_the_deck_and_the_landing_point_the_centre_dropped():
    R = np.eye(3)[None]
    p = np.zeros((1, 3))
    verts = np.array([[[1.0, 2.0, 7.0], [3.0, 2.0, 6.5], [1.0, 4.0, 8.0]]])
    C, land_body, touch = clearance_to_deck(verts, np.array([[2.0, 3.0, 7.0]]), R, p, 4.0)
    assert C[0] == pytest.approx(2.5)
    assert np.allclose(land_body[0], [2.0, 3.0]) and np.allclose(touch[0], [2.0, 3.0, 4.0])


@pytest.mark.parametrize("key, value, words", [
    ("world.lift.program.target_deck_m", "[60.0, 0.0]", "open deck"),
    ("world.lift.program.target_deck_m", "[0.0, 10.5]", "open deck"),
    ("world.lift.load", "box", "world.lift.load_size_m"),
])
def test_a_lift_off_the_deck_or_without_a_size_is_refused_naming_the_key(key, value, words):
    with pytest.raises(Exception, match=words.replace(".", r"\.")):
        LiftSimulation(load_scenario("lift", [f"{key}={value}", "duration_s=2"]))


def test_a_spot_beyond_the_boom_is_refused_naming_the_key():
    with pytest.raises(ValueError, match=r"world\.lift\.program\.target_deck_m.*reach"):
        LiftSimulation(load_scenario("lift", ["installation.crane.geometry.boom_length_m=20", "duration_s=2"]))


@pytest.fixture(scope="module")
def landing():
    """A short lift that starts 3 m above the deck and lowers at once: it lands within the run."""
    return LiftSimulation(load_scenario("lift", [
        "duration_s=30", "world.lift.program.start_clearance_m=3", "world.lift.program.pause_clearance_m=1",
        "world.lift.program.lower_start_s=2", "world.lift.program.wait_s=0", "world.lift.program.approach_slew_deg=0",
        "world.lift.program.approach_luff_deg=0"]))


def test_the_load_hangs_on_the_rope_below_the_block_until_it_lands(landing):
    sim = landing
    t_td, _, _ = sim.touchdown()
    assert 2.0 < t_td < 30.0
    tr = sim.truth.columns
    assert tuple(tr) == LIFT_TRUTH_COLUMNS
    t = np.asarray(tr["t"])
    before = t < t_td - 0.1
    R, p_load = sim.load_pose(t[before])
    r_hook = np.column_stack([tr[f"hook_rel_{a}"][before] for a in "xyz"])
    u = r_hook / np.linalg.norm(r_hook, axis=1, keepdims=True)
    # the load's axis is the rope's line: its underside centre below_hook further down it
    p_tip = np.column_stack([tr[f"tip_{a}"][before] for a in "xyz"]) + sim._vessel_translation(t[before])
    assert np.allclose(p_load, p_tip + r_hook + sim.below_hook_m * u, atol=1e-9)
    C, h = np.asarray(tr["clearance"]), np.asarray(tr["centre_clearance"])
    assert np.all(C[before] > -1e-3) and np.all(C[t >= t_td] == 0.0)
    # the centre lies above the lowest corner by no more than the load's half diagonal's tilt
    assert np.all(h[before] >= C[before]) and np.all(h[before] - C[before] < 0.5)
    # its rate, on the hanging side alone (the load lies down flat at touchdown: a step)
    assert np.allclose(np.asarray(tr["relative_vz"])[before], np.gradient(h[t < t_td], t[t < t_td])[before[t < t_td]], atol=1e-9)
    assert np.all(np.asarray(tr["relative_vz"])[t >= t_td] == 0.0)
    assert np.all(np.asarray(tr["contact"])[t >= t_td] == 1.0) and np.all(np.asarray(tr["contact"])[before] == 0.0)


def test_the_feeders_pose_at_the_tip_carries_the_landing_point_from_its_body_frame_to_the_tips(landing):
    tr = landing.truth.columns
    before = np.asarray(tr["contact"]) < 0.5
    R_f = rpy_matrices(np.column_stack([np.asarray(tr[f"feeder_{a}"])[before] for a in ("roll", "pitch", "yaw")]))
    land_body = np.column_stack([np.asarray(tr["landing_x"])[before], np.asarray(tr["landing_y"])[before],
                                 np.full(np.count_nonzero(before), landing.scenario.world.feeder.geometry.freeboard_m)])
    rel = np.einsum("mij,mj->mi", R_f, land_body) + np.column_stack([np.asarray(tr[f"feeder_rel_{a}"])[before] for a in "xyz"])
    assert np.allclose(rel[:, 0], np.asarray(tr["landing_rel_x"])[before], atol=1e-9)
    assert np.allclose(rel[:, 1], np.asarray(tr["landing_rel_y"])[before], atol=1e-9)
    assert np.ptp(np.asarray(tr["feeder_roll"])) > 0.01  # it rolls: the rotation is exercised


def test_once_landed_the_load_moves_with_the_feeder_and_the_slack_rope_leaves_the_block_above_it(landing):
    sim = landing
    t_td, _, _ = sim.touchdown()
    t = np.linspace(t_td + 0.5, 29.0, 40)
    R, p = sim.load_pose(t)
    R_f, p_f = sim._feeder_pose(t)
    in_feeder = np.einsum("mji,mj->mi", R_f, p - p_f)
    assert np.ptp(in_feeder, axis=0).max() < 1e-9  # fixed on the deck
    assert np.allclose(in_feeder[:, 2], sim.scenario.world.feeder.geometry.freeboard_m)
    r = sim._hook_rel_tip(t)
    p_tip = sim._interp("p_tip_world", t) + sim._vessel_translation(t)
    top = p[:, 2] + R[:, 2, 2] * sim.below_hook_m
    assert np.all(p_tip[:, 2] + r[:, 2] >= top - 1e-9)


def test_a_frame_sees_the_load_its_slings_and_the_deck_below(landing):
    f = landing.lidar_frame(40, 2.0)
    lab = f.fields["label"]
    assert np.count_nonzero(lab == int(Label.LOAD)) > 30
    assert np.count_nonzero(lab == int(Label.FEEDER_DECK)) > 500
    assert np.count_nonzero(lab == int(Label.HOOK)) > 3


def test_the_radar_sees_the_load_and_the_deck_with_their_true_range_rates(landing):
    t = 5.0  # lowering
    _, origins, dirs, hits, p_hit, v_hit, v_sensor = landing._radar_hits(t)
    names = [b.name for b in landing.world.bodies]
    feeder = hits.hit & (hits.body == names.index("feeder"))
    assert np.count_nonzero(feeder) > 500 and np.count_nonzero(hits.hit & (hits.body == names.index("load"))) > 10
    # the feeder's motion in closed form: the central differences of its poses agree to well below the radar's noise
    exact = landing.world.feeder_motion.states(np.array([t])).point_velocity(p_hit[feeder], 0)
    assert np.abs(v_hit[feeder] - exact).max() < 1e-4
    # the load's points move with the load's pose (its truth's, turning and all), differenced over 2 ms
    load = hits.hit & (hits.body == names.index("load"))
    R, c = landing.load_pose(np.array([t - 0.001, t, t + 0.001]))
    local = (p_hit[load] - c[1]) @ R[1]
    v_rigid = ((local @ R[2].T + c[2]) - (local @ R[0].T + c[0])) / 0.002
    assert np.abs(v_hit[load] - v_rigid).max() < 1e-3
    f = landing.radar_frame(3, t)
    assert {"range", "range_rate", "label"} <= set(f.fields) and np.count_nonzero(f.fields["label"] == int(Label.LOAD)) > 5
