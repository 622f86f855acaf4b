"""The runner builds its chain from the installation and processing alone: the world (the
provenance) changes nothing; a calm sea and a scenario with nothing but a LiDAR run to the end."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from boomtip.data.io.recording import Recording, RecordingError, write_recording
from boomtip.tools.config.scenario import ScenarioError, load_scenario
from boomtip.data.sim.simulator import Simulation
from boomtip.tools.cli.commands import app
from boomtip.tools.chains.runner import run

pytestmark = pytest.mark.slow  # every test here runs a chain end to end

runner = CliRunner()
CALM = [f"{v}.motion.{d}.amplitude=0" for v in ("crane", "feeder") for d in ("heave", "roll", "pitch")]


def _rows(path):
    with open(path) as fh:
        return [{k: v for k, v in r.items() if k != "time_ms"} for r in csv.DictReader(fh)]


def test_deleting_the_provenance_changes_no_estimate(tmp_path):
    rec = tmp_path / "rec"
    write_recording(Simulation(load_scenario("sts-loaded", ["duration_s=4"])), rec)
    blind = tmp_path / "blind"
    shutil.copytree(rec, blind)
    meta = json.loads((blind / "meta.json").read_text())
    assert meta["provenance"]["scenario"]["world"]["mismatch"]["mru_lag_s"] > 0  # the world is in there
    del meta["provenance"]
    (blind / "meta.json").write_text(json.dumps(meta))
    run(Recording(rec), tmp_path / "a")
    run(Recording(blind), tmp_path / "b")
    assert (tmp_path / "a" / "estimates.csv").read_bytes() == (tmp_path / "b" / "estimates.csv").read_bytes()
    assert _rows(tmp_path / "a" / "measurements.csv") == _rows(tmp_path / "b" / "measurements.csv")


def test_a_recording_says_what_the_installation_is_not_what_the_world_was(tmp_path):
    s = load_scenario("sts-loaded", ["duration_s=0.3", "mismatch.lidar_mount_rpy_deg=[0.5,0,0]"])
    write_recording(Simulation(s), tmp_path / "rec")
    meta = json.loads((tmp_path / "rec" / "meta.json").read_text())
    assert meta["installation"]["lidar"]["mount"]["rpy_deg"] == [90.0, 90.0, 0.0]  # as surveyed
    assert set(meta) >= {"installation", "processing", "provenance"} and "world" not in meta
    sim = Simulation(s)  # ... while the simulation casts from the true, rotated mount
    angle = np.degrees(np.arccos((np.trace(sim.world.T_boomtip_sensor["lidar"][:3, :3].T @ sim.meta.T_boomtip_sensor["lidar"][:3, :3]) - 1) / 2))
    assert angle == pytest.approx(0.5, abs=1e-6)


def test_a_calm_sea_runs_to_the_end(tmp_path):
    r = runner.invoke(app, ["run", "-s", "sts-loaded", "--duration", "8", "--out", str(tmp_path / "calm"), *sum((["--set", c] for c in CALM), [])])
    assert r.exit_code == 0, r.output
    kpis = json.loads((tmp_path / "calm" / "kpis.json").read_text())
    assert kpis["solutions"]["fused"]["mae_D_m"] < 0.002


def test_a_scenario_with_nothing_but_a_lidar_runs(tmp_path):
    path = tmp_path / "only-lidar.yaml"
    path.write_text("duration_s: 3\ninstallation:\n  lidar:\n    rate_hz: 10\n")
    r = runner.invoke(app, ["run", "-s", str(path), "--out", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    kpis = json.loads((tmp_path / "out" / "kpis.json").read_text())
    assert kpis["measurements"]["deck_lidar"]["valid_fraction"] > 0.9


def test_keys_without_their_section_resolve_to_the_one_that_has_them():
    s = load_scenario("sts-loaded", ["crane.motion.heave.amplitude=0.25", "lidar.rate_hz=5", "mismatch.mru_lag_s=0.01"])
    assert s.world.crane.motion.heave.amplitude == 0.25
    assert s.installation.lidar.rate_hz == 5 and s.world.mismatch.mru_lag_s == 0.01
    with pytest.raises(ScenarioError, match="world.mismatch.mru_lag_s"):
        load_scenario("sts-loaded", ["mismatch.mru_lagg=0.01"])
    with pytest.raises(ScenarioError, match=r"--set lidar.mount.rpy_deg=\[1,2\]"):
        load_scenario("sts-loaded", ["lidar.mount.rpy_deg=[1,2]"])


def test_every_built_in_scenario_deviates_from_its_installation():
    from boomtip.tools.config.scenario import available_scenarios
    from boomtip.data.sim.world import Mismatch

    for name in available_scenarios():
        assert load_scenario(name).world.mismatch != Mismatch(), name
    from boomtip.tools.config.scenario import Scenario
    from boomtip.data.sim.world import DEFAULT_MISMATCH

    assert Scenario().world.mismatch == DEFAULT_MISMATCH != Mismatch()  # a scenario that says nothing deviates too
    assert load_scenario("sts-loaded", ["mismatch={}"]).world.mismatch == Mismatch()  # a perfect world, on request


def test_a_recording_without_an_installation_is_refused_naming_the_key(tmp_path):
    write_recording(Simulation(load_scenario("sts-empty", ["duration_s=0.3"])), tmp_path / "rec")
    meta_path = tmp_path / "rec" / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["installation"]["lidar"]["rate_hzz"] = 10
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(RecordingError, match=r"installation.lidar.rate_hzz.*installation.lidar.rate_hz"):
        Recording(tmp_path / "rec")
    del meta["installation"]
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(RecordingError, match="missing key 'installation'"):
        Recording(tmp_path / "rec")


def test_the_hook_chain_needs_its_encoders(tmp_path):
    from boomtip.tools.config.processing import Processing
    from boomtip.tools.chains.runner import build_chain

    sim = Simulation(load_scenario("sts-empty", ["duration_s=0.3"]))
    with pytest.raises(ValueError, match="encoder stream"):
        build_chain(sim, Processing(chain="hook"))


def test_bad_processing_settings_in_a_recording_name_the_key(tmp_path):
    write_recording(Simulation(load_scenario("sts-empty", ["duration_s=0.3"])), tmp_path / "rec")
    meta_path = tmp_path / "rec" / "meta.json"
    meta = json.loads(meta_path.read_text())
    for bad, key in (({"heave": {"methods": ["bogus"]}}, "processing.heave.methods.0"),
                     ({"fusion": {"solutions": ["nope"]}}, "processing.fusion.solutions.0"),
                     ({"hook": {"filter": {"levelling_bias_sigma_radd": 1}}}, "processing.hook.filter.levelling_bias_sigma_radd")):
        meta["processing"] = bad
        meta_path.write_text(json.dumps(meta))
        r = runner.invoke(app, ["process", str(tmp_path / "rec"), "--out", str(tmp_path / "o"), "--force"])
        assert r.exit_code == 2 and key in r.output, r.output
    meta["processing"] = {"fusion": {"solutions": []}}  # nothing to estimate: no report crash
    meta_path.write_text(json.dumps(meta))
    r = runner.invoke(app, ["process", str(tmp_path / "rec"), "--out", str(tmp_path / "o"), "--force"])
    assert r.exit_code == 0, r.output
    (tmp_path / "rec" / "meta.json").write_bytes(b"{\xff}")
    r = runner.invoke(app, ["process", str(tmp_path / "rec"), "--out", str(tmp_path / "o"), "--force"])
    assert r.exit_code == 2 and "not UTF-8" in r.output


def test_without_a_lidar_fused_falls_back_on_the_radar_deck_and_says_so(tmp_path):
    r = runner.invoke(app, ["run", "-s", "sts-loaded", "--duration", "12", "--set", "lidar.enabled=false",
                            "--out", str(tmp_path / "radar")])
    assert r.exit_code == 0, r.output
    assert "fused: no LiDAR distance" in r.output
    kpis = json.loads((tmp_path / "radar" / "kpis.json").read_text())
    assert kpis["sources"]["fused"] == {"D": ["deck_radar"], "D_dot": ["doppler_radar_rot"]}
    assert kpis["solutions"]["fused"]["mae_D_m"] < 0.004  # 1.6 mm measured; the bound is 15 mm
    assert "deck_lidar" not in kpis["solutions"]  # no distance source: no numbers with a 100 m sigma
    assert "Warning" in (tmp_path / "radar" / "report.md").read_text()


def test_a_sensor_the_installation_has_but_the_recording_lacks_is_said(tmp_path):
    """A radar in the installation whose frames are all missing from the recording (a wrong
    topic, a dead sensor): the run goes on with the LiDAR and says the radar measured nothing;
    without truth it says what was estimated."""
    rec = tmp_path / "rec"
    assert runner.invoke(app, ["simulate", "-s", "sts-empty", "--duration", "2", "--out", str(rec)]).exit_code == 0
    for p in (rec / "radar").iterdir():
        p.unlink()
    (rec / "truth.csv").unlink()
    r = runner.invoke(app, ["process", str(rec), "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    kpis = json.loads((tmp_path / "o" / "kpis.json").read_text())
    assert "installation.radar.enabled is true, but sts-empty has no radar frame: nothing was measured with it" in kpis["warnings"]
    assert kpis["estimated"]["fused"]["estimates"] > 0 and "No truth to score against" in r.output
    assert "- mm" not in r.output


def test_a_blackout_of_every_sensor_is_lost_not_a_number_to_use(tmp_path):
    """LiDAR and radar both out for the last 12 s: the fused D is lost soon after the blackout
    starts (its sigma beyond 0.25 m), estimates.csv leaves it empty with the reason, and the
    first warning says so; before the blackout nothing is lost."""
    out = tmp_path / "o"
    r = runner.invoke(app, ["run", "-s", "sts-loaded", "--duration", "20", "--set", "world.lidar.outages_s=[[8,20]]",
                            "--set", "world.radar.outages_s=[[8,20]]", "--set", "processing.feeder.enabled=false",
                            "--out", str(out)])
    assert r.exit_code == 0, r.output
    kpis = json.loads((out / "kpis.json").read_text())
    assert kpis["warnings"][0].startswith("fused: lost for ")
    fused = kpis["solutions"]["fused"]
    assert 8.0 < fused["first_lost_t_s"] < 10.0 and fused["lost_fraction"] > 0.5
    with open(out / "estimates.csv") as fh:
        rows = [row for row in csv.DictReader(fh) if row["solution"] == "fused"]
    before = [row for row in rows if 1.0 <= float(row["t"]) < 8.0]
    assert all(row["status"] == "ok" and row["D"] for row in before)
    late = [row for row in rows if float(row["t"]) >= 12.0]
    assert late and all(row["D"] == "" and row["status"].startswith("lost: D sigma beyond 0.25 m") for row in late)
    assert all(float(row["var_D"]) > 0.25**2 for row in late)


def test_a_hook_recording_without_truth_says_the_path_it_estimated(tmp_path):
    rec = tmp_path / "rec"
    assert runner.invoke(app, ["simulate", "-s", "hook-2", "--duration", "6", "--out", str(rec)]).exit_code == 0
    (rec / "truth.csv").unlink()
    r = runner.invoke(app, ["process", str(rec), "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    assert "the hook's path as estimated" in r.output and "RMSE" not in r.output and "nan" not in r.output
    path = json.loads((tmp_path / "o" / "kpis.json").read_text())["hook"]["estimated"]["ekf_flexible"]
    assert path["samples"] > 0 and all(a < b for a, b in zip(path["min_m"], path["max_m"]))
    assert "| ekf_flexible |" in (tmp_path / "o" / "report.md").read_text()


def test_a_radar_noisier_than_stated_is_flagged_and_the_fused_estimate_holds(tmp_path):
    """The world's radar 5x noisier than the installation says: without truth, the consistency
    block flags the radar's streams (and not the LiDAR's deck), its rows are marked not
    consistent, the filters widen the radar's noise, and the fused D stays within 3 mm."""
    out = {}
    for scale in (1, 5):
        out[scale] = tmp_path / f"r{scale}"
        r = runner.invoke(app, ["run", "-s", "sts-loaded", "--duration", "20", "--set",
                                f"world.mismatch.radar_noise_scale={scale}", "--out", str(out[scale])])
        assert r.exit_code == 0, r.output
    calm, loud = (json.loads((out[s] / "kpis.json").read_text()) for s in (1, 5))
    assert not any(v["flagged"] for block in calm["consistency"].values() for v in block.values())
    c = loud["consistency"]
    assert c["deck_radar"]["deck_radar"]["flagged"] and c["doppler_radar"]["doppler_radar"]["flagged"]
    assert c["feeder"]["doppler"]["flagged"] and c["feeder"]["doppler"]["noise_scale_last"] > 4.0
    assert not c["deck_lidar"]["deck_lidar"]["flagged"]
    assert c["fused"]["doppler_radar_rot"]["noise_scale_max"] > 10.0
    assert any(w.startswith("deck_radar: the deck_radar updates' innovations are ") for w in loud["warnings"])
    assert loud["solutions"]["fused"]["mae_D_m"] < 0.003 and loud["solutions"]["fused"]["within_3sigma_D"] > 0.97
    with open(out[5] / "estimates.csv") as fh:
        rows = list(csv.DictReader(fh))
    flags = {s: {row["consistent"] for row in rows if row["solution"] == s} for s in ("deck_lidar", "doppler_radar")}
    assert flags["deck_lidar"] == {"1"} and "0" in flags["doppler_radar"]


