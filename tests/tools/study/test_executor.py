"""Running a study (tools/study/executor.py) with a stand-in for the chain (run_task replaced by a
function of the task) and an executor that finishes one task at a time: runs.csv is rewritten
after every finished task, in task order; `--resume` keeps the finished rows byte for byte and
runs only the rest (failed rows again); a folder is never reused for another study; summary.csv
gives mean, standard deviation and the Student-t 95 % interval of the mean on known numbers."""

from __future__ import annotations

import csv
import math
from concurrent.futures import Executor, Future

import pytest

from boomtip.data.io.recording import RecordingError
from boomtip.tools.study import executor as ex
from boomtip.tools.study.tasks import Task

T_975_4 = 2.7764451051977987  # Student t, 97.5 % quantile, 4 degrees of freedom (tables: 2.776)
T_975_1 = 12.706204736174698  # 1 degree of freedom (tables: 12.706)
GRID = ["lidar.rate_hz"]


def fake_run_task(task: Task) -> dict:
    """A row as run_task returns it, from the task alone: a KPI that depends on the seed, a
    failure where the overrides ask for one."""
    failed = "fail" in task.overrides
    return {"task": task.id, **task.grid, "seed": task.seed, "status": "failed" if failed else "ok",
            "error": "ValueError: asked to fail" if failed else "", "wall_s": 0.25,
            **({} if failed else {"kpi.mae_D_m": task.seed / 1000 + 0.1, "kpi.samples": 100 + task.seed})}


def tasks(fail: str = "") -> list[Task]:
    out = []
    for rate in (5, 10):
        for seed in (1, 2, 3):
            tid = f"lidar.rate_hz={rate}|seed={seed}"
            out.append(Task(tid, "sts-empty", ("fail",) if tid == fail else (), 1.0, seed, {"lidar.rate_hz": rate}))
    return out


class OneAtATime(Executor):
    """Runs a task when it is submitted but finishes its future only when released: the first at
    once, each later one by `release()` (called once runs.csv has been written for the one before)."""

    def __init__(self) -> None:
        self.pending: list[tuple[Future, dict]] = []
        self.submitted: list[str] = []

    def submit(self, fn, /, *args, **kwargs):
        fut: Future = Future()
        self.submitted.append(args[0].id)
        self.pending.append((fut, fn(*args, **kwargs)))
        if len(self.submitted) == 1:
            self.release()
        return fut

    def release(self) -> None:
        if self.pending:
            fut, row = self.pending.pop(0)
            fut.set_result(row)


@pytest.fixture
def study(monkeypatch):
    """The executor, the runs.csv snapshots taken after each write and the progress calls."""
    monkeypatch.setattr(ex, "run_task", fake_run_task)
    pool = OneAtATime()
    snapshots: list[list[str]] = []
    real_write = ex.write_rows

    def write_and_release(path, rows, grid_keys):
        real_write(path, rows, grid_keys)
        snapshots.append([r["task"] for r in ex.read_rows(path)])
        pool.release()

    monkeypatch.setattr(ex, "write_rows", write_and_release)
    return pool, snapshots


def study_json(**changes) -> dict:
    return {"scenario": {"name": "sts-empty"}, "grid": GRID, "tasks": [t.id for t in tasks()], **changes}


# ---------------------------------------------------------------------------------------
# runs.csv


def test_runs_csv_is_rewritten_after_each_task_in_task_order(tmp_path, study):
    pool, snapshots = study
    all_tasks = tasks()
    ids = [t.id for t in all_tasks]
    done = [fake_run_task(all_tasks[1]), fake_run_task(all_tasks[4])]  # finished before: kept, not rerun
    progress: list[int] = []
    rows = ex.run_study(all_tasks, tmp_path, GRID, pool, done, progress.append)
    assert pool.submitted == [ids[0], ids[2], ids[3], ids[5]]
    # after each task the file holds what has finished so far, in the tasks' order; then once more at the end
    assert snapshots == [[ids[0], ids[1], ids[4]], [ids[0], ids[1], ids[2], ids[4]], [ids[0], ids[1], ids[2], ids[3], ids[4]],
                         ids, ids]
    assert progress == [2, 1, 1, 1, 1]  # the resumed rows at once, then one per task
    assert [r["task"] for r in rows] == ids


