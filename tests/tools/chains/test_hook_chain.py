"""The hook chain end to end: simulated scene, recording with encoders, run -> kpis."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from boomtip.data.frames import ENCODER_COLUMNS, HOOK_TRUTH_COLUMNS
from boomtip.data.sim.hook_world import HookSimulation
from boomtip.data.io.recording import Recording, write_recording
from boomtip.tools.config.scenario import load_scenario
from boomtip.data.meshes import Label
from boomtip.tools.cli.commands import app

pytestmark = pytest.mark.slow  # every test here runs a chain end to end


@pytest.fixture(scope="module")
def sim():
    return HookSimulation(load_scenario("hook-2", ["duration_s=3"]))


def test_the_block_and_rope_are_where_the_truth_says(sim):
    f = sim.lidar_frame(10, 0.5)
    lab = f.fields["label"]
    assert np.count_nonzero(lab == int(Label.HOOK)) >= 3
    assert np.count_nonzero(lab == int(Label.ROPE)) > 0
    # Hook points, moved to the world with the sensor pose, lie within the block's size of the truth.
    R_ws, p_ws, *_ = sim._scene_poses(np.array([0.5]), "lidar")
    hook_w = f.points_sensor[lab == int(Label.HOOK)] @ R_ws[0].T + p_ws[0]
    ref = np.array([sim.truth.at(f"hook_{a}", np.array([0.5]))[0] for a in "xyz"])
    d = hook_w - ref
    assert np.all(np.abs(d[:, :2]) < 2.0) and np.all((d[:, 2] < 0.1) & (d[:, 2] > -5.0))


def test_truth_and_encoders_are_consistent(sim):
    tr = sim.truth.columns
    assert set(HOOK_TRUTH_COLUMNS) <= set(tr)
    rel = np.column_stack([tr[f"hook_rel_{a}"] for a in "xyz"])
    # the reeving stretches by m g l / EA (the world's true mass and EA; the encoder reads l)
    mm, crane = sim.scenario.world.mismatch, sim.scenario.installation.crane
    stretch = 1.0 + crane.dynamics.hook_mass_kg * mm.hook_mass * 9.81 / mm.rope_ea_n
    assert stretch > 1.00005
    assert np.allclose(np.linalg.norm(rel, axis=1), tr["hoist"] * stretch, atol=1e-6)
    enc = sim.encoders
    assert set(ENCODER_COLUMNS) <= set(enc)
    assert np.abs(np.interp(enc["t"], tr["t"], tr["slew"]) - enc["slew"]).max() < np.deg2rad(0.6)  # 0.1 deg noise


def test_hook_recording_round_trips_encoders_and_truth(sim, tmp_path):
    short = HookSimulation(load_scenario("hook-2", ["duration_s=0.5"]))
    write_recording(short, tmp_path / "rec")
    rec = Recording(tmp_path / "rec")
    assert np.allclose(rec.encoders["slew"], short.encoders["slew"], atol=1e-9)
    assert np.allclose(rec.truth.columns["hook_rel_z"], short.truth.columns["hook_rel_z"], atol=1e-6)
    assert sum(1 for f in rec if f.sensor == "lidar") == 10


def test_boomtip_run_on_a_hook_scenario_writes_hook_kpis(tmp_path):
    out = tmp_path / "hook"
    r = CliRunner().invoke(app, ["run", "-s", "hook-2", "--duration", "8", "--out", str(out), "--rerun"])
    assert r.exit_code == 0, r.output
    everything = json.loads((out / "kpis.json").read_text())
    kpis = everything["hook"]
    for name in ("ekf_flexible", "ekf_rigid", "ukf_flexible", "ukf_rigid"):
        # each estimator's consistency from its own innovations, block fixes and rope directions apart
        c = everything["consistency"][f"hook_{name}"]
        assert c["lidar_block"]["nis_dof"] == 3 and c["lidar_rope"]["nis_dof"] == 2 and c["lidar_block"]["updates"] > 50
        assert not c["lidar_block"]["flagged"]
        assert {"rmse_pos_m", "rmse_vel_mps", "max_pos_m", "max_vel_mps", "runtime_fraction", "rmse_rel_pos_m",
                "rmse_rel_vel_mps"} <= set(kpis[name])
        assert len(kpis[name]["rmse_pos_m"]) == 3
    seg = kpis["segmentation"]
    assert {"precision", "recall", "found_fraction", "rmse_m"} <= set(seg)
    assert seg["precision"] > 0.95 and seg["found_fraction"] > 0.5
    assert max(kpis["ekf_flexible"]["rmse_pos_m"]) < 0.3  # a working chain; the targets are measured by the full runs
    rope = kpis["rope"]
    assert rope["found_fraction"] > 0.95 and rope["precision"] > 0.99
    assert rope["rmse_angle_mrad"] < 0.5 and max(rope["rmse_at_hook_m"]) < 0.05
    assert abs(rope["radius_median_m"] - 0.04) < 1e-3
    for name in ("hook_measurements.csv", "hook_estimates.csv", "report.md", "plots/hook_trajectory.png", "boomtip.rrd"):
        assert (out / name).is_file()
    import csv

    with open(out / "hook_measurements.csv", newline="") as fh:
        frames = list(csv.DictReader(fh))
    assert len(frames) == 160 and {"rope_status", "rope_ux", "rope_radius_m", "rope_accepted"} <= set(frames[0])
    fitted = [f for f in frames if f["rope_status"] == "ok"]
    assert len(fitted) > 150
    u = np.array([[float(f[f"rope_u{a}"]) for a in "xyz"] for f in fitted])
    assert np.allclose(np.linalg.norm(u, axis=1), 1.0, atol=1e-5) and np.all(u[:, 2] < -0.99)
    # The recording holds the cloud, the segmented block, the rope line, the estimated and the
    # true hook with their trails, and the errors (rerun's own reader lists its entities).
    rerun_cli = Path(sys.executable).with_name("rerun")
    if rerun_cli.exists():
        listing = subprocess.run([str(rerun_cli), "rrd", "print", str(out / "boomtip.rrd")], capture_output=True,
                                 text=True, timeout=120, env={**os.environ, "RERUN_ANALYTICS": "0"})
        assert listing.returncode == 0, listing.stderr
        for entity in ("/sensors/lidar", "/detections/hook/segment", "/detections/rope/axis", "/estimates/ekf_flexible/hook/rope",
                       "/estimates/ekf_flexible/hook/position", "/estimates/ekf_flexible/hook/trail", "/truth/hook/position",
                       "/truth/hook/trail", "/truth/error_cm/x"):
            assert entity in listing.stdout, entity


def test_bench_fusion_writes_its_figures(tmp_path):
    """`boomtip bench fusion` prints and writes the exact vs numeric Jacobian runtimes and the
    chain's filter with the rope stream (the speed ratio itself is measured by the full bench)."""
    path = tmp_path / "fusion.json"
    r = CliRunner().invoke(app, ["bench", "fusion", "--duration", "8", "--json", str(path)])
    assert r.exit_code == 0, r.output
    figures = json.loads(path.read_text())
    for label in ("analytic", "numeric", "analytic_rope"):
        k = figures[label]
        assert k["runtime_s"] > 0 and k["runtime_fraction"] > 0  # figures of the bench, not a test of speed
        assert all(np.isfinite(k["rmse_pos_m"])) and max(k["rmse_pos_m"]) < 0.1
    assert figures["ratio"] > 0 and "ratio numeric / exact" in r.output
    again = CliRunner().invoke(app, ["bench", "fusion", "--duration", "8", "--json", str(path)])
    assert again.exit_code != 0 and "--force" in again.output  # an existing result is not overwritten
