"""The feeder chain end to end on short simulated runs: its outputs, its accuracy where the
short run allows it, a LiDAR outage it survives with a covariance that grows, and the
switches that leave it out."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from boomtip.tools.config.scenario import load_scenario
from boomtip.data.sim.simulator import Simulation
from boomtip.tools.report.feeder import COLUMNS
from boomtip.tools.chains.runner import run

pytestmark = pytest.mark.slow  # every test here runs a chain end to end


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("feeder") / "run"
    res = run(Simulation(load_scenario("sts-loaded", ["duration_s=14"])), out)
    return out, res


def test_outputs_and_kpis(short_run):
    out, _ = short_run
    with open(out / "feeder_estimates.csv") as fh:
        rows = list(csv.reader(fh))
    assert tuple(rows[0]) == COLUMNS and len(rows) > 200
    k = json.loads((out / "kpis.json").read_text())["feeder"]
    for key in ("rmse_pos_m", "max_pos_m", "rmse_rpy_deg", "max_rpy_deg", "rmse_vel_mps", "apt_ms", "nees_mean"):
        assert key in k
    # where a LiDAR frame's milliseconds go: every stage's mean, summing to the frame's
    by_stage = k["apt_ms_by_stage"]
    assert {"feeder.returns", "feeder.static_count", "feeder.static_mask", "feeder.structure", "feeder.registration",
            "feeder.filter", "feeder.model", "feeder.lines", "feeder.deck_reused"} <= set(by_stage)
    assert sum(by_stage.values()) == pytest.approx(k["apt_ms"], abs=0.01 * len(by_stage))
    assert "Feeder 6-DOF" in (out / "report.md").read_text()
    assert (out / "plots" / "feeder_pose.png").exists()
    # the estimates as a live controller had them: the same rows; 14 s is under the calibration's 30 s
    with open(out / "feeder_estimates_online.csv") as fh:
        online = list(csv.reader(fh))
    assert online[0] == rows[0] and [r[0] for r in online] == [r[0] for r in rows]
    with open(out / "feeder_calibration.csv") as fh:
        cal = list(csv.DictReader(fh))
    assert 13 <= len(cal) <= 15 and all(float(r["about_x_deg"]) == 0.0 and float(r["span_s"]) == 0.0 for r in cal)
    assert float(cal[0]["sigma_x_deg"]) == pytest.approx(math.hypot(0.03, 0.02), rel=1e-6)  # the survey's
    assert k["online"]["calibrated_at_s"] is None and k["online"]["samples"] == k["samples"]
    assert "the levelling was not calibrated in this run" in (out / "report.md").read_text()


def test_accuracy_on_a_short_run(short_run):
    """14 s: no levelling calibration yet (it needs 30 s), so roll and pitch carry the rig's
    0.03 deg levelling error; x and z are at the millimetre level, y at the registration's."""
    k = short_run[1].kpis["feeder"]
    x, y, z = k["rmse_pos_m"]
    assert x < 0.01 and z < 0.003 and y < 0.03
    assert max(k["rmse_rpy_deg"][:2]) < 0.05 and k["rmse_rpy_deg"][2] < 0.09
    assert 0.5 < k["nees_mean"] < 8
    d = k["D_side_by_side"]
    assert d["feeder_rmse_m"] < 0.005 and d["feeder_minus_fused_rms_m"] < 0.005


def test_returns_spread_over_the_sweep_give_the_plane_with_its_spin(short_run, tmp_path):
    """The scene moving during the LiDAR's 0.1 s sweep: the plane alone, fitted to returns
    spread over it and taken at the frame's start, was 23.5 mm off in z (the heave over half a
    sweep), with a NEES of 343; the plane and its spin from the returns' times, 1.6 mm and 3.6.
    Without per-point times (the short run's: nothing moves during its sweep) the plane alone."""
    res = run(Simulation(load_scenario("sts-loaded", ["duration_s=14", "lidar.motion_during_sweep=true"])), tmp_path / "run")
    k = res.kpis["feeder"]
    assert k["updates"]["deck_spin_lidar"]["accepted"] == 140 and "deck_lidar" not in k["updates"]
    assert k["rmse_pos_m"][2] < 0.003 and max(k["rmse_rpy_deg"]) < 0.035 and 0.5 < k["nees_mean"] < 8
    assert k["updates"]["doppler"]["gated"] == 0  # the first frame's state is the spin's, not the plane's mean time
    short = short_run[1].kpis["feeder"]["updates"]
    assert "deck_spin_lidar" not in short and short["deck_lidar"]["accepted"] > 100