def test_done_rows_of_other_tasks_are_ignored(tmp_path, study):
    pool, _ = study
    stranger = {"task": "lidar.rate_hz=99|seed=1", "seed": 1, "status": "ok"}
    rows = ex.run_study(tasks(), tmp_path, GRID, pool, [stranger], None)
    assert len(pool.submitted) == 6 and stranger["task"] not in [r["task"] for r in rows]


def test_runs_csv_columns_and_exact_floats(tmp_path):
    rows = [{"task": "a", "seed": 1, "status": "ok", "error": "", "wall_s": 0.1 + 0.2, "lidar.rate_hz": 5,
             "z.kpi": 1 / 3, "a.kpi": None, "m.kpi": float("nan")},
            {"task": "b", "seed": 2, "status": "failed", "error": "ValueError: x, y", "wall_s": 1.5, "lidar.rate_hz": 10.0}]
    ex.write_rows(tmp_path / "runs.csv", rows, GRID)
    with open(tmp_path / "runs.csv", newline="") as fh:
        raw = list(csv.reader(fh))
    # task, the grid, seed, status, error, wall_s, then every other column sorted
    assert raw[0] == ["task", "lidar.rate_hz", "seed", "status", "error", "wall_s", "a.kpi", "m.kpi", "z.kpi"]
    assert raw[1] == ["a", "5", "1", "ok", "", "0.30000000000000004", "", "nan", "0.3333333333333333"]
    assert raw[2] == ["b", "10.0", "2", "failed", "ValueError: x, y", "1.5", "", "", ""]
    back = ex.read_rows(tmp_path / "runs.csv")
    assert back[0]["wall_s"] == 0.1 + 0.2 and back[0]["z.kpi"] == 1 / 3  # repr: the same float back
    assert back[0]["lidar.rate_hz"] == 5 and isinstance(back[0]["lidar.rate_hz"], int)
    assert back[1]["lidar.rate_hz"] == 10.0 and isinstance(back[1]["lidar.rate_hz"], float)
    assert back[0]["a.kpi"] == "" and math.isnan(back[0]["m.kpi"]) and back[1]["error"] == "ValueError: x, y"
    assert ex.read_rows(tmp_path / "missing.csv") == []


# ---------------------------------------------------------------------------------------
# The study folder and --resume


def test_resume_keeps_finished_rows_and_reruns_the_rest(tmp_path, study):
    pool, _ = study
    out = tmp_path / "study"
    all_tasks = tasks(fail="lidar.rate_hz=5|seed=2")
    ids = [t.id for t in all_tasks]
    assert ex.prepare_study_dir(out, False, False, study_json()) == []
    ex.run_study(all_tasks, out, GRID, pool, [], None)
    full = (out / "runs.csv").read_text().splitlines()
    assert len(full) == 7 and full[2].split(",")[3] == "failed"
    # a crash after four rows: the header and four rows are left
    (out / "runs.csv").write_text("\n".join(full[:5]) + "\n")

    done = ex.prepare_study_dir(out, False, True, study_json())
    assert [r["task"] for r in done] == [ids[0], ids[2], ids[3]]  # the failed row is not done
    assert done[0] == fake_run_task(all_tasks[0])  # the values come back as they were written
    again = _self_releasing(OneAtATime())  # the fixture's spy releases the first pool only
    rows = ex.run_study(tasks(), out, GRID, again, done, None)
    assert again.submitted == [ids[1], ids[4], ids[5]]  # the failed task (now without its failure) and the lost rows
    assert [r["status"] for r in rows] == ["ok"] * 6
    resumed = (out / "runs.csv").read_text().splitlines()
    assert [resumed[i] for i in (0, 1, 3, 4)] == [full[i] for i in (0, 1, 3, 4)]  # byte for byte


def _self_releasing(pool: OneAtATime) -> OneAtATime:
    """An executor that finishes every task at once (for a run without the runs.csv spy's release)."""
    original = pool.submit

    def submit(fn, /, *args, **kwargs):
        fut = original(fn, *args, **kwargs)
        pool.release()
        return fut

    pool.submit = submit  # type: ignore[method-assign]
    return pool


