"""Studies: grids, derived seeds, summaries with confidence intervals, resume, failed runs,
and the same rows from local processes and a Dask cluster."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from scipy.stats import t as student_t
from typer.testing import CliRunner

from boomtip.tools.cli.commands import app
from boomtip.tools.study.tasks import TIMING_KEYS, Task, axis_from_grid, derived_seeds, flatten, run_task, summarise, sweep_tasks

pytestmark = pytest.mark.slow  # every test here runs a chain end to end

runner = CliRunner()
SHORT = ["-s", "sts-empty", "--duration", "0.6"]


def _rows(path, drop_timing=True):
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    if drop_timing:
        rows = [{k: v for k, v in r.items() if not any(t in k for t in TIMING_KEYS)} for r in rows]
    return rows


def test_the_grid_is_the_product_of_its_axes_and_seeds_are_derived():
    a, b = axis_from_grid("lidar.rate_hz=5,10,20"), axis_from_grid("mismatch.mru_lag_s=0,0.01")
    tasks = sweep_tasks("sts-empty", [a, b], 3, ["duration_s=1"], None, 7)
    assert len(tasks) == 3 * 2 * 3 and len({t.id for t in tasks}) == 18
    assert tasks[0].grid == {"lidar.rate_hz": 5, "mismatch.mru_lag_s": 0}
    assert tasks[0].overrides == ("duration_s=1", "lidar.rate_hz=5", "mismatch.mru_lag_s=0")
    seeds = derived_seeds(7, 3)
    assert seeds[0] == 7 and len(set(seeds)) == 3 and seeds == derived_seeds(7, 3)
    assert derived_seeds(8, 3) != seeds
    with pytest.raises(ValueError, match="KEY=V1"):
        axis_from_grid("lidar.rate_hz")


def test_summary_gives_mean_std_and_a_student_interval():
    rows = [{"task": str(i), "k": 1, "seed": i, "status": "ok", "x": v} for i, v in enumerate([1.0, 2.0, 4.0])]
    rows.append({"task": "f", "k": 1, "seed": 9, "status": "failed", "x": 100.0})
    (s,) = [r for r in summarise(rows, ["k"]) if r["kpi"] == "x"]
    assert s["n"] == 3 and s["mean"] == pytest.approx(7 / 3)
    assert s["std"] == pytest.approx(np.std([1, 2, 4], ddof=1))
    half = student_t.ppf(0.975, 2) * s["std"] / np.sqrt(3)
    assert s["ci95_hi"] - s["mean"] == pytest.approx(half)


def test_kpis_flatten_to_one_level():
    assert flatten({"a": {"b": 1.5, "c": [1, 2]}, "d": "x"}) == {"a.b": 1.5, "a.c.0": 1, "a.c.1": 2, "d": "x"}


def test_a_failed_run_is_a_row_with_its_error():
    row = run_task(Task("bad", "sts-empty", ("lidar.rate_hz=-1",), 0.5, 1))
    assert row["status"] == "failed" and "rate_hz" in row["error"] and row["wall_s"] >= 0


def test_a_sweep_on_dask_gives_the_local_rows_and_resumes(tmp_path):
    args = ["sweep", *SHORT, "--grid", "lidar.rate_hz=5,10", "--seeds", "2", "--workers", "2"]
    r = runner.invoke(app, [*args, "--out", str(tmp_path / "local")])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, [*args, "--out", str(tmp_path / "dask"), "--executor", "dask"])
    assert r.exit_code == 0, r.output
    local, dask = _rows(tmp_path / "local" / "runs.csv"), _rows(tmp_path / "dask" / "runs.csv")
    assert len(local) == 4 and all(row["status"] == "ok" for row in local)
    assert local == dask  # bit for bit, timings aside
    assert float(local[0]["measurements.deck_lidar.valid_fraction"]) == 1.0
    summary = _rows(tmp_path / "local" / "summary.csv", drop_timing=False)
    assert {row["lidar.rate_hz"] for row in summary} == {"5", "10"}
    meta = json.loads((tmp_path / "local" / "sweep.json").read_text())
    assert meta["tasks"] == 4 and meta["ok"] == 4 and meta["scenario"]["name"] == "sts-empty"
    # a non-empty --out is refused; --resume keeps the finished runs and does the rest, of the same study only
    assert runner.invoke(app, [*args, "--out", str(tmp_path / "local")]).exit_code == 2
    other = ["sweep", *SHORT, "--grid", "lidar.rate_hz=5,20", "--seeds", "2", "--workers", "2"]
    r = runner.invoke(app, [*other, "--out", str(tmp_path / "local"), "--resume"])
    assert r.exit_code == 2 and "different study" in r.output
    full = (tmp_path / "local" / "runs.csv").read_text().splitlines()
    (tmp_path / "local" / "runs.csv").write_text("\n".join(full[:3]) + "\n")  # two of four kept
    r = runner.invoke(app, [*args, "--out", str(tmp_path / "local"), "--resume"])
    assert r.exit_code == 0, r.output
    resumed = (tmp_path / "local" / "runs.csv").read_text().splitlines()
    assert resumed[:3] == full[:3] and len(resumed) == 5  # the kept rows untouched, byte for byte


def test_batch_processes_many_recordings(tmp_path):
    for name, seed in (("a", "1"), ("b", "2")):
        assert runner.invoke(app, ["simulate", *SHORT, "--seed", seed, "--set", "lidar.range_noise_m=0.02",
                                   "--out", str(tmp_path / name)]).exit_code == 0
    r = runner.invoke(app, ["batch", str(tmp_path / "a"), str(tmp_path / "b"), str(tmp_path / "a"), "--out",
                            str(tmp_path / "batch"), "--workers", "1"])
    assert r.exit_code == 0, r.output
    rows = _rows(tmp_path / "batch" / "runs.csv")
    assert [row["status"] for row in rows] == ["ok", "ok", "ok"]
    assert rows[0]["measurements.deck_lidar.mae"] == rows[2]["measurements.deck_lidar.mae"]  # same recording
    assert rows[0]["measurements.deck_lidar.mae"] != rows[1]["measurements.deck_lidar.mae"]  # another one
    r = runner.invoke(app, ["batch", str(tmp_path / "nope"), "--out", str(tmp_path / "b2")])
    assert r.exit_code == 2 and "nope" in r.output


def test_force_never_deletes_the_current_folder_or_a_parent(tmp_path, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    (tmp_path / "keep.txt").write_text("mine")
    monkeypatch.chdir(work)
    for out in ("..", ".", str(tmp_path)):
        r = runner.invoke(app, ["sweep", *SHORT, "--grid", "lidar.rate_hz=5", "--out", out, "--force"])
        assert r.exit_code == 2 and "name a folder" in r.output or "parents" in r.output, r.output
    r = runner.invoke(app, ["sweep", *SHORT, "--grid", "lidar.rate_hz=5", "--out", "s", "--executor", "nope"])
    assert r.exit_code == 2 and "--executor" in r.output
    assert (tmp_path / "keep.txt").read_text() == "mine" and work.is_dir()


def test_the_median_interval_is_the_binomial_order_statistics():
    import numpy as np

    from boomtip.tools.study.tasks import median_interval

    assert median_interval(np.arange(1.0, 21.0)) == (6.0, 15.0)  # n = 20: x(6) and x(15), 95.9 %
    assert median_interval(np.arange(10.0, 0.0, -1.0)) == (2.0, 9.0)  # unsorted in, n = 10: x(2), x(9)
    assert all(v != v for v in median_interval(np.arange(5.0)))
