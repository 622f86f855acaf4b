"""The feeder chain end to end on short simulated runs: its outputs, its accuracy where the
short run allows it, a LiDAR outage it survives with a covariance that grows, and the
switches that leave it out."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from boomtip.data.scenario import load_scenario
from boomtip.data.sim.simulator import Simulation
from boomtip.tools.feeder_outputs import COLUMNS
from boomtip.tools.runner import run


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
    assert "Feeder 6-DOF" in (out / "report.md").read_text()
    assert (out / "plots" / "feeder_pose.png").exists()


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
    from boomtip.tools.feeder_outputs import feeder_kpis, report_section

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


def test_a_first_frame_without_structure_is_no_keyframe():
    from boomtip.data.processing import Processing
    from boomtip.tools.feeder_chain import FeederChain
    from boomtip.tools.heave_chain import HeaveChain

    sim = Simulation(load_scenario("sts-loaded", ["duration_s=8"]))
    heave, feeder = HeaveChain(sim, Processing()), FeederChain(sim, Processing())
    first = True
    for frame in sim:
        res = heave.process(frame)
        if frame.sensor == "lidar" and first:  # the first LiDAR frame sees only the deck
            first = False
            keep = np.abs(frame.points_sensor[:, 0] - np.median(frame.points_sensor[:, 0])) < 0.3
            frame.points_sensor = frame.points_sensor[keep]
        feeder.process(frame, res)
    out = feeder.finish()
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
    223 mm in x / y and a y RMSE of 63 mm; with the detections 52 / 82 and 40 mm."""
    s = load_scenario("sts-loaded", ["duration_s=30", "world.lidar.outages_s=[[18,28]]"])
    res = run(Simulation(s), tmp_path / "r", report=False)
    k = res.kpis["feeder"]
    assert k["updates"]["radar_registration"]["accepted"] > 180  # 20 a second
    assert k["outage"]["rmse_pos_m"][1] < 0.05 and k["outage"]["rmse_rpy_deg"][2] < 0.15
    assert min(k["outage"]["within_3sigma_pct"]) > 95 and 0.8 < k["outage"]["nees_mean"] < 3
    f = res.result.feeder
    late = np.sqrt(f.var[(f.t_s > 27.0) & (f.t_s < 28.0), :2].mean(axis=0))
    assert late[0] < 0.07 and late[1] < 0.1


@pytest.mark.parametrize("args, expected", [
    (["--duration", "3"], "expected more than 6 s"),
    (["-s", "hook-2", "--duration", "8"], "the feeder chain does not run here"),
    (["--duration", "8", "--set", "lidar.enabled=false"], "the feeder chain does not run here"),
])
def test_bench_feeder_says_what_it_cannot_score(args, expected):
    from typer.testing import CliRunner

    from boomtip.tools.cli import app

    r = CliRunner().invoke(app, ["bench", "feeder", *args])
    assert r.exit_code == 2 and expected in r.output and "Traceback" not in r.output


def test_the_recording_shows_the_feeder_mesh_at_the_estimate_and_the_truth(short_run):
    """The simulated feeder's mesh in the feeder frame as the truth defines it: the chain's own
    model (registered returns) lies on it; the recording gets it once per pose and then only
    the two poses' transforms."""
    import open3d as o3d
    import rerun as rr

    from boomtip.perception.feeder_registration import inverse, transform
    from boomtip.tools.feeder_outputs import log_feeder, truth_of
    from boomtip.tools.runner import build_chain, processing_for

    res = short_run[1].result.feeder
    sim = Simulation(load_scenario("sts-loaded", ["duration_s=14"]))
    chain = build_chain(sim, processing_for(sim))
    vertices, triangles = chain._feeder_mesh(sim.truth, res)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    model_feeder = transform(inverse(res.T_map_feeder), res.model_points_map).astype(np.float32)
    d = scene.compute_distance(o3d.core.Tensor(model_feeder)).numpy()
    assert np.median(d) < 0.03 and np.percentile(d, 90) < 0.08  # 0.014 / 0.041 m when written

    logged = []

    class Rec:
        def log(self, path, item, static=False):
            logged.append((path, type(item).__name__, static))

        def send_columns(self, path, indexes, columns):
            logged.append((path, "columns", False))

        def set_time(self, *a, **k):
            pass

    class Viz:
        def __init__(self):
            self.rr, self.rec = rr, Rec()

    truth_pose = truth_of(res, sim.truth, chain.p_tip_crane_m)[0]
    log_feeder(Viz(), res, res.model_points_map, res.T_map_feeder, truth_pose, lambda t: 0.0, mesh_feeder=(vertices, triangles))
    assert ("tip/feeder/estimate/mesh", "Mesh3D", True) in logged and ("tip/feeder/truth/mesh", "Mesh3D", True) in logged
    assert ("tip/feeder/estimate", "columns", False) in logged and ("tip/feeder/truth", "columns", False) in logged
    assert not any(kind == "Points3D" for _, kind, _ in logged)
    # a real recording has no mesh: the chain's model as points instead
    assert build_chain(sim, processing_for(sim))._feeder_mesh(None, res) is None
