"""The hook run's samples kept on disk (tools.hook_store), the per-frame rows as columns
(tools.hook_rows), and the KPIs and CSVs computed from them a chunk at a time: the same figures,
to the last bit, as from the whole series in memory."""

from __future__ import annotations

import math

import numpy as np
import pytest

import boomtip.fusion.hook_run as hook_run
from boomtip.data.crane_model import CraneParams
from boomtip.data.frames import Truth
from boomtip.data.sim.crane_joints import CraneJointProfiles
from boomtip.data.sim.crane_truth import simulate_crane
from boomtip.data.sim.hook_measurements import measurements_from_truth
from boomtip.data.sim.vessel_waves import VesselWaves
from boomtip.fusion.hook_run import run_hook_filter
from boomtip.tools.report import hook as hook_outputs
from boomtip.tools.report import hook_store
from boomtip.tools.report.hook_eval import world_hook_from_states
from boomtip.tools.report.hook_rows import COLUMNS, FrameRows
from boomtip.data.io.atomic import atomic_text_file
from boomtip.tools.report.hook_store import EstimateStore

DEG = math.pi / 180


@pytest.fixture(scope="module")
def crane():
    joints = CraneJointProfiles.from_moves(90 * DEG, 30 * DEG, 80.0, slew_moves=[(3.0, 80 * DEG)])
    return simulate_crane(CraneParams(), joints, VesselWaves.regular(1.0, 8.0), 8.0)


@pytest.fixture(scope="module")
def runs(crane):
    """The same run kept in memory and sent to a store, in chunks of 97 samples (several chunks,
    a short last one)."""
    mp = pytest.MonkeyPatch()
    mp.setattr(hook_run, "_OUTPUT_CHUNK", 97)
    mp.setattr(hook_store, "READ_CHUNK", 89)  # read back in other chunks than written
    meas = measurements_from_truth(crane, seed=3)
    full = run_hook_filter(meas, "ekf", "flexible")
    store = EstimateStore(CraneParams())
    streamed = run_hook_filter(meas, "ekf", "flexible", sink=store)
    yield full, streamed, store
    mp.undo()
    store.close()


def _truth(crane) -> Truth:
    cols = {"t": crane.t}
    for prefix, name in (("hook_", "p_hook_world"), ("hook_v", "v_hook_world"), ("hook_rel_", "p_hook_rel_tip"),
                         ("hook_rel_v", "v_hook_rel_tip")):
        for k, a in enumerate("xyz"):
            cols[prefix + a] = getattr(crane, name)[:, k]
    return Truth(cols)


def test_a_run_sent_to_a_sink_keeps_no_sample_and_stores_them_all(runs):
    full, streamed, store = runs
    assert streamed.x is None and streamed.p_rel is None and streamed.t is None
    assert store.n == streamed.n_samples == full.n_samples == len(full.t) > 3 * 97 and store.n % 97
    assert (streamed.n_lidar_accepted, streamed.n_rope_accepted) == (full.n_lidar_accepted, full.n_rope_accepted)
    assert streamed.runtime_s > 0 and streamed.cpu_s >= 0
    t, p_rel = store.columns(hook_store.P_REL)
    np.testing.assert_array_equal(t, full.t)
    np.testing.assert_array_equal(p_rel, full.p_rel)
    _, _, p, v = world_hook_from_states(CraneParams(), full.x)
    np.testing.assert_array_equal(store.columns(hook_store.P)[1], p)
    np.testing.assert_array_equal(store.columns(hook_store.V)[1], v)
    t4, v_rel4 = store.columns(hook_store.V_REL, every=4)
    np.testing.assert_array_equal(t4, full.t[::4])
    np.testing.assert_array_equal(v_rel4, full.v_rel[::4])
    cov = np.concatenate([c.cov_p for c in store.chunks()])
    np.testing.assert_array_equal(cov, full.cov_p)
    assert [len(c.t) for c in store.chunks()][:2] == [89, 89]


def test_the_states_digest_tells_equal_runs_from_different_ones(crane, runs):
    _, _, store = runs
    meas = measurements_from_truth(crane, seed=3)
    again, other = EstimateStore(CraneParams()), EstimateStore(CraneParams())
    run_hook_filter(meas, "ekf", "flexible", sink=again)
    run_hook_filter(measurements_from_truth(crane, seed=4), "ekf", "flexible", sink=other)
    assert again.states_sha1 == store.states_sha1 != other.states_sha1