def test_a_lidar_outage_is_bridged_with_a_growing_covariance(tmp_path):
    s = load_scenario("sts-loaded", ["duration_s=18", "world.lidar.outages_s=[[9,14]]"])
    res = run(Simulation(s), tmp_path / "o", report=False)
    k = res.kpis["feeder"]
    assert k["outage"]["samples"] > 50  # the radar and the MRU carry it
    f = res.result.feeder
    inside = (f.t_s >= 9) & (f.t_s < 14)
    before = f.var[(f.t_s > 8.0) & (f.t_s < 9.0), 0].mean()
    late = f.var[(f.t_s > 13.0) & (f.t_s < 14.0), 0].mean()
    assert late > 2 * before  # x is not observed by the radar: its variance grows
    assert np.all(np.isfinite(f.pose[inside]))
    assert min(k["outage"]["within_3sigma_pct"]) > 80
    assert max(k["outage"]["rmse_pos_m"]) < 0.5


def test_switched_off_and_without_a_lidar(tmp_path):
    s = load_scenario("sts-loaded", ["duration_s=1", "processing.feeder.enabled=false"])
    res = run(Simulation(s), tmp_path / "a", report=False)
    assert "feeder" not in res.kpis and not (tmp_path / "a" / "feeder_estimates.csv").exists()
    s = load_scenario("sts-loaded", ["duration_s=1", "installation.lidar.enabled=false"])
    res = run(Simulation(s), tmp_path / "b", report=False)
    assert "feeder" not in res.kpis


def test_a_run_shorter_than_the_warmup_still_ends(tmp_path):
    res = run(Simulation(load_scenario("sts-loaded", ["duration_s=2"])), tmp_path / "c", report=False)
    assert len(res.result.feeder.t_s) > 20  # the frames held back are processed at the end


def test_without_truth_the_two_Ds_are_still_compared(short_run):
    from boomtip.tools.report.feeder import feeder_kpis, report_section

    res = short_run[1]
    fused = res.result.heave.estimates["fused"]
    k = feeder_kpis(res.result.feeder, None, np.zeros(3), heave_D=(fused.t_s, fused.x[:, 0]))
    with_truth = res.kpis["feeder"]["D_side_by_side"]
    assert "rmse_pos_m" not in k and set(k["D_side_by_side"]) == {"feeder_minus_fused_rms_m"}
    assert k["D_side_by_side"]["feeder_minus_fused_rms_m"] == with_truth["feeder_minus_fused_rms_m"]  # the truth is finite throughout
    assert "RMS apart (no truth)" in report_section({"feeder": k})


def test_the_levelling_calibration_takes_out_the_rigs_tilt(tmp_path):
    """40 s: the calibration applies (after 30 s of decks) and roll and pitch drop from the
    rig's 0.03 deg levelling error to a few thousandths."""
    res = run(Simulation(load_scenario("sts-loaded", ["duration_s=40"])), tmp_path / "d", report=False)
    k = res.kpis["feeder"]
    assert max(k["rmse_rpy_deg"][:2]) < 0.015
    t = k["levelling_tilt_deg"]
    assert t["about_x"] == pytest.approx(-0.0295, abs=0.003) and t["about_y"] == pytest.approx(-0.0251, abs=0.003)
    # online: the survey's levelling until 30 s of decks, the calibration so far from then on;
    # the last row has the whole run's definition, as the offline estimate
    f, o = res.result.feeder, k["online"]
    assert o["calibrated_at_s"] == pytest.approx(f.t_s[0] + 30.0, abs=1.0)
    until, once = o["until_calibrated"], o["once_calibrated"]
    assert 0.02 < min(until["online"]["rmse_rpy_deg"][:2]) and max(until["offline"]["rmse_rpy_deg"][:2]) < 0.015
    assert max(once["online"]["rmse_rpy_deg"][:2]) < 0.02 and max(o["rmse_pos_m"]) < 0.01
    assert np.array_equal(f.online.pose[-1], f.pose[-1]) and np.array_equal(f.online.var[-1], f.var[-1])
    last = f.online.history[-1]
    assert np.degrees(f.tilt.rx_rad) == pytest.approx(last[1], abs=1e-12) and last[7] == f.tilt.span_s
    assert not np.array_equal(f.online.pose[0], f.pose[0])