def test_resume_refuses_another_study_naming_what_changed(tmp_path):
    out = tmp_path / "study"
    ex.prepare_study_dir(out, False, False, study_json())
    with pytest.raises(RecordingError) as exc:
        ex.prepare_study_dir(out, False, True, study_json(grid=["lidar.rate_hz", "seed"], extra=1))
    assert "--resume with a different study (extra, grid changed)" in str(exc.value)


def test_a_non_empty_folder_needs_resume_or_force(tmp_path):
    out = tmp_path / "study"
    ex.prepare_study_dir(out, False, False, study_json())
    (out / "runs.csv").write_text("task\nx\n")
    with pytest.raises(RecordingError, match="is not empty; pass --resume"):
        ex.prepare_study_dir(out, False, False, study_json())
    assert ex.prepare_study_dir(out, True, False, study_json(grid=[])) == []  # --force: a fresh folder
    assert sorted(p.name for p in out.iterdir()) == ["study.json"]


def test_resume_of_a_folder_that_is_no_study(tmp_path):
    out = tmp_path / "other"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(RecordingError, match="not a study folder"):
        ex.prepare_study_dir(out, False, True, study_json())
    assert (out / "notes.txt").read_text() == "mine"


def test_unknown_executor_is_refused():
    with pytest.raises(RecordingError, match="--executor 'threads': expected local or dask"):
        ex.check_executor("threads")
    with pytest.raises(RecordingError, match="expected local or dask"):
        with ex.make_executor("threads"):
            pass


# ---------------------------------------------------------------------------------------
# summary.csv


def _summary(path) -> dict[tuple, dict]:
    with open(path, newline="") as fh:
        return {(r["lidar.rate_hz"], r["kpi"]): r for r in csv.DictReader(fh)}


def test_summary_gives_the_student_interval_on_known_numbers(tmp_path):
    rows = [{"task": f"a{i}", "lidar.rate_hz": 5, "seed": i, "status": "ok", "error": "", "mae": v}
            for i, v in enumerate([1.0, 2.0, 3.0, 4.0, 5.0])]
    rows += [{"task": "nan", "lidar.rate_hz": 5, "seed": 9, "status": "ok", "error": "", "mae": float("nan")},
             {"task": "bad", "lidar.rate_hz": 5, "seed": 8, "status": "failed", "error": "x", "mae": 100.0},
             {"task": "b1", "lidar.rate_hz": 10, "seed": 1, "status": "ok", "error": "", "mae": 2.0, "name": "text"},
             {"task": "b2", "lidar.rate_hz": 10, "seed": 2, "status": "ok", "error": "", "mae": 4.0, "flag": True}]
    ex.write_summary(tmp_path, rows, GRID)
    lines = (tmp_path / "summary.csv").read_text().splitlines()
    assert lines[0] == ("lidar.rate_hz,kpi,n,mean,std,ci95_lo,ci95_hi,median,median_ci95_lo,median_ci95_hi,"
                        "p2_5,p97_5")
    s = _summary(tmp_path / "summary.csv")
    assert set(s) == {("5", "mae"), ("10", "mae")}  # no seed, no text, no bool, no failed row
    five = s[("5", "mae")]
    std = math.sqrt(2.5)  # of 1..5, n - 1 in the denominator; the NaN and the failed run left out
    half = T_975_4 * std / math.sqrt(5)
    assert int(five["n"]) == 5 and float(five["mean"]) == 3.0
    assert float(five["std"]) == pytest.approx(std, rel=1e-15)
    assert float(five["ci95_lo"]) == pytest.approx(3.0 - half, rel=1e-14)
    assert float(five["ci95_hi"]) == pytest.approx(3.0 + half, rel=1e-14)
    ten = s[("10", "mae")]
    assert int(ten["n"]) == 2 and float(ten["mean"]) == 3.0
    assert float(ten["ci95_hi"]) == pytest.approx(3.0 + T_975_1 * math.sqrt(2.0) / math.sqrt(2), rel=1e-14)
    # the median, its interval (none from 5 values: the order statistics cannot give 95 %) and the spread
    assert float(five["median"]) == 3.0 and five["median_ci95_lo"] == "nan"
    assert float(five["p2_5"]) == pytest.approx(1.1) and float(five["p97_5"]) == pytest.approx(4.9)