def _kpis_in_memory(run, truth: Truth, params) -> dict:
    """The KPIs as computed on the whole series in memory (the chain's code before the store)."""
    t_from = 5.0 if np.any(run.t >= 5.0) else float(run.t[0])
    keep = (run.t >= t_from) & (run.t <= truth.end_s)
    t = run.t[keep]
    _, _, p_hook, v_hook = world_hook_from_states(params, run.x[keep])
    ep = p_hook - np.column_stack([truth.at(f"hook_{a}", t) for a in "xyz"])
    ev = v_hook - np.column_stack([truth.at(f"hook_v{a}", t) for a in "xyz"])
    e_rel = run.p_rel[keep] - np.column_stack([truth.at(f"hook_rel_{a}", t) for a in "xyz"])
    ev_rel = run.v_rel[keep] - np.column_stack([truth.at(f"hook_rel_v{a}", t) for a in "xyz"])
    nees = np.einsum("ni,ni->n", e_rel, np.linalg.solve(run.cov_p[keep], e_rel[..., None])[..., 0])
    return {"rmse_pos_m": np.sqrt(np.mean(ep**2, axis=0)).tolist(), "rmse_vel_mps": np.sqrt(np.mean(ev**2, axis=0)).tolist(),
            "max_pos_m": np.abs(ep).max(axis=0).tolist(), "max_vel_mps": np.abs(ev).max(axis=0).tolist(),
            "rmse_rel_pos_m": np.sqrt(np.mean(e_rel**2, axis=0)).tolist(),
            "rmse_rel_vel_mps": np.sqrt(np.mean(ev_rel**2, axis=0)).tolist(), "evaluated_from_s": t_from,
            "nees_pos_mean": float(np.mean(nees)), "nees_pos_within_95": float(np.mean(nees < hook_outputs.CHI2_3_95))}


def test_kpis_from_the_store_equal_those_of_the_whole_series_to_the_last_bit(crane, runs):
    full, streamed, store = runs
    truth = _truth(crane)
    got = hook_outputs.estimator_kpis(streamed, store, truth)
    want = _kpis_in_memory(full, truth, CraneParams())
    assert {k: got[k] for k in want} == want
    assert got["evaluated_from_s"] == 5.0 and 0 < got["rmse_pos_m"][0] < 0.1


def test_the_estimates_csv_is_written_from_the_store(tmp_path, runs):
    full, _, store = runs
    hook_outputs.write_estimates(tmp_path / "e.csv", {"ekf_flexible": store})
    lines = (tmp_path / "e.csv").read_text().splitlines()
    assert lines[0].startswith("t,estimator,x,y,z,vx") and len(lines) == 1 + len(full.t)
    _, _, p, v = world_hook_from_states(CraneParams(), full.x)
    k = 200
    want = [f"{full.t[k]:.4f}", "ekf_flexible"] + [f"{x:.5f}" for x in (*p[k], *v[k], *full.p_rel[k], *full.v_rel[k])]
    assert lines[1 + k].split(",") == want
    assert [f.name for f in tmp_path.iterdir()] == ["e.csv"]  # no temporary left


def test_a_failed_atomic_write_leaves_no_file(tmp_path):
    with pytest.raises(RuntimeError), atomic_text_file(tmp_path / "a.csv") as fh:
        fh.write("half")
        raise RuntimeError("stop")
    assert list(tmp_path.iterdir()) == []


def _row(i: int, status: str) -> dict:
    nan = float("nan")
    return {"t": 0.05 * i, "status": status, "x": 1.0 + i if status == "ok" else nan, "y": 2.0, "z": np.float64(-60.5),
            "sigma_x_m": 0.1, "sigma_y_m": 0.1, "sigma_z_m": 0.2, "n_points": 40 + i, "fit_rms_m": 0.02,
            "precision": 1.0, "recall": 0.5, "hook_points_true": i, "tracker_accepted": np.bool_(i % 2),
            "pred_x": 0.0, "pred_y": 0.0, "pred_z": -60.0, "pred_sigma_across_m": 0.3, "rope_status": "ok",
            "rope_points": 300, "rope_ux": 0.0, "rope_uy": 0.6, "rope_uz": -0.8, "rope_sigma_across_m": 0.01,
            "rope_radius_m": 0.04, "rope_accepted": True, "rope_precision": nan, "time_ms": 12.25}


def test_frame_rows_keep_the_values_and_their_types(tmp_path):
    rows = FrameRows()
    cov = np.arange(9.0).reshape(3, 3)
    rows.append(_row(0, "ok"), cov, np.array([0.0, 0.6, -0.8]), np.eye(3))
    rows.append(_row(1, 'far "block"'), cov + 1, None, None)
    assert len(rows) == 2
    np.testing.assert_array_equal(rows["x"], [1.0, np.nan])
    assert rows["n_points"].dtype == np.int64 and rows["tracker_accepted"].tolist() == [False, True]
    assert rows["status"].tolist() == ["ok", 'far "block"']
    np.testing.assert_array_equal(rows.cov_m2[1], cov + 1)
    np.testing.assert_array_equal(rows.rope_direction, [[0.0, 0.6, -0.8], [np.nan] * 3])
    assert np.isnan(rows.rope_cov[1]).all() and (rows.rope_cov[0] == np.eye(3)).all()
    assert rows.row(1)["tracker_accepted"] is True and rows.row(0)["z"] == -60.5
    rows.append(_row(2, "ok"), cov, None, None)  # columns handed out do not stop it growing
    hook_outputs.write_rows(tmp_path / "m.csv", rows)
    lines = (tmp_path / "m.csv").read_text().splitlines()
    assert lines[0] == ",".join(COLUMNS)
    assert lines[2] == ('0.05,"far \'block\'",,2,-60.5,0.1,0.1,0.2,41,0.02,1,0.5,1,True,0,0,-60,0.3,"ok",300,0,0.6,-0.8,'
                        '0.01,0.04,True,,12.25')
    assert len(lines) == 4


