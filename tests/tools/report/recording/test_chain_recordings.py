"""Each chain's recording read back (rerun's own reader): the convention's roots, and as many
entries under each as the run's own CSVs say there were frames, detections and estimates."""

from __future__ import annotations

import collections
import csv
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader
from typer.testing import CliRunner

from boomtip.data.io.recording import write_recording
from boomtip.data.sim.simulator import Simulation
from boomtip.tools.cli import app
from boomtip.tools.config.scenario import load_scenario
from boomtip.tools.report.recording.convention import ROOTS
from boomtip.tools.report.recording.world import WORLD_RATE_HZ

pytestmark = pytest.mark.slow  # every test here runs a chain end to end

DURATION_S = 4


def rows_per_entity(path: Path) -> tuple[dict[str, int], set[str]]:
    """(entity -> its temporal rows that log data (not a Clear), the entities with static data) of an .rrd."""
    rows: dict[str, int] = collections.Counter()
    static = set()
    for chunk in RrdReader(path).stream().to_chunks():
        if chunk.is_static:
            static.add(chunk.entity_path)
            continue
        rb = chunk.to_record_batch()
        data = [rb.column(n) for n in rb.schema.names if ":" in n and not n.startswith(("Clear:", "rerun."))]
        if data:
            rows[chunk.entity_path] += int(np.any([c.is_valid().to_numpy(zero_copy_only=False) for c in data], axis=0).sum())
    return rows, static


def run(out: Path, *args: str) -> tuple[dict[str, int], set[str]]:
    res = CliRunner().invoke(app, [*args, "--rerun", "--workers", "1", "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert len(RrdReader(out / "boomtip.rrd").blueprints()) == 1
    return rows_per_entity(out / "boomtip.rrd")


def csv_rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def roots(rows: dict, static: set) -> set[str]:
    return {p.split("/")[1] for p in set(rows) | static if p.count("/") >= 1 and p != "/" and not p.startswith("/__")}


def test_a_ship_run_draws_both_ships_every_stage_and_the_estimates(tmp_path):
    out = tmp_path / "ship run é"
    rows, static = run(out, "run", "-s", "sts-loaded", "--duration", str(DURATION_S))
    assert roots(rows, static) == set(ROOTS)
    meas = csv_rows(out / "measurements.csv")
    frames = {s: len({r["t"] for r in meas if r["method"] == m}) for s, m in (("lidar", "deck_lidar"), ("radar", "deck_radar"))}
    assert rows["/sensors/lidar"] == frames["lidar"] == DURATION_S * 10 and rows["/sensors/radar"] == frames["radar"]
    for stage in ("deck_lidar", "deck_radar"):  # a plane, its wire and D per frame the stage measured
        ok = sum(r["method"] == stage and r["status"] == "ok" for r in meas)
        assert ok > 0 and rows[f"/detections/{stage}/plane"] == rows[f"/detections/{stage}/p_d"] == ok
    fused = [r for r in csv_rows(out / "estimates.csv") if r["solution"] == "fused"]
    n_D = sum(r["D"] != "" for r in fused)
    assert {f"/estimates/fused/D{b}" for b in ("", "/sigma3_high", "/sigma3_low")} <= static
    assert {"/truth/D", "/truth/error_D_mm/fused", "/world/crane/mesh", "/world/feeder/mesh", "/estimates/feeder/body/mesh",
            "/truth/feeder/body/mesh"} <= static
    # the bodies move at WORLD_RATE_HZ over the frames' span; the deck point's ellipsoid at 10 Hz
    assert rows["/world/crane"] == rows["/world/feeder"] == pytest.approx((DURATION_S - 0.1) * WORLD_RATE_HZ, abs=2)
    assert 0 < n_D and "/estimates/fused/deck_point" in static
    # the mesh moves with its own transform; the origin's ellipsoid and the series beside it stay in the tip view's axes
    assert rows["/estimates/feeder/body"] > 0 and rows["/estimates/feeder/origin"] > 0 and rows["/detections/feeder/model"] >= 1
    assert "/estimates/feeder" not in rows


def test_a_radar_only_run_draws_its_deck_planes(tmp_path):
    rows, static = run(tmp_path / "radar", "run", "-s", "sts-loaded", "--duration", str(DURATION_S),
                       "--set", "installation.lidar.enabled=false")
    assert "/sensors/lidar" not in rows and rows["/sensors/radar"] > 0
    assert rows["/detections/deck_radar/plane"] > 0 and not any(p.startswith("/detections/deck_lidar") for p in rows)


def test_a_hook_run_draws_the_segment_the_block_model_the_rope_and_the_estimate(tmp_path):
    out = tmp_path / "hook"
    rows, static = run(out, "run", "-s", "hook-2", "--duration", str(DURATION_S))
    assert roots(rows, static) == set(ROOTS)
    frames = csv_rows(out / "hook_measurements.csv")
    fixes = sum(r["status"] == "ok" for r in frames)
    assert rows["/detections/hook/segment"] == len(frames) and rows["/detections/hook/block"] == fixes > 0
    assert rows["/detections/rope/axis"] == sum(r["rope_status"] == "ok" for r in frames) > 0
    est = "/estimates/ekf_flexible/hook"
    assert rows[f"{est}/position"] == rows["/truth/hook/position"] > 0 and f"{est}/sigma3" in static
    assert {"/world/crane/mesh", "/world/boom/mesh", "/world/block/mesh", "/world/rope/mesh"} <= static
    assert rows["/world/block"] == rows["/world/rope"] > 0


def test_a_recording_of_a_real_run_has_no_simulated_world(tmp_path):
    rec = tmp_path / "recording"
    write_recording(Simulation(load_scenario("sts-loaded", [f"duration_s={DURATION_S}"])), rec)
    rows, static = run(tmp_path / "processed", "process", str(rec))
    assert [p for p in set(rows) | static if p.startswith("/world")] == ["/world/boom_tip"]
    assert rows["/sensors/lidar"] > 0 and rows["/detections/deck_lidar/plane"] > 0
    # no mesh for a real feeder: its registered model at the estimated pose, and the estimate's ellipsoid
    assert "/estimates/feeder/body" not in rows and rows["/detections/feeder/model"] >= 1 and rows["/estimates/feeder/origin"] > 0