def test_one_run_has_no_spread_and_no_interval(tmp_path):
    ex.write_summary(tmp_path, [{"task": "a", "lidar.rate_hz": 5, "seed": 1, "status": "ok", "error": "", "mae": 0.5}], GRID)
    assert (tmp_path / "summary.csv").read_text().splitlines()[1] == "5,mae,1,0.5,nan,nan,nan,0.5,nan,nan,0.5,0.5"


def test_a_resumed_boolean_grid_is_summarised_as_one_point(tmp_path, study):
    pool, _ = study
    grid = ["feeder.cargo"]
    all_tasks = [Task(f"feeder.cargo={c}|seed={s}", "sts-empty", (), 1.0, s, {"feeder.cargo": c})
                 for c in (True, False) for s in (1, 2)]
    out = tmp_path / "study"
    ex.prepare_study_dir(out, False, False, study_json(grid=grid))
    ex.run_study(all_tasks, out, grid, pool, [], None)
    full = (out / "runs.csv").read_text().splitlines()
    (out / "runs.csv").write_text("\n".join(full[:2]) + "\n")  # one row kept
    done = ex.prepare_study_dir(out, False, True, study_json(grid=grid))
    rows = ex.run_study(all_tasks, out, grid, _self_releasing(OneAtATime()), done, None)
    summary = ex.write_summary(out, rows, grid)
    points = [(r["feeder.cargo"], r["kpi"]) for r in summary if r["kpi"] == "kpi.mae_D_m"]
    assert len(points) == 2 and all(r["n"] == 2 for r in summary if r["kpi"] == "kpi.mae_D_m")


def test_a_local_worker_runs_its_libraries_on_one_thread_each():
    import os

    from boomtip.tools.study.executor import make_executor
    from boomtip.tools.study.worker_env import ONE_THREAD

    with make_executor("local", 1) as pool:
        got = {k: pool.submit(os.getenv, k).result() for k in ONE_THREAD}
    assert got == {k: os.environ.get(k, v) for k, v in ONE_THREAD.items()}  # the user's own setting wins


@pytest.mark.slow
def test_dask_runs_every_call_even_an_equal_one():
    import time

    from boomtip.tools.study.executor import make_executor

    with make_executor("dask", 1) as pool:
        calls = [pool.submit(time.perf_counter) for _ in range(2)]  # both held, as a study holds its tasks
        first, second = sorted(c.result() for c in calls)
    assert second > first  # dask's default (pure) would hand back the first call's result


def _pool_then_die(pid_file: str) -> None:
    """In a process of its own: a study's local pool, one task that says its worker's pid, then
    this process killed as a user kills a sweep (no chance to stop the pool)."""
    import os
    import signal

    from boomtip.tools.study.executor import make_executor

    with make_executor("local", 1) as pool:
        with open(pid_file, "w") as fh:
            fh.write(str(pool.submit(os.getpid).result()))
        os.kill(os.getpid(), signal.SIGKILL)


def test_a_local_worker_ends_when_the_sweep_that_started_it_is_killed(tmp_path):
    import multiprocessing
    import os
    import time

    from boomtip.tools.study.worker_env import PARENT_POLL_S

    pid_file = tmp_path / "worker.pid"
    parent = multiprocessing.get_context("spawn").Process(target=_pool_then_die, args=(str(pid_file),))
    parent.start()
    parent.join(60)
    assert parent.exitcode == -9
    worker = int(pid_file.read_text())

    def alive() -> bool:
        try:
            os.kill(worker, 0)
        except ProcessLookupError:
            return False
        with open(f"/proc/{worker}/stat") as fh:  # a zombie is gone but for its parent's wait
            return fh.read().split(")")[-1].split()[0] != "Z"

    deadline = time.monotonic() + 5 * PARENT_POLL_S + 5.0
    while alive() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not alive()