def test_a_first_frame_without_structure_is_no_keyframe():
    from boomtip.tools.chains.ship import ShipChain
    from boomtip.tools.config.processing import Processing

    sim = Simulation(load_scenario("sts-loaded", ["duration_s=8"]))
    chain = ShipChain(sim, Processing())
    first = True
    for frame in sim:
        if frame.sensor == "lidar" and first:  # the first LiDAR frame sees only the deck
            first = False
            keep = np.abs(frame.points_sensor[:, 0] - np.median(frame.points_sensor[:, 0])) < 0.3
            frame.points_sensor = frame.points_sensor[keep]
            frame.fields = {k: v[keep] for k, v in frame.fields.items()}
        chain.process(frame)
    out = chain.finish().feeder
    assert out.counts.get("registration", {}).get("accepted", 0) > 20


def test_a_feeder_mru_carries_the_attitude_and_position_through_a_lidar_outage(tmp_path):
    """The same 5 s outage with an MRU on the feeder (004's second MRU): its yaw and rates keep
    the yaw to a few hundredths of a degree where the radar alone lets it wander (0.07 deg in
    this run without it), and its offsets are learnt while the LiDAR sees the deck."""
    s = load_scenario("sts-loaded", ["duration_s=18", "world.lidar.outages_s=[[9,14]]", "world.feeder.mru.enabled=true"])
    res = run(Simulation(s), tmp_path / "o", report=False)
    k = res.kpis["feeder"]
    x, y, _ = k["outage"]["rmse_pos_m"]
    assert x < 0.02 and y < 0.035 and k["outage"]["rmse_rpy_deg"][2] < 0.045
    assert min(k["outage"]["within_3sigma_pct"]) > 95
    m = k["feeder_mru"]
    # what the MRU's yaw differs from the map's by: the world's 0.5 deg between the heading
    # references and the crane MRU's 0.05 deg yaw bias
    assert abs(m["heading_offset_deg"] + m["body_yaw_in_map_deg"] + 0.55) < 0.1
    assert k["updates"]["feeder_mru"]["accepted"] > 400 and k["updates"]["feeder_mru"]["gated"] == 0


def test_the_radars_detections_hold_x_y_and_yaw_through_a_lidar_outage(tmp_path):
    """A 10 s outage once the model is merged and the radar's offset from the LiDAR learnt
    (after about 15 s), no feeder MRU: each radar frame's detections registered to the model
    update x, y and yaw. With the Doppler alone the same run ends the outage with 1-sigma 91 /
    223 mm in x / y and a y RMSE of 63 mm; with the detections 66 / 106 and under 50 mm (20 Hz
    radar frames share their errors: each counts half)."""
    s = load_scenario("sts-loaded", ["duration_s=30", "world.lidar.outages_s=[[18,28]]"])
    res = run(Simulation(s), tmp_path / "r", report=False)
    k = res.kpis["feeder"]
    assert k["updates"]["radar_registration"]["accepted"] > 180  # 20 a second
    assert k["outage"]["rmse_pos_m"][1] < 0.05 and k["outage"]["rmse_rpy_deg"][2] < 0.15
    # the NEES of one 10 s outage (its samples a second apart share their errors): 0.77-0.82 over
    # random draws that differ only in the radar deck search's subsets
    assert min(k["outage"]["within_3sigma_pct"]) > 95 and 0.6 < k["outage"]["nees_mean"] < 3
    f = res.result.feeder
    late = np.sqrt(f.var[(f.t_s > 27.0) & (f.t_s < 28.0), :2].mean(axis=0))
    assert late[0] < 0.08 and late[1] < 0.125


@pytest.mark.parametrize("args, expected", [
    (["--duration", "3"], "expected more than 6 s"),
    (["-s", "hook-2", "--duration", "8"], "the feeder chain does not run here"),
    (["--duration", "8", "--set", "lidar.enabled=false"], "the feeder chain does not run here"),
])
def test_bench_feeder_says_what_it_cannot_score(args, expected):
    from typer.testing import CliRunner

    from boomtip.tools.cli.commands import app

    r = CliRunner().invoke(app, ["bench", "feeder", *args])
    assert r.exit_code == 2 and expected in r.output and "Traceback" not in r.output