def test_a_radar_whose_rates_wrap_gives_the_same_d_dot_as_one_that_does_not(tmp_path):
    """A 2.5 m feeder heave (D-dot up to 1.6 m/s) seen by a radar whose range rates wrap at
    +-1.25 m/s: the fused D-dot is as good as with a radar that never wraps, and no wrap is a
    jump in it; the first scan, with no prior yet, gives no velocity rather than a guess."""
    k = {}
    for v in (0.0, 1.25):
        out = tmp_path / f"v{v}"
        r = runner.invoke(app, ["run", "-s", "sts-loaded", "--duration", "20", "--set", "world.feeder.motion.heave.amplitude=2.5",
                                "--set", "world.crane.motion.heave.amplitude=0", "--set", f"radar.unambiguous_range_rate_mps={v}",
                                "--set", "processing.feeder.enabled=false", "--out", str(out)])
        assert r.exit_code == 0, r.output
        k[v] = json.loads((out / "kpis.json").read_text())["solutions"]["fused"]
    assert k[0.0]["max_D_dot_mps"] < 0.05 and k[1.25]["max_D_dot_mps"] < 0.05  # no 2.5 m/s jump
    assert k[1.25]["mae_D_dot_mps"] < 0.008 and k[1.25]["mae_D_dot_mps"] == pytest.approx(k[0.0]["mae_D_dot_mps"], rel=0.05)
    rows = _rows(tmp_path / "v1.25" / "measurements.csv")
    unknown = [x for x in rows if x["status"].startswith("Doppler alias unknown")]
    assert 0 < len(unknown) <= 4 and all(float(x["t"]) < 0.2 for x in unknown)