def test_frame_kpis_from_the_columns(tmp_path):
    rows = FrameRows()
    for i in range(6):
        rows.append(_row(i, "ok" if i < 4 else "sparse"), np.eye(3), None, None)
    t = np.linspace(0, 1, 21)
    cols = {"t": t, **{f"hook_rel_{a}": np.full(21, v) for a, v in zip("xyz", (2.0, 2.0, -60.0))}}
    seg = hook_outputs.segmentation_kpis(rows, Truth(cols))
    assert seg["frames_in_view"] == 5 and seg["precision"] == 1.0 and seg["recall"] == 0.5
    # the model fits: x = 1 + i for i = 0..3 against 2: errors -1, 0, 1, 2
    np.testing.assert_allclose(seg["rmse_m"], [math.sqrt(1.5), 0.0, 0.5], rtol=1e-12)
    assert np.isnan(seg["sparse_rmse_m"][0])  # the sparse rows have no x
    rope = hook_outputs.rope_kpis(rows, None)
    assert rope == {"found_fraction": 1.0, "accepted_fraction": 1.0, "points_median": 300.0, "radius_median_m": 0.04}


def test_frame_rows_read_back_across_the_file_and_the_buffer(monkeypatch):
    """Records on disk (whole chunks) and in the buffer read back alike: whole columns and single
    rows on either side."""
    from boomtip.tools.report import hook_rows

    monkeypatch.setattr(hook_rows, "CHUNK", 7)  # 30 rows: 4 chunks on disk, 2 in the buffer
    rows = FrameRows()
    for i in range(30):
        row = _row(i, "ok" if i % 3 else "sparse")
        row["n_points"] = 1000 + i
        rows.append(row, np.full((3, 3), float(i)), np.array([i, 0.0, -1.0]) if i % 2 else None, None)
    assert len(rows) == 30
    np.testing.assert_array_equal(rows["n_points"], 1000 + np.arange(30))
    np.testing.assert_array_equal(rows.cov_m2[:, 1, 2], np.arange(30.0))
    np.testing.assert_array_equal(rows.rope_direction[1::2, 0], np.arange(1, 30, 2))
    assert np.isnan(rows.rope_direction[::2]).all()
    for i in (0, 6, 7, 27, 28, 29, -1):
        assert rows.row(i)["n_points"] == 1000 + (i % 30) and rows.row(i)["status"] == ("ok" if (i % 30) % 3 else "sparse")


def test_a_disk_table_reads_back_its_rows_by_slices(monkeypatch):
    """The chain's encoder and MRU tables on disk: any row slice (across the written chunks, empty,
    open-ended) and the whole table equal the array's, and only slices are read."""
    from boomtip.tools.report import hook_rows

    monkeypatch.setattr(hook_rows, "CHUNK", 2)  # written 16 rows at a time: 50 rows in 4 writes
    table = np.random.default_rng(3).standard_normal((50, 4))
    disk = hook_rows.DiskTable(table)
    assert len(disk) == 50 and disk.shape == (50, 4)
    for rows in (slice(0, 1), slice(15, 17), slice(31, 50), slice(49, 60), slice(20, 20), slice(None, 5), slice(-3, None)):
        np.testing.assert_array_equal(disk[rows], table[rows])
        assert disk[rows].shape == table[rows].shape
    np.testing.assert_array_equal(np.asarray(disk), table)
    with pytest.raises(TypeError):
        disk[3]
    with pytest.raises(TypeError):
        disk[::2]
    disk.close()


def test_without_truth_the_path_is_read_from_the_store_as_from_the_whole_series(runs):
    full, _, store = runs
    _, _, p, v = world_hook_from_states(CraneParams(), full.x)
    path = hook_outputs.estimated_path(store)
    assert path["samples"] == len(full.t) and path["last_t_s"] == full.t[-1]
    assert path["min_m"] == [round(float(x), 4) for x in p.min(axis=0)] and path["max_m"] == [round(float(x), 4) for x in p.max(axis=0)]
    assert path["top_speed_mps"] == round(float(np.linalg.norm(v, axis=1).max()), 4)
    sig = np.sqrt(np.diagonal(full.cov_p, axis1=1, axis2=2))
    # every 10th sample of each read chunk (89 here): close to the whole series' median
    np.testing.assert_allclose(path["median_sigma_rel_m"], np.median(sig, axis=0), rtol=0.05)
    assert hook_outputs.estimated_path(EstimateStore(CraneParams())) == {"samples": 0}