def test_the_recording_shows_the_feeder_mesh_at_the_estimate_and_the_truth(short_run):
    """The simulated feeder's mesh in the feeder frame as the truth defines it: the chain's own
    model (registered returns) lies on it; the recording gets it once per pose and then only
    the two poses' transforms."""
    import open3d as o3d
    from boomtip.data.poses import inverse, transform
    from boomtip.tools.report.feeder import truth_of
    from boomtip.tools.chains.runner import build_chain, processing_for

    res = short_run[1].result.feeder
    sim = Simulation(load_scenario("sts-loaded", ["duration_s=14"]))
    chain = build_chain(sim, processing_for(sim))
    vertices, triangles = chain._visualised_feeder_mesh(sim.truth, res)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    model_feeder = transform(inverse(res.T_map_feeder), res.model_points_map).astype(np.float32)
    d = scene.compute_distance(o3d.core.Tensor(model_feeder)).numpy()
    assert np.median(d) < 0.03 and np.percentile(d, 90) < 0.08  # 0.014 / 0.041 m when written

    logged = []

    class Recording:
        def mesh(self, path, vertices, triangles, cls, alpha=255):
            logged.append((path, "mesh", cls))

        def poses(self, path, t_s, R, p, scale=None):
            logged.append((path, "poses", len(t_s)))

        def series(self, panel, path, t_s, values, name, colour, sigma=None, width=1.2):
            logged.append((path, "series", sigma is not None))

        def points(self, path, points, cls, radius_m, labels=None):
            logged.append((path, "points", cls))

        def ellipsoids(self, path, t_s, centers, half_sizes, cls, quaternions_xyzw=None):
            logged.append((path, "ellipsoids", len(t_s)))

        def time(self, t_s):
            pass

    class Viz:
        def __init__(self):
            self.recording = Recording()

    from boomtip.tools.report.recording.feeder import log_feeder

    truth_pose = truth_of(res, sim.truth, chain.p_tip_crane_m)[0]
    log_feeder(Viz(), res, truth_pose, lambda t: 0.0, mesh_feeder=(vertices, triangles))
    assert ("estimates/feeder/body/mesh", "mesh", "feeder_vessel") in logged and ("truth/feeder/body/mesh", "mesh", "truth") in logged
    n_10hz = len(np.unique(np.floor(res.t_s * 10.0)))  # the poses at 10 Hz
    assert ("estimates/feeder/body", "poses", n_10hz) in logged and ("truth/feeder/body", "poses", n_10hz) in logged
    assert ("estimates/feeder/pose/z", "series", True) in logged and ("truth/feeder/pose/z", "series", False) in logged
    assert ("detections/feeder/model", "points", "feeder_model") in logged  # the registered model, mesh or not
    assert ("estimates/feeder/origin", "ellipsoids", n_10hz) in logged
    # a real recording has no mesh: the chain's model as points instead
    assert build_chain(sim, processing_for(sim))._visualised_feeder_mesh(None, res) is None

# -- the model's merges beside the frames ----------------------------------------------------

BESIDE = (2, 5, 50, 100)  # merges beside the frames (the default is inline)

def test_merges_beside_the_frames_repeat_bit_for_bit_however_slow(tmp_path, monkeypatch):
    """The same run with each merge's worker slowed by 1.5 s: the chain waits at the taking
    frames, and its estimates are byte for byte the first run's."""
    import time

    from boomtip.perception import feeder_merges as feeder_merge

    beside = ["duration_s=14", f"processing.feeder.perception.registration.merge_lag_frames={list(BESIDE)}"]
    res1 = run(Simulation(load_scenario("sts-loaded", beside)), tmp_path / "fast", report=False)
    out1 = tmp_path / "fast"
    real = feeder_merge.merged_model
    monkeypatch.setattr(feeder_merge, "merged_model", lambda *a: (time.sleep(1.5), real(*a))[1])
    res2 = run(Simulation(load_scenario("sts-loaded", beside)), tmp_path / "slow", report=False)
    m1, m2 = res1.kpis["feeder"]["model_merges"], res2.kpis["feeder"]["model_merges"]
    # 20 and 50 frames taken 2 and 5 frames later; 100 started, due 50 frames later, after the run's end
    assert [m["status"] for m in m1] == ["ok", "ok", "dropped: the run ended first"]
    assert [(m["frames"], m["taken_frame"] - m["started_frame"]) for m in m1[:2]] == [(20, 2), (50, 5)]
    assert [(m["frames"], m["started_frame"], m["taken_frame"], m["status"]) for m in m1] == \
        [(m["frames"], m["started_frame"], m["taken_frame"], m["status"]) for m in m2]
    assert all(m["wait_s"] > 1.0 for m in m2[:2])
    assert res2.kpis["feeder"]["merge_wait_ms"]["max"] > 1000 and res2.kpis["feeder"]["apt_ms_max"] > 1000
    assert (out1 / "feeder_estimates.csv").read_bytes() == (tmp_path / "slow" / "feeder_estimates.csv").read_bytes()