def test_a_lidar_outage_is_bridged_by_the_radar_deck_within_a_centimetre(tmp_path):
    """LiDAR out 10 s: the fused D takes the radar's deck, its offset learnt before, and stays
    within 10 mm and within its 3 sigma; the bridged stream is consistent."""
    out = tmp_path / "o"
    r = runner.invoke(app, ["run", "-s", "sts-loaded", "--duration", "45", "--set", "world.lidar.outages_s=[[30,40]]",
                            "--set", "processing.feeder.enabled=false", "--out", str(out)])
    assert r.exit_code == 0, r.output
    kpis = json.loads((out / "kpis.json").read_text())
    outage = kpis["solutions"]["fused"]["outage"]
    assert outage["max_D_m"] < 0.010 and outage["within_3sigma_D"] == 1.0
    bridged = kpis["consistency"]["fused"]["deck_radar_bridged"]
    assert bridged["updates"] > 150 and not bridged["flagged"]


@pytest.mark.slow
def test_a_run_on_two_processes_draws_the_same_frames_kept_whole_as_on_one(tmp_path, monkeypatch):
    """The representative frame's cloud comes back from the worker, and the worst frame the
    worker held is the one a run on one process picks (the picture is drawn in a child of a
    run on two processes: what it drew is written down where the parent can read it)."""
    import json

    from boomtip.tools.chains.resources import RunResources
    from boomtip.tools.chains.runner import run_into
    from boomtip.tools.report import detections

    real = detections.write_detections

    def drawing(out, frames, *a):
        seen = [[f.frame.t_s, why, len(f.frame.points_sensor), bool(f.deck_lidar.ok)] for f, why in frames]
        (out / "drawn.json").write_text(json.dumps(seen))
        return real(out, frames, *a)

    monkeypatch.setattr(detections, "write_detections", drawing)

    from boomtip.data.sim.sources import simulation_for

    for workers in (2, 1):
        sim = simulation_for(load_scenario("sts-loaded", ["duration_s=3"]))
        (tmp_path / str(workers)).mkdir()
        run_into(sim, tmp_path / str(workers), resources=RunResources(lean=True, workers=workers))
    assert "![detections](plots/detections.png)" in (tmp_path / "2" / "report.md").read_text()
    two, one = (json.loads((tmp_path / w / "drawn.json").read_text()) for w in ("2", "1"))
    (t_middle, _, n_middle, deck_ok), (_, why, n_worst, _) = two
    assert t_middle >= 1.5 and n_middle > 1000 and deck_ok  # its cloud came back
    assert n_worst > 1000 and "of its sigmas" in why
    assert [(t, w) for t, w, *_ in one] == [(t, w) for t, w, *_ in two]
    import matplotlib.image as mpimg

    assert mpimg.imread(tmp_path / "2" / "plots" / "detections.png")[..., :3].std() > 0.05


def test_a_run_that_fails_closes_what_its_chain_runs_beside_the_frames(tmp_path, monkeypatch):
    from boomtip.data.sim.sources import simulation_for
    from boomtip.tools.chains import runner
    from boomtip.tools.chains.ship import ShipChain

    closed = []
    monkeypatch.setattr(ShipChain, "close", lambda self: closed.append(True))
    monkeypatch.setattr(ShipChain, "finish", lambda self: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        runner.run_into(simulation_for(load_scenario("sts-loaded", ["duration_s=0.3"])), tmp_path)
    assert closed == [True]
