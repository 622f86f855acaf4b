"""Fusion solutions on real pipeline output, KPIs on known errors, and the run/process commands."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from boomtip.data.io.recording import write_recording
from boomtip.data.scenario import load_scenario
from boomtip.data.sim.simulator import Simulation
from boomtip.fusion.solutions import FusionConfig, run_solution
from boomtip.fusion.tuning import relative_heave_components
from boomtip.fusion.heave_filter import jerk_psd_from_sea_state
from boomtip.perception.pipeline import HeavePipeline
from boomtip.tools.cli import app
from boomtip.tools.kpis import error_stats

runner = CliRunner()


@pytest.fixture(scope="module")
def loaded_rows():
    s = load_scenario("sts-loaded", ["duration_s=12"])
    sim = Simulation(s)
    pipe = HeavePipeline(sim.meta, sim.mru)
    rows = [m for f in sim for m in pipe.process(f).measurements]
    return s, sim.truth, rows


def test_error_stats_on_a_known_series():
    st = error_stats(np.array([1.0, -2.0, 3.0, np.nan]))
    assert st["mae"] == pytest.approx(2.0) and st["max"] == 3.0
    assert st["rmse"] == pytest.approx(np.sqrt(14 / 3)) and st["n"] == 3


def test_sea_state_tuning_comes_from_the_scenario():
    calm = load_scenario("sts-loaded", ["feeder.motion.heave.amplitude=0.5", "crane.motion.heave.amplitude=0.3"])
    rough = load_scenario("sts-loaded", ["feeder.motion.heave.amplitude=3.0"])
    assert jerk_psd_from_sea_state(relative_heave_components(rough)) > jerk_psd_from_sea_state(relative_heave_components(calm))
    irregular = load_scenario("sts-loaded", ["feeder.irregular.enabled=true"])
    assert len(relative_heave_components(irregular)) > len(relative_heave_components(rough))


def _mae(est, truth, col):
    keep = est.t_s >= 5.0
    return np.nanmean(np.abs(est.x[keep, col] - truth.at("D" if col == 0 else "D_dot", est.t_s[keep])))


def test_fused_solution_meets_its_targets(loaded_rows):
    s, truth, rows = loaded_rows
    est = run_solution("fused", rows, s, FusionConfig(), 12.0)
    assert _mae(est, truth, 0) < 0.005
    assert _mae(est, truth, 1) < 0.008


def test_known_latency_does_not_bias_the_fused_estimate(loaded_rows):
    s, truth, rows = loaded_rows
    late = s.model_copy(update={"lidar": s.lidar.model_copy(update={"latency_s": 0.1}),
                                "radar": s.radar.model_copy(update={"latency_s": 0.1})})
    est = run_solution("fused", rows, late, FusionConfig(), 12.0)
    assert _mae(est, truth, 0) < 0.010


def test_outliers_are_gated_not_followed(loaded_rows):
    s, truth, rows = loaded_rows
    import copy

    bad = copy.deepcopy(rows)
    for r in bad[200::40]:
        if r.method == "deck_lidar" and r.ok:
            r.value += 5.0
    est = run_solution("deck_lidar", bad, s, FusionConfig(), 12.0)
    assert est.statuses.get("gated", 0) >= 1
    assert _mae(est, truth, 0) < 0.005


def test_run_and_process_write_their_outputs(tmp_path):
    rec, out1, out2 = tmp_path / "rec", tmp_path / "run", tmp_path / "proc"
    r = runner.invoke(app, ["run", "-s", "sts-empty", "--duration", "6", "--out", str(out1), "--rerun"])
    assert r.exit_code == 0, r.output
    for name in ("measurements.csv", "estimates.csv", "kpis.json", "report.md", "heave_D.png", "boomtip.rrd"):
        assert (out1 / name).is_file(), name
    kpis = json.loads((out1 / "kpis.json").read_text())
    assert set(kpis["measurements"]) == {"deck_lidar", "deck_radar", "reflectors_lidar", "doppler_radar", "doppler_radar_rot"}
    assert {"mae", "max", "apt_ms", "valid_fraction"} <= set(kpis["measurements"]["deck_lidar"])
    assert {"mae_D_m", "rmse_D_dot_mps", "apt_ms"} <= set(kpis["solutions"]["fused"])
    with open(out1 / "measurements.csv") as fh:
        header = next(csv.reader(fh))
    assert header[:6] == ["t", "method", "quantity", "value", "time_ms", "status"]
    # process a recording with a corrupt frame: the run goes on and says which file
    write_recording(Simulation(load_scenario("sts-empty", ["duration_s=3"])), rec)
    victim = sorted((rec / "lidar").iterdir())[5]
    victim.write_bytes(b"not a pcd at all")
    r = runner.invoke(app, ["process", str(rec), "--out", str(out2)])
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(open(out2 / "measurements.csv")))
    bad = [x for x in rows if victim.name in x["status"]]
    assert len(bad) == 2 and all(x["value"] == "" for x in bad)
    assert sum(1 for x in rows if x["status"] == "ok") > 50
    # outputs are never written over inputs or existing results without --force
    assert runner.invoke(app, ["process", str(rec), "--out", str(rec / "out")]).exit_code == 2
    r = runner.invoke(app, ["process", str(rec), "--out", str(out2)])
    assert r.exit_code == 2 and "--force" in r.output
    assert runner.invoke(app, ["process", str(rec), "--out", str(out2), "--force"]).exit_code == 0