def test_a_run_whose_merges_fail_goes_on_with_its_keyframe(tmp_path, monkeypatch):
    from boomtip.perception import feeder_merges as feeder_merge

    def broken(*_):
        raise MemoryError("merge")

    monkeypatch.setattr(feeder_merge, "merged_model", broken)
    res = run(Simulation(load_scenario("sts-loaded", ["duration_s=10", f"processing.feeder.perception.registration.merge_lag_frames={list(BESIDE)}"])),
              tmp_path / "f")
    k = res.kpis["feeder"]
    # each failure is found where its model would have been taken; the last is due after the run's end
    assert [(m["frames"], m["status"]) for m in k["model_merges"]] == [
        (20, "failed: MemoryError: merge"), (50, "failed: MemoryError: merge"), (100, "dropped: the run ended first")]
    assert len(res.result.feeder.t_s) > 50 and np.all(np.isfinite(res.result.feeder.pose))
    assert "not taken: failed: MemoryError: merge" in (tmp_path / "f" / "report.md").read_text()



def test_merges_run_inline_by_default(short_run):
    """Inline (lag 0): each merge is taken at the frame it was due, with no wait apart from its
    own time, which is in that frame's time."""
    merges = short_run[1].kpis["feeder"]["model_merges"]
    assert [(m["frames"], m["status"]) for m in merges] == [(20, "ok"), (50, "ok"), (100, "ok")]
    assert all(m["taken_frame"] == m["started_frame"] for m in merges)
    assert short_run[1].kpis["feeder"]["apt_ms_max"] >= max(1e3 * m["worker_s"] for m in merges)


def test_a_crane_mru_gap_is_bridged_with_the_predicted_attitude(tmp_path):
    """world.mru.outages_s: with processing.feeder.mru_gap on, the frames in the gap are levelled
    with the MRU's own forecast (tools/feeder_mru_gap); off (the default), the chain pauses."""
    s = load_scenario("sts-loaded", ["duration_s=16", "world.mru.outages_s=[[11,13]]", "processing.feeder.mru_gap.enabled=true"])
    res = run(Simulation(s), tmp_path / "g", report=False)
    k, f = res.kpis["feeder"], res.result.feeder
    inside = (f.t_s >= 11) & (f.t_s < 13)
    assert k["mru_outage"]["samples"] == inside.sum() >= 38  # a row per LiDAR and radar frame: 20 a second
    assert np.all(np.isfinite(f.pose[inside])) and np.all(np.isfinite(f.var[inside])) and np.all(f.var[inside] > 0)
    # 16 s is under the calibration's 30 s: the angles carry the mount's error (0.03 deg) inside and out
    gap, out = k["mru_outage"], k["outside_outage"]
    assert max(gap["rmse_pos_m"]) < 0.01 and max(gap["rmse_rpy_deg"]) < 1.3 * max(out["rmse_rpy_deg"])
    assert min(gap["within_3sigma_pct"]) == 100.0 and 1.8 < gap["nees_mean"] < 18
    assert not any(why == "no MRU attitude" for t, _, why in f.missing if 11 <= t < 13)
    # the prediction's error is on the rows: x's variance in the gap's second half above the rows before it
    assert f.var[(f.t_s > 12.5) & inside, 0].mean() > f.var[(f.t_s > 10.0) & (f.t_s < 11.0), 0].mean()
    off = load_scenario("sts-loaded", ["duration_s=16", "world.mru.outages_s=[[11,13]]"])  # the default: the pause
    paused = run(Simulation(off), tmp_path / "p", report=False)
    assert paused.kpis["feeder"]["mru_outage"]["samples"] == 0
    # before the gap the two runs agree to the bit as a live controller had them (causal rows)
    g, p = res.result.feeder.online, paused.result.feeder.online
    before = g.t_s < 11
    assert before.sum() > 150 and np.array_equal(g.t_s[before], p.t_s[p.t_s < 11])
    assert np.array_equal(g.pose[before], p.pose[p.t_s < 11]) and np.array_equal(g.var[before], p.var[p.t_s < 11])
